"""``calibrate()`` across its options: distortion models, robot noise, losses, the linear
estimate alone, known parameters and the re-judging branch after refinement."""

from __future__ import annotations

import numpy as np
import pytest

from transcalib import CalibrateOptions, InputError, RansacOptions, RefineOptions, calibrate, simulate
from transcalib.geometry.rotation import rotation_angle_deg


def _scene(dist=(), noise_px=0.0, robot_noise=0.0, n=150, views=5, seed=3):
    return simulate.random_scene(n, views, dist=dist, noise_px=noise_px, robot_noise=robot_noise, rng=seed)


@pytest.mark.parametrize("model,exact", [("none", False), ("radial1", False), ("radial2", True), ("opencv5", True)])
def test_each_distortion_model(model, exact):
    scene = _scene(dist=(-0.12, 0.03))
    cal = calibrate(scene.uv, scene.T, distortion=model)
    assert cal.dist_model == model and cal.dist.size == {"none": 0, "radial1": 1, "radial2": 2, "opencv5": 5}[model]
    assert cal.options.refinement.distortion == model
    err = np.abs(cal.K - scene.K).max() / scene.K[0, 0]
    if exact:  # the model contains the truth: exact on noise-free data
        assert err < 1e-9 and np.allclose(cal.dist_opencv[:2], [-0.12, 0.03], atol=1e-9)
    else:
        assert err > 1e-6  # a model without k2 cannot fit k2 exactly


def test_sigma_T_models_robot_noise():
    scene = _scene(noise_px=0.3, robot_noise=0.5, seed=4)
    cal = calibrate(scene.uv, scene.T, sigma_T=0.5, rng=0)
    assert cal.options.refinement.sigma_T == 0.5
    assert "T_std" in cal.info and cal.info["T_std"].shape == (5, 3)
    assert not np.allclose(cal.T, scene.T)  # the translations were refined
    assert np.all(cal.info["T_std"][1:] > 0)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_each_robust_loss_marks_corrupted_observations(loss):
    scene = _scene(noise_px=0.5, seed=5)
    uv = scene.uv.copy()
    bad = np.flatnonzero(np.isfinite(uv[2, :, 0]))[:6]
    uv[2, bad] += 25.0  # six corrupted observations
    cal = calibrate(uv, scene.T, robust=False, refinement=RefineOptions(loss=loss, loss_scale_px=1.0))
    assert cal.options.refinement.loss == loss
    good = np.ones(scene.n_points, bool)
    good[bad] = False
    assert not cal.inliers[bad].any() and cal.inliers[good].mean() > 0.97
    assert abs(cal.K[0, 0] / scene.K[0, 0] - 1) < 5 * cal.std["fx"] / scene.K[0, 0]


def test_refine_false_returns_the_linear_estimate():
    scene = _scene(noise_px=0.5, seed=6)
    cal = calibrate(scene.uv, scene.T, refine=False, rng=0)
    assert cal.info["stages"] == ["robust"] and cal.cov is None and cal.std == {}
    np.testing.assert_array_equal(cal.K, cal.linear.K)


@pytest.mark.parametrize("kw", [{"sigma_T": 0.1}, {"distortion": "radial2"}, {"fix": {"cx": 400.0}},
                                {"refinement": RefineOptions(loss="huber")}])
def test_options_without_effect_raise(kw):
    scene = _scene(seed=7)
    with pytest.raises(InputError):
        calibrate(scene.uv, scene.T, refine=False, **kw)


def test_ransac_options_without_robust_raise():
    scene = _scene(seed=7)
    with pytest.raises(InputError, match="robust=False"):
        calibrate(scene.uv, scene.T, robust=False, ransac=RansacOptions(threshold_px=3.0))


def test_misspelt_option_fails_loudly():
    with pytest.raises(TypeError):
        RefineOptions(distorsion="radial2")
    with pytest.raises(InputError, match="fix"):
        RefineOptions(fix={"cz": 1.0})


def test_options_are_recorded():
    scene = _scene(noise_px=0.3, seed=8)
    refinement = RefineOptions(distortion="radial2", estimate_skew=True)
    cal = calibrate(scene.uv, scene.T, refinement=refinement, rng=1, unit="mm")
    assert cal.options == CalibrateOptions(refinement=refinement, unit="mm")
    assert "skew" in cal.std


def test_known_principal_point_and_square_pixels_exact():
    scene = _scene(seed=9)
    cx, cy = scene.K[0, 2], scene.K[1, 2]
    cal = calibrate(scene.uv, scene.T, fix={"cx": cx, "cy": cy})
    assert cal.K[0, 2] == cx and cal.K[1, 2] == cy and "cx" not in cal.std
    assert np.abs(cal.K - scene.K).max() < 1e-9 * scene.K[0, 0]
    assert rotation_angle_deg(cal.R @ scene.R.T) < 1e-9


def test_rejudging_after_refinement_recovers_tracks_under_strong_distortion():
    """RANSAC judges tracks with the distortion-free linear camera; the refined camera
    with distortion takes back the good tracks it rejected."""
    scene = simulate.random_scene(300, 5, dist=(-0.35, 0.12), noise_px=0.2, rng=11)
    cal = calibrate(scene.uv, scene.T, distortion="radial2", ransac=RansacOptions(threshold_px=1.0), rng=0)
    assert "reclassify+refine" in cal.info["stages"]
    assert cal.inliers.mean() > 0.98
    assert abs(cal.K[0, 0] / scene.K[0, 0] - 1) < 1e-3
