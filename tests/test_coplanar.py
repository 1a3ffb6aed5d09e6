"""Coplanar translations (XY table, 2-axis gantry) with known parameters: the linear start
``fit_coplanar``, its robust variant, refinement from it, identifiability from the Fisher
information, and the span diagnosis ``explain_span`` — all against ground truth."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from transcalib.errors import DegenerateError, Diagnostic, InputError
from transcalib.estimate.coplanar import fit_coplanar, fit_coplanar_robust
from transcalib.estimate.covariance import crlb
from transcalib.estimate.degeneracy import explain_span, identifiability_hint, translation_basis, translation_rank
from transcalib.estimate.noise import sigma_from_threshold
from transcalib.estimate.refine import fit_refine
from transcalib.geometry.camera import project
from transcalib.synth.simulate import observe, random_scene
from transcalib.pipeline import calibrate
from transcalib.types import RansacOptions, RefineOptions


def coplanar_scene(seed, *, n_views=6, n_points=60, noise_px=0.0, square=False, normal=None, R_rel=None,
                   collinear=False):
    """``random_scene``'s camera and points, the translations replaced by moves in a plane.

    ``normal``: plane normal in robot axes (default random); ``R_rel``: camera orientation
    relative to the plane basis ``[p1 p2 n]`` (``R = R_rel P^T``; default random's R).
    """
    rng = np.random.default_rng(seed)
    sc = random_scene(n_points, 4, rng=rng)
    K = sc.K.copy()
    if square:
        K[1, 1] = K[0, 0]
    n = Rotation.random(random_state=rng).apply([0, 0, 1.0]) if normal is None else np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    P = np.linalg.svd(np.eye(3) - np.outer(n, n))[0]
    P[:, 2] = np.cross(P[:, 0], P[:, 1])
    R = sc.R if R_rel is None else R_rel @ P.T
    c = rng.uniform(-200, 200, (n_views, 2))
    if collinear:
        c[:, 1] = 0.0
    T = c @ P[:, :2].T + rng.normal(0, 50, 3)
    uv0 = np.column_stack([rng.uniform(80, 720, n_points), rng.uniform(60, 540, n_points)])
    rays = np.column_stack([uv0, np.ones(n_points)]) @ np.linalg.inv(K).T
    X = (rays * rng.uniform(800, 1200, n_points)[:, None]) @ R + T[0]
    uv = project(K, R, X, T)
    exact = replace(sc, K=K, R=R, T_true=T, T=T.copy(), X=X, uv=uv, uv_true=uv)
    return observe(exact, noise_px, rng=rng)


def pp(scene):
    return {"cx": float(scene.K[0, 2]), "cy": float(scene.K[1, 2])}


def assert_exact(est, scene, rtol=1e-9, uv=None):
    uv = scene.uv if uv is None else uv
    fx = scene.K[0, 0]
    np.testing.assert_allclose(est.K, scene.K, atol=rtol * fx)
    np.testing.assert_allclose(est.R, scene.R, atol=rtol)
    ok = np.isfinite(est.X).all(axis=1)
    assert ok.mean() > 0.8 and np.array_equal(ok, np.isfinite(uv[..., 0]).sum(axis=0) >= 2)
    np.testing.assert_allclose(est.X[ok], scene.X[ok], atol=rtol * np.abs(scene.X).max())


# ---------------------------------------------------------------------------------------
# noise-free recovery
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_known_principal_point_recovers_fx_fy_R_exactly(seed):
    scene = coplanar_scene(seed)
    assert translation_rank(scene.T) == 2
    est = fit_coplanar(scene.uv, scene.T, fix=pp(scene))
    assert est.method == "coplanar" and abs(scene.K[0, 0] - scene.K[1, 1]) > 1.0  # fx != fy really solved
    assert_exact(est, scene)
    assert np.nanmin(est.depth) > 0
    cal = fit_refine(scene.uv, scene.T, est, RefineOptions(fix=pp(scene), sigma_px=1.0))
    assert_exact(cal, scene)


def test_square_pixels_and_one_known_focal_length():
    scene = coplanar_scene(5, square=True)
    assert_exact(fit_coplanar(scene.uv, scene.T, fix=pp(scene), square_pixels=True), scene)
    scene = coplanar_scene(6)
    fix = pp(scene) | {"fx": float(scene.K[0, 0])}
    est = fit_coplanar(scene.uv, scene.T, fix=fix)
    assert_exact(est, scene)
    cal = fit_refine(scene.uv, scene.T, est, RefineOptions(fix=fix, sigma_px=1.0))
    assert_exact(cal, scene)


def test_fully_known_K_gives_R_and_points():
    scene = coplanar_scene(7)
    K = scene.K
    fix = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    est = fit_coplanar(scene.uv, scene.T, fix=fix)
    assert_exact(est, scene)
    cal = fit_refine(scene.uv, scene.T, est, RefineOptions(fix=fix, sigma_px=1.0))
    assert cal.param_names == ("rx", "ry", "rz")
    assert_exact(cal, scene)


def test_known_focal_lengths_free_principal_point_start_at_centre():
    """fx, fy known, cx, cy free is identifiable (2 free intrinsics): start the coplanar
    estimate at the image centre, let the refinement free the principal point."""
    scene = coplanar_scene(10)
    fix = {"fx": float(scene.K[0, 0]), "fy": float(scene.K[1, 1])}
    assert np.hypot(scene.K[0, 2] - 399.5, scene.K[1, 2] - 299.5) > 20
    start = fit_coplanar(scene.uv, scene.T, fix=fix | {"cx": 399.5, "cy": 299.5})
    cal = fit_refine(scene.uv, scene.T, start, RefineOptions(fix=fix, sigma_px=1.0))
    assert cal.param_names == ("cx", "cy", "rx", "ry", "rz")
    assert_exact(cal, scene)


def test_static_track_is_left_out():
    """An overlay (the same pixel in every view) has no depth: left out, no crash."""
    scene = coplanar_scene(22)
    uv = scene.uv.copy()
    uv[:, 0] = [100.0, 50.0]
    for fit in (lambda: fit_coplanar(uv, scene.T, fix=pp(scene)),
                lambda: fit_coplanar_robust(uv, scene.T, fix=pp(scene), rng=0)[0]):
        est = fit()
        assert not est.used[0] and np.isnan(est.X[0]).all()
        np.testing.assert_allclose(est.K, scene.K, atol=1e-6)


def test_xy_table_with_missing_points_and_robot_plane_offset():
    scene = coplanar_scene(8, normal=[0, 0, 1], n_views=5)
    uv = scene.uv.copy()
    uv[1, :10] = np.nan  # some points unseen in some views
    uv[3, 20:25] = np.nan
    est = fit_coplanar(uv, scene.T, fix=pp(scene))
    assert_exact(est, scene, uv=uv)
    np.testing.assert_allclose(translation_basis(scene.T)[0][:, 2], [0, 0, 1], atol=1e-12)


def test_robot_jitter_off_the_plane_with_tol():
    """Measured z of an XY table jitters by 0.01 mm: with tol=1e-3 it counts as coplanar."""
    exact = coplanar_scene(9, normal=[0, 0, 1])
    scene = observe(exact, 0.0, robot_noise=0.01, rng=4)
    assert translation_rank(scene.T) == 3 and translation_rank(scene.T, 1e-3) == 2
    with pytest.raises(DegenerateError, match="raise tol"):
        fit_coplanar(scene.uv, scene.T, fix=pp(scene))
    assert explain_span(scene.T, pp(scene), tol=1e-3).code == "translations_coplanar_known_params"
    est = fit_coplanar(scene.uv, scene.T, fix=pp(scene), tol=1e-3)
    np.testing.assert_allclose(np.diag(est.K), np.diag(exact.K), rtol=2e-3)
    np.testing.assert_allclose(est.R, exact.R, atol=2e-3)


# ---------------------------------------------------------------------------------------
# noise: Monte Carlo against the Cramér-Rao bound
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("square", [False, True])
def test_monte_carlo_std_matches_crlb(square):
    """200 trials at 0.5 px: the refined focal lengths are unbiased and their std is within
    15 % of the CRLB (sampling error of a std from 200 trials: 5 %)."""
    exact = coplanar_scene(11, n_points=50, square=square)
    fix = pp(exact)
    bound = crlb(observe(exact, 0.5, rng=0), fix=fix, square_pixels=square)
    opts = RefineOptions(fix=fix, square_pixels=square)
    est_fx, est_fy, lin_fx = [], [], []
    for trial in range(200):
        scene = observe(exact, 0.5, rng=1000 + trial)
        lin = fit_coplanar(scene.uv, scene.T, fix=fix, square_pixels=square)
        cal = fit_refine(scene.uv, scene.T, lin, opts)
        lin_fx.append(lin.K[0, 0])
        est_fx.append(cal.K[0, 0])
        est_fy.append(cal.K[1, 1])
    for est, name, k in ((est_fx, "fx", 0), (est_fy, "fy", 1)):
        est = np.asarray(est)
        sd = est.std(ddof=1)
        assert abs(sd / bound[name] - 1) < 0.15, (name, sd, bound[name])
        assert abs(est.mean() - exact.K[k, k]) < 4 * sd / np.sqrt(len(est)) + 0.02 * sd
    assert np.std(lin_fx) < 5 * bound["fx"]  # the linear start is a sane start


# ---------------------------------------------------------------------------------------
# identifiability (Fisher information of the posed problem)
# ---------------------------------------------------------------------------------------

GENERIC = Rotation.from_rotvec([0.45, 0.30, 0.15]).as_matrix()


@pytest.mark.parametrize("known, square, identifiable", [
    ((), False, False), ((), True, False),
    (("cx", "cy"), False, True), (("cx", "cy"), True, True),
    (("fx", "fy"), False, True),
    (("cx",), False, False), (("cx",), True, True),
    (("fx", "fy", "cx", "cy"), False, True),
])
def test_fisher_identifiability_and_explain_span_agree(known, square, identifiable):
    """With coplanar translations at most two intrinsics are determined (A' has 5 dof, R
    takes 3): the CRLB at the truth and the a-priori explain_span give the same answer."""
    scene = observe(coplanar_scene(12, square=True, R_rel=GENERIC), 0.5, rng=1)
    values = {"fx": scene.K[0, 0], "fy": scene.K[1, 1], "cx": scene.K[0, 2], "cy": scene.K[1, 2]}
    fix = {k: float(values[k]) for k in known}
    if identifiable:
        bound = crlb(scene, fix=fix, square_pixels=square)
        assert all(np.isfinite(v) and v < 50 for v in bound.values())
        d = explain_span(scene.T, fix, square, "mm")
        assert isinstance(d, Diagnostic) and d.code == "translations_coplanar_known_params"
    else:
        with pytest.raises(DegenerateError, match="cy"):
            crlb(scene, fix=fix, square_pixels=square)
        with pytest.raises(DegenerateError, match=r"coplanar.*missing.*cy.*principal-point=centre"):
            explain_span(scene.T, fix, square, "mm")


def test_free_principal_point_refinement_raises_naming_it():
    scene = coplanar_scene(13, noise_px=0.5)
    est = fit_coplanar(scene.uv, scene.T, fix=pp(scene))
    with pytest.raises(DegenerateError, match=r"c[xy].*c[xy]"):
        fit_refine(scene.uv, scene.T, est, RefineOptions())


def test_camera_along_plane_normal_loses_the_focal_length():
    """Image plane parallel to the motion plane: f trades against depth, even with square
    pixels; with one focal length known the other is determined."""
    scene = coplanar_scene(14, normal=[0, 0, 1], R_rel=Rotation.from_euler("z", 20, degrees=True).as_matrix(),
                           square=True)
    with pytest.raises(DegenerateError, match="along the normal"):
        fit_coplanar(scene.uv, scene.T, fix=pp(scene))
    with pytest.raises(DegenerateError, match="f"):
        fit_coplanar(scene.uv, scene.T, fix=pp(scene), square_pixels=True)
    with pytest.raises(DegenerateError, match="f"):
        crlb(observe(scene, 0.5, rng=0), fix=pp(scene), square_pixels=True)
    fix = pp(scene) | {"fx": float(scene.K[0, 0])}
    assert_exact(fit_coplanar(scene.uv, scene.T, fix=fix), scene)


def test_tilt_about_an_image_axis_needs_square_pixels():
    """Tilted about the camera x axis only: the orthogonality equations give one constraint,
    fx and fy are not both determined (Sturm & Maybank); square pixels suffice."""
    R_rel = Rotation.from_euler("zx", [35, 30], degrees=True).as_matrix()  # Rx(30) Rz(35): tilt about camera x
    scene = coplanar_scene(15, R_rel=R_rel, square=True)
    with pytest.raises(DegenerateError, match="image axes"):
        fit_coplanar(scene.uv, scene.T, fix=pp(scene))
    with pytest.raises(DegenerateError, match="fx|fy"):
        crlb(observe(scene, 0.5, rng=0), fix=pp(scene))
    assert_exact(fit_coplanar(scene.uv, scene.T, fix=pp(scene), square_pixels=True), scene)


# ---------------------------------------------------------------------------------------
# span diagnosis
# ---------------------------------------------------------------------------------------


def test_explain_span_names_the_missing_direction():
    scene = coplanar_scene(16, normal=[0, 0, 1])
    with pytest.raises(DegenerateError, match=r"\(0, 0, 1\).*--fix cx=\.\.,cy=\.\."):
        explain_span(scene.T, {}, unit="mm")
    d = explain_span(scene.T, pp(scene), unit="mm")
    assert d.code == "translations_coplanar_known_params"
    assert "(0, 0, 1)" in d and "fx, fy, R" in d
    assert explain_span(random_scene(10, 5, rng=0).T) is None
    assert explain_span(scene.T, pp(scene) | {"fx": 1.0, "fy": 1.0}).count("looks") == 0


def test_collinear_raises_naming_two_directions():
    scene = coplanar_scene(17, normal=[0, 0, 1], collinear=True)
    line = translation_basis(scene.T)[0]
    assert translation_rank(scene.T) == 1
    K = scene.K
    full = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    with pytest.raises(DegenerateError, match=r"collinear.*directions \(.*\) and \(.*\) are missing"):
        explain_span(scene.T, full)
    with pytest.raises(DegenerateError, match=r"\(0, 0, 1\)"):
        explain_span(scene.T, full)
    with pytest.raises(DegenerateError, match="collinear"):
        fit_coplanar(scene.uv, scene.T, fix=full)
    with pytest.raises(DegenerateError, match="r[xyz]"):  # even a known K leaves the roll about the line
        crlb(observe(scene, 0.5, rng=0), fix=full)
    assert abs(line[2, 0]) < 1e-9
    with pytest.raises(DegenerateError, match="did not move"):
        explain_span(np.ones((4, 3)))


def test_fit_coplanar_input_errors():
    scene = coplanar_scene(18)
    with pytest.raises(InputError, match="principal point"):
        fit_coplanar(scene.uv, scene.T, fix={})
    with pytest.raises(DegenerateError, match="3-D"):
        s3 = random_scene(20, 5, rng=1)
        fit_coplanar(s3.uv, s3.T, fix=pp(s3))
    with pytest.raises(DegenerateError, match="constraints"):
        fit_coplanar(scene.uv[:3, :1], scene.T[:3], fix=pp(scene))  # one point in 3 views: 3 constraints


def test_identifiability_hint():
    T = coplanar_scene(19, normal=[0, 0, 1]).T
    assert "--fix cx=..,cy=.." in identifiability_hint(["fx", "cx", "rx"], T)
    assert "(0, 0, 1)" in identifiability_hint(["cx"], T)
    assert "--square-pixels" in identifiability_hint(["fx", "fy"], T)
    assert "simpler distortion" in identifiability_hint(["k1", "k2"])
    assert "skew must be known" in identifiability_hint(["fx", "fy", "skew"], T)
    with pytest.raises(DegenerateError, match="singular in 1 direction.*skew must be known"):
        explain_span(T, {"cx": 1.0, "cy": 2.0}, estimate_skew=True)
    assert explain_span(T, {"cx": 1.0, "cy": 2.0}, distortion="radial2").code == "translations_coplanar_known_params"
    assert "three independent" in identifiability_hint(["rx"], np.outer(np.arange(4), [1.0, 0, 0]))


# ---------------------------------------------------------------------------------------
# robust variant
# ---------------------------------------------------------------------------------------


def test_robust_finds_planted_outliers():
    scene = coplanar_scene(20, n_points=80, noise_px=0.3)
    rng = np.random.default_rng(3)
    bad = rng.choice(80, 20, replace=False)
    uv = scene.uv.copy()
    uv[:, bad] += rng.uniform(-40, 40, (uv.shape[0], 20, 2))
    est, inl, stats = fit_coplanar_robust(uv, scene.T, fix=pp(scene), rng=0)
    truth = np.ones(80, bool)
    truth[bad] = False
    assert np.array_equal(inl, truth) and abs(stats.sigma_px / 0.3 - 1) < 0.2 and stats.n_inliers == 60
    assert abs(est.K[0, 0] - scene.K[0, 0]) < 0.02 * scene.K[0, 0]
    np.testing.assert_allclose(est.R, scene.R, atol=0.01)


def _corrupted_plane(seed=20, n_points=80, fraction=0.4):
    scene = coplanar_scene(seed, n_points=n_points, noise_px=0.3)
    rng = np.random.default_rng(seed + 1)
    bad = rng.random(n_points) < fraction
    uv = scene.uv.copy()
    uv[:, bad] += rng.uniform(-40, 40, (uv.shape[0], int(bad.sum()), 2))
    return scene, uv, bad


def test_robust_honours_every_ransac_option():
    """threshold_px and false_rejection set the rule's sigma; confidence and max_trials the
    number of pairs drawn (the loop of :mod:`transcalib.estimate.ransac`)."""
    scene, uv, bad = _corrupted_plane()
    for alpha in (0.01, 0.05):
        _, inl, stats = fit_coplanar_robust(uv, scene.T, fix=pp(scene), rng=0,
                                            options=RansacOptions(threshold_px=1.5, false_rejection=alpha))
        assert stats.sigma_px == sigma_from_threshold(1.5, alpha) and np.array_equal(inl, ~bad)
    trials = {}
    for confidence in (0.5, 0.999999):
        calls = []
        fit_coplanar_robust(uv, scene.T, fix=pp(scene), rng=0, options=RansacOptions(confidence=confidence),
                            progress=calls.append)
        trials[confidence] = calls[-1].done
        assert calls[-1].done >= calls[-1].info["trials_needed"]
    assert trials[0.5] < trials[0.999999]
    calls = []
    fit_coplanar_robust(uv, scene.T, fix=pp(scene), rng=0, progress=calls.append,
                        options=RansacOptions(confidence=0.999999, max_trials=5))
    assert calls[-1].done == 5 < calls[-1].info["trials_needed"]


def test_calibrate_passes_the_ransac_options_to_the_coplanar_start():
    scene, uv, bad = _corrupted_plane()
    seen = {}
    cal = calibrate(uv, scene.T, fix=pp(scene), rng=0, ransac=RansacOptions(threshold_px=1.5, false_rejection=0.05),
                    progress=lambda e: seen.setdefault(e.stage, e.info) if e.finished else None)
    assert seen["robust (coplanar)"]["sigma_px"] == sigma_from_threshold(1.5, 0.05)
    assert cal.stats.ransac.rule_sigma_px == sigma_from_threshold(1.5, 0.05)
    assert cal.linear.method == "coplanar" and np.array_equal(cal.inliers, ~bad)
