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
    assert cal.T_std is not None and cal.T_std.shape == (5, 3)
    assert not np.allclose(cal.T, scene.T)  # the translations were refined
    assert np.all(cal.T_std[1:] > 0)


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
    assert cal.stats.stages == ("robust",) and cal.cov is None and cal.std == {}
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
    assert "reclassify+refine" in cal.stats.stages
    assert cal.inliers.mean() > 0.98
    assert abs(cal.K[0, 0] / scene.K[0, 0] - 1) < 1e-3


def test_precise_tracks_under_distortion_are_all_taken_back():
    """With tracks of 0.02 px under mild distortion RANSAC's distortion-free camera keeps
    a central patch (39 of 1500 tracks here); the lens fitted there extrapolates badly
    to the corners. The inliers grow round by round, and the lens is chosen again on
    each much larger set: every good track comes back (before, three rounds with the
    patch's lens ended at 1114 of 1500)."""
    scene = simulate.random_scene(1500, 12, noise_px=0.02, dist=(-0.06, 0.02), rng=3)
    events = []
    cal = calibrate(scene.uv, scene.T, image_size=scene.image_size, rng=0, progress=events.append)
    assert [e.info["inliers"] for e in events if e.stage == "robust"][0] < 100
    assert "reclassify+refine (lens chosen again)" in cal.stats.stages
    assert cal.inliers.sum() > 0.97 * len(cal.inliers)
    assert cal.dist_model == "radial2"
    assert abs(cal.K[0, 0] - scene.K[0, 0]) < 3 * cal.std["fx"]


def test_tracks_whose_noise_differs_stay_in():
    """800 tracks of 12 views, each with its own noise (log-normal about 0.3 px, spread
    0.6 in the log variance: a tracker's texture and contrast): judged with one sigma a
    quarter of these good tracks were out and the noise came out 18 % low (30 scenes:
    76 % kept, sigma 0.82 of the tracks' RMS noise); judged again with the spread their
    halves of views show, 99 % stay and sigma is their RMS noise (0.99)."""
    scene = simulate.random_scene(800, 12, rng=4)
    rng = np.random.default_rng(4)
    s = 0.3 * np.exp(0.5 * (0.6 * rng.normal(size=800) - 0.18))
    uv = scene.uv + rng.normal(size=scene.uv.shape) * s[None, :, None]
    cal = calibrate(uv, scene.T, rng=0, check_rotation=False)
    one = calibrate(uv, scene.T, rng=0, check_rotation=False, ransac=RansacOptions(noise_spread=False))
    assert any(st.startswith("noise spread") for st in cal.stats.stages)
    assert not any(st.startswith("noise spread") for st in one.stats.stages)
    assert cal.inliers.mean() > 0.97 and one.inliers.mean() < 0.85
    rms = np.sqrt(np.mean(s**2))
    assert abs(cal.sigma_px / rms - 1) < 0.05 and one.sigma_px < 0.9 * rms
    assert abs(cal.K[0, 0] - scene.K[0, 0]) < 3 * cal.std["fx"]


def test_noise_spread_with_a_subset_of_the_tracks():
    """6000 tracks (above the 5000 of the iterative stages' subset) whose noise differs:
    the pass judges the subset again, refits it and then every track, which nearly all
    stay (one sigma's rule would leave a quarter out), with sigma their RMS noise."""
    scene = simulate.random_scene(6000, 8, rng=5)
    rng = np.random.default_rng(5)
    s = 0.3 * np.exp(0.5 * (0.6 * rng.normal(size=6000) - 0.18))
    cal = calibrate(scene.uv + rng.normal(size=scene.uv.shape) * s[None, :, None], scene.T, rng=0,
                    check_rotation=False)
    assert cal.stats.stages[-2].startswith("noise spread: refine") and cal.stats.stages[-1] == "all tracks"
    assert cal.inliers.mean() > 0.99 and abs(cal.sigma_px / np.sqrt(np.mean(s**2)) - 1) < 0.02
    assert abs(cal.K[0, 0] - scene.K[0, 0]) < 3 * cal.std["fx"] and cal.X.shape == (6000, 3)


# --------------------------------------------------------------------------------------
# Many tracks: the iterative stages on a subset, then one Gauss-Newton step with all
# --------------------------------------------------------------------------------------

_INTRINSICS = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}


def test_subset_then_one_step_is_the_full_maximum_likelihood():
    """Oracle: refinement of every track to convergence (subset_points=None). Without a
    robust stage both fit the same data, so the Gauss-Newton steps must land on the same
    optimum to a small fraction of the standard deviations (the subset alone is ~2.4 std
    off; observed after the steps: 4e-4 std)."""
    scene = simulate.random_scene(3000, 5, dist=(-0.05, 0.01), noise_px=1.0, rng=11)
    full = calibrate(scene.uv, scene.T, robust=False, distortion="radial2", subset_points=None)
    fast = calibrate(scene.uv, scene.T, robust=False, distortion="radial2", subset_points=500, rng=1)
    assert fast.stats.stages[-1] == "all tracks" and fast.stats.subset.n_points_used == 500
    assert "all tracks" not in full.stats.stages
    for name, (a, b) in _INTRINSICS.items():
        assert abs(fast.K[a, b] - full.K[a, b]) < 0.005 * full.std[name], name
        assert fast.std[name] == pytest.approx(full.std[name], rel=1e-3)
    assert np.max(np.abs(fast.dist - full.dist) / np.array([full.std["k1"], full.std["k2"]])) < 0.005
    assert fast.sigma_px == pytest.approx(full.sigma_px, rel=1e-4)
    assert np.nanmax(np.abs(fast.X - full.X) / full.X_std) < 0.005
    assert np.nanmax(np.abs(fast.X_std / full.X_std - 1)) < 1e-2
    assert fast.X.shape == (3000, 3) and np.isfinite(fast.X).all()


def test_subset_path_exact_on_noise_free_data_and_judges_every_track():
    scene = simulate.random_scene(2000, 5, dist=(-0.08, 0.02), noise_px=0.0, rng=5)
    uv = scene.uv.copy()
    every_tenth = np.arange(0, 2000, 10)
    bad = every_tenth[np.isfinite(uv[2, every_tenth, 0])]  # ~10 % of the tracks corrupted in one view
    uv[2, bad] += 40.0
    cal = calibrate(uv, scene.T, subset_points=400, rng=0)
    assert cal.stats.stages[-1] == "all tracks"
    assert np.abs(cal.K - scene.K).max() / scene.K[0, 0] < 1e-9
    assert cal.dist_model == "radial2" and np.allclose(cal.dist, [-0.08, 0.02], atol=1e-9)
    assert set(np.flatnonzero(~cal.inliers)) == set(bad)
    assert cal.linear.X.shape == (2000, 3) and cal.linear.used.sum() <= 400
    assert np.array_equal(np.isfinite(cal.residuals_px[:, bad]), np.isfinite(uv[:, bad]))  # outliers too


def test_subset_points_is_checked_and_recorded():
    scene = _scene(noise_px=0.5)
    with pytest.raises(InputError, match="subset_points"):
        calibrate(scene.uv, scene.T, subset_points=10)
    with pytest.raises(InputError, match="subset_points"):
        CalibrateOptions(subset_points=2.5)
    cal = calibrate(scene.uv, scene.T, subset_points=100, rng=0)
    assert cal.options.subset_points == 100 and cal.stats.stages[-1] == "all tracks"
    assert calibrate(scene.uv, scene.T, rng=0).stats.stages[-1] != "all tracks"  # 150 <= the default
