"""The linear estimator against ground truth, and the O(n) path against the dense SVD."""

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from transcalib import simulate
from transcalib.geometry.camera import project
from transcalib.geometry.rotation import (euler_zyx_to_matrix, matrix_to_quaternion, matrix_to_rotvec,
                                         quaternion_to_matrix, rotation_angle_deg, rotation_defect, rotvec_to_matrix,
                                         rq_decompose)
from transcalib.estimate.linear import estimate_linear, reference_motion, solve_tls
from transcalib.types import DegenerateError, InputError, MirroredError


def rel_err_K(K, K_true):
    """Largest error of fx, fy, cx, cy, skew relative to the focal length."""
    return np.max(np.abs(K - K_true)) / K_true[0, 0]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    n_views=st.integers(4, 8),
    n_points=st.integers(6, 60),
    planar=st.booleans(),
    missing=st.sampled_from([0.0, 0.15, 0.35]),
    skew=st.sampled_from([0.0, 3.0]),
)
def test_noise_free_exact(seed, n_views, n_points, planar, missing, skew):
    """Random cameras, orientations, 4-8 views, planar or not, missing data: exact."""
    scene = simulate.random_scene(n_points, n_views, planar=planar, missing=missing, skew=skew, rng=seed)
    k = np.isfinite(scene.uv[..., 0]).sum(axis=0)
    assume(np.sum(np.maximum(2 * k - 3, 0)) >= 16)  # twice the 8 equations A needs (net of depths)
    try:
        est = estimate_linear(scene.uv, scene.T)
    except DegenerateError:
        # a genuinely undetermined configuration (few points, few views each): the dense
        # reference must find it undetermined too
        with pytest.raises(DegenerateError):
            estimate_linear(scene.uv, scene.T, method="dense")
        assume(False)
    assert rel_err_K(est.K, scene.K) < 1e-9
    assert rotation_angle_deg(est.R @ scene.R.T) < 1e-7
    assert np.linalg.det(est.R) == pytest.approx(1.0, abs=1e-12)
    used = est.used
    assert np.nanmax(np.abs(est.X[used] - scene.X[used])) < 1e-7 * np.abs(scene.X).max()
    depth_true = np.einsum("a,vna->vn", scene.R[2], scene.X[None] - scene.T[:, None])
    seen = np.isfinite(scene.uv[..., 0]) & used[None]
    np.testing.assert_allclose(est.depth[seen], depth_true[seen], rtol=1e-8)
    assert np.all(np.isnan(est.depth[~np.isfinite(scene.uv[..., 0])]))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_views=st.integers(4, 7), missing=st.sampled_from([0.0, 0.3]),
       noise=st.sampled_from([0.3, 1.0, 3.0]))
@example(seed=7040, n_views=6, missing=0.0, noise=3.0)  # TLS dominated by 2-view points: mirrored
def test_fast_equals_dense(seed, n_views, missing, noise):
    """The O(n) solution is the dense SVD's (paper §2.2) to rounding, on noisy data -
    also where the paper's estimate itself fails (then both fail alike)."""
    scene = simulate.random_scene(40, n_views, noise_px=noise, robot_noise=0.5, missing=missing, rng=seed)
    used = np.isfinite(scene.uv[..., 0]).sum(axis=0) >= 2
    weights = np.random.default_rng(seed).uniform(0.2, 3.0, scene.n_points)  # row weights (depth weighting)
    for w in (None, weights):
        A_fast, depth_fast, sv_fast = solve_tls(scene.uv, scene.T, used, "fast", w)
        A_dense, depth_dense, sv_dense = solve_tls(scene.uv, scene.T, used, "dense", w)
        np.testing.assert_allclose(A_fast, A_dense, atol=1e-9 * np.abs(A_dense).max())
        np.testing.assert_allclose(depth_fast, depth_dense, rtol=1e-8)
    try:  # the paper's TLS as published: one solve, so fast and dense agree to rounding
        fast = estimate_linear(scene.uv, scene.T, weighting="none")
    except (MirroredError, DegenerateError) as exc:
        with pytest.raises(type(exc)):
            estimate_linear(scene.uv, scene.T, method="dense", weighting="none")
        return
    dense = estimate_linear(scene.uv, scene.T, method="dense", weighting="none")
    assert rel_err_K(fast.K, dense.K) < 1e-9
    np.testing.assert_allclose(fast.R, dense.R, atol=1e-9)
    np.testing.assert_allclose(fast.depth, dense.depth, rtol=1e-8)
    np.testing.assert_allclose(fast.singular_values, dense.singular_values, rtol=1e-6, atol=1e-12)


def test_fast_equals_dense_across_chunks(monkeypatch):
    """Chunks of 7 points, every reference view and visibility pattern mixed, unused
    points in between: still the dense SVD's solution."""
    from transcalib.estimate import arrowhead

    monkeypatch.setattr(arrowhead, "_CHUNK", 7)
    scene = simulate.random_scene(60, 6, noise_px=1.0, missing=0.45, rng=12)
    used = np.isfinite(scene.uv[..., 0]).sum(axis=0) >= 2
    used[::5] = False
    first = np.argmax(np.isfinite(scene.uv[..., 0]), axis=0)[used]
    assert len(np.unique(first)) >= 3  # several reference views
    weights = np.random.default_rng(3).uniform(0.2, 3.0, scene.n_points)
    A_fast, depth_fast, _ = solve_tls(scene.uv, scene.T, used, "fast", weights)
    A_dense, depth_dense, _ = solve_tls(scene.uv, scene.T, used, "dense", weights)
    np.testing.assert_allclose(A_fast, A_dense, atol=1e-9 * np.abs(A_dense).max())
    np.testing.assert_allclose(depth_fast, depth_dense, rtol=1e-8)
    assert np.isnan(depth_fast[:, ~used]).all()


def test_paper_preset_noise_free_and_noisy():
    scene = simulate.paper_scene()
    est = estimate_linear(scene.uv, scene.T)
    assert rel_err_K(est.K, scene.K) < 1e-9
    # 0.5 px noise: the linear estimate is within a few percent (paper §3)
    noisy = simulate.paper_scene(noise_px=0.5, robot_noise=0.1, rng=3)
    est = estimate_linear(noisy.uv, noisy.T)
    assert abs(est.K[0, 0] / scene.K[0, 0] - 1) < 0.05
    assert est.singular_values[0] < 0.1 * est.singular_values[1]


def test_noisy_error_shrinks_with_points():
    """More points, smaller error: consistent estimator (statistical, fixed seeds)."""
    errs = []
    for n in (30, 3000):
        e = [rel_err_K(estimate_linear(s.uv, s.T).K, s.K)
             for s in (simulate.random_scene(n, 5, noise_px=0.5, rng=k) for k in range(5))]
        errs.append(np.median(e))
    assert errs[1] < errs[0] / 3


def test_points_in_two_views_only_and_unused_points():
    scene = simulate.random_scene(20, 5, rng=7)
    uv = scene.uv.copy()
    uv[2:, 0] = np.nan  # point 0 in views 0, 1 only
    uv[1:, 1] = np.nan  # point 1 in one view: unused
    est = estimate_linear(uv, scene.T)
    assert not est.used[1] and est.used[0]
    assert np.all(np.isnan(est.X[1]))
    assert est.n_used_points == 19
    np.testing.assert_allclose(est.X[0], scene.X[0], rtol=1e-8)


def test_translation_origin_irrelevant():
    scene = simulate.random_scene(30, 5, noise_px=0.5, rng=2)
    a = estimate_linear(scene.uv, scene.T)
    b = estimate_linear(scene.uv, scene.T + [1000.0, -50.0, 7.0])
    np.testing.assert_allclose(a.K, b.K, rtol=1e-8)
    np.testing.assert_allclose(b.X, a.X + [1000.0, -50.0, 7.0], rtol=1e-8)


def test_units_scale_points_not_camera():
    scene = simulate.random_scene(30, 4, noise_px=0.3, rng=4)
    mm = estimate_linear(scene.uv, scene.T)
    m = estimate_linear(scene.uv, scene.T / 1000.0)
    np.testing.assert_allclose(mm.K, m.K, rtol=1e-9)
    np.testing.assert_allclose(mm.X / 1000.0, m.X, rtol=1e-8)


# ---------------------------------------------------------------------------------- errors


@pytest.fixture
def scene():
    return simulate.paper_scene()  # 24 points, all seen in the 4 views


def test_wrong_shapes(scene):
    with pytest.raises(InputError, match=r"\(n_views, n_points, 2\)"):
        estimate_linear(scene.uv[..., 0], scene.T)
    with pytest.raises(InputError, match=r"\(n_views, 3\)"):
        estimate_linear(scene.uv, scene.T[:, :2])
    with pytest.raises(InputError, match="4 views but T has 5 translations"):
        estimate_linear(scene.uv, np.vstack([scene.T, scene.T[:1]]))
    with pytest.raises(InputError, match="array of numbers"):
        estimate_linear([["a"]], scene.T)


def test_nonfinite_translations(scene):
    T = scene.T.copy()
    T[2, 1] = np.nan
    with pytest.raises(InputError, match=r"views \[2\]"):
        estimate_linear(scene.uv, T)
    T[2, 1] = np.inf
    with pytest.raises(InputError, match="not finite"):
        estimate_linear(scene.uv, T)


def test_infinite_pixels_and_half_nan(scene):
    uv = scene.uv.copy()
    uv[1, 3, 0] = np.inf
    with pytest.raises(InputError, match="infinite"):
        estimate_linear(uv, scene.T)
    uv = scene.uv.copy()
    uv[1, 3, 0] = np.nan
    with pytest.raises(InputError, match="NaN in both"):
        estimate_linear(uv, scene.T)


def test_too_few_views(scene):
    with pytest.raises(InputError, match="at least 4 views"):
        estimate_linear(scene.uv[:3], scene.T[:3])


def test_translations_not_spanning_3d():
    scene = simulate.random_scene(20, 5, rng=1)
    T = scene.T.copy()
    T[:, 2] = T[0, 2]  # all in a plane z = const
    uv = project(scene.K, scene.R, scene.X, T)
    with pytest.raises(DegenerateError, match="singular values") as info:
        estimate_linear(uv, T)
    assert "span 3-D" in str(info.value)


def test_fewer_than_two_points(scene):
    uv = scene.uv.copy()
    uv[1:, 1:] = np.nan
    with pytest.raises(DegenerateError, match="at least 2 points"):
        estimate_linear(uv, scene.T)


def test_undetermined_camera():
    """6 points, mostly in 2 views, on a plane: 8 net equations for 8 unknowns, singular."""
    scene = simulate.random_scene(6, 4, planar=True, missing=0.35, rng=6)
    with pytest.raises(DegenerateError, match="null space"):
        estimate_linear(scene.uv, scene.T)


def test_views_without_points(scene):
    uv = scene.uv.copy()
    uv[3] = np.nan
    with pytest.raises(DegenerateError, match="only 3 views"):
        estimate_linear(uv, scene.T)


def test_mirrored_data_detected(scene):
    """Swapping two robot axes makes the frame left-handed: said clearly, never det R = -1."""
    T = scene.T[:, [1, 0, 2]]  # the same images, with the x and y columns swapped
    with pytest.raises(MirroredError, match="left-handed") as info:
        estimate_linear(scene.uv, T)
    assert isinstance(info.value, InputError) and isinstance(info.value, DegenerateError)


def test_unknown_method(scene):
    with pytest.raises(InputError, match="method"):
        estimate_linear(scene.uv, scene.T, method="svd")


def test_dense_refuses_large_problems():
    scene = simulate.random_scene(3100, 4, rng=0)
    with pytest.raises(InputError, match="fast"):
        estimate_linear(scene.uv, scene.T, method="dense")


def test_inputs_not_modified(scene):
    uv, T = scene.uv.copy(), scene.T.copy()
    estimate_linear(uv, T)
    np.testing.assert_array_equal(uv, scene.uv)
    np.testing.assert_array_equal(T, scene.T)


def test_solve_tls_scale_and_sign():
    scene = simulate.random_scene(25, 4, rng=11)
    A, depth, sv = solve_tls(scene.uv, scene.T)
    assert np.linalg.norm(A[2]) == pytest.approx(1.0)
    assert np.nanmin(depth) > 0
    np.testing.assert_allclose(A, scene.K @ scene.R / np.linalg.norm((scene.K @ scene.R)[2]), atol=1e-9 * np.abs(A).max())
    assert sv.shape == (3,) and sv[0] < 1e-6 * sv[1]


def test_rq_decompose_recovers_K_and_R():
    """A = s K R for random cameras and scales: K (K[2,2] = 1, positive diagonal, skew
    kept) and R (det +1) come back to rounding; a mirrored A is refused."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    for R_true in Rotation.random(50, random_state=5).as_matrix():
        K_true = np.array([[rng.uniform(100, 3000), rng.uniform(-5, 5), rng.uniform(0, 2000)],
                           [0.0, rng.uniform(100, 3000), rng.uniform(0, 2000)], [0.0, 0.0, 1.0]])
        K, R = rq_decompose(rng.uniform(1e-4, 1e4) * K_true @ R_true)
        np.testing.assert_allclose(K, K_true, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(R, R_true, atol=1e-12)
    with pytest.raises(MirroredError):
        rq_decompose(np.diag([1.0, 1.0, -1.0]))


def _hard_rotations():
    """Random rotations and the hard cases: identity, half turns, near-half turns, tiny turns."""
    from scipy.spatial.transform import Rotation

    return np.stack([*Rotation.random(200, random_state=6).as_matrix(), np.eye(3), np.diag([1.0, -1.0, -1.0]),
                     np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0]),
                     Rotation.from_rotvec([0.0, np.pi - 1e-9, 0.0]).as_matrix(),
                     Rotation.from_rotvec(np.pi * np.array([0.6, 0.0, 0.8])).as_matrix(),
                     Rotation.from_rotvec([1e-13, -2e-13, 3e-13]).as_matrix(),
                     Rotation.from_rotvec([0.0, 0.0, 1e-7]).as_matrix()])


def test_matrix_to_quaternion_agrees_with_scipy():
    """Shepperd's method against scipy's Rotation (an independent implementation), one
    matrix at a time and as a stack, and back."""
    from scipy.spatial.transform import Rotation

    rotations = _hard_rotations()
    stack = matrix_to_quaternion(rotations)
    assert stack.shape == (len(rotations), 4)
    for R, q_stacked in zip(rotations, stack):
        q, ref = matrix_to_quaternion(R), Rotation.from_matrix(R).as_quat()
        assert q.shape == (4,) and np.array_equal(q, q_stacked)
        assert q[3] >= 0 and np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
        assert min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-12  # q and -q: the same rotation
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), R, atol=1e-12)
        np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-12)
    np.testing.assert_allclose(quaternion_to_matrix(-3.0 * stack), rotations, atol=1e-12)  # any norm, either sign


def test_rotation_vectors_euler_and_angles_agree_with_scipy():
    """``rotvec <-> matrix``, KUKA Z-Y-X Euler angles and the rotation angle against scipy,
    one at a time and stacked; the angle and the rotation vector stay accurate for tiny
    angles (where ``arccos((tr R - 1) / 2)`` loses all digits) and half turns."""
    from scipy.spatial.transform import Rotation

    rotations = _hard_rotations()
    ref = Rotation.from_matrix(rotations)
    w = matrix_to_rotvec(rotations)
    assert w.shape == (len(rotations), 3) and np.array_equal(matrix_to_rotvec(rotations[3]), w[3])
    angle = np.linalg.norm(w, axis=1)
    assert np.all(angle <= np.pi + 1e-15)
    np.testing.assert_allclose(angle, ref.magnitude(), rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(rotvec_to_matrix(w), rotations, atol=2e-15)
    np.testing.assert_allclose(rotvec_to_matrix(ref.as_rotvec()), rotations, atol=2e-15)
    assert rotvec_to_matrix(ref.as_rotvec()[0]).shape == (3, 3)
    ok = ref.magnitude() < np.pi - 1e-6  # below a half turn the vector is unique
    np.testing.assert_allclose(w[ok], ref.as_rotvec()[ok], rtol=1e-9, atol=1e-15)
    degrees = rotation_angle_deg(rotations)
    np.testing.assert_allclose(degrees, np.degrees(ref.magnitude()), rtol=1e-9, atol=1e-13)
    assert isinstance(rotation_angle_deg(rotations[0]), float)
    assert rotation_angle_deg(rotations[-2]) == pytest.approx(np.degrees(np.sqrt(14) * 1e-13), rel=1e-6)
    abc = ref.as_euler("ZYX", degrees=True)  # intrinsic Z-Y-X: Rz(a) Ry(b) Rx(c)
    np.testing.assert_allclose(euler_zyx_to_matrix(abc), rotations, atol=1e-12)
    np.testing.assert_allclose(euler_zyx_to_matrix(abc[5]), rotations[5], atol=1e-12)


def test_rotation_defect():
    R = _hard_rotations()[:3]
    bad = np.stack([R[0], -R[1], 1.01 * R[2], np.full((3, 3), np.nan)])
    d = rotation_defect(bad)
    assert d[0] < 1e-15 and d[1] == np.inf and 0.019 < d[2] < 0.021 and d[3] == np.inf


def test_rotation_convention():
    """R maps world vectors to the camera: the optical axis R[2] points at the scene."""
    scene = simulate.random_scene(20, 4, rng=5)
    est = estimate_linear(scene.uv, scene.T)
    centre = np.nanmean(est.X, axis=0)
    assert est.R[2] @ (centre - scene.T[0]) > 0


def test_one_visibility_pattern_plus_unused_points():
    scene = simulate.paper_scene(noise_px=0.3, rng=1)
    uv = scene.uv.copy()
    uv[1:, 5] = np.nan  # point 5 only in view 0: unused; every other point in all views
    fast, dense = estimate_linear(uv, scene.T), estimate_linear(uv, scene.T, method="dense")
    assert not fast.used[5] and np.isnan(fast.X[5]).all() and np.isnan(fast.depth[:, 5]).all()
    assert rel_err_K(fast.K, dense.K) < 1e-9


def test_many_views():
    """More than 62 views: visibility patterns are no longer bit masks."""
    scene = simulate.random_scene(40, 70, missing=0.5, noise_px=0.3, rng=2)
    fast, dense = estimate_linear(scene.uv, scene.T), estimate_linear(scene.uv, scene.T, method="dense")
    assert rel_err_K(fast.K, dense.K) < 1e-9


def test_repeated_robot_positions():
    """Two views at the same robot position give equations without A; the weighted TLS
    and the pipeline still recover the camera (regression: the O(n) solver crashed)."""
    from transcalib import calibrate
    from transcalib.synth.simulate import _make_scene

    base = simulate.random_scene(100, 6, rng=3)
    T = base.T_true.copy()
    T[4], T[5] = T[0], T[1]
    scene = _make_scene(base.K, base.R, base.dist, T, base.X, base.image_size, 0.5, 0.0, 0.0, 3, meta={})
    lin = estimate_linear(scene.uv, scene.T)
    assert abs(lin.K[0, 0] / base.K[0, 0] - 1) < 0.02
    cal = calibrate(scene.uv, scene.T, rng=0, check_rotation=False)
    assert abs(cal.K[0, 0] - base.K[0, 0]) < 4 * cal.std["fx"]


# ------------------------------------------------------------------------- the O(n) path


def test_hartley_normalisation_written_once(monkeypatch):
    """The used observations to zero mean and mean distance sqrt(2), translations centred
    to unit mean norm; in any chunking; the minimal solver's normalisation is the same."""
    from transcalib.estimate import minimal, normalisation

    scene = simulate.random_scene(50, 6, noise_px=0.5, missing=0.3, rng=5)
    used = np.random.default_rng(1).random(scene.n_points) < 0.7
    norm = normalisation.hartley(scene.uv, scene.T, used)
    x = scene.uv[:, used][np.isfinite(scene.uv[:, used, 0])] * norm.scale + norm.H[:2, 2]
    assert np.abs(x.mean(axis=0)).max() < 1e-12
    assert np.hypot(*x.T).mean() == pytest.approx(np.sqrt(2.0), rel=1e-12)
    assert np.abs(norm.T.mean(axis=0)).max() < 1e-12
    assert np.linalg.norm(norm.T, axis=1).mean() == pytest.approx(1.0, rel=1e-12)
    monkeypatch.setattr(normalisation, "CHUNK", 7)
    np.testing.assert_allclose(normalisation.hartley(scene.uv, scene.T, used).H, norm.H, rtol=1e-13)
    every = normalisation.hartley(scene.uv, scene.T)
    pb = minimal.normalise(scene.uv, scene.T)
    np.testing.assert_array_equal(pb.H, every.H)
    np.testing.assert_array_equal(pb.T, every.T)
    seen = np.isfinite(scene.uv[..., 0]).T
    np.testing.assert_allclose(pb.x[seen], scene.uv.transpose(1, 0, 2)[seen] * every.scale + every.H[:2, 2])


def test_median_helpers_are_numpys():
    """Column medians (sorting network or np.sort) and the sign of a streamed median equal
    numpy's nanmedian, with NaN, zeros, ties and every row count."""
    from transcalib.estimate.arrowhead import MedianSign, column_median, signed_medians

    rng = np.random.default_rng(0)
    for k in (1, 2, 3, 4, 5, 8, 9, 12):
        a = rng.choice([-2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, np.nan], size=(k, 3000))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns
            ref = np.nanmedian(a, axis=0)
            pos = np.nanmedian(np.where(a > 0, a, np.nan), axis=0)
            neg = np.nanmedian(np.where(a < 0, -a, np.nan), axis=0)
        np.testing.assert_array_equal(column_median(a), ref)
        p, n = signed_medians(a)
        np.testing.assert_array_equal(p, pos)
        np.testing.assert_array_equal(n, neg)
    for _ in range(3000):
        x = rng.choice([-2.0, -1.0, -0.5, 0.0, 0.5, 1.0, 2.0, np.nan], size=rng.integers(1, 9))
        sign = MedianSign()
        for part in np.array_split(x, 3):
            sign.add(part)
        assert sign.negative == bool(np.isfinite(x).any() and np.nanmedian(x) < 0)


def test_reference_motion():
    scene = simulate.random_scene(300, 6, noise_px=0.5, missing=0.4, rng=8)
    d, ref = reference_motion(scene.uv)
    first = np.argmax(np.isfinite(scene.uv[..., 0]), axis=0)
    np.testing.assert_array_equal(ref, first)
    expected = np.linalg.norm(scene.uv - scene.uv[first, np.arange(300)][None], axis=2)
    np.testing.assert_allclose(d, expected, rtol=1e-15, atol=1e-12)
    assert np.array_equal(np.isnan(d), ~np.isfinite(scene.uv[..., 0]))


def test_newton_from_the_pilot_is_newtons_root(monkeypatch):
    """10^5 points: Newton started from the pilot's root and confirmed by the depth pass
    reads the data fewer times than Newton from mu = 0, and finds the same root to
    rounding, for both weightings."""
    from transcalib.estimate import arrowhead

    scene = simulate.random_scene(100_000, 5, noise_px=1.0, missing=0.2, rng=5)
    full_passes = []
    taylor = arrowhead.Arrowhead.taylor
    monkeypatch.setattr(arrowhead.Arrowhead, "taylor", lambda self, mu: (
        full_passes.append(mu) if self.points.n_used > 50_000 else None) or taylor(self, mu))
    fast = {w: estimate_linear(scene.uv, scene.T, weighting=w) for w in ("depth", "none")}
    n_fast, full_passes[:] = len(full_passes), []
    assert n_fast <= 2 * 3  # three solves: two with the depth weighting, one without
    # Newton on the linear model from mu = 0, as before the pilot
    monkeypatch.setattr(arrowhead.Arrowhead, "_pilot", lambda self, mu_start: 0.0)
    monkeypatch.setattr(arrowhead.Arrowhead, "_confirmed_steps", lambda self, model, *args: (None, model))
    for w, est in fast.items():
        newton = estimate_linear(scene.uv, scene.T, weighting=w)
        assert rel_err_K(est.K, newton.K) < 1e-11
        np.testing.assert_allclose(est.depth, newton.depth, rtol=1e-10)
    assert len(full_passes) >= n_fast + 3


def test_memory_is_the_results():
    """The call's own allocations beyond its result (X, depth, used, static) stay a few
    chunks' worth (the dense reference's C would be 400 GB; the per-view arrays 26 MiB)."""
    import tracemalloc

    scene = simulate.random_scene(200_000, 4, noise_px=0.5, rng=1)
    estimate_linear(scene.uv, scene.T)
    tracemalloc.start()
    est = estimate_linear(scene.uv, scene.T)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    result = est.X.nbytes + est.depth.nbytes + est.used.nbytes + est.static.nbytes
    assert peak < result + 12 * 2**20
