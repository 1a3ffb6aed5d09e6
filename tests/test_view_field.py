"""Each view's image error field as a variance component (transcalib.estimate.view_field)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.polynomial import legendre
from scipy.optimize import minimize
from scipy.stats import chi2

from transcalib.estimate.covariance import covariance, linearise
from transcalib.estimate.layout import FlangeModel
from transcalib.estimate.refine import fit_refine
from transcalib.estimate.robot_error import perturb_poses
from transcalib.estimate.view_field import DEGREES, N_BASIS, fit_components, legendre_basis, view_field
from transcalib.geometry.camera import project
from transcalib.geometry.rotation import rotvec_to_matrix
from transcalib.handeye.simulate import session_scene, with_robot_error
from transcalib.types import Calibration, Camera, RefineOptions

from test_sandwich import _jacobian

BOX = (0.0, 0.0, 640.0, 480.0)


def _basis_oracle(uv: np.ndarray, box=BOX) -> np.ndarray:
    """``(n, 5)`` from numpy's Legendre series: ``sqrt(2a + 1) sqrt(2b + 1) P_a(u) P_b(v)``
    for ``a + b`` 1 or 2 in the order u, v, u^2, uv, v^2, with ``u, v`` the position in
    ``box`` scaled to [-1, 1]."""
    u = 2 * (uv[0] - box[0]) / (box[2] - box[0]) - 1
    v = 2 * (uv[1] - box[1]) / (box[3] - box[1]) - 1
    P = lambda k, x: legendre.legval(x, np.eye(3)[k]) * np.sqrt(2 * k + 1)  # noqa: E731
    return np.stack([P(a, u) * P(b, v) for a, b in ((1, 0), (0, 1), (2, 0), (1, 1), (0, 2))], axis=1)


def test_the_basis_is_numpys_legendre_and_orthonormal_over_the_image():
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [BOX[2], BOX[3]], (200_000, 2)).T
    B = legendre_basis(uv, np.array(BOX))
    assert np.allclose(B, _basis_oracle(uv), atol=1e-12)
    assert np.allclose(B.T @ B / len(B), np.eye(N_BASIS), atol=0.01)  # Monte Carlo over the image


def _ml_oracle(z, C0, parts):
    """The maximum-likelihood ``tau >= 0`` of ``z ~ N(0, C0 + sum tau_d parts[d])`` by a
    bounded quasi-Newton search over ``log``-free scaled variables (scipy's L-BFGS-B)."""
    scale = np.array([1.0 / np.trace(A) * np.trace(C0) / len(z) for A in parts])

    def nll(x):
        C = C0 + sum(xi * s * A for xi, s, A in zip(x, scale, parts))
        sign, logdet = np.linalg.slogdet(C)
        return 0.5 * (logdet + z @ np.linalg.solve(C, z))

    best = min((minimize(nll, x0, bounds=[(0, None)] * len(parts), method="L-BFGS-B",
                         options={"ftol": 1e-15, "gtol": 1e-12}) for x0 in ([0.1] * len(parts), [2.0] * len(parts))),
               key=lambda res: res.fun)
    return best.x * scale, -best.fun


def test_variance_components_are_the_maximum_likelihood_ones():
    """Fisher scoring on the active set lands on the likelihood's maximum (a bounded
    quasi-Newton search as oracle), components with no signal at 0; over many draws the
    estimates are unbiased to their std, and the likelihood-ratio test's p-values at
    ``tau = 0`` are no smaller than uniform ones (a conservative mixture)."""
    rng = np.random.default_rng(1)
    k = 60
    lam = np.exp(rng.uniform(0, 6, k))
    P = rng.normal(size=(10, k)) * np.sqrt(lam)  # one view's 10 coefficients' rows as in view_field
    degree = np.tile(DEGREES, 2)
    parts = [P[degree == d].T @ P[degree == d] for d in (1, 2)]
    s2 = 0.04
    for truth in (np.array([0.0, 0.0]), np.array([2e-3, 5e-3])):
        C = np.diag(s2 * lam) + sum(t * A for t, A in zip(truth, parts))
        L = np.linalg.cholesky(C)
        taus, ps = [], []
        for trial in range(300):
            z = L @ rng.normal(size=k)
            tau, cov, lr = fit_components(z, lam, parts, s2)
            if trial < 20:
                ref, ll = _ml_oracle(z, np.diag(s2 * lam), parts)
                C_got = np.diag(s2 * lam) + sum(t * A for t, A in zip(tau, parts))
                ll_got = -0.5 * (np.linalg.slogdet(C_got)[1] + z @ np.linalg.solve(C_got, z))
                assert ll_got >= ll - 1e-7  # at least as high as the oracle's maximum
            taus.append(tau)
            ps.append(chi2.sf(lr, 1) / 2 + chi2.sf(lr, 2) / 4 if lr > 0 else 1.0)
        taus = np.array(taus)
        if truth.any():
            on = truth > 0
            assert np.all(np.abs(taus.mean(axis=0)[on] - truth[on]) < 4 * taus.std(axis=0)[on] / np.sqrt(300)
                          + 0.1 * truth[on])
        else:
            assert np.mean(np.array(ps) < 0.05) < 0.05 + 3 * np.sqrt(0.05 * 0.95 / 300)


def test_the_fields_information_and_response_equal_the_dense_oracle():
    """Three sessions with robot errors (priors), noise and a field in every view: the
    fields' response ``G = S^-1 S_cf`` and their estimated RMS equal those of a dense
    oracle (every point, every view's errors and every field coefficient in one finite-
    difference Jacobian, the ML estimate of ``tau`` by a bounded 1-D search)."""
    s_rot, s_pos = 0.1, 1.0
    sc = session_scene(21, n_sessions=3, views_per_session=3, n_points=20, noise_px=0.3)
    rep, _ = with_robot_error(sc, s_rot, s_pos, rng=22)
    rng = np.random.default_rng(5)
    V, n = rep.uv.shape[:2]
    seen = np.isfinite(rep.uv[..., 0])
    fields = rng.normal(0.0, 0.3, (V, 2, N_BASIS))
    uv = rep.uv + np.stack([np.einsum("nl,kl->nk", _basis_oracle(rep.uv[i].T), fields[i]) for i in range(V)])
    flange = FlangeModel(np.transpose(rep.R, (0, 2, 1)), sc.t_X.copy(), np.eye(3))
    start = Calibration(camera=Camera(sc.K, sc.R_X.T), X=sc.X, residuals_px=np.zeros_like(sc.uv), rms_px=0.0,
                        T=rep.T)
    opts = RefineOptions(distortion="none", robot_sigma_deg=s_rot, robot_sigma_pos=s_pos, tol=1e-12)
    cal = fit_refine(uv, rep.T, start, opts, flange=flange)
    lin = linearise(uv, rep.T, cal, opts, polish=0)
    cv = covariance(lin.state, lin.layout, lin.data)
    got = view_field(lin.state, lin.layout, lin.data, cv.system, cv.Sinv, cal.sigma_px, BOX)

    re, w = cal.robot_error, cal.sigma_px / np.array([np.radians(s_rot), s_pos])
    p_cam = 10
    theta0 = np.concatenate([[cal.K[0, 0], cal.K[1, 1], cal.K[0, 2], cal.K[1, 2]], np.zeros(3), cal.hand_eye.t,
                             cal.X.ravel(), np.radians(re.rot_deg).ravel(), re.pos.ravel(),
                             np.zeros(V * 2 * N_BASIS)])
    n_e = 6 * V

    def residuals(theta):
        K = np.array([[theta[0], 0, theta[2]], [0, theta[1], theta[3]], [0, 0, 1.0]])
        R = rotvec_to_matrix(theta[4:7]) @ cal.R
        t, X = theta[7:10], theta[10: 10 + 3 * n].reshape(n, 3)
        E = theta[10 + 3 * n: 10 + 3 * n + n_e].reshape(2, V, 3)
        a = theta[10 + 3 * n + n_e:].reshape(V, 2, N_BASIS)
        Ri, Ti = perturb_poses(rep.R, rep.T, np.hstack([E[0], E[1]]))
        pred = project(K, R @ np.transpose(Ri, (0, 2, 1)), X, Ti + Ri @ t)
        pred = pred + np.stack([np.einsum("nl,kl->nk", _basis_oracle(uv[i].T), a[i]) for i in range(V)])
        r = (pred - uv)[seen].ravel()
        return np.concatenate([r, w[0] * E[0].ravel(), w[1] * E[1].ravel()])

    J, r = _jacobian(residuals, theta0), -residuals(theta0)
    f = np.arange(10 + 3 * n + n_e, len(theta0))
    c = np.setdiff1d(np.arange(len(theta0)), f)
    A = J.T @ J
    Acc_inv = np.linalg.inv(A[np.ix_(c, c)])
    G = (Acc_inv @ A[np.ix_(c, f)])[:p_cam]
    Q = A[np.ix_(f, f)] - A[np.ix_(f, c)] @ Acc_inv @ A[np.ix_(c, f)]
    g = J[:, f].T @ r - A[np.ix_(f, c)] @ Acc_inv @ (J[:, c].T @ r)
    lam, vec = np.linalg.eigh(Q)
    pts = np.arange(10, 10 + 3 * n)  # the fields' information with the points alone eliminated: S_ff
    S_ff = A[np.ix_(f, f)] - A[np.ix_(f, pts)] @ np.linalg.solve(A[np.ix_(pts, pts)], A[np.ix_(pts, f)])
    keep = lam > 1e-3 * np.median(np.diag(S_ff))
    z, P = vec[:, keep].T @ g, vec[:, keep] * lam[keep]
    degree = np.tile(DEGREES, 2 * V)
    tau, _ = _ml_oracle(z, np.diag(cal.sigma_px**2 * lam[keep]), [P[degree == d].T @ P[degree == d] for d in (1, 2)])
    names = ("fx", "fy", "cx", "cy", "rx", "ry", "rz", "t_x", "t_y", "t_z")
    k = [lin.layout.names().index(nm) for nm in names]
    assert np.abs(got.G[k] - G).max() / np.abs(G).max() < 1e-5
    assert got.p_value < 1e-6
    assert np.all(np.abs(got.tau - tau) <= 1e-3 * np.sqrt(np.diag(got.tau_cov)))  # to a thousandth of its std
    assert abs(got.rms_px - np.sqrt(tau @ [2, 3])) < 1e-3 * got.rms_std_px
    assert 0.4 < got.rms_px < 1.0  # the fields drawn: sqrt(5) 0.3 = 0.67 px RMS


def _tracks_with_fields(tmp_path, field_px: float):
    """A scene of 400 points in 8 views, 0.1 px noise, each view's tracks bent by its own
    field of degree 1 and 2 of ``field_px`` per coefficient; tracks.csv and poses.csv."""
    from transcalib import simulate
    from transcalib import io as tio

    sc = simulate.random_scene(400, 8, noise_px=0.1, rng=7)
    rng = np.random.default_rng(8)
    uv = sc.uv.copy()
    for i in range(len(uv)):
        B = _basis_oracle(uv[i].T, (0.0, 0.0, 800.0, 600.0))
        uv[i] += B @ rng.normal(0.0, field_px, (N_BASIS, 2))
    tio.write_tracks_csv(tmp_path / "t.csv", uv)
    tio.write_poses_csv(tmp_path / "p.csv", sc.T)
    return tmp_path / "t.csv", tmp_path / "p.csv"


def test_cli_reports_the_field_and_widens_the_std_only_where_found(tmp_path, capsys):
    """Through ``calibrate``: a field of 0.02 px per coefficient under 0.1 px noise is found
    (summary line, calibration.json and --json), the model std grows by its share and the
    estimate stays; ``--no-view-field`` reports none; the saved file loads back."""
    import json

    from transcalib.cli.main import main
    from transcalib.io.calibration_file import load_calibration

    tracks, poses = _tracks_with_fields(tmp_path, 0.02)
    runs = {}
    for name, extra in (("on", []), ("off", ["--no-view-field"])):
        out = tmp_path / name
        code = main(["calibrate", "--tracks", str(tracks), "--poses", str(poses), "--out", str(out),
                     "--formats", "json", "--uncertainty", "model", *extra])
        assert code in (0, 1)
        runs[name] = (capsys.readouterr().out, json.loads((out / "calibration.json").read_text()), out)
    text_on, doc_on, out_on = runs["on"]
    text_off, doc_off, _ = runs["off"]
    vf = doc_on["estimates"]["uncertainty"]["view_field"]
    assert vf["included"] and vf["p_value"] < 0.05 and 0.005 < vf["rms_px"] < 0.2
    assert "Per-view error field:" in text_on and "included in the model-based std" in text_on
    assert doc_off["estimates"]["uncertainty"]["view_field"] is None and "Per-view error field" not in text_off
    assert doc_on["K"] == doc_off["K"]  # the estimate does not change
    assert doc_on["std"]["fx"] > 1.05 * doc_off["std"]["fx"]
    back = load_calibration(out_on).uncertainty.view_field
    assert back.included and back.rms_px == pytest.approx(vf["rms_px"], rel=1e-12)


def test_option_validated():
    from transcalib.types import InputError, RefineOptions

    with pytest.raises(InputError, match="view_field must be True or False"):
        RefineOptions(view_field="no")


def test_white_noise_rarely_finds_a_field():
    """Pure white noise on 40 random scenes: the test's false alarms stay near its 5 %
    level (at most 6 of 40), and the std then changes little."""
    from transcalib import calibrate, simulate

    found = 0
    for k in range(40):
        sc = simulate.random_scene(150, 6, noise_px=0.3, rng=100 + k)
        cal = calibrate(sc.uv, sc.T, rng=0)
        found += cal.uncertainty.view_field.included
    assert found <= 6


def test_many_points_of_white_noise_find_no_field():
    """10^5 points of white noise in 5 views: the directions the model absorbs all but
    1e-5 of (where the fit's second-order terms, not noise, are what is left) stay out
    of the estimate; before, they made tau 2e4 px^2 there."""
    from transcalib import calibrate, simulate

    sc = simulate.random_scene(100_000, 5, noise_px=0.5, rng=1)
    vf = calibrate(sc.uv, sc.T, rng=0).uncertainty.view_field
    assert vf.rms_px < 0.01


def test_a_sample_of_the_points_measures_what_all_of_them_do(monkeypatch):
    """Above ``MAX_POINTS`` the fields are measured on blocks of points spread over
    them, with the sample's own information on the camera: on 8000 points in 6 views
    with a field of 0.03 px per coefficient, half the points give the fields' RMS and
    their share of fx's and cx's std within 25 % of what every point gives."""
    from dataclasses import replace

    from transcalib import calibrate, simulate
    import transcalib.estimate.view_field as vfm

    sc = simulate.random_scene(8000, 6, noise_px=0.3, rng=11)
    rng = np.random.default_rng(12)
    uv = sc.uv.copy()
    for i in range(len(uv)):
        uv[i] += _basis_oracle(uv[i].T, (0.0, 0.0, 800.0, 600.0)) @ rng.normal(0.0, 0.03, (N_BASIS, 2))
    cal = calibrate(uv, sc.T, rng=0)
    opts = replace(cal.options.refinement, distortion=cal.dist_model)
    lin = linearise(uv, sc.T, cal, opts, polish=0)
    cv = covariance(lin.state, lin.layout, lin.data)
    out = {}
    for cap in (10**6, 4096):
        monkeypatch.setattr(vfm, "MAX_POINTS", cap)
        out[cap] = view_field(lin.state, lin.layout, lin.data, cv.system, cv.Sinv, cal.sigma_px, (0, 0, 800, 600))
    full, sample = out[10**6], out[4096]
    assert full.detected and sample.detected
    assert abs(sample.rms_px / full.rms_px - 1) < 0.25
    k = [lin.layout.names().index(nm) for nm in ("fx", "cx")]
    ratio = np.sqrt(np.diag(sample.covariance())[k] / np.diag(full.covariance())[k])
    assert np.all(np.abs(ratio - 1) < 0.25)
