"""Tests of the cluster-robust (sandwich) covariance (estimate/covariance.py::sandwich) and
of how the refinement reports it (Calibration.uncertainty)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from transcalib import estimate_linear, simulate
from transcalib.estimate.layout import FlangeModel
from transcalib.estimate.refine import fit_refine, fit_refine_deferred, refine
from transcalib.estimate.robot_error import perturb_poses
from transcalib.geometry.camera import project
from transcalib.geometry.rotation import rotvec_to_matrix
from transcalib.handeye.simulate import session_scene, with_robot_error
from transcalib.types import Calibration, Camera, InputError, RefineOptions


def _jacobian(residuals, theta0: np.ndarray) -> np.ndarray:
    """Central differences of ``residuals`` at ``theta0``."""
    J = np.empty((len(residuals(theta0)), len(theta0)))
    for k in range(len(theta0)):
        h = 1e-6 * max(1.0, abs(theta0[k]))
        d = np.zeros_like(theta0)
        d[k] = h
        J[:, k] = (residuals(theta0 + d) - residuals(theta0 - d)) / (2 * h)
    return J


def _dense_cr2_sandwich(J: np.ndarray, r: np.ndarray, clusters: list) -> np.ndarray:
    """The oracle: every parameter (points included) in one dense Jacobian ``J (N, P)``,
    residuals ``r (N,)``, clusters as lists of row indices; ``B^-1 (sum_c J_c^T r*_c
    r*_c^T J_c) B^-1`` with ``B = J^T J`` and CR2 residuals ``r*_c = (I - H_cc)^(+1/2) r_c``
    (the pseudo-inverse square root: a point's own directions have leverage 1)."""
    Binv = np.linalg.inv(J.T @ J)
    M = np.zeros_like(Binv)
    for rows in clusters:
        Jc = J[rows]
        lam, Q = np.linalg.eigh(Jc @ Binv @ Jc.T)
        f = np.where(lam < 1 - 1e-6, 1.0 / np.sqrt(np.clip(1 - lam, 1e-300, None)), 0.0)
        g = Jc.T @ (Q @ (f * (Q.T @ r[rows])))
        M += np.outer(g, g)
    return Binv @ M @ Binv


def _point_clusters(seen: np.ndarray) -> list:
    """Row indices of each point's observations in ``project(...)[seen].ravel()`` order."""
    V, n = seen.shape
    obs = np.full((V, n), -1)
    obs[seen] = np.arange(seen.sum())
    return [np.concatenate([[2 * k, 2 * k + 1] for k in obs[:, j] if k >= 0]).astype(int) for j in range(n)]


def _to_degrees(cov: np.ndarray, rot: slice) -> np.ndarray:
    cov = cov.copy()
    cov[rot, :] *= np.degrees(1.0)
    cov[:, rot] *= np.degrees(1.0)
    return cov


def test_sandwich_equals_the_dense_oracle_one_session():
    """Heteroscedastic noise (per-point scales 0.1-2 px, so the sandwich is not the
    model): the reported sandwich of fx, fy, cx, cy, R equals the dense CR2 sandwich with
    the points as parameters."""
    rng = np.random.default_rng(3)
    sc = simulate.random_scene(12, 5, rng=4)
    uv = sc.uv_true + rng.normal(size=sc.uv.shape) * rng.uniform(0.1, 2.0, (1, 12, 1))
    cal = refine(uv, sc.T, estimate_linear(uv, sc.T), options=RefineOptions(distortion="none", tol=1e-12))
    V, n = uv.shape[:2]
    seen = np.isfinite(uv[..., 0])
    theta0 = np.concatenate([[cal.K[0, 0], cal.K[1, 1], cal.K[0, 2], cal.K[1, 2]], np.zeros(3), cal.X.ravel()])

    def residuals(theta):
        K = np.array([[theta[0], 0, theta[2]], [0, theta[1], theta[3]], [0, 0, 1.0]])
        R = rotvec_to_matrix(theta[4:7]) @ cal.R
        return (project(K, R, theta[7:].reshape(n, 3), sc.T) - uv)[seen].ravel()

    J, r = _jacobian(residuals, theta0), residuals(theta0)
    oracle = _to_degrees(_dense_cr2_sandwich(J, r, _point_clusters(seen))[:7, :7], slice(4, 7))
    k = [cal.param_names.index(nm) for nm in ("fx", "fy", "cx", "cy", "rx", "ry", "rz")]
    got = cal.uncertainty.cov_robust[np.ix_(k, k)]
    assert np.abs(got - oracle).max() / np.abs(oracle).max() < 1e-5
    ratio = np.sqrt(np.diag(got) / np.diag(cal.cov[np.ix_(k, k)]))
    assert np.abs(ratio - 1).max() > 0.1  # the data are heteroscedastic: not the model's


@pytest.mark.parametrize("unseen", [None, 4])
def test_sandwich_with_robot_error_priors_equals_the_dense_oracle(unseen):
    """Three sessions, robot pose errors with given scales (priors: one cluster per view,
    rows ``w I``): the sandwich of K, R_X, t_X equals the dense CR2 sandwich with every
    point and every view's errors as parameters. With a view that sees nothing (left out)
    its errors are its priors' alone: their sandwich is NaN (the model's std reported),
    the others' still that of the oracle, whose CR2 factor drops a cluster of leverage 1."""
    s_rot, s_pos = 0.1, 1.0
    sc = session_scene(21, n_sessions=3, views_per_session=3, n_points=15, noise_px=0.5)
    rep, _ = with_robot_error(sc, s_rot, s_pos, rng=22)
    if unseen is not None:
        rep.uv[unseen] = np.nan
    flange = FlangeModel(np.transpose(rep.R, (0, 2, 1)), sc.t_X.copy(), np.eye(3))
    start = Calibration(camera=Camera(sc.K, sc.R_X.T), X=sc.X, residuals_px=np.zeros_like(sc.uv), rms_px=0.0,
                        T=rep.T)
    opts = RefineOptions(distortion="none", robot_sigma_deg=s_rot, robot_sigma_pos=s_pos, tol=1e-12)
    cal = fit_refine(rep.uv, rep.T, start, opts, flange=flange)
    V, n = rep.uv.shape[:2]
    seen = np.isfinite(rep.uv[..., 0])
    re = cal.robot_error
    w = cal.sigma_px / np.array([np.radians(s_rot), s_pos])  # the priors' weights, px per unit
    theta0 = np.concatenate([[cal.K[0, 0], cal.K[1, 1], cal.K[0, 2], cal.K[1, 2]], np.zeros(3), cal.hand_eye.t,
                             cal.X.ravel(), np.radians(re.rot_deg).ravel(), re.pos.ravel()])

    def residuals(theta):
        K = np.array([[theta[0], 0, theta[2]], [0, theta[1], theta[3]], [0, 0, 1.0]])
        R = rotvec_to_matrix(theta[4:7]) @ cal.R
        t, X = theta[7:10], theta[10: 10 + 3 * n].reshape(n, 3)
        E = theta[10 + 3 * n:].reshape(2, V, 3)
        Ri, Ti = perturb_poses(rep.R, rep.T, np.hstack([E[0], E[1]]))
        r = (project(K, R @ np.transpose(Ri, (0, 2, 1)), X, Ti + Ri @ t) - rep.uv)[seen].ravel()
        return np.concatenate([r, w[0] * E[0].ravel(), w[1] * E[1].ravel()])

    J, r = _jacobian(residuals, theta0), residuals(theta0)
    n_px = 2 * int(seen.sum())
    priors = [np.concatenate([n_px + 3 * i + np.arange(3), n_px + 3 * (V + i) + np.arange(3)]) for i in range(V)]
    oracle = _to_degrees(_dense_cr2_sandwich(J, r, _point_clusters(seen) + priors)[:10, :10], slice(4, 7))
    names = ("fx", "fy", "cx", "cy", "rx", "ry", "rz", "t_x", "t_y", "t_z")
    k = [cal.param_names.index(nm) for nm in names]
    got = cal.uncertainty.cov_robust[np.ix_(k, k)]
    assert np.abs(got - oracle).max() / np.abs(oracle).max() < 1e-4
    own = [nm for nm in cal.param_names if nm.startswith(f"robot{unseen}_")]
    assert len(own) == (0 if unseen is None else 6)
    assert all(np.isnan(cal.uncertainty.std_robust[nm]) and cal.uncertainty.reported[nm] == "model"
               and np.isfinite(cal.std[nm]) for nm in own)
    assert np.isfinite(cal.uncertainty.misfit)


def test_noise_free_meat_is_zero_and_the_std_exact():
    """Exact data: every residual is ~0, so the meat and the sandwich std vanish (the
    model's too: sigma ~ 0); the result is the model's to the last bit."""
    sc = simulate.random_scene(30, 5, rng=5)
    cal = refine(sc.uv, sc.T, estimate_linear(sc.uv, sc.T), options=RefineOptions(distortion="none"))
    u = cal.uncertainty
    assert max(u.std_robust[k] for k in ("fx", "fy", "cx", "cy")) < 1e-7
    assert np.all(np.abs(u.cov_robust) < 1e-12)


def _heteroscedastic(seed: int):
    """A 60-point scene whose pixel noise grows with the distance from the image centre
    (0.15 + 1.2 (rho / rho_max)^2 px): the points that determine f are the noisy ones."""
    rng = np.random.default_rng(seed)
    sc = simulate.random_scene(60, 6, rng=7)
    uv = simulate.observe(sc, 0.0).uv
    c = np.array(sc.image_size) / 2 - 0.5
    rho = np.linalg.norm(uv - c, axis=2, keepdims=True) / np.linalg.norm(c)
    return sc, uv + rng.normal(size=uv.shape) * (0.15 + 1.2 * rho**2)


def test_model_right_sandwich_agrees_with_the_model_within_its_sampling_noise():
    """White 0.5 px noise, 30 scenes: the sandwich / model variance ratio averages 1 within
    3 standard errors predicted from the effective dof (``2 / dof`` per trial); the default
    reports the model's std in all but a few trials (its test at 5 %)."""
    ratios, dofs, robust = [], [], 0
    robust_fx = lambda u: u.reported["fx"] == "robust"  # noqa: E731
    for seed in range(30):
        sc = simulate.random_scene(60, 6, noise_px=0.5, rng=100 + seed)
        cal = refine(sc.uv, sc.T, estimate_linear(sc.uv, sc.T), options=RefineOptions(distortion="none",
                                                                                      robot_error=False))
        u = cal.uncertainty
        ratios.append((u.std_robust["fx"] / u.std_model["fx"]) ** 2)
        dofs.append(u.dof["fx"])
        robust += robust_fx(u)
        assert cal.std["fx"] == pytest.approx((u.std_robust if robust_fx(u) else u.std_model)["fx"], rel=1e-12)
    se = np.sqrt(np.mean(2 / np.array(dofs)) / len(ratios))
    assert abs(np.mean(ratios) - 1) < 3 * se
    assert np.std(ratios) < 2 * np.sqrt(np.mean(2 / np.array(dofs)))  # the spread the dof predicts, not more
    assert robust <= 4  # the test's 5 % level: 1.5 expected


def test_heteroscedastic_noise_switches_fx_to_the_sandwich():
    """Noise growing towards the edges: the model's fx std is too small (by ~2x, measured
    in bench_sandwich); the sandwich is significantly larger and the default reports it."""
    sc, uv = _heteroscedastic(1)
    cal = refine(uv, sc.T, estimate_linear(uv, sc.T), options=RefineOptions(distortion="none", robot_error=False))
    u = cal.uncertainty
    assert u.std_robust["fx"] > 1.3 * u.std_model["fx"]
    assert u.p_value["fx"] < 0.01 and u.reported["fx"] == "robust"
    assert cal.std["fx"] == pytest.approx(u.std_robust["fx"])
    k = cal.param_names.index("fx")
    assert np.sqrt(cal.cov[k, k]) == pytest.approx(u.std_robust["fx"])
    model = refine(uv, sc.T, estimate_linear(uv, sc.T),
                   options=RefineOptions(distortion="none", robot_error=False, uncertainty="model"))
    assert model.std["fx"] == pytest.approx(u.std_model["fx"], rel=1e-9)
    robust = refine(uv, sc.T, estimate_linear(uv, sc.T),
                    options=RefineOptions(distortion="none", robot_error=False, uncertainty="robust"))
    assert np.allclose(robust.cov, u.cov_robust, rtol=1e-9, atol=0)


def test_uncertainty_option_validated():
    with pytest.raises(InputError, match="uncertainty"):
        RefineOptions(uncertainty="sandwich")


@pytest.mark.parametrize("rule, which", [("model", "std_model"), ("robust", "std_robust")])
def test_cli_uncertainty_option_chooses_the_reported_std(tmp_path, rule, which):
    """``--uncertainty`` reaches the refinement: calibration.json's std is the chosen one."""
    import json
    from pathlib import Path

    from transcalib.cli.main import main

    paper = Path(__file__).resolve().parents[1] / "examples" / "paper"
    out = tmp_path / "out"
    code = main(["calibrate", "--tracks", str(paper / "tracks.csv"), "--poses", str(paper / "poses.csv"),
                 "--out", str(out), "--formats", "json", "--quiet", "--uncertainty", rule])
    assert code in (0, 1)
    d = json.loads((out / "calibration.json").read_text())
    unc = d["estimates"]["uncertainty"]
    assert d["options"]["refinement"]["uncertainty"] == rule
    assert set(unc["reported"].values()) == {"model" if rule == "model" else "robust"}
    assert d["std"]["fx"] == pytest.approx(unc[which]["fx"], rel=1e-9)


def test_summary_without_a_sandwich_says_why_and_prints_no_nan(tmp_path, capsys):
    """The paper's 24 tracks with ``--robot-sigma 0.1`` (make demo's first step): too few
    points for the cluster-robust check, so every std is the model's; the summary says so
    instead of printing NaN ratios."""
    from pathlib import Path

    from transcalib.cli.main import main

    paper = Path(__file__).resolve().parents[1] / "examples" / "paper"
    code = main(["calibrate", "--tracks", str(paper / "tracks.csv"), "--poses", str(paper / "poses.csv"),
                 "--robot-sigma", "0.1", "--out", str(tmp_path / "out"), "--formats", "json"])
    out = capsys.readouterr().out
    assert code in (0, 1)
    line = next(ln for ln in out.splitlines() if ln.startswith("Uncertainty:"))
    assert "model-based (too few points" in line and "nan" not in out.lower()


def test_deferred_fit_completes_to_the_full_result():
    """The pipeline's refits that may only judge the tracks defer the uncertainty: the
    light result holds the same solution with the model's covariance alone, and completed
    it is exactly :func:`fit_refine`'s (sandwich, views' fields, sessions' error)."""
    sc = session_scene(5, n_sessions=3, views_per_session=4, n_points=40, noise_px=0.5)
    rep, _ = with_robot_error(sc, 0.1, 1.0, rng=6)
    flange = FlangeModel(np.transpose(rep.R, (0, 2, 1)), sc.t_X.copy(), np.eye(3))
    start = Calibration(camera=Camera(sc.K, sc.R_X.T), X=sc.X, residuals_px=np.zeros_like(sc.uv), rms_px=0.0,
                        T=rep.T)
    opts = RefineOptions(distortion="none")
    full = fit_refine(rep.uv, rep.T, start, opts, flange=flange)
    later = fit_refine_deferred(rep.uv, rep.T, start, opts, flange=flange)
    done = later.complete()
    assert full.robot_error is not None and full.uncertainty.std_robust["fx"] > 0
    assert later.light.uncertainty is None
    for a, b in ((later.light.K, full.K), (later.light.X, full.X), (done.cov, full.cov),
                 (done.uncertainty.cov_robust, full.uncertainty.cov_robust),
                 (later.light.robot_error.pos, full.robot_error.pos)):
        np.testing.assert_array_equal(a, b)
    assert done.std == full.std
    plain = replace(opts, uncertainty="model", view_field=False, session_error=False)
    model = fit_refine(rep.uv, rep.T, start, plain, flange=flange)  # sigma^2 S^-1 alone
    np.testing.assert_allclose(later.light.cov, model.cov, rtol=1e-12, atol=0)
