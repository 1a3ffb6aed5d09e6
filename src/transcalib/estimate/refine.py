"""Maximum-likelihood refinement: the bundle adjuster run on a calibration problem.

Minimises ``0.5 sum_ij rho(|r_ij|^2) [+ 0.5 sum_i |T_i - T_i^meas|^2 sigma^2 / sigma_T^2]``
with ``r_ij = uv_ij - pi(K, dist, Q_i R (X_j - T_i))`` (paper eq. 2 with OpenCV
distortion; :mod:`transcalib.estimate.bundle`) over the free intrinsics, distortion,
``R``, every point and, with a robot precision ``sigma_T``, the translations (errors in
images *and* robot). Robust losses are minimised by IRLS inside Levenberg-Marquardt,
then the inlier observations are refitted by least squares so that estimate and
covariance are those of the inliers. The covariance is ``sigma^2 S^-1``
(:mod:`transcalib.estimate.covariance`), with ``sigma`` estimated from the residuals
(``sqrt(sum |r|^2 / dof)``) unless known.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Callable, NamedTuple

import numpy as np

from ..errors import DegenerateError, InputError
from ..geometry.camera import pad_dist
from ..types import Calibration, DistortionStep, LinearEstimate, RefineOptions
from ..types.options import check_fixed_distortion
from ..validate import as_uv_T
from .bundle import BundleProblem, all_residuals, cost, sum_sq
from .covariance import linearise, profile_step, reduced_information
from .distributions import f_sf
from .layout import FlangeModel, Layout, State, dist_indices, robot_sigma
from .noise import LOSS_SCALE, OBS_QUANTILE, SIGMA_FLOOR_PX, mad_sigma
from .observations import build_data
from .robot_error import COMPONENTS
from .refine_result import diverged, result
from .robot_scales import (DROP_FRACTION, DROP_REDUNDANCY, RobotFit, RobotStart, RunAway, check_growth,
                           component_sigma, extrapolated, robot_error_on, robot_weights)
from .solvers import gauss_newton, levenberg_marquardt
from .variance_components import (GATE_ALPHA, MAX_ROUNDS, MISFIT_ALPHA, RTOL, JointScore, moment_noise, redundancy,
                                  score_test)

__all__ = ["refine", "fit_refine", "fit_refine_deferred", "Deferred", "climb_distortion", "FlangeModel", "crlb",
           "with_robot_scales"]

from .covariance import crlb  # noqa: E402  (re-exported: refine and its bound live together)


@dataclass(frozen=True)
class _Problem:
    """Validated data of one refinement: observations, start, layout and options."""

    uv: np.ndarray  # (V, n, 2)
    T: np.ndarray  # (V, 3) measured
    seen: np.ndarray  # (V, n) bool
    used_idx: np.ndarray  # points that enter the fit
    n_behind: int  # points left out because they start behind the camera
    lay: Layout
    start: State
    t_sigma: np.ndarray  # (V,) robot precision, 0 where exact
    opts: RefineOptions
    robot_given: dict  # robot error component -> known sigma (rad, unit), None: estimated; absent: off
    robot_start: "RobotStart | None" = None  # the start's robot error, to continue from (refits)


def refine(uv, T, initial, *, distortion: str | None = None, sigma_T=None, options: RefineOptions | None = None,
           progress=None) -> Calibration:
    """Maximum-likelihood refinement of a calibration (sparse bundle adjustment).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Observed pixels, NaN where a point is not seen.
    T : (n_views, 3) float
        Measured robot translations (world frame, user units).
    initial : LinearEstimate or Calibration
        Starting point: ``K``, ``R``, ``X`` (and the distortion of a Calibration).
        Points with non-finite ``X``, seen in fewer than 2 views, or behind the camera in
        some view are left out (NaN in the result, counted in ``stats.refine``).
    distortion : {"auto", "none", "radial1", "radial2", "opencv5"}, optional
        Lens distortion model (overrides ``options.distortion``; ``"auto"``, the default
        of :class:`RefineOptions`, chooses it from the data).
    sigma_T : float or (n_views,) float, optional
        Robot translation precision (overrides ``options.sigma_T``).
    options : RefineOptions, optional
        Every other option (fixed parameters, loss, skew, known noise, view rotations).
    progress : callable, optional
        Called after each accepted step with a :class:`~transcalib.types.ProgressEvent`
        (stage ``"refine: iteration"``, ``done`` the step, ``info`` ``cost`` and ``damping``).

    Returns
    -------
    Calibration
        ``camera``, ``X``, ``residuals_px``, ``rms_px``, ``T`` (refined with
        ``sigma_T``), ``sigma_px``, ``cov`` / ``std`` / ``param_names`` (rotations in
        degrees), ``X_std``, ``inliers`` (robust loss only), ``linear``, ``T_std`` (with
        ``sigma_T``), ``view_rotations`` (with ``estimate_view_rotations``) and
        ``stats.refine`` (:class:`~transcalib.types.RefineStats`: iterations, cost, stop
        reason, degrees of freedom, counts, time).

    Raises
    ------
    InputError
        Malformed input.
    DegenerateError
        Fewer than 2 usable points, no degrees of freedom to estimate the noise, or
        parameters the data do not determine (named).
    """
    opts = options if options is not None else RefineOptions()
    if distortion is not None or sigma_T is not None:
        opts = replace(opts, distortion=opts.distortion if distortion is None else distortion,
                       sigma_T=opts.sigma_T if sigma_T is None else sigma_T)
    check_fixed_distortion(opts)
    uv, T = as_uv_T(uv, T, min_views=2)
    return fit_refine(uv, T, initial, opts, progress)


def fit_refine(uv: np.ndarray, T: np.ndarray, initial, opts: RefineOptions, progress=None,
               flange: FlangeModel | None = None, near_solution: bool = False) -> Calibration:
    """:func:`refine` on validated arrays and options (the pipeline's entry); with
    ``flange`` (default: the model of an ``initial`` Calibration that has flange
    orientations) the views carry known flange rotations and the hand-eye offset ``t`` is
    estimated along its determined directions (``hand_eye.t``, std ``t_x, t_y, t_z`` when
    fully determined). ``near_solution``: ``initial`` is within a few standard
    deviations of the solution (the fit of a subset of the tracks): undamped Gauss-Newton
    steps."""
    flange = flange if flange is not None else FlangeModel.of(initial)
    if opts.distortion == "auto":
        return _fit_auto(uv, T, initial, opts, progress, flange)
    return result(*_solved(uv, T, initial, opts, progress, flange, near_solution))


class Deferred(NamedTuple):
    """A refinement whose uncertainty waits until asked for: ``light`` is its Calibration
    with the model's covariance ``sigma^2 S^-1`` alone (``uncertainty`` None), and
    ``complete()`` the one :func:`fit_refine` returns (the same solution, with the
    sandwich, the views' error fields and the sessions' error)."""

    light: Calibration
    complete: Callable[[], Calibration]


def fit_refine_deferred(uv: np.ndarray, T: np.ndarray, initial, opts: RefineOptions,
                        flange: FlangeModel | None = None) -> Deferred:
    """:func:`fit_refine` for the pipeline's refits that may only judge the tracks: the
    uncertainty of all but the last of them, a third of a 12-view calibration's time,
    is never computed. With ``distortion="auto"`` both are the full result."""
    flange = flange if flange is not None else FlangeModel.of(initial)
    if opts.distortion == "auto":
        cal = _fit_auto(uv, T, initial, opts, None, flange)
        return Deferred(cal, lambda: cal)
    pb, fitter, fit, initial, t_start = _solved(uv, T, initial, opts, None, flange)
    light, waited = result(pb, fitter, fit, initial, t_start, full=False), time.perf_counter()
    # the time until asked for is not the refinement's
    return Deferred(light, lambda: result(pb, fitter, fit, initial, t_start + time.perf_counter() - waited))


def _solved(uv, T, initial, opts: RefineOptions, progress, flange, near_solution: bool = False) -> tuple:
    """``(problem, fitter, fit, initial, start time)`` of a refinement with a fixed lens
    model: what :func:`~.refine_result.result` takes."""
    t_start = time.perf_counter()
    pb = _problem(uv, T, initial, opts, flange)
    fitter = _Fitter(pb, progress, near_solution)
    fit = _fit(pb, fitter)
    _check_converged_camera(fit.state.intr)
    return pb, fitter, fit, initial, t_start


def _check_converged_camera(intr) -> None:
    """A refinement that ran away to no camera (a focal length not positive or not finite)
    raises :class:`DegenerateError` saying what usually causes it."""
    fx, fy = float(intr[0]), float(intr[1])
    if not (np.all(np.isfinite(intr)) and fx > 0 and fy > 0):
        raise diverged(intr)


def _problem(uv, T, initial, opts: RefineOptions, flange: FlangeModel | None = None) -> _Problem:
    """Check the start, choose the used points and lay out the parameters."""
    n_views, n_points = uv.shape[:2]
    X0, K0, R0 = _check_initial(initial, n_points)
    seen = np.isfinite(uv[..., 0])  # validated: both coordinates NaN where unseen
    views = seen.sum(axis=0)
    usable = np.isfinite(X0[:, 0]) & np.isfinite(X0[:, 1]) & np.isfinite(X0[:, 2]) & (views >= 2)
    if flange is None:  # depth R (X_j - T_i) . e_z without a (V, n, 3) temporary
        z0 = (X0 @ R0[2])[None, :] - (T @ R0[2])[:, None]
    else:
        z0 = (np.einsum("vab,vnb->vna", flange.F, X0[None] - T[:, None]) - flange.t0) @ R0[2]
    in_front = np.all(~seen | (z0 > 0) | ~usable[None], axis=0)
    used_idx = np.flatnonzero(usable & in_front)
    if len(used_idx) < 2:
        raise DegenerateError(f"only {len(used_idx)} usable points (finite initial X, seen in >= 2 views, in "
                              "front of the camera); refinement needs at least 2. Track more points.")
    t_sigma = robot_sigma(opts.sigma_T, n_views)
    lay = Layout.from_options(opts, n_views, None if flange is None else flange.t_basis)
    lay.robot_inverted = flange is not None and flange.inverted
    intr = _start_intrinsics(K0, opts)
    dist5 = pad_dist(getattr(initial, "dist", ()) if isinstance(initial, Calibration) else ())
    keep = np.zeros(5, bool)
    keep[list(lay.dist_free)] = True
    dist5 = np.where(keep, dist5, 0.0)
    for k, name in enumerate(("k1", "k2", "p1", "p2", "k3")):
        dist5[k] = opts.fix.get(name, dist5[k])
    start = State(intr, dist5, R0.copy(), np.tile(np.eye(3), (n_views, 1, 1)), T.copy(), X0[used_idx],
                  None if flange is None else flange.F, np.zeros(3) if flange is None else flange.t0.copy())
    n_obs = int(views[used_idx].sum())
    dof = lay.residual_dof(n_obs, len(used_idx))
    if dof < 0 or (dof == 0 and opts.sigma_px is None):
        raise DegenerateError(f"too few observations: {2 * n_obs} residuals for {lay.n_global_no_T + 3 * len(used_idx)} "
                              f"unknowns ({len(used_idx)} points, {lay.n_global_no_T} camera parameters). Track more "
                              "points, use more views, or a simpler distortion model.")
    given = _robot_given(opts)
    return _Problem(uv, T, seen, used_idx, int(np.sum(usable & ~in_front)), lay, start, t_sigma, opts, given,
                    RobotStart.of(initial, given, n_views))


def with_robot_scales(opts: RefineOptions, calibration) -> RefineOptions:
    """``opts`` with the robot error scales ``calibration`` found given (0 for a component
    it left out): refits of the same data (tests of extra parameters, every track after a
    subset) keep its error model instead of estimating it again."""
    re = getattr(calibration, "robot_error", None)
    if re is None or not robot_error_on(opts):
        return opts
    return replace(opts, robot_sigma_deg=float(re.sigma_rot_deg), robot_sigma_pos=float(re.sigma_pos))


def _lens_first(opts: RefineOptions) -> RefineOptions:
    """``opts`` with the robot error components whose scale is to be estimated off (the
    given scales kept), or ``opts`` itself when none is: the options the distortion climb
    runs with (:func:`_fit_auto`)."""
    estimated = [c for c, v in _robot_given(opts).items() if v is None]
    if not estimated:
        return opts
    return replace(opts, robot_sigma_deg=0.0 if "rot" in estimated else opts.robot_sigma_deg,
                   robot_sigma_pos=0.0 if "pos" in estimated else opts.robot_sigma_pos)


def _robot_given(opts: RefineOptions) -> dict:
    """The robot error components in play: known sigma (radians, robot units) or None
    (estimated); a component given as 0, ``robot_error=False`` or ``sigma_T`` leave them out."""
    if not robot_error_on(opts):
        return {}
    given = {"rot": None if opts.robot_sigma_deg is None else np.radians(opts.robot_sigma_deg),
             "pos": opts.robot_sigma_pos}
    return {c: v for c, v in given.items() if v is None or v > 0}


def _check_initial(initial, n_points: int):
    if not isinstance(initial, (LinearEstimate, Calibration)):
        raise InputError(f"initial must be a LinearEstimate or a Calibration, got {type(initial).__name__}; "
                         "run transcalib.estimate_linear(uv, T) first")
    X0 = np.asarray(initial.X, dtype=float)
    if X0.shape != (n_points, 3):
        raise InputError(f"initial.X has shape {X0.shape}, expected (n_points, 3) = ({n_points}, 3) to match uv")
    K0 = np.asarray(initial.K, dtype=float)
    if K0.shape != (3, 3) or not np.all(np.isfinite(K0)) or K0[0, 0] <= 0 or K0[1, 1] <= 0:
        raise InputError(f"initial.K must be a finite 3x3 matrix with fx, fy > 0, got {K0.tolist()}")
    R0 = np.asarray(initial.R, dtype=float)
    if R0.shape != (3, 3) or not np.all(np.isfinite(R0)) or not np.allclose(R0 @ R0.T, np.eye(3), atol=1e-6) \
            or np.linalg.det(R0) < 0:
        raise InputError("initial.R must be a 3x3 rotation matrix (orthonormal, det +1), got "
                         f"{np.array2string(R0, precision=4)}")
    return X0, K0, R0


def _start_intrinsics(K0: np.ndarray, opts: RefineOptions) -> np.ndarray:
    """``fx, fy, cx, cy, skew`` to start from: the initial K with the fixed values put in
    (the skew at 0 unless estimated or fixed; equal focal lengths with square pixels)."""
    intr = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], K0[0, 1] if opts.estimate_skew else 0.0])
    for k, name in enumerate(("fx", "fy", "cx", "cy", "skew")):
        intr[k] = opts.fix.get(name, intr[k])
    if opts.square_pixels:
        f = opts.fix.get("fx", opts.fix.get("fy", 0.5 * (intr[0] + intr[1])))
        intr[:2] = f
    return intr


# ----------------------------------------------------------------------------------------
# Distortion model chosen from the data
# ----------------------------------------------------------------------------------------

#: Nested distortion models ``distortion="auto"`` climbs, simplest first.
AUTO_CHAIN = ("none", "radial2", "opencv5")
#: False-positive rate of each step of the climb (score test of the added coefficients).
AUTO_ALPHA = 0.01


def _fit_auto(uv, T, initial, opts: RefineOptions, progress, flange=None) -> Calibration:
    """Refine without distortion, then add coefficients while the data ask for them.

    At the solution of model ``m`` the score test of the coefficients ``m'`` adds
    (``k`` of them, the others profiled out) gives ``F = (D / k) / ((RSS - D) / (dof - k))``
    with ``D`` the RSS reduction of one Gauss-Newton step: F(k, dof - k) when ``m``
    suffices. ``m'`` is taken when ``p < AUTO_ALPHA`` and its refit determines every
    coefficient (its covariance exists); ``stats.distortion_selection`` says why.

    The lens comes first: the climb runs with the robot error components whose scales
    are estimated left out (:func:`_lens_first`), then the chosen model is fitted with
    them (their score tests decide), and the climb is made again with the scales they
    settled at held (:func:`_lens_with_robot_error`). A handful of lens coefficients
    shared by every view cannot absorb independent per-view pose errors, but
    ``3 n_views`` per-view errors can absorb much of an unmodelled lens, and trade with
    the focal length doing it.
    """
    lens = _lens_first(opts)
    cal = fit_refine(uv, T, initial, replace(lens, distortion=AUTO_CHAIN[0]), progress, flange)
    cal = climb_distortion(uv, T, cal, lens, progress)
    if lens is opts:
        return cal
    a = cal.stats.refine
    try:
        full = fit_refine(uv, T, cal, replace(opts, distortion=cal.dist_model), _counting_on(progress, a.iterations))
    except DegenerateError:  # the fit breaks down with the robot error where it held without: a misfit
        return _as_misfit(cal, opts)
    full, again = _lens_with_robot_error(uv, T, full, opts, progress)
    b = full.stats.refine
    both = replace(b, iterations=a.iterations + b.iterations, time_s=a.time_s + b.time_s)
    return replace(full, options=replace(full.options, refinement=opts),
                   stats=replace(full.stats, refine=both, distortion_selection=cal.stats.distortion_selection + again))


def _lens_with_robot_error(uv, T, full: Calibration, opts: RefineOptions, progress) -> tuple:
    """The climb of :func:`_fit_auto` again with the robot error's scales that ``full``
    found held: without them the per-view pose errors left in the residuals pass for
    lens coefficients, or hide the lens (``bench_robot_error.py --lens``, single sessions
    with a two-coefficient lens: at 0.1 deg / 1 mm ``opencv5`` in 61 of 100 fits, at
    0.2 deg / 2 mm no lens in 17; held: ``radial2`` in 100 and 98). ``(calibration, the
    climb's steps)``: ``full`` when the same model comes out, else that model refitted
    with the scales estimated."""
    re = full.robot_error
    if re is None or not re.active:
        return full, ()
    held = with_robot_scales(opts, full)
    try:
        cal = climb_distortion(uv, T, fit_refine(uv, T, full, replace(held, distortion=AUTO_CHAIN[0]), progress),
                               held, progress)
    except DegenerateError:  # the simplest lens no longer fits with the errors held: the first choice stands
        return full, ()
    steps = tuple(replace(s, robot_error_held=True) for s in cal.stats.distortion_selection)
    if cal.dist_model == full.dist_model:
        return full, steps
    return fit_refine(uv, T, cal, replace(opts, distortion=cal.dist_model), progress), steps


def _as_misfit(cal: Calibration, opts: RefineOptions) -> Calibration:
    """The exact-pose fit ``cal`` of :func:`_fit_auto` as the result of ``opts``: the robot
    error components to estimate marked ``"misfit"`` (consistency p-value 0)."""
    re = cal.robot_error
    if re is not None:
        estimated = [_robot_given(opts).get(c, 0.0) is None for c in COMPONENTS]
        re = replace(re, source=tuple("misfit" if e else s for e, s in zip(estimated, re.source)),
                     consistency_p=np.where(estimated, 0.0, re.consistency_p))
    return replace(cal, robot_error=re, options=replace(cal.options, refinement=opts))


def _counting_on(progress, done: int):
    """``progress`` with the iteration events' ``done`` counted on from ``done`` (None stays None)."""
    if progress is None:
        return None
    return lambda event: progress(replace(event, done=event.done + done) if event.done is not None else event)


def climb_distortion(uv, T, cal: Calibration, opts: RefineOptions, progress=None) -> Calibration:
    """From the refined ``cal`` (a model of :data:`AUTO_CHAIN`), add coefficients while
    the score test asks for them (:func:`_fit_auto`); ``opts`` are recorded. Each refit
    starts where ``cal`` left off, its flange model (the hand-eye offset) included."""
    steps = []
    start = AUTO_CHAIN.index(cal.dist_model) if cal.dist_model in AUTO_CHAIN else len(AUTO_CHAIN) - 1
    for simpler, richer in zip(AUTO_CHAIN[start:], AUTO_CHAIN[start + 1:]):
        F, p = _distortion_score(uv, T, cal, replace(opts, distortion=simpler), richer)
        step = DistortionStep(richer, F, p, AUTO_ALPHA, bool(p < AUTO_ALPHA))
        if step.chosen:
            try:
                richer_cal = fit_refine(uv, T, cal, replace(opts, distortion=richer), progress)
            except DegenerateError as exc:  # the added coefficients are not determined
                step = replace(step, chosen=False, reason=f"not determined: {exc}")
            else:
                cal = richer_cal
        steps.append(step)
        if not step.chosen:
            break
    return replace(cal, options=replace(cal.options, refinement=opts),
                   stats=replace(cal.stats, distortion_selection=tuple(steps)))


def _distortion_score(uv, T, cal: Calibration, simpler: RefineOptions, richer: str) -> tuple[float, float]:
    """Score test at ``cal`` (the ML solution of ``simpler``) of the coefficients that
    ``richer`` adds: ``(F, p-value)``."""
    lin = linearise(uv, T, cal, simpler, polish=0)
    lay = replace(lin.layout, dist_free=dist_indices(richer, simpler.fix))
    added = [lay.i_dist + m for m, k in enumerate(lay.dist_free) if k not in lin.layout.dist_free]
    if not added:
        return 0.0, 1.0
    S, b, sse = lin.system(lay)
    nuisance = np.setdiff1d(np.arange(lay.size), added)
    red = profile_step(S, b, np.array(added), nuisance)[2]
    k, d = len(added), lin.dof - len(added)
    if d <= 0:
        return 0.0, 1.0
    F = (red / k) / max((sse - red) / d, SIGMA_FLOOR_PX**2)
    return float(F), float(f_sf(F, k, d))


# ----------------------------------------------------------------------------------------
# Fitting stages
# ----------------------------------------------------------------------------------------


#: Convergence tolerance of the robust loss's fit (``tol`` of :func:`levenberg_marquardt`).
#: That fit only sorts the observations into inliers for the least-squares polish, which
#: converges to the user's ``tol``; its IRLS steps converge linearly (by 3-7 % a step with
#: a third of the tracks outliers), so the user's 1e-6 took the full 100 iterations.
ROBUST_TOL = 1e-2
#: Convergence tolerance of the fits inside the robot error's rounds of variance-component
#: updates but the last: each starts from the previous round's solution with slightly other
#: weights, and its cost need only settle far below the scales' own tolerance
#: (:data:`.variance_components.RTOL`); the last fit converges to the user's ``tol``.
ROUND_TOL = 1e-2


class _Fitter:
    """Runs LM on a subset of observations; handles the robot-noise (``sigma_T``) mode.

    With ``sigma_T`` and unknown pixel noise the prior weight ``sigma_px / sigma_T`` needs
    ``sigma_px``: it is estimated by a fit with fixed translations, then refined by the
    fixed point ``sigma^2 = sum |r|^2 / (dof - chi2_T)`` (the whitened cost then equals its
    expectation, the degrees of freedom).
    """

    def __init__(self, pb: _Problem, progress, near_solution: bool = False):
        self.pb, self.progress, self.near_solution = pb, progress, near_solution
        self.system = self.residuals = None
        self.iterations = 0
        self.warm = pb.robot_start  # robot error to continue from (a refit; the robust loss's polish)
        self.set_scale(pb.opts.loss_scale_px or 1.0)

    def set_scale(self, sigma: float) -> None:
        """Scale ``c`` of the robust loss and the inlier threshold of an observation's
        residual norm: given ones, or from the pixel noise ``sigma`` (Huber ``1.345
        sigma``, Cauchy ``2.385 sigma``: 95 % efficiency under Gaussian noise; threshold
        ``sqrt(chi2_2(0.999)) sigma = 3.72 sigma``)."""
        o = self.pb.opts
        self.c = float(o.loss_scale_px) if o.loss_scale_px is not None else LOSS_SCALE[o.loss] * sigma
        if o.inlier_threshold_px is not None:
            self.thr = float(o.inlier_threshold_px)
        else:
            self.thr = 3.0 * self.c if o.loss_scale_px is not None else OBS_QUANTILE * sigma

    def _lm(self, state, lay, data, loss, tol: float | None = None):
        """Levenberg-Marquardt, or Gauss-Newton steps near the solution (then the last
        step's reduced system is kept for the covariance, ``self.system``, and the
        residuals at the solution, ``self.residuals``); ``tol``: a looser tolerance than
        the user's."""
        o = self.pb.opts
        problem = BundleProblem(lay, data, loss, self.c)
        if self.near_solution:
            sol = gauss_newton(problem, state, o.max_iterations, o.tol, self.progress)
            self.system = sol.linearisation
            self.residuals = None if sol.linearisation is None else problem.residuals(sol.state)
        else:
            tol = max(o.tol, tol or 0.0, 0.0 if loss == "linear" else ROBUST_TOL)
            sol = levenberg_marquardt(problem, state, o.max_iterations, tol, self.progress)
        self.iterations += sol.iterations
        return sol.state, sol.cost, sol.reason

    def _weights(self, sigma):
        s = self.pb.t_sigma
        return np.where(s > 0, sigma / np.where(s > 0, s, 1.0), 0.0)

    def __call__(self, state, idx, mask, loss):
        """Fit the points ``idx`` on the observations ``mask``: ``(state, cost, reason,
        data, pixel sigma used for the priors or None)``; the layout fitted is
        ``self.lay`` (with the robot error components found), ``self.robot`` the robot
        error's scales (:class:`RobotFit`)."""
        self.lay, self.robot = self.pb.lay, None
        if self.pb.robot_given and loss == "linear":
            return self._with_robot(state, idx, mask)
        return self._plain(state, idx, mask, loss)

    def _plain(self, state, idx, mask, loss):
        """:meth:`__call__` without robot pose errors."""
        pb, lay = self.pb, self.pb.lay
        n_views = len(pb.T)
        if not lay.i_T:
            data = build_data(pb.uv, mask, idx, pb.T, np.zeros(n_views))
            return (*self._lm(state, lay, data, loss), data, None)
        if pb.opts.sigma_px is not None:
            data = build_data(pb.uv, mask, idx, pb.T, self._weights(pb.opts.sigma_px))
            return (*self._lm(state, lay, data, loss), data, float(pb.opts.sigma_px))
        dof = lay.residual_dof(int(mask[:, idx].sum()), len(idx))
        fixed = replace(lay, T_views=())
        data = build_data(pb.uv, mask, idx, pb.T, np.zeros(n_views))
        state, _, _ = self._lm(state, fixed, data, loss)
        sigma = np.sqrt(sum_sq(state, fixed, data, loss, self.thr) / max(dof, 1))
        free = pb.t_sigma > 0
        for _ in range(5):
            data = build_data(pb.uv, mask, idx, pb.T, self._weights(sigma))
            state, f, reason = self._lm(state, lay, data, loss)
            chi2_T = float(np.sum(((state.T - pb.T)[free] / pb.t_sigma[free, None]) ** 2))
            new = float(np.sqrt(sum_sq(state, lay, data, loss, self.thr) / max(dof - chi2_T, 0.5 * dof)))
            done = abs(new - sigma) <= 1e-3 * sigma
            sigma = new
            if done:
                break
        data = build_data(pb.uv, mask, idx, pb.T, self._weights(sigma))
        self.system = self.residuals = None  # linearised with other prior weights than the final data's
        return state, cost(state, lay, data, loss, self.c), reason, data, sigma

    def _with_robot(self, state, idx, mask):
        """:meth:`__call__` with the robot pose error: the fit without it, the score test
        of each component whose scale is not given, then rounds of fit and
        variance-component update (:mod:`.variance_components`) of the scales found and
        the pixel noise; then the fitted scales are checked against the scores at zero
        (:meth:`_drop_misfits`); a component whose rounds run away alone is fitted again
        with the others the same tests found before it counts as a misfit. Near the
        solution (scales given by the fit of a
        subset) one round. A refit of nearly the same tracks (:class:`RobotStart`: other
        inliers, a richer lens, the robust loss's polish on the inliers) runs the rounds
        from the scales and errors found before and tests only the components not tested
        before."""
        pb = self.pb
        given, p_values, sig = pb.robot_given, {c: np.nan for c in COMPONENTS}, {}
        consistent = {}  # component -> p-value of its fitted scale against its score (JointScore)
        scores = {}  # component -> its scale's moment estimate where first tested (rad, unit)
        zero = None  # (scores, fit, layout, robot fit) where the first components were tested
        state = replace(state, E=None)
        dof = pb.lay.residual_dof(int(mask[:, idx].sum()), len(idx))
        plain, sigma_px = None, pb.opts.sigma_px
        self.rounds = 0
        sig.update({c: float(v) for c, v in given.items() if v is not None})
        tried, out, warm = set(sig), None, None if self.near_solution else self.warm
        if warm is not None and warm.sigma:  # a refit: on from the scales found before
            try:
                out = self._rounds(replace(state, E=warm.E), idx, mask, {**sig, **warm.sigma}, dof, sigma_px)
                sig = dict(self.robot.sigma)
            except DegenerateError:  # they no longer fit these tracks: select afresh
                warm = None
        if warm is not None:
            tried |= set(warm.p_values)
            p_values.update(warm.p_values)
            consistent.update(warm.consistency)
            scores.update(warm.scores)
        if out is None and sig:
            out = self._rounds(state, idx, mask, sig, dof, sigma_px)
        elif out is None and not self.near_solution:
            out = plain = self._plain(state, idx, mask, "linear")
        while not self.near_solution:  # forward selection: the most significant component next
            state, sigma_px = out[0], out[4] or pb.opts.sigma_px
            if sigma_px is None:
                sigma_px = np.sqrt(max(sum_sq(state, self.lay, out[3]), 0.0) / max(dof, 1))
            if sigma_px <= SIGMA_FLOOR_PX:  # exact data: no robot error to find
                break
            tests, joint = self._gate(state, idx, mask, sigma_px, tried)
            if not tests:
                break
            zero = zero or (joint, out, self.lay, self.robot)
            p_values.update({c: t.p_value for c, t in tests.items()})
            for k, t in tests.items():
                scores.setdefault(k, float(np.sqrt(t.sigma2)))
            picked = _next_component(tests, joint, sig, state.F is None, sigma_px)
            if picked is None:
                break
            c, sig[c] = picked
            tried.add(c)  # tested once: a component the rounds drop again is not tried twice
            before = (out, self.lay, self.robot)
            at_zero = zero[0]  # the scores the scales are checked against
            fit, p_run = self._try_rounds(state, idx, mask, sig, dof, sigma_px, at_zero)
            # one component alone can run away where the data need both (one orientation and
            # the lens estimated: the lens takes up the other's errors): with every component
            # these tests found, before it counts as a misfit
            both = {k: float(np.sqrt(t.sigma2)) for k, t in tests.items()
                    if k not in sig and t.p_value < GATE_ALPHA and t.sigma2 > 0}
            if fit is None and both:
                out, self.lay, self.robot = before
                fit, _ = self._try_rounds(state, idx, mask, {**sig, **both}, dof, sigma_px, at_zero)
                if fit is not None:
                    tried |= set(both)
            if fit is not None:
                out, sig = fit
            else:
                consistent[c] = p_run.get(c, 0.0)
                out, self.lay, self.robot = before
                sig = {} if self.robot is None else dict(self.robot.sigma)
        if zero is not None and sig:
            out, sig = self._drop_misfits(out, sig, zero, consistent, idx, mask, dof)
        tested = [c for c in tried if given.get(c, 0.0) is None]
        self.warm = RobotStart({c: sig[c] for c in sig if c in tested}, None if out is None else out[0].E,
                                {c: p_values[c] for c in tested}, {c: consistent.get(c, np.nan) for c in tested},
                                {c: scores[c] for c in tested if c in scores})
        if out is None or not sig:
            self.lay = pb.lay
            self.robot = RobotFit({}, {}, p_values, given, None, consistent, scores)
            return out if out is not None and plain is not None and out is plain else self._plain(
                replace(state, E=None), idx, mask, "linear")
        self.robot = replace(self.robot, p_values=p_values, consistency=consistent, scores=scores)
        return out

    def _try_rounds(self, state, idx, mask, sig, dof, sigma_px, joint):
        """:meth:`_rounds` of the scales ``sig``: ``((out, fitted scales), {})``, or
        ``(None, p-values)`` when the scales left the scores' evidence behind
        (:class:`RunAway`) or the fit broke down (a misfit too)."""
        try:
            out = self._rounds(state, idx, mask, sig, dof, sigma_px, joint)
        except RunAway as run:
            return None, run.p
        except DegenerateError:
            return None, {}
        sig = dict(self.robot.sigma)
        return ((out, sig), {}) if all(np.isfinite(v) for v in sig.values()) else (None, {})

    def _drop_misfits(self, out, sig, zero, consistent, idx, mask, dof):
        """The fitted scales ``sig`` checked against the scores where they were tested
        (``zero``: :class:`.variance_components.JointScore`, that fit, its layout and robot
        fit): while a component's p-value is below ``MISFIT_ALPHA`` the worst is left out
        (a misfit) and the others fitted again from there. Records the p-values in
        ``consistent``; returns ``(out, sig)``."""
        joint, zero_out, zero_lay, zero_robot = zero
        while sig:
            p = joint.consistency({c: v**2 for c, v in sig.items()}, self.robot.sigma_px)
            consistent.update(p)
            worst = min(p, key=p.get, default=None)
            if worst is None or p[worst] >= MISFIT_ALPHA:
                break
            sig = {c: v for c, v in sig.items() if c != worst}
            out, self.lay, self.robot = zero_out, zero_lay, zero_robot
            if not set(sig) & set(joint.blocks):  # only those given remain: the fit they were tested at
                sig = {} if zero_robot is None else dict(zero_robot.sigma)
            else:
                try:
                    out = self._rounds(zero_out[0], idx, mask, sig, dof, zero_out[4], joint)
                    sig = dict(self.robot.sigma)
                except DegenerateError as exc:  # (a RunAway too)
                    consistent.update({c: getattr(exc, "p", {}).get(c, 0.0) for c in sig})
                    out, self.lay, self.robot, sig = zero_out, zero_lay, zero_robot, {}
        return out, sig

    def _rounds(self, state, idx, mask, sig, dof, sigma_px, joint: JointScore | None = None):
        """Fit and variance-component updates until the scales settle (:meth:`_with_robot`).
        With the scores ``joint``, raises :class:`RunAway` as soon as a growing scale
        fails their check at ``RUNAWAY_ALPHA`` (it would only fail worse further on)."""
        pb, n_views, given = self.pb, len(self.pb.T), self.pb.robot_given
        start = dict(sig)
        lay = replace(pb.lay, robot=tuple(c for c in COMPONENTS if c in sig))
        state = replace(state, E=np.zeros((n_views, 6)) if state.E is None else state.E)
        if sigma_px is None:
            data = build_data(pb.uv, mask, idx, pb.T, np.zeros(n_views))
            sigma_px = np.sqrt(sum_sq(state, lay, data) / max(dof, 1))
        history = {}
        for _ in range(MAX_ROUNDS):
            self.rounds += 1
            w = robot_weights(sigma_px, sig)
            data = build_data(pb.uv, mask, idx, pb.T, np.zeros(n_views), w)
            state, f, reason = self._lm(state, lay, data, "linear", ROUND_TOL)
            Sinv = _inverse(reduced_information(state, lay, data).S)
            r = {c: redundancy(Sinv, lay.robot_columns(c), w[COMPONENTS.index(c)]) for c in lay.robot}
            new = {c: (v if given.get(c) is not None else component_sigma(state, c, r[c])) for c, v in sig.items()}
            sse = sum_sq(state, lay, data)
            new_px = pb.opts.sigma_px or float(np.sqrt(sse / max(dof - sum(r.values()), 0.5 * dof, 1)))
            done = all(abs(new[c] - sig[c]) <= RTOL * sig[c] for c in sig) and abs(new_px - sigma_px) <= RTOL * sigma_px
            check_growth(joint, sig, new, new_px)
            if not done:
                new = extrapolated(history, new, given)
            sig, sigma_px = new, new_px
            # the data show none after all: the scale collapses while its redundancy vanishes
            dropped = [c for c, v in sig.items() if given.get(c) is None and v <= DROP_FRACTION * start[c]
                       and (r[c] < DROP_REDUNDANCY or v <= 0)]
            if dropped:
                sig = {c: v for c, v in sig.items() if c not in dropped}
                E = state.E.copy()
                for c in dropped:
                    E[:, slice(0, 3) if c == "rot" else slice(3, 6)] = 0.0
                state = replace(state, E=E)
                if not sig:
                    self.robot = RobotFit({}, {}, {}, given, None)
                    return self._plain(replace(state, E=None), idx, mask, "linear")
                lay = replace(pb.lay, robot=tuple(c for c in COMPONENTS if c in sig))
                continue
            if done or self.near_solution:
                break
        if not self.near_solution:  # the last fit to the user's tol, at the weights the scales settled with
            state, f, reason = self._lm(state, lay, data, "linear")
            self.system = self.residuals = None
        self.lay = lay
        self.robot = RobotFit(sig, r, {}, given, sigma_px)
        return state, cost(state, lay, data, "linear", self.c), reason, data, sigma_px

    def _gate(self, state, idx, mask, sigma_px, tried) -> tuple:
        """Score tests at zero (:func:`.variance_components.score_test`) of the components
        to estimate not yet ``tried``, at the fit ``state`` with the components of
        ``self.robot`` (their priors in the profiled parameters), and their joint score
        (:class:`.variance_components.JointScore`)."""
        pb = self.pb
        comps = tuple(c for c in COMPONENTS if c in pb.robot_given and pb.robot_given[c] is None and c not in tried)
        if not comps:
            return {}, None
        sig = {} if self.robot is None else self.robot.sigma
        lay = replace(pb.lay, robot=tuple(c for c in COMPONENTS if c in sig or c in comps))
        data = build_data(pb.uv, mask, idx, pb.T, np.zeros(len(pb.T)), robot_weights(sigma_px, sig))
        E = np.zeros((len(pb.T), 6)) if state.E is None else state.E
        red = reduced_information(replace(state, E=E), lay, data)
        test = {c: lay.robot_columns(c).ravel() for c in comps}
        others = np.setdiff1d(np.arange(lay.size), np.concatenate(list(test.values())))
        joint = JointScore.of(red.S, red.rhs, test, others)  # one profiling for every component
        return {c: score_test(*joint.block(c), sigma_px) for c in test}, joint


def _next_component(tests: dict, joint: JointScore, sig: dict, one_orientation: bool, sigma_px: float):
    """The component the forward selection of :meth:`_Fitter._with_robot` takes next and
    its starting scale, or None: the most significant of the score ``tests`` if below
    ``GATE_ALPHA``; with one orientation the position once the rotation is in, whatever
    its test says (the flange rotation moves the camera centre by its lever arm, which
    the model folds into the centre's error; started at the larger of its moment
    estimate and that estimate's std at zero)."""
    c = min(tests, key=lambda k: tests[k].p_value)
    if tests[c].p_value < GATE_ALPHA and tests[c].sigma2 > 0:
        return c, float(np.sqrt(tests[c].sigma2))
    if one_orientation and "rot" in sig and "pos" in tests:
        return "pos", float(np.sqrt(max(tests["pos"].sigma2, moment_noise(joint.block("pos")[1], sigma_px))))
    return None


def _inverse(S: np.ndarray) -> np.ndarray:
    """``S^-1`` of a symmetric positive (semi-)definite ``S``, Jacobi-scaled (a parameter
    without information, a zero row and column, left unscaled: its pseudo-inverse is 0)."""
    diag = np.diag(S)
    d = 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0))
    return np.linalg.pinv(S * d[:, None] * d[None, :], rcond=1e-14, hermitian=True) * d[:, None] * d[None, :]


@dataclass
class _Fit:
    """Outcome of the fitting stages: ``state`` holds every used point, ``last`` the
    points ``idx`` of the final least-squares stage (observations ``mask``, ``data``)."""

    state: State
    last: State
    idx: np.ndarray
    mask: np.ndarray
    data: object
    sigma_T_mode: float | None  # pixel sigma of the priors (translations, robot errors)
    inliers: np.ndarray | None  # robust loss: inlier points
    lay: Layout | None = None  # the layout fitted last (with the robot error components found)
    robot: "RobotFit | None" = None


def _fit(pb: _Problem, fit: _Fitter) -> _Fit:
    """The (robust) fit, then for a robust loss the least-squares polish on the inlier
    observations (points keeping >= 2 of them), repeated until the inlier set settles.
    A robust loss without a given scale takes it from the noise, estimated robustly
    (median absolute residual) at the start and again at the robust solution."""
    state = pb.start
    if pb.opts.loss != "linear" and pb.opts.loss_scale_px is None:
        fit.set_scale(_robust_sigma(pb, state))
    state, fit.cost, fit.reason, data, sigma_T_mode = fit(state, pb.used_idx, pb.seen, pb.opts.loss)
    if pb.opts.loss == "linear":
        return _Fit(state, state, pb.used_idx, pb.seen, data, sigma_T_mode, None, fit.lay, fit.robot)
    if pb.opts.loss_scale_px is None:
        sigma = _robust_sigma(pb, state)
        if abs(sigma * LOSS_SCALE[pb.opts.loss] / fit.c - 1) > 0.1:  # the start's residuals misled the scale
            fit.set_scale(sigma)
            state, fit.cost, fit.reason, data, sigma_T_mode = fit(state, pb.used_idx, pb.seen, pb.opts.loss)
    last, idx, mask, previous = state, pb.used_idx, pb.seen, None
    for _ in range(3):
        obs_in = _inlier_observations(pb, state, fit.thr)
        if previous is not None and np.array_equal(obs_in, previous):
            break
        previous = obs_in
        keep = obs_in[:, pb.used_idx].sum(axis=0) >= 2
        last, fit.cost, fit.reason, data, sigma_T_mode = fit(replace(state, X=state.X[keep]), pb.used_idx[keep],
                                                             obs_in, "linear")
        X = state.X.copy()
        X[keep] = last.X
        state = replace(last, X=X)
        idx, mask = pb.used_idx[keep], obs_in
    obs_in = _inlier_observations(pb, state, fit.thr)
    inliers = np.zeros(pb.uv.shape[1], bool)
    inliers[pb.used_idx] = np.all(obs_in[:, pb.used_idx] | ~pb.seen[:, pb.used_idx], axis=0)
    return _Fit(state, last, idx, mask, data, sigma_T_mode, inliers, fit.lay, fit.robot)


def _robust_sigma(pb: _Problem, state: State) -> float:
    """Pixel noise per coordinate: :func:`.noise.mad_sigma` of the residuals at ``state``."""
    res = all_residuals(state, pb.lay, pb.uv, pb.seen, pb.used_idx, pb.T)
    return mad_sigma(res, pb.lay.n_global_no_T + 3 * len(pb.used_idx))


def _inlier_observations(pb: _Problem, state: State, thr: float) -> np.ndarray:
    """(n_views, n_points) bool: observations of the used points with residual norm <= thr."""
    obs_in = np.zeros(pb.seen.shape, bool)
    res = all_residuals(state, pb.lay, pb.uv, pb.seen, pb.used_idx, pb.T)
    obs_in[:, pb.used_idx] = pb.seen[:, pb.used_idx] & (np.sum(res**2, axis=2) <= thr * thr)
    return obs_in
