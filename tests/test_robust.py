"""Robust estimation: the two-point minimal solver and LO-MSAC (transcalib.estimate.robust)."""

import numpy as np
import pytest

from transcalib import simulate
from transcalib.estimate.minimal import solve_minimal
from transcalib.estimate.robust import RobustEstimate, estimate_robust, point_errors
from transcalib.types import DegenerateError, InputError, RansacOptions


def _A_true(scene):
    A = scene.K @ scene.R
    return A / np.linalg.norm(A[2])


def plant_outliers(scene, fraction, rng, uv=None):
    """Replace 1..n_views-1 observations of a random ``fraction`` of the tracks by random
    pixels (gross mismatches). Returns (uv, outlier mask)."""
    rng = np.random.default_rng(rng)
    uv = (scene.uv if uv is None else uv).copy()
    n_views, n_points = uv.shape[:2]
    w, h = scene.image_size
    out = rng.random(n_points) < fraction
    for j in np.flatnonzero(out):  # test set-up, not a hot path
        views = np.flatnonzero(np.isfinite(uv[:, j, 0]))
        k = rng.integers(1, max(2, len(views)))
        for v in rng.choice(views, k, replace=False):
            uv[v, j] = rng.uniform([0, 0], [w, h])
    return uv, out


@pytest.mark.parametrize("seed", range(5))
def test_minimal_solver_exact_on_noise_free_pairs(seed):
    scene = simulate.random_scene(30, 4 + seed % 3, planar=bool(seed % 2), rng=seed)
    seen = np.isfinite(scene.uv[..., 0])
    full = np.flatnonzero(seen.sum(axis=0) >= 4)
    pairs = full[:8].reshape(-1, 2)
    A = solve_minimal(scene.uv, scene.T, pairs)
    assert np.all(np.isfinite(A))
    np.testing.assert_allclose(A, np.broadcast_to(_A_true(scene), A.shape), atol=1e-9, rtol=0)


def test_minimal_solver_paper_scene_and_missing_views():
    scene = simulate.paper_scene()
    A = solve_minimal(scene.uv, scene.T, [[0, 1], [5, 17], [3, 22]])
    np.testing.assert_allclose(A, np.broadcast_to(_A_true(scene), A.shape), atol=1e-9)
    # six views; point 0 seen in views 0-2 only, point 1 in views 1-5: 3 + 5 = 8 views in all
    scene = simulate.random_scene(10, 6, rng=7)
    uv = scene.uv.copy()
    uv[3:, 0] = np.nan
    uv[0, 1] = np.nan
    A = solve_minimal(uv, scene.T, [[0, 1]])
    np.testing.assert_allclose(A[0], _A_true(scene), atol=1e-9)


def test_minimal_solver_flags_underdetermined_pairs():
    scene = simulate.random_scene(10, 4, rng=3)
    uv = scene.uv.copy()
    uv[3, :2] = np.nan  # both points in 3 views: 6 < 8 constraints
    A = solve_minimal(uv, scene.T, [[0, 1]])
    assert np.all(np.isnan(A))


@pytest.mark.parametrize("seed", range(4))
def test_planted_outliers_found_exactly_on_clean_data(seed):
    scene = simulate.random_scene(300, 4 + seed % 3, planar=seed == 1, rng=seed)
    uv, out = plant_outliers(scene, 0.3, rng=100 + seed)
    r = estimate_robust(uv, scene.T, rng=seed)
    assert isinstance(r, RobustEstimate)
    usable = np.isfinite(uv[..., 0]).sum(axis=0) >= 2  # points seen once are never inliers
    out |= ~usable
    np.testing.assert_array_equal(r.inliers, ~out)
    np.testing.assert_allclose(r.linear.K, scene.K, rtol=0, atol=1e-9 * scene.K[0, 0])
    np.testing.assert_allclose(r.linear.R, scene.R, atol=1e-9)
    assert np.all(np.isnan(r.linear.X[out]))
    np.testing.assert_allclose(r.linear.X[~out], scene.X[~out], rtol=1e-8, atol=1e-6)
    assert r.inlier_ratio == pytest.approx((~out).mean())
    assert np.all(r.sse_px2[~out] < 1e-12) and np.all(r.sse_px2[out & usable] > 1.0)
    assert r.trials >= 1 and r.sigma_px < 1e-5  # exact data: the noise floor


def test_planted_outliers_with_missing_observations():
    scene = simulate.random_scene(400, 6, missing=0.25, rng=11)
    uv, out = plant_outliers(scene, 0.3, rng=12)
    seen2 = np.isfinite(uv[..., 0]).sum(axis=0) >= 2
    r = estimate_robust(uv, scene.T, rng=1)
    # points seen in exactly 2 views with one corrupted view cannot be told apart from
    # inliers (2 views give 1 residual dof): compare where the data decide
    decidable = np.isfinite(scene.uv[..., 0]).sum(axis=0) >= 3
    np.testing.assert_array_equal(r.inliers[decidable & seen2], ~out[decidable & seen2])
    np.testing.assert_allclose(r.linear.K, scene.K, rtol=0, atol=1e-8 * scene.K[0, 0])


@pytest.mark.parametrize("noise_px", [0.5, 2.0])
def test_noisy_data_recall_precision_and_noise_estimate(noise_px):
    """No threshold given: the noise is estimated from the data (false rejection 1 %)."""
    scene = simulate.random_scene(500, 4, noise_px=noise_px, rng=21)
    uv, out = plant_outliers(scene, 0.3, rng=22)
    r = estimate_robust(uv, scene.T, rng=0)
    recall = np.sum(r.inliers & ~out) / np.sum(~out)
    precision = np.sum(r.inliers & ~out) / np.sum(r.inliers)
    assert recall >= 0.97 and precision >= 0.99
    assert abs(r.sigma_px / noise_px - 1) < 0.1
    assert abs(r.linear.K[0, 0] / scene.K[0, 0] - 1) < 0.01 * noise_px


def test_user_threshold_overrides_the_noise_estimate():
    scene = simulate.random_scene(300, 5, noise_px=0.5, rng=23)
    r = estimate_robust(scene.uv, scene.T, rng=0, options=RansacOptions(threshold_px=3.0))
    assert r.rule_sigma_px == pytest.approx(3.0 / np.sqrt(-2 * np.log(0.01)))
    assert abs(r.sigma_px / 0.5 - 1) < 0.1 and r.inliers.mean() > 0.99


def test_seeded_runs_are_reproducible_and_progress_is_called():
    scene = simulate.random_scene(100, 4, noise_px=0.3, rng=5)
    uv, _ = plant_outliers(scene, 0.4, rng=6)
    calls = []
    r1 = estimate_robust(uv, scene.T, rng=3, progress=calls.append)
    r2 = estimate_robust(uv, scene.T, rng=3)
    np.testing.assert_array_equal(r1.inliers, r2.inliers)
    np.testing.assert_array_equal(r1.linear.K, r2.linear.K)
    assert calls and calls[-1].stage == "robust" and calls[-1].done == r1.trials
    assert {"trials_needed", "best_inliers"} <= set(calls[-1].info)


def test_point_errors_match_definition():
    scene = simulate.random_scene(20, 5, rng=8)
    uv = scene.uv.copy()
    uv[2, 3] += [5.0, 0.0]
    sse, res = point_errors(scene.K @ scene.R, uv, scene.T)
    assert sse[3] > 1.0 and np.all(np.delete(sse, 3) < 1e-12)
    assert np.nansum(res[:, 3] ** 2) == pytest.approx(sse[3])


def test_no_consensus_raises():
    rng = np.random.default_rng(0)
    T = simulate.random_scene(5, 4, rng=1).T
    uv = rng.uniform(0, 800, (4, 40, 2))
    with pytest.raises(DegenerateError, match="no consensus"):
        estimate_robust(uv, T, rng=0, options=RansacOptions(threshold_px=0.5, max_trials=200))


def test_too_few_sampleable_points_raises():
    scene = simulate.random_scene(10, 4, rng=2)
    uv = scene.uv.copy()
    uv[2:, 1:] = np.nan  # only point 0 is seen in more than 2 views
    with pytest.raises(DegenerateError, match="at least 3 views"):
        estimate_robust(uv, scene.T)


@pytest.mark.parametrize("kw", [{"threshold_px": 0}, {"threshold_px": np.nan}, {"confidence": 1.0},
                                {"max_trials": 0}, {"max_trials": 2.5}])
def test_bad_options_raise_input_error(kw):
    with pytest.raises(InputError):
        RansacOptions(**kw)


def test_misspelt_option_fails_loudly():
    with pytest.raises(TypeError):
        RansacOptions(treshold_px=2.0)


def test_bad_shapes_raise_input_error():
    with pytest.raises(InputError):
        estimate_robust(np.zeros((4, 5, 3)), np.zeros((4, 3)))


from hypothesis import given, settings, strategies as st  # noqa: E402


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_views=st.integers(4, 7), planar=st.booleans())
def test_minimal_solver_exact_property(seed, n_views, planar):
    scene = simulate.random_scene(12, n_views, planar=planar, rng=seed)
    k = np.isfinite(scene.uv[..., 0]).sum(axis=0)
    idx = np.flatnonzero(k >= 4)
    if len(idx) < 2:
        return
    A = solve_minimal(scene.uv, scene.T, [idx[:2]])
    np.testing.assert_allclose(A[0], _A_true(scene), atol=1e-8)


def test_mirrored_data_raise_mirrored_error():
    from transcalib.types import MirroredError

    scene = simulate.random_scene(60, 4, noise_px=0.2, rng=4)
    T = scene.T * np.array([1.0, 1.0, -1.0])  # a left-handed robot frame
    with pytest.raises(MirroredError):
        estimate_robust(scene.uv, T, rng=0)
