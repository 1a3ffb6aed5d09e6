"""The result of a refinement (:mod:`.refine`): the covariance at the solution, the
uncertainty it reports (model-based, sandwich, the views' error fields), the residuals,
the robot pose error found, the hand-eye pose, and the :class:`Calibration` that holds them.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..errors import DegenerateError
from ..geometry.camera import DIST_MODELS, DIST_NAMES, Camera, K_from_params
from ..geometry.rotation import matrix_to_rotvec
from ..types import (CalibrateOptions, Calibration, CalibrationStats, HandEye, LinearEstimate, RefineOptions,
                     RefineStats, RobotError, SessionErrorEstimate, Uncertainty, ViewFieldEstimate,
                     ViewRotations)
from ..types.options import SESSION_TOLERANCE_DEG
from .bundle import all_residuals, sum_sq
from .covariance import covariance, sandwich
from .degeneracy import identifiability_hint
from .distributions import chi2_sf
from .layout import Layout, State, complement
from .robot_error import COMPONENTS
from .robot_scales import robot_error_on
from .session_error import session_error
from .variance_components import MISFIT_ALPHA
from .view_field import view_field

__all__ = ["result", "diverged", "SANDWICH_ALPHA"]

#: Level of the per-parameter test with which ``uncertainty="auto"`` reports the sandwich
#: (its variance significantly above the model's). 5 %: with the model right the reported
#: RMS std stays within 2 % of the model's (the CRB), under misfit the coverage is within
#: 0.5-2 points of the sandwich's own (1 %: 2-3 points below; bench_sandwich.py).
SANDWICH_ALPHA = 0.05


def result(pb, fitter, fit, initial, t_start, full: bool = True) -> Calibration:
    """Covariance at the solution and the :class:`Calibration` of a refinement: ``pb`` its
    problem, ``fitter`` the fitter its stages ran (the cost, reason, iterations, threshold
    and Gauss-Newton system of the last), ``fit`` their outcome, ``initial`` the start
    (its camera's image size, linear estimate and hand-eye record are kept), ``t_start``
    :func:`time.perf_counter` at the start. ``full=False``: the model's ``sigma^2 S^-1``
    alone, ``uncertainty`` None (no sandwich, views' error fields or sessions' error;
    :func:`~transcalib.estimate.refine.fit_refine_deferred`)."""
    lay, n_views, n_points = fit.lay, *pb.uv.shape[:2]
    cv = covariance(fit.last, lay, fit.data, hint=lambda names: identifiability_hint(names, pb.T),
                    system=fitter.system)
    var_X, ok = cv.var_X, cv.ok
    dof_fit = lay.residual_dof(int(fit.mask[:, fit.idx].sum()), len(fit.idx))
    sigma = _sigma(pb, fit, fitter.cost, dof_fit)
    if full:
        uncertainty, cov = _uncertainty(fit, lay, cv, sigma, pb.opts)
    else:
        d = _degrees(lay)
        uncertainty, cov = None, sigma**2 * cv.Sinv * np.outer(d, d)
    names = lay.names()
    negative = [nm for nm, v in zip(names, np.diag(cov)) if not v >= 0]
    if negative:  # no minimum: the information is not positive there
        raise diverged(fit.state.intr, f"where {', '.join(negative)} would have a negative variance")
    std = _std(cov, names)
    X_std = np.full((n_points, 3), np.nan)
    X_std[fit.idx[ok]] = sigma * np.sqrt(var_X[ok])
    X = np.full((n_points, 3), np.nan)
    X[pb.used_idx] = fit.state.X
    residuals, rms = _residuals(pb, fit, fitter)
    T_std = None
    if lay.i_T:
        T_std = np.zeros((n_views, 3))
        for i, s in lay.i_T.items():
            T_std[i] = np.sqrt(np.diag(cov)[s: s + 3])
    image_size = initial.camera.image_size if isinstance(initial, Calibration) else None
    slots = [DIST_NAMES.index(k) for k in DIST_MODELS[pb.opts.distortion]]
    camera = Camera(K_from_params(*fit.state.intr), fit.state.R, fit.state.dist5[slots], pb.opts.distortion,
                    image_size)
    linear = initial if isinstance(initial, LinearEstimate) else getattr(initial, "linear", None)
    return Calibration(
        camera=camera, X=X, residuals_px=residuals, rms_px=rms,
        T=fit.state.T.copy(), sigma_px=sigma, linear=linear, cov=cov, std=std, param_names=names, X_std=X_std,
        inliers=fit.inliers, T_std=T_std, view_rotations=_view_rotations(lay, fit.state, cov, n_views),
        flange_rotations=None if fit.state.F is None else np.transpose(fit.state.F, (0, 2, 1)),
        hand_eye=None if fit.state.F is None else _hand_eye(lay, fit.state, cov, initial),
        robot_error=_robot_error(pb, fit, cov), uncertainty=uncertainty,
        options=CalibrateOptions(robust=False, refinement=pb.opts),
        stats=CalibrationStats(stages=("refine",), refine=_stats(pb, fitter, dof_fit, int(np.sum(~ok)), t_start)))


def diverged(intr, where: str = "") -> DegenerateError:
    """The error of a refinement that ran away (intrinsics ``intr``: fx, fy, cx, cy, ...;
    ``where``: what else shows it), saying what usually causes it."""
    fx, fy, cx, cy = (float(v) for v in intr[:4])
    return DegenerateError(
        f"the refinement diverged (it reached fx = {fx:.3g}, fy = {fy:.3g}, cx = {cx:.3g}, cy = {cy:.3g} px"
        f"{', ' + where if where else ''}): the images and the poses disagree too much for one camera. Most often "
        "a pose was typed wrong or belongs to another run, or most tracks are wrong; check the poses (a view far off "
        "its neighbours), then the tracks.")


def _degrees(lay: Layout) -> np.ndarray:
    """(p,) the factor of each parameter into the reported units: rotations in degrees."""
    return np.where(lay.rotation_mask(), np.degrees(1.0), 1.0)


def _std(cov: np.ndarray, names: tuple) -> dict:
    """``sqrt(diag(cov))`` by name; with square pixels ``f`` also as ``fx``, ``fy``."""
    std = {nm: float(np.sqrt(cov[k, k])) for k, nm in enumerate(names)}
    if "f" in std:
        std["fx"] = std["fy"] = std["f"]
    return std


def _uncertainty(fit, lay: Layout, cv, sigma: float, opts: RefineOptions) -> tuple[Uncertainty, np.ndarray]:
    """The model-based covariance ``sigma^2 S^-1`` (plus the views' error fields where
    the residuals show them, :func:`_view_field`) and the sandwich (:func:`sandwich`)
    side by side, and the covariance ``Calibration.cov`` reports (rotations in degrees):
    the one ``opts.uncertainty`` chooses, plus the sessions' common robot error where its
    test finds it (:func:`_session_error`), added to either.

    ``opts.uncertainty``: "model", "robust", "max" (per parameter the larger), or
    "auto": per parameter the sandwich where its variance ratio to the model's is
    significant, ``P(chi2(nu)/nu >= ratio) < SANDWICH_ALPHA`` (``nu`` its effective dof),
    else the model's. The chosen covariance is the model's with those rows and columns
    scaled by the std ratio (``D C D``: the model's correlations, positive
    semi-definite); with "robust" the sandwich itself.

    The two components differ in what the sandwich sees of them. A view's field stays in
    the residuals, and the sandwich takes up part of it, for some parameters all (fx on
    tests/test_view_field.py's tracks): so the model with the field and the sandwich are
    compared, as two estimates of one thing. A session's error moves its views' robot
    error columns, which the fit estimates, so it hardly shows in the residuals and the
    sandwich, clustered by point, holds none of it: reported without it, the hand-eye
    offset's pooled RMS z was 5.96 under a mostly common session error, 0.94 with it
    (tests/test_session_error.py).
    """
    names, rule = lay.names(), opts.uncertainty
    scale = _degrees(lay)
    in_units = lambda c: c * scale[:, None] * scale[None, :]  # noqa: E731
    field, cov_field = _view_field(fit, lay, cv, sigma) if opts.view_field else (None, 0.0)
    sessions, cov_sessions = _session_error(fit, lay, cv, sigma) if opts.session_error else (None, 0.0)
    cov_model, cov_sessions = in_units(sigma**2 * cv.Sinv + cov_field), in_units(cov_sessions)
    try:
        sw = sandwich(fit.last, lay, fit.data, cv.system, cv.Sinv, None if cv.ok.all() else cv.ok)
        cov_robust, dof = in_units(sw.cov), sw.dof
        replicated = int(np.isfinite(np.diag(sw.cov)).sum())  # not a view's priors alone
        misfit = float(np.trace(cv.Sinv @ sw.meat) / (sigma**2 * replicated)) if sigma > 0 else np.nan
        n_clusters = sw.n_clusters
    except DegenerateError:  # a point alone determines a parameter combination: no sandwich
        cov_robust, dof, misfit, n_clusters = np.full_like(cov_model, np.nan), np.full(lay.size, np.nan), np.nan, 0
    v_model, v_robust = np.diag(cov_model), np.diag(cov_robust)
    ratio = v_robust / np.where(v_model > 0, v_model, np.nan)
    p_value = np.where(np.isfinite(ratio) & (dof > 0), chi2_sf(dof * np.nan_to_num(ratio), dof), np.nan)
    robust = np.isfinite(ratio) & {"model": False, "robust": True, "max": ratio > 1,
                                   "auto": p_value < SANDWICH_ALPHA}[rule]
    if rule == "robust" and robust.all():
        cov = cov_robust
    else:
        d = np.where(robust, np.sqrt(np.nan_to_num(ratio, nan=1.0)), 1.0)
        cov = cov_model * d[:, None] * d[None, :]
    cov_model, cov_robust = cov_model + cov_sessions, cov_robust + cov_sessions
    named = lambda v: {nm: float(x) for nm, x in zip(names, v)}  # noqa: E731
    unc = Uncertainty(_std(cov_model, names), _std(cov_robust, names), cov_robust, named(dof), named(p_value),
                      {nm: "robust" if r else "model" for nm, r in zip(names, robust)}, misfit, n_clusters, field,
                      sessions)
    return unc, cov + cov_sessions


def _view_field(fit, lay: Layout, cv, sigma: float) -> tuple[ViewFieldEstimate | None, np.ndarray | float]:
    """The views' error fields at the solution (:mod:`.view_field`, the basis over the
    tracked area) and their share of the model's covariance (unit px^2, 0 unless the
    test finds them). None without pixel noise to measure them against."""
    if not sigma > 0:
        return None, 0.0
    seen = [u for u in fit.data.uv if u.size]  # the tracked area, without a copy of every observation
    box = np.concatenate([np.min([u.min(axis=1) for u in seen], axis=0), np.max([u.max(axis=1) for u in seen], axis=0)])
    vf = view_field(fit.last, lay, fit.data, cv.system, cv.Sinv, sigma, box, None if cv.ok.all() else cv.ok)
    est = ViewFieldEstimate(vf.rms_px, vf.rms_std_px, vf.tau, vf.p_value, vf.detected)
    return est, vf.covariance() if vf.detected else 0.0


def _session_error(fit, lay: Layout, cv, sigma: float) -> tuple[SessionErrorEstimate | None, np.ndarray | float]:
    """The robot error common to each session (:mod:`.session_error`) and its share of
    the model's covariance (unit px^2, 0 unless the test finds it)."""
    se = session_error(fit.last, lay, fit.data, cv.system, cv.Sinv, sigma, SESSION_TOLERANCE_DEG)
    if se is None:
        return None, 0.0
    scale = {"rot": np.degrees(1.0), "pos": 1.0}
    sd = {c: float(np.sqrt(se.tau.get(c, 0.0)) * scale[c]) for c in scale}
    sd_std = {c: float(np.sqrt(se.tau_cov[c]) * scale[c] ** 2 / (2 * sd[c])) if sd[c] > 0 else float("nan")
              for c in scale}
    est = SessionErrorEstimate(sd["rot"], sd_std["rot"], sd["pos"], sd_std["pos"], se.p_value, se.n_sessions,
                               se.detected)
    return est, se.covariance() if se.detected else 0.0


def _residuals(pb, fit, fitter) -> tuple[np.ndarray, float]:
    """Residuals ``(n_views, n_points, 2)`` of the used points at the solution (NaN
    elsewhere) and their RMS norm (px): the Gauss-Newton steps' own residuals when they
    cover every observation."""
    out = np.full(pb.uv.shape, np.nan)
    if fitter.residuals is not None and fit.last is fit.state:
        idx = pb.used_idx
        for i, (pts, r) in enumerate(zip(fit.data.pts, fitter.residuals)):
            out[i, idx[pts]] = r.T
        sse = sum(float(np.einsum("kn,kn->", r, r)) for r in fitter.residuals)
        return out, float(np.sqrt(sse / fit.data.n_obs))
    used = all_residuals(fit.state, pb.lay, pb.uv, pb.seen, pb.used_idx, pb.T)
    out[:, pb.used_idx] = used
    return out, float(np.sqrt(np.nanmean(np.einsum("vnk,vnk->vn", used, used))))


def _sigma(pb, fit, cost: float, dof_fit: int) -> float:
    """Pixel noise per coordinate: the one the translation priors used, the known one, or
    ``sqrt(sum |r|^2 / dof)`` of the final least-squares stage (whose ``cost`` is half the sum)."""
    if fit.sigma_T_mode is not None:
        return fit.sigma_T_mode
    if pb.opts.sigma_px is not None:
        return float(pb.opts.sigma_px)
    if dof_fit <= 0:
        raise DegenerateError("no residual degrees of freedom left among the inliers to estimate the pixel "
                              "noise; pass sigma_px or track more points")
    sse = 2.0 * cost if not pb.lay.i_T else sum_sq(fit.last, pb.lay, fit.data)
    return float(np.sqrt(sse / dof_fit))


def _stats(pb, fit, dof_fit, n_undetermined, t_start) -> RefineStats:
    n_points = pb.uv.shape[1]
    return RefineStats(
        iterations=int(fit.iterations), cost=float(fit.cost), stop_reason=fit.reason,
        converged=fit.reason.startswith("converged"), dof=int(dof_fit),
        n_observations=int(pb.seen[:, pb.used_idx].sum()), n_points_used=int(len(pb.used_idx)),
        n_points_excluded=int(n_points - len(pb.used_idx)), n_points_behind_camera=pb.n_behind,
        n_points_undetermined=n_undetermined,
        inlier_threshold_px=fit.thr if pb.opts.loss != "linear" else None, time_s=time.perf_counter() - t_start)


def _hand_eye(lay: Layout, state: State, cov: np.ndarray, initial) -> HandEye:
    """The camera's pose in the flange (or, eye-to-hand, the base) with its uncertainty:
    ``R = R_model^T``, ``t`` and its covariance ``B cov_t B^T`` along the determined
    directions ``B``; the setup, sessions and notes of ``initial`` when it has them."""
    B = lay.t_basis if lay.t_free else np.zeros((3, 0))
    it = slice(lay.i_t, lay.i_t + lay.n_t)
    t_cov = B @ cov[it, it] @ B.T if lay.t_free else np.zeros((3, 3))
    R_std = np.sqrt(np.diag(cov)[lay.i_rot: lay.i_rot + 3])
    before = getattr(initial, "hand_eye", None)
    if before is None:
        setup = "eye-to-hand" if lay.robot_inverted else "eye-in-hand"
        before = HandEye(setup, np.eye(3), np.zeros(3), np.zeros(3), np.zeros((3, 3)), np.eye(3),
                         np.zeros(lay.n_views, int), ("0",))
    return replace(before, R=state.R.T.copy(), t=state.t.copy(), R_std_deg=R_std, t_cov=t_cov,
                   undetermined=complement(B))


def _robot_error(pb, fit, cov: np.ndarray) -> RobotError | None:
    """The robot pose error found (:class:`RobotError`; None when not in play): scales with
    their std ``sigma / sqrt(2 r)``, each view's error and std from ``cov`` (degrees)."""
    if not robot_error_on(pb.opts):
        return None
    lay, rf, n_views = fit.lay, fit.robot, len(pb.T)
    E = np.zeros((n_views, 6)) if fit.state.E is None else fit.state.E
    std = np.zeros((n_views, 6))
    for k, comp in enumerate(COMPONENTS):
        if comp in lay.robot:
            std[:, 3 * k: 3 * k + 3] = np.sqrt(np.diag(cov)[lay.robot_columns(comp)])
    sigma, sd, source = [], [], []
    for comp in COMPONENTS:
        s = rf.sigma.get(comp, 0.0) if rf is not None else 0.0
        r = rf.r.get(comp, 0.0) if rf is not None else 0.0
        given = pb.robot_given.get(comp, 0.0)
        misfit = rf is not None and rf.consistency.get(comp, 1.0) < MISFIT_ALPHA
        source.append("off" if comp not in pb.robot_given else "given" if given is not None
                      else "estimated" if s > 0 else "misfit" if misfit else "not detected")
        sigma.append(s)
        sd.append(s / np.sqrt(2 * r) if source[-1] == "estimated" and r > 0 else 0.0)
    p = np.array([np.nan, np.nan]) if rf is None else np.array([rf.p_values[c] for c in COMPONENTS])
    r = np.zeros(2) if rf is None else np.array([rf.r.get(c, 0.0) for c in COMPONENTS])
    pc = np.array([np.nan if rf is None else rf.consistency.get(c, np.nan) for c in COMPONENTS])
    score = np.array([np.nan if rf is None else rf.scores.get(c, np.nan) for c in COMPONENTS])
    return RobotError(float(np.degrees(sigma[0])), float(sigma[1]), float(np.degrees(sd[0])), float(sd[1]),
                      tuple(source), np.degrees(E[:, :3]), E[:, 3:].copy(), std[:, :3], std[:, 3:], r, p,
                      bool(lay.robot_inverted), pc, np.array([np.degrees(score[0]), score[1]]))


def _view_rotations(lay, state, cov, n_views) -> ViewRotations | None:
    """Fitted view rotations (degrees), their std and Wald statistics ``w^T cov^-1 w``
    (chi-square(3) if the view did not rotate); None without view rotations."""
    if not lay.i_vrot:
        return None
    rot, std, chi2 = np.zeros((n_views, 3)), np.zeros((n_views, 3)), np.zeros(n_views)
    for i, s in lay.i_vrot.items():
        rot[i] = np.degrees(matrix_to_rotvec(state.Q[i]))
        std[i] = np.sqrt(np.diag(cov)[s: s + 3])
        chi2[i] = rot[i] @ np.linalg.solve(cov[s: s + 3, s: s + 3], rot[i])
    return ViewRotations(rot, std, chi2)
