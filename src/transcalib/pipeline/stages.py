"""The stages after the start, for every motion: refinement, every track judged again, the
finish with every track, and the residuals reported.

Each view's camera comes from the calibration itself (:meth:`Calibration.camera_poses`:
one rotation for every view without flange orientations, one per view with them), so the
same stages serve one orientation, sessions and single views.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..check.common import camera_poses
from ..estimate.layout import FlangeModel, complement
from ..estimate.noise import SIGMA_FLOOR_PX, inlier_rule, noise_spread, sigma_from_threshold, truncation_factor
from ..estimate.refine import climb_distortion, fit_refine, fit_refine_deferred, with_robot_scales
from ..geometry.camera import DIST_NAMES, Camera, camera_frame, project, project_camera_frame
from ..geometry.triangulate import triangulate
from ..types import INTRINSIC_NAMES, CalibrateOptions, Calibration, CalibrationStats, HandEye, LinearEstimate, report

#: The refined camera's verdict refits only when it changes more than this fraction of
#: the inliers (borderline tracks trading places at the false-rejection rate do not count).
REJUDGE_FRACTION = 0.005
#: Rounds of judging every track again and refitting, at most (they stop when the inliers settle).
REJUDGE_ROUNDS = 6
#: With ``distortion="auto"`` the lens is chosen again when a round's inliers outnumber the
#: set it was chosen on by this factor: RANSAC's distortion-free model keeps a central patch
#: of precise tracks, and coefficients chosen there (tangential, k3) extrapolate badly to
#: the corners, where the judge then rejects good tracks.
LENS_AGAIN_GROWTH = 1.25
#: Tracks per block where every track is evaluated (small temporaries stay in cache).
TRACK_BLOCK = 32768
#: Gauss-Newton steps with every track after the fit of a subset (see extend_to_all_tracks).
GAUSS_NEWTON_STEPS = 2


def masked(uv: np.ndarray, inliers) -> np.ndarray:
    """``uv`` with the outlier tracks set to NaN (``inliers`` None: all kept)."""
    return uv if inliers is None else np.where(inliers[None, :, None], uv, np.nan)


def _cameras(cal: Calibration):
    """``(A, centres)`` for :func:`triangulate`: ``K R_cam``, one for every view or one per
    view (:func:`~transcalib.check.common.camera_poses`: with flange orientations or the
    views' estimated pose errors)."""
    R_cam, C = camera_poses(cal, cal.T)
    return cal.K @ R_cam, C


def triangulated(uv: np.ndarray, cal: Calibration) -> np.ndarray:
    """Every track triangulated with the cameras of ``cal`` ``(n_points, 3)``."""
    A, C = _cameras(cal)
    return triangulate(A, uv, C, K=cal.K, dist=cal.dist)


def _camera_values(cal: Calibration) -> dict:
    """Intrinsics and the five distortion coefficients of ``cal`` by parameter name
    (``f`` too, for square pixels)."""
    cam = cal.camera
    values = dict(zip(INTRINSIC_NAMES + DIST_NAMES, np.concatenate([cam.intrinsics, cam.dist5])))
    return {**values, "f": values["fx"]}


def extend_to_all_tracks(uv, T, cal: Calibration, inliers, opts: CalibrateOptions, progress, spread: bool = False):
    """From the calibration of a subset of the tracks, the maximum-likelihood one of all
    of them: every track triangulated and judged by the subset's camera (the inlier rule
    of the robust stage), then :data:`GAUSS_NEWTON_STEPS` undamped steps of the camera
    and every inlier track jointly, with the covariance at that solution. The subset's
    solution is a few of its standard deviations from the full one, where the cost is
    nearly quadratic: the first step lands within a few hundredths of a standard
    deviation, the second within about 1e-4 (tests/test_pipeline.py). ``spread``: the
    judging takes in the spread of the tracks' noise (:func:`judge_tracks`). Returns
    ``(cal, inliers)``."""
    X_all = triangulated(uv, cal)
    k = np.isfinite(uv[..., 0]).sum(axis=0)
    if inliers is not None:
        inliers = judge_tracks(uv, cal, X_all, opts, spread)
    start = replace(cal, X=X_all if inliers is None else np.where(inliers[:, None], X_all, np.nan))
    step = with_robot_scales(replace(opts.refinement, distortion=cal.dist_model, max_iterations=GAUSS_NEWTON_STEPS),
                             cal)  # the subset's robot error scales: one model for both fits
    full = _as_estimated(fit_refine(uv, T, start, step, near_solution=True), cal)  # outliers have no X: not used
    if full.inliers is not None:  # the robust loss classified points too
        inliers = full.inliers if inliers is None else inliers & full.inliers
    if inliers is not None and opts.ransac.threshold_px is None and opts.refinement.sigma_px is None:
        full = untruncated(full, k[inliers], opts.ransac.false_rejection)
    before, after = _camera_values(cal), _camera_values(full)
    moved = max((abs(after[k] - before[k]) / v for k, v in full.std.items() if v > 0 and k in before), default=0.0)
    subset = cal.stats.refine
    refined = replace(full.stats.refine, converged=True,
                      stop_reason=f"{full.stats.refine.iterations} Gauss-Newton step(s) from the fit of "
                                  f"{subset.n_points_used} tracks (which moved the camera by {moved:.2g} standard "
                                  "deviations at most)")
    stats = replace(full.stats, refine=refined, subset=subset, distortion_selection=cal.stats.distortion_selection)
    report(progress, "all tracks", points=refined.n_points_used, rms_px=full.rms_px)
    return replace(full, options=replace(full.options, refinement=opts.refinement), stats=stats), inliers


def _as_estimated(full: Calibration, subset: Calibration) -> Calibration:
    """``full``'s robot error (fitted with the scales of ``subset`` given) reported as the
    subset estimated them: sources, the scales' std, redundancies, p-values (score tests
    and scale checks) and the scores' scales."""
    a, b = full.robot_error, subset.robot_error
    if a is None or b is None:
        return full
    return replace(full, robot_error=replace(a, source=b.source, sigma_rot_std_deg=b.sigma_rot_std_deg,
                                             sigma_pos_std=b.sigma_pos_std, redundancy=b.redundancy,
                                             p_values=b.p_values, consistency_p=b.consistency_p,
                                             score_scales=b.score_scales))


def refine_and_rejudge(uv, T, linear, inliers, opts: CalibrateOptions, progress, flange: FlangeModel | None = None,
                       spread: bool = False):
    """Refine on the inliers (with ``flange``: the views' flange rotations and the offset);
    then judge every track again with the refined camera (RANSAC judged them with the
    linear, distortion-free one: this matters under strong distortion) and refit while the
    inlier set changes; with ``distortion="auto"`` a set grown beyond
    :data:`LENS_AGAIN_GROWTH` times the one the lens was chosen on has it chosen again
    (the final climb then tries more coefficients at the fit with the robot error). A fit
    that left a robot error component out as a misfit judges the tracks at given scales
    (:func:`_misfit_scales`) with the lens chosen again; the refits keep those scales until
    the inlier set settles (stages ``"reclassify+refine (scales held)"``), and the scales
    are estimated again from there on the settled set (``"refine (scales estimated)"``,
    :func:`_held_as_start`). ``spread``: the judging takes in the spread of the tracks'
    noise (:func:`judge_tracks`). Returns ``(cal, inliers, stages)``."""
    cal = fit_refine(masked(uv, inliers), T, linear, opts.refinement, flange=flange)
    report(progress, "refine", iterations=cal.stats.refine.iterations, rms_px=cal.rms_px, distortion=cal.dist_model)
    stages = ["refine"]
    chosen = replace(opts.refinement, distortion=cal.dist_model)  # refits keep the model chosen
    selection = cal.stats.distortion_selection
    k = np.isfinite(uv[..., 0]).sum(axis=0)
    refit, verdict = chosen, None  # the refits' options (a misfit's judge's scales given); that fit's robot error
    lens_set = 0 if inliers is None else int(inliers.sum())  # the tracks the lens was chosen on
    last = None  # the last refit, its uncertainty computed only if it stays the result
    for _ in range(REJUDGE_ROUNDS if inliers is not None else 0):  # until the inlier set settles
        scales, judge = _misfit_scales(cal), cal
        if scales is not None:  # the lens is chosen again too: a misfit's fit chose it
            verdict = cal.robot_error
            given = dict(robot_sigma_deg=scales[0], robot_sigma_pos=scales[1])
            judge = fit_refine_deferred(masked(uv, inliers), T, cal, replace(opts.refinement, **given)).light
            chosen = replace(chosen, distortion=judge.dist_model)
            refit = replace(chosen, **given)
        X_all = triangulated(uv, judge)
        again = judge_tracks(uv, judge, X_all, opts, spread)
        # a few borderline tracks trading places change nothing: refit only for more
        if np.sum(again != inliers) <= max(2, REJUDGE_FRACTION * inliers.sum()) or again.sum() < 2:
            break
        inliers = again
        start = replace(judge, X=np.where(inliers[:, None], X_all, np.nan))
        if opts.refinement.distortion == "auto" and refit == chosen and again.sum() > LENS_AGAIN_GROWTH * lens_set:
            cal = fit_refine(masked(uv, inliers), T, start, opts.refinement)  # the lens chosen again
            chosen = refit = replace(chosen, distortion=cal.dist_model)
            selection, lens_set = cal.stats.distortion_selection, int(again.sum())
            stages.append("reclassify+refine (lens chosen again)")
            continue
        last = fit_refine_deferred(masked(uv, inliers), T, start, refit)
        cal = last.light
        stages.append("reclassify+refine" if refit == chosen else "reclassify+refine (scales held)")
    if refit != chosen:  # the scales estimated again, on the inliers the given ones settled
        cal = fit_refine(masked(uv, inliers), T, _held_as_start(cal, verdict), chosen)
        stages.append("refine (scales estimated)")
    elif last is not None and cal is last.light:
        cal = last.complete()
    if opts.refinement.distortion == "auto" and stages[-1] != "refine":  # more tracks: more distortion?
        cal = climb_distortion(masked(uv, inliers), T, cal, opts.refinement)
        cal = replace(cal, stats=replace(cal.stats, distortion_selection=selection + cal.stats.distortion_selection))
    if cal.inliers is not None:  # the robust loss classified points too
        inliers = cal.inliers if inliers is None else inliers & cal.inliers
    if inliers is not None and opts.ransac.threshold_px is None and opts.refinement.sigma_px is None:
        cal = untruncated(cal, k[inliers], opts.ransac.false_rejection)
    return cal, inliers, stages


def _held_as_start(cal: Calibration, verdict) -> Calibration:
    """``cal`` (fitted at held scales) as the start of the fit that estimates them again:
    its scales and per-view errors as estimated ones, so that the variance-component
    rounds continue from there (:class:`~transcalib.estimate.robot_scales.RobotStart`)
    rather than select afresh from the exact-pose fit, where they ran away before (on a
    render with single views at 0.2 deg / 2 mm selecting afresh ended with cx 9 std off);
    the score tests' p-values are those of the misfit's fit ``verdict``, the scales'
    checks against them not made (NaN). With a component held at 0 (left out) the
    selection starts afresh (no robot error in the start): a prior of scale 0 would weigh
    its errors infinitely, and continued without it the other component took up a wrong
    lens's misfit with fx (13 % on ``tests/test_realistic.py``'s scene with the lens
    forced to none), which the fresh selection's checks against the scores leave out."""
    re = cal.robot_error
    if re is None or verdict is None or min(re.sigma_rot_deg, re.sigma_pos) <= 0:
        return replace(cal, robot_error=None)
    return replace(cal, robot_error=replace(re, source=("estimated",) * len(re.source), p_values=verdict.p_values,
                                            consistency_p=np.full(len(re.source), np.nan),
                                            score_scales=verdict.score_scales))


def _misfit_scales(cal: Calibration) -> tuple | None:
    """``(sigma_rot_deg, sigma_pos)`` to judge the tracks with where ``cal`` left a robot
    error component out as a misfit: the fitted scales, a misfit's at the score's moment
    estimate (the data's first-order evidence, ``RobotError.score_scales``); else None.
    Wrong links in a few views make the variance-component rounds run away; the
    exact-pose fit then judges with a pixel noise that the robot's error inflated and
    keeps them (renders, session + single views at 0.1 deg / 1 mm: 0.5 px against
    0.04 px; one session at 0.2 deg / 2 mm: fx 81 px off)."""
    re = cal.robot_error
    if re is None or "misfit" not in re.source:
        return None
    fitted = np.array([re.sigma_rot_deg, re.sigma_pos])
    scales = np.where(np.array(re.source) == "misfit", re.score_scales, fitted)
    return (float(scales[0]), float(scales[1])) if np.all(np.isfinite(scales)) else None


def untruncated(cal: Calibration, k: np.ndarray, alpha: float) -> Calibration:
    """Undo the bias of a noise estimated on chi-square-selected inliers: the rule drops
    the largest ``alpha`` of the good tracks' errors, so ``sigma^2`` (and every variance
    scaled by it) comes out low by :func:`truncation_factor` (about 2 %)."""
    c = truncation_factor(k, alpha)
    root = float(np.sqrt(c))
    return replace(cal, sigma_px=float(cal.sigma_px / root), cov=cal.cov / c,
                   std={name: float(v / root) for name, v in cal.std.items()}, X_std=cal.X_std / root,
                   T_std=None if cal.T_std is None else cal.T_std / root,
                   uncertainty=None if cal.uncertainty is None else cal.uncertainty.scaled(c),
                   stats=replace(cal.stats, sigma_truncation_factor=c))


def track_sse(uv: np.ndarray, cal: Calibration, X: np.ndarray, halves: bool = False):
    """Sum of squared reprojection errors (px^2) of each track over the views that see it
    (n_points,); inf for tracks that cannot be triangulated or fall behind the camera.
    With ``halves``, also the sums over each half of its views (alternate views of those
    that see it: ``(sse, sse_a, sse_b)``, what :func:`transcalib.estimate.noise.noise_spread`
    compares). Evaluated ``TRACK_BLOCK`` tracks at a time (small temporaries)."""
    out = np.empty((3, uv.shape[1]))
    R_cam, C = camera_poses(cal, cal.T)
    for lo in range(0, uv.shape[1], TRACK_BLOCK):
        b = slice(lo, lo + TRACK_BLOCK)
        xc = camera_frame(R_cam, np.nan_to_num(X[b]), C)
        pred = project_camera_frame(cal.camera.intrinsics, cal.camera.dist5, xc, valid=xc[2] > 0).pred  # behind: inf
        seen = np.isfinite(uv[:, b, 0])
        du, dv = uv[:, b, 0] - pred[0], uv[:, b, 1] - pred[1]
        e2 = du * du + dv * dv
        parts = [np.sum(e2, axis=0, where=seen)]
        if halves:  # each view's own level out (a pose error is not noise), then alternate views
            rel = e2 / _view_levels(e2, seen)
            first = (np.cumsum(seen, axis=0) % 2 == 1) & seen  # the 1st, 3rd, ... view that sees the track
            parts += [np.sum(rel, axis=0, where=w) for w in (first, seen & ~first)]
        behind = np.any(seen & (xc[2] <= 0), axis=0)
        out[:len(parts), b] = np.where(np.isfinite(X[b, 0]) & ~behind, parts, np.inf)
    return tuple(out) if halves else out[0]


def _view_levels(e2: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """``(n_views, 1)``: each view's median squared residual over the tracks it sees (1
    for a view that sees none, or of exact residuals)."""
    level = np.ones((len(e2), 1))
    for i in np.flatnonzero(seen.any(axis=1)):
        m = np.median(e2[i, seen[i]])
        level[i] = m if m > 0 else 1.0
    return level


def judge_tracks(uv: np.ndarray, cal: Calibration, X: np.ndarray, opts: CalibrateOptions,
                 spread: bool = False) -> np.ndarray:
    """Inlier tracks ``(n_points,)`` by the refined camera ``cal`` and their points ``X``;
    with ``spread`` the rule takes in the spread of the tracks' noise that their two
    halves of views show (:func:`transcalib.estimate.noise.noise_spread`; none with a
    user threshold)."""
    k = np.isfinite(uv[..., 0]).sum(axis=0)
    if not spread or opts.ransac.threshold_px is not None:
        return inlier_rule(track_sse(uv, cal, X), k, rule_sigma(cal, opts), opts.ransac.false_rejection)
    sse, sse_a, sse_b = track_sse(uv, cal, X, halves=True)
    return inlier_rule(sse, k, rule_sigma(cal, opts), opts.ransac.false_rejection, noise_spread(sse_a, sse_b, k))


def rule_sigma(cal: Calibration, opts: CalibrateOptions) -> float:
    """The sigma of the inlier rule after refinement: the refined estimate, or the one a
    user threshold implies."""
    if opts.ransac.threshold_px is not None:
        return sigma_from_threshold(opts.ransac.threshold_px, opts.ransac.false_rejection)
    return max(cal.sigma_px, SIGMA_FLOOR_PX)


def all_residuals(uv, cal: Calibration, inliers) -> np.ndarray:
    """Residuals of every observation for reporting, outliers included: an outlier is
    triangulated with the final camera for that (its ``X`` stays NaN)."""
    if inliers is None:
        return cal.residuals_px
    out = cal.residuals_px.copy()
    missing = ~np.isfinite(cal.X[:, 0])  # only these need triangulating and projecting
    X = triangulated(uv[:, missing], cal)
    R_cam, C = cal.camera_poses()
    res = uv[:, missing] - project(cal.K, R_cam, np.nan_to_num(X), C, cal.dist)
    out[:, missing] = np.where(np.isfinite(X)[None, :, :1], res, np.nan)
    return out


def from_linear(uv: np.ndarray, T: np.ndarray, linear: LinearEstimate, flange: FlangeModel | None = None
                ) -> Calibration:
    """A :class:`Calibration` holding the linear estimate alone (no distortion).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float
    linear : LinearEstimate
    flange : FlangeModel, optional
        The views' flange rotations and the offset (several orientations).
    """
    cal = Calibration(camera=Camera(linear.K, linear.R), X=linear.X, residuals_px=np.zeros(uv.shape), rms_px=0.0,
                      T=T.copy(), linear=linear, stats=CalibrationStats(stages=("linear",)),
                      flange_rotations=None if flange is None else np.transpose(flange.F, (0, 2, 1)),
                      hand_eye=None if flange is None else linear_hand_eye(linear.R, flange, len(T)))
    R_cam, C = cal.camera_poses()
    residuals = uv - project(linear.K, R_cam, np.nan_to_num(linear.X), C)
    residuals[:, ~linear.used] = np.nan
    r2 = np.sum(residuals**2, axis=2)
    rms = float(np.sqrt(np.nanmean(r2))) if np.isfinite(r2).any() else float("nan")
    return replace(cal, residuals_px=residuals, rms_px=rms)


def linear_hand_eye(R: np.ndarray, flange: FlangeModel, n_views: int) -> HandEye:
    """The hand-eye pose of a start without uncertainty: ``R_X = R^T``, ``t`` of ``flange``,
    the directions ``flange.t_basis`` leaves free undetermined."""
    return HandEye("eye-in-hand", R.T.copy(), np.asarray(flange.t0, float), np.full(3, np.nan), np.full((3, 3), np.nan),
                   complement(np.asarray(flange.t_basis).reshape(3, -1)), np.zeros(n_views, int), ("0",))
