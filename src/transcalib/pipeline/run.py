"""``calibrate()``: the one call users make, for every robot motion.

    uv, poses ──motion (sessions by orientation; eye-to-hand poses inverted)──▶ Motion
          ──explain what the motion determines (degeneracy first)──▶
          ──start (robust TLS of one orientation, or of the sessions, single views joined)──▶
          ──refine (ML bundle adjustment)──▶ every track judged again, refit
          ──diagnose──▶ Calibration with warnings (and the hand-eye pose)

With more than ``subset_points`` tracks the stages up to the re-judging run on a random
subset of them; "all tracks" then judges every track with that camera and takes
Gauss-Newton steps with all of them (:func:`.stages.extend_to_all_tracks`). Input is
checked here once; the stages take checked arrays and options.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from ..check import diagnose, skipped
from ..check.prediction import LOO_MIN_VIEWS, leave_one_view_out
from ..errors import DegenerateError, InputError
from ..handeye.sessions import SESSION_TOLERANCE_DEG
from ..types import SUBSET_POINTS, CalibrateOptions, Calibration, LinearEstimate, RansacOptions, RefineOptions, report
from ..types.options import check_fixed_distortion
from ..validate import as_uv_T
from .motion import Motion, motion_of
from .result import with_motion
from .stages import (REJUDGE_FRACTION, all_residuals, extend_to_all_tracks, from_linear, judge_tracks, masked,
                     refine_and_rejudge, triangulated)
from .start import explain_motion, initial_estimate
from .views_off import (leave_out_pose_outliers, orientation_off, pose_left_out, rejudge_views, view_indices,
                        without_views)

__all__ = ["calibrate"]


class _Fitted(NamedTuple):
    """A refined fit: the calibration, its inlier tracks, the stages run, their clocks, and
    ``rotation_data`` ``(uv, calibration)`` the subset's fit (with a subset; else None),
    which the tests of the poses run on."""

    cal: Calibration
    inliers: np.ndarray | None
    stages: list
    timings: dict
    rotation_data: tuple | None


def calibrate(
    uv,
    poses,
    *,
    setup: str = "eye-in-hand",
    session_tolerance_deg: float = SESSION_TOLERANCE_DEG,
    refine: bool = True,
    robust: bool | None = None,
    distortion: str | None = None,
    sigma_T=None,
    fix=None,
    square_pixels: bool | None = None,
    ransac: RansacOptions | None = None,
    refinement: RefineOptions | None = None,
    check_rotation: bool = True,
    keep_pose_outliers: bool = False,
    image_size=None,
    unit: str = "units",
    subset_points: int | None = SUBSET_POINTS,
    rng=0,
    progress=None,
) -> Calibration:
    """Calibrate the camera and reconstruct the scene from tracks and known robot poses.

    One model serves every motion (docs/hand-eye.md): a view has a flange pose ``(R_i,
    T_i)`` in the robot base frame and the camera sits in the flange at ``(R_X, t_X)``,
    ``x_ij ~ K (R_i R_X)^T (X_j - T_i - R_i t_X)``. One orientation (translations only)
    is the paper's case; views whose orientations agree within ``session_tolerance_deg``
    form a pure-translation session, every other view is a single view at its own
    orientation; any mix. Eye-to-hand, the camera is fixed and the flange carries the
    scene.

    Parameters
    ----------
    uv : array_like (n_views, n_points, 2)
        Pixel coordinates (centre of the top-left pixel is (0, 0)), NaN where unseen.
    poses : transcalib.Poses or array_like (n_views, 3)
        The flange poses of the views (:func:`transcalib.io.read_poses`, or
        ``Poses.of(T, R)``), or the robot translations alone (one orientation; robot
        frame: every output length is in its unit).
    setup : {"eye-in-hand", "eye-to-hand"}
        The camera on the flange (default), or fixed and watching the flange, which
        carries the scene: the scene points are then in the flange frame and
        ``hand_eye`` is the camera in the base frame.
    session_tolerance_deg : float
        Views whose flange orientations differ by less than this form one session.
    refine : bool
        Maximum-likelihood refinement after the linear estimate (default). ``False``
        returns the paper's linear estimate, triangulated.
    robust : bool or None
        RANSAC over 2-point samples before the linear fit. ``None`` (default): on from
        ``ROBUST_MIN_POINTS`` points.
    distortion : {"auto", "none", "radial1", "radial2", "opencv5"}, optional
        Lens distortion model of the refinement (default ``refinement.distortion``,
        ``"auto"``: chosen from the data, see :class:`RefineOptions`).
    sigma_T : float or (n_views,) float, optional
        Robot translation precision (user units): translations become measurements.
    fix : mapping, optional
        Known parameters, e.g. ``{"cx": 320.0, "cy": 240.0, "skew": 0.0}``.
    square_pixels : bool, optional
        ``fx = fy``.
    ransac : RansacOptions, optional
        Options of the robust stage.
    refinement : RefineOptions, optional
        Options of the refinement; the keywords above override their fields.
    check_rotation : bool
        Test for views where the camera turned otherwise than the poses say (model
        violation), and whether each view's image agrees with its recorded pose; needs
        ``refine``.
    keep_pose_outliers : bool
        Name a view whose image contradicts its recorded pose (``pose_outlier``) but keep
        it in the fit. Default: such views are left out, the most significant first, and
        the calibration refitted without them (at most a quarter of the views;
        ``pose_left_out`` names each with the size of its error).
    image_size : (width, height), optional
        Recorded in the result's camera.
    unit : str
        Name of the length unit of the translations, used in messages.
    subset_points : int or None
        With more tracks, the iterative stages run on a random subset of this many and
        Gauss-Newton steps with every track finish (:class:`CalibrateOptions`). None:
        every stage uses every track.
    rng : seed or Generator
        Randomness of RANSAC and of the subset. The default seed gives the same result for
        the same input on every run; pass a Generator (or None) for fresh randomness.
    progress : callable, optional
        ``progress(event)`` with a :class:`~transcalib.types.ProgressEvent` after each
        stage (and each step of the long ones).

    Returns
    -------
    Calibration
        With ``diagnostics``, ``inliers`` (robust runs), ``cov``/``std``/``X_std``
        (refined runs), ``hand_eye`` (with orientations in the poses), ``options``,
        ``stats`` (stages, timings, the robust stage, the refinement) and ``info``
        (``"views_left_out"``: the views whose images contradict their poses, each
        ``{"view": index, "why": "orientation" | "pose"}``; ``"leave_one_view_out"``).

    Raises
    ------
    InputError, DegenerateError, MirroredError
        See :func:`transcalib.estimate_linear`; ``InputError`` also for an option that
        would have no effect (e.g. ``sigma_T`` with ``refine=False``).
    """
    motion = motion_of(poses, setup, session_tolerance_deg)
    uv, _ = as_uv_T(uv, motion.T, **({} if motion.constant else {"min_views": 2}))
    opts = _options(refine, robust, distortion, sigma_T, fix, square_pixels, ransac, refinement,
                    check_rotation, keep_pose_outliers, unit, subset_points, setup, session_tolerance_deg)
    t0 = time.perf_counter()
    span = explain_motion(motion, opts)  # degeneracy first: raises naming what the motion cannot determine
    subset = _fit_subset(uv, opts, rng)
    def run(data):  # the start and the refinement of ``data`` (every view's, or fewer)
        return _start_and_fit(data, motion, opts, subset, span is not None, image_size, rng, progress)

    def start_of(data):  # the start alone, quietly
        return initial_estimate(data if subset is None else data[:, subset], motion, opts, rng, None,
                                coplanar=span is not None, image_size=image_size)

    if opts.refine and opts.check_rotation and not opts.keep_pose_outliers:
        pose_off, start, fitted = leave_out_pose_outliers(uv, motion, opts, run, start_of, progress)
    else:
        pose_off, (start, fitted) = [], run(uv)
    off_views = view_indices(start.off_views) + [o.view for o in pose_off]
    left_out = np.isin(np.arange(motion.n_views), off_views)
    uv = without_views(uv, off_views)

    def finished(fit: _Fitted):  # the fit as the result, and what the checks find in it
        cal, inliers, stages, timings, rotation_data = fit
        timings = dict(timings)
        begin = timings.pop("begin_s")
        timings = {f"{start.stages[0]}_s": timings.pop("start_s") - begin, **timings}
        if pose_off:
            stages = stages + [f"{len(pose_off)} view(s) left out (pose)"]
            timings["earlier_fits_s"] = begin - t0
        result = replace(cal, camera=replace(cal.camera, image_size=image_size), inliers=inliers,
                         residuals_px=all_residuals(uv, cal, inliers), options=opts, diagnostics=(),
                         stats=replace(cal.stats, stages=tuple(stages), timings_s=timings, ransac=start.ransac))
        found = [orientation_off(v, deg, motion.grouping.tolerance_deg) for v, deg in start.off_views]
        if pose_off:
            found.append(pose_left_out(pose_off, motion, view_ids=getattr(poses, "views", None), unit=unit))
        found += diagnose(
            uv, motion.T, result, linear=result.linear, check_rotation=opts.check_rotation and opts.refine,
            unit=unit, all_uv=uv, rotation_data=rotation_data, sessions=motion.session_of_view,
            views_left_out=left_out, view_ids=getattr(poses, "views", None), setup=setup)
        if span is not None:  # the coplanar motion was understood: say what it allows instead
            found = [span] + [d for d in found if d.code not in ("translations_coplanar", "translations_small")]
        if opts.check_rotation and not opts.refine:
            found.append(skipped("rotation test (did the camera turn otherwise than the poses say?)",
                                 "it needs the refined calibration (refine=False, CLI --no-refine)"))
        return result, found

    t2 = time.perf_counter()
    result, found = finished(fitted)
    if not MISFIT_CODES & {d.code for d in found}:  # a misfit spreads the errors too: that is not noise
        spread = _with_noise_spread(uv, motion.T, subset, start, fitted, opts, progress)
        if spread is not fitted:
            fitted = spread
            t2 = time.perf_counter()
            result, found = finished(fitted)
    rotation_data = fitted.rotation_data
    report(progress, "diagnostics", warnings=len(found))
    t3 = time.perf_counter()
    info = _prediction(rotation_data or (uv, result), motion, opts, getattr(poses, "views", None))
    report(progress, "prediction", **({} if not info else {"rms_px": info["leave_one_view_out"]["rms_px"]}))
    timings = {**result.stats.timings_s, "diagnostics_s": t3 - t2, "prediction_s": time.perf_counter() - t3}
    result = replace(result, diagnostics=tuple(found), stats=replace(result.stats, timings_s=timings),
                     info={**result.info, **info, "views_left_out": _left_out_info(start.off_views, pose_off)})
    return with_motion(result, motion, start.notes)


#: Diagnostics of a model misfit (a wrong fixed value, a pose or an orientation off): the
#: tracks' errors then spread by more than their noise, and are not judged by that spread.
MISFIT_CODES = frozenset({"fix_contradicted", "pose_outlier", "pose_repeated", "view_rotation", "view_residuals",
                          "implausible_intrinsics"})


def _left_out_info(off_views, pose_off) -> list:
    """``Calibration.info["views_left_out"]``: ``{"view": index, "why": "orientation" |
    "pose"}`` for each view left out of the fit (the diagnostics say by how much)."""
    return [{"view": int(v), "why": "orientation"} for v in view_indices(off_views)] + [
        {"view": o.view, "why": "pose"} for o in pose_off]


def _start_and_fit(uv, motion: Motion, opts: CalibrateOptions, subset, coplanar: bool, image_size, rng,
                   progress):
    """The start on ``uv`` (the subset's tracks), the refinement without the single views
    whose orientation the start found off, and again with those the refined lens takes
    back: ``(start, fitted)``; ``fitted.timings["begin_s"]`` the clock at the beginning."""
    begin = time.perf_counter()
    start = initial_estimate(uv if subset is None else uv[:, subset], motion, opts, rng, progress,
                             coplanar=coplanar, image_size=image_size)
    fitted = _fit(without_views(uv, view_indices(start.off_views)), motion.T, subset, start, opts, progress)
    if start.off_views and opts.refine:  # judged again with the refined lens: those that agree come back
        off = rejudge_views(uv, motion, fitted.cal, start.off_views, rng)
        if len(off) < len(start.off_views):
            report(progress, "views re-admitted", views=len(start.off_views) - len(off))
            start = replace(start, off_views=off)
            again = _fit(without_views(uv, view_indices(off)), motion.T, subset, start, opts, progress)
            fitted = _refitted(fitted, again)
    return start, fitted._replace(timings={"begin_s": begin, **fitted.timings})


def _with_noise_spread(uv, T, subset, start, fitted: _Fitted, opts: CalibrateOptions, progress) -> _Fitted:
    """The tracks judged again by the final fit with the spread of their noise taken in
    (:func:`~.stages.judge_tracks`; docs/robust-and-diagnostics.md §2, "Tracks whose noise
    differs"), and refitted where that changes the inlier set: the refinement and its
    re-judging from the final fit (the lens model kept), then every track. Run last, once
    the views whose pose or orientation is off are out and only when the checks find no
    misfit (:data:`MISFIT_CODES`): a wrong pose or fixed value spreads the tracks' errors
    too, which is not their noise. ``fitted`` itself when there is nothing to judge (no
    robust stage, a user threshold, ``RansacOptions.noise_spread`` False), the set
    hardly changes, or the refit fails (the spread was a misfit's)."""
    if not (opts.refine and opts.ransac.noise_spread) or fitted.inliers is None or opts.ransac.threshold_px is not None:
        return fitted
    uv_sub, inliers = (uv, fitted.inliers) if subset is None else (uv[:, subset], fitted.inliers[subset])
    X = triangulated(uv_sub, fitted.cal)
    again = judge_tracks(uv_sub, fitted.cal, X, opts, spread=True)
    if np.sum(again != inliers) <= max(2, REJUDGE_FRACTION * inliers.sum()):
        return fitted
    t1 = time.perf_counter()
    kept = replace(opts, refinement=replace(opts.refinement, distortion=fitted.cal.dist_model))
    begin = replace(fitted.cal, X=np.where(again[:, None], X, np.nan))
    try:
        cal, inliers, more = refine_and_rejudge(uv_sub, T, begin, again, kept, progress, start.flange, spread=True)
    except DegenerateError:  # the spread was a misfit's (a wrong fixed value, say): the fit of one noise stands
        return fitted
    stages, timings, rotation_data = fitted.stages + ["noise spread: " + "+".join(more)], dict(fitted.timings), None
    if subset is not None:
        rotation_data = (masked(uv_sub, inliers), cal)
        cal, inliers = extend_to_all_tracks(uv, T, cal, inliers, kept, progress, spread=True)
        stages.append("all tracks")
    timings["noise_spread_s"] = time.perf_counter() - t1
    cal = replace(cal, linear=fitted.cal.linear,
                  stats=replace(cal.stats, distortion_selection=fitted.cal.stats.distortion_selection))
    return _Fitted(cal, inliers, stages, timings, rotation_data)


def _refitted(old: _Fitted, new: _Fitted) -> _Fitted:
    """``new`` with the clock of ``old``'s start (the first fit's)."""
    return new._replace(timings={**new.timings, "start_s": old.timings["start_s"]})


def _prediction(fit, motion: Motion, opts: CalibrateOptions, view_ids) -> dict:
    """``{"leave_one_view_out": ...}`` (:func:`transcalib.check.prediction.leave_one_view_out`
    on the fit ``(uv, calibration)``) for a refined calibration of at least
    ``LOO_MIN_VIEWS`` views, else empty."""
    if not opts.refine or motion.n_views < LOO_MIN_VIEWS:
        return {}
    try:
        return {"leave_one_view_out": leave_one_view_out(fit[0], motion.T, fit[1], view_ids=view_ids)}
    except DegenerateError:  # too few observations to refit without a view
        return {}


def _fit(uv, T, subset, start, opts: CalibrateOptions, progress):
    """Refinement and re-judging on the fit's tracks, then every track (with a subset):
    a :class:`_Fitted`; ``timings["start_s"]`` the clock at the start's end."""
    uv_sub = uv if subset is None else uv[:, subset]
    timings, stages, inliers = {"start_s": time.perf_counter()}, list(start.stages), start.inliers
    if not opts.refine:
        return _Fitted(replace(from_linear(masked(uv, inliers), T, start.linear, start.flange), linear=start.linear),
                       inliers, stages, timings, None)
    t1 = time.perf_counter()
    cal, inliers, more = refine_and_rejudge(uv_sub, T, start.linear, inliers, opts, progress, start.flange)
    stages += more
    timings["refine_s"] = time.perf_counter() - t1
    if subset is None:
        return _Fitted(cal, inliers, stages, timings, None)
    t1 = time.perf_counter()
    rotation_data = (masked(uv_sub, inliers), cal)  # the rotation test runs on the subset's fit
    cal, inliers = extend_to_all_tracks(uv, T, cal, inliers, opts, progress)
    stages.append("all tracks")
    timings["all_tracks_s"] = time.perf_counter() - t1
    return _Fitted(replace(cal, linear=_widened(start.linear, subset, uv.shape[1])), inliers, stages, timings,
                   rotation_data)


def _fit_subset(uv: np.ndarray, opts: CalibrateOptions, rng) -> np.ndarray | None:
    """Sorted indices of the tracks the iterative stages use (``opts.subset_points`` of
    those seen in >= 2 views, drawn at random), or None when they use every track."""
    m = opts.subset_points
    if not opts.refine or m is None:
        return None
    tracked = np.flatnonzero(np.isfinite(uv[..., 0]).sum(axis=0) >= 2)
    if len(tracked) <= m:
        return None
    return np.sort(np.random.default_rng(rng).choice(tracked, m, replace=False))


def _widened(linear: LinearEstimate, subset: np.ndarray, n_points: int) -> LinearEstimate:
    """The linear estimate of the tracks ``subset`` with its per-point arrays over all
    ``n_points`` tracks (NaN / unused outside the subset)."""
    def spread(a, fill, axis):
        shape = list(np.shape(a))
        shape[axis] = n_points
        out = np.full(shape, fill, dtype=np.asarray(a).dtype)
        out[(slice(None),) * axis + (subset,)] = a
        return out

    return replace(linear, X=spread(linear.X, np.nan, 0), depth=spread(linear.depth, np.nan, 1),
                   used=spread(linear.used, False, 0),
                   static=None if linear.static is None else spread(linear.static, False, 0))


def _options(refine, robust, distortion, sigma_T, fix, square_pixels, ransac, refinement, check_rotation,
             keep_pose_outliers, unit, subset_points, setup, session_tolerance_deg) -> CalibrateOptions:
    """The :class:`CalibrateOptions` of a call; keywords override ``refinement``'s fields."""
    r = refinement if refinement is not None else RefineOptions()
    overrides = {k: v for k, v in (("distortion", distortion), ("sigma_T", sigma_T), ("fix", fix),
                                   ("square_pixels", square_pixels)) if v is not None}
    if overrides:
        r = replace(r, **overrides)
    if not refine and r.distortion not in ("none", "auto"):
        raise InputError(f"distortion={r.distortion!r} needs refine=True: the linear estimate has no distortion")
    if refine:
        check_fixed_distortion(r)
    return CalibrateOptions(refine=bool(refine), robust=robust, ransac=ransac or RansacOptions(), refinement=r,
                            check_rotation=bool(check_rotation), keep_pose_outliers=bool(keep_pose_outliers),
                            unit=str(unit), subset_points=subset_points,
                            setup=setup, session_tolerance_deg=float(session_tolerance_deg))


