"""Views left out because their images contradict their recorded poses.

**A single view's orientation.**
The start judges each single view's orientation with the start's camera, which has no
lens distortion: with a distorted lens the image pose of a view turned far from the
others is a little off, and a view can look off that is not. After the refinement (the
lens, the points and the hand-eye pose of every other view) the views left out are judged
again with the same rule (:func:`transcalib.handeye.join.judge_orientations`) on
undistorted pixels; the views that now agree come back into the fit, the others stay out,
named with their angle (``pose_orientation_off``).

**Any view's pose** (:func:`leave_out_pose_outliers`). After the refinement the view
whose image contradicts its recorded pose most significantly
(:func:`transcalib.check.poses.find_pose_outliers`) is left out and the whole fit run
again without it, until the test names none or :func:`max_left_out` views are out
(``pose_left_out``, with the size of each error). A wrong pose biases every parameter
and, with the robot error in the model, inflates its scale and so every reported std.
First, a wrong pose may have broken the fit (few tracks kept, far noisier than the start,
or diverged): the view without which the start fits best is tested
(:func:`_view_breaking_the_fit`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..check.fixed import check_fixed
from ..check.poses import (POSE_ALPHA, describe_pose_outlier, find_pose_outliers, pose_contradiction, repeated_pairs,
                           view_name)
from ..check.prediction import LOO_MIN_VIEWS
from ..check.tracks import MIN_INLIER_FRACTION
from ..errors import DegenerateError, Diagnostic
from ..estimate.noise import mad_sigma
from ..handeye.join import judge_orientations, view_pose
from ..types import CalibrateOptions, report
from .motion import Motion

__all__ = ["rejudge_views", "orientation_off", "leave_out_pose_outliers", "max_left_out", "pose_left_out",
           "view_indices", "without_views", "MAX_LEFT_OUT_FRACTION"]

#: At most this fraction of the views (at least one) is left out for contradicting its pose.
MAX_LEFT_OUT_FRACTION = 0.25
#: A start without one view fits better than those without each other view by this many
#: robust standard deviations of theirs: the view may have broken the fit (then tested).
OUTLYING_Z = 3.0


def rejudge_views(uv: np.ndarray, motion: Motion, cal, off_views, rng=None) -> tuple:
    """The views of ``off_views`` still off with the refined calibration ``cal``
    (module docstring): ``((view, degrees), ...)``, the angle the refined camera gives (or
    the start's, for a view whose pose the refined points cannot give).

    ``uv (n_views, n_points, 2)`` every observation; ``motion`` the model's poses
    (eye-to-hand inverted); ``cal`` refined with the flange model."""
    single = np.flatnonzero(motion.session_sizes()[motion.grouping.session_of_view] == 1)
    undistorted = cal.camera.undistort_points(uv[single])
    found = [p for p in (view_pose(u, cal.X, cal.K, int(v), rng) for u, v in zip(undistorted, single))
             if p is not None]
    _, off_now = judge_orientations(found, motion.R, cal.R.T, motion.grouping.tolerance_deg)
    now, judged = dict(off_now), {p.view for p in found}
    return tuple((v, now[v]) if v in now else (v, deg) for v, deg in off_views if v in now or v not in judged)


def orientation_off(view: int, angle_deg: float, tolerance_deg: float) -> Diagnostic:
    """The warning for a single view whose recorded orientation its image contradicts."""
    return Diagnostic(
        "pose_orientation_off",
        f"view {view}: its recorded flange orientation is {angle_deg:.2f} deg off the camera orientation its image "
        f"shows (more than the session tolerance of {tolerance_deg:g} deg, significantly): the pose is "
        "wrong (a typo, another view's orientation, the wrong rotation format or axis order), or the camera "
        "moved on the flange. The view is left out; check its pose.")


def max_left_out(n_views: int) -> int:
    """How many views may be left out for contradicting their poses."""
    return max(1, int(MAX_LEFT_OUT_FRACTION * n_views))


def pose_left_out(found: list, motion: Motion, *, view_ids=None, unit: str = "units") -> Diagnostic:
    """The warning for the views left out because their images contradict their recorded
    poses (``found``: :class:`~transcalib.check.poses.PoseOutlier`, in the order left out),
    each named with the size of its error and, where its recorded pose is another view's,
    with that view."""
    pairs = repeated_pairs(motion.T, motion.R)
    parts = []
    for o in found:
        same = [j if i == o.view else i for i, j in pairs if o.view in (i, j)]
        parts.append(describe_pose_outlier(o, view_ids=view_ids, unit=unit, setup=motion.setup, R_model=motion.R)
                     + "".join(f"; its recorded pose is that of {view_name(view_ids, j)} (a copied row?)"
                               for j in same[:1]))
    one = len(found) == 1
    return Diagnostic(
        "pose_left_out",
        f"the image of {'a view' if one else f'{len(found)} views'} contradicted the recorded pose: "
        f"{'; '.join(parts)}. {'It was' if one else 'They were'} left out and the calibration fitted without "
        f"{'it' if one else 'them'}: check {'that pose' if one else 'those poses'} for a typo, a swapped or missing "
        "digit, a move that did not finish or a row of another view, and correct "
        f"{'it' if one else 'them'} (keep_pose_outliers=True, CLI --keep-pose-outliers, keeps such views in).")


def view_indices(off_views) -> list:
    """The view indices of ``off_views`` ((view, degrees), ...)."""
    return [v for v, _ in off_views]


def without_views(uv: np.ndarray, views) -> np.ndarray:
    """``uv`` without the observations of ``views`` (indices)."""
    return np.where(np.isin(np.arange(uv.shape[0]), views)[:, None, None], np.nan, uv) if len(views) else uv


def leave_out_pose_outliers(uv, motion: Motion, opts: CalibrateOptions, run, start_of, progress) -> tuple:
    """The fit ``run(uv)`` (``(start, fitted)``), then views whose image contradicts
    their recorded pose left out one at a time, the most significant first, the whole fit
    run again without each (at most :func:`max_left_out`; one that leaves a motion the fit
    cannot use is kept, and so is one whose fit keeps fewer than half of the tracks where
    the fit with it kept more): ``(found, start, fitted)``, ``found`` a list of
    :class:`~transcalib.check.poses.PoseOutlier`. First a view that breaks the fit
    (:func:`_view_breaking_the_fit`; ``start_of(uv)`` the start alone). Not with a fixed
    parameter the data contradict: its residuals would be blamed on the poses."""
    try:
        start, fitted = run(uv)
    except DegenerateError as exc:
        start, fitted, failed = None, None, exc
    found = []
    broke = _view_breaking_the_fit(uv, motion, start, fitted, run, start_of, progress)
    if broke is not None:
        report(progress, "view left out (its image contradicts its pose)", view=broke[0][0].view)
        found, start, fitted = broke
    elif fitted is None:
        raise failed
    while len(found) < max_left_out(motion.n_views):
        fit_uv = without_views(uv, view_indices(start.off_views) + [o.view for o in found])
        data = fitted.rotation_data or (fit_uv, replace(fitted.cal, inliers=fitted.inliers))  # as diagnose()
        try:
            if not found and opts.refinement.fix and any(
                    d.code == "fix_contradicted" for d in check_fixed(data[0], motion.T, data[1])):
                break
            new = find_pose_outliers(data[0], motion.T, data[1])[:1]
            if not new:
                break
            again = run(without_views(uv, [o.view for o in found + new]))
        except DegenerateError:
            break
        if _share(again[1].inliers, uv) < min(_share(fitted.inliers, uv), MIN_INLIER_FRACTION):
            break  # the fit without it keeps fewer than half of the tracks: that view was not the wrong one
        report(progress, "view left out (its image contradicts its pose)", view=new[0].view)
        (start, fitted), found = again, found + new
    return found, start, fitted


def _view_breaking_the_fit(uv, motion: Motion, start, fitted, run, start_of, progress):
    """When the fit failed (``fitted`` None), kept fewer than half of the tracks or ended
    with a noise estimate over twice the robust start's: the view without which the
    robust start fits best, and its recorded pose contradicted
    (:func:`~transcalib.check.poses.pose_contradiction`) by the whole fit run again without
    it: ``([PoseOutlier], start, fitted)``; else None.

    One wrong pose makes every track misfit in its view: the start's noise estimate grows
    (one orientation) or its session keeps few tracks (sessions), the refinement then
    keeps only the few tracks that fit, or none, and the score test has too few left to
    name the view. The candidates are the view without which the start's noise estimate
    is lowest and the one without which it keeps the most tracks, each when it stands out
    of the starts without the other views (:func:`_standing_out` on the logarithms: a
    misfit of the model is alike without every view); the fit without the candidate must not be broken
    itself, and the test of its pose decides."""
    if motion.n_views < LOO_MIN_VIEWS or (fitted is not None and not _broken(start, fitted, uv)):
        return None
    report(progress, "the fit broke: the start without each view", views=motion.n_views)
    fits = np.full((motion.n_views, 2), np.nan)  # (noise estimate, tracks kept) without each view
    for v in range(motion.n_views):
        try:
            ransac = start_of(without_views(uv, [v])).ransac
        except DegenerateError:
            continue
        if ransac is not None:
            fits[v] = ransac.sigma_px, ransac.n_inliers
    if not np.isfinite(fits[:, 0]).any():
        return None
    sigma, kept = fits.T
    with np.errstate(divide="ignore"):  # on a log scale: a start's noise and tracks vary by factors
        candidates = _standing_out(-np.log(sigma)) + _standing_out(np.log(kept))
    for v in dict.fromkeys(candidates):
        try:
            start, again = run(without_views(uv, [v]))
            if _broken(start, again, without_views(uv, [v])):
                continue  # not the view that broke it
            found = pose_contradiction(without_views(uv, view_indices(start.off_views)), motion.T,
                                       replace(again.cal, inliers=again.inliers), v)
        except DegenerateError:
            continue
        if found is not None and found.p_value < POSE_ALPHA:
            return [found], start, again
    return None


def _standing_out(x: np.ndarray) -> list:
    """``[argmax x]`` when the largest of ``x`` stands out of the others (more than
    ``OUTLYING_Z`` robust standard deviations, MAD, above their median), else ``[]``."""
    v = int(np.nanargmax(x))
    rest = np.delete(x, v)
    rest = rest[np.isfinite(rest)]
    if rest.size < 2:
        return []
    centre = np.median(rest)
    scale = mad_sigma(rest - centre, 0, floor=1e-12 * abs(centre))
    return [v] if x[v] - centre > OUTLYING_Z * scale else []


def _broken(start, fitted, uv: np.ndarray) -> bool:
    """The fit kept fewer than half of the tracks, or its pixel noise is over twice the
    robust start's (which without the lens and with the robot's error in it is larger)."""
    noisier = start.ransac is not None and fitted.cal.sigma_px > 2 * start.ransac.sigma_px
    return noisier or _share(fitted.inliers, uv) < MIN_INLIER_FRACTION


def _share(inliers, uv: np.ndarray) -> float:
    """The share of ``inliers`` among the tracks of ``uv`` seen in two views or more (1
    without a robust stage)."""
    tracked = np.isfinite(uv[..., 0]).sum(axis=0) >= 2
    return 1.0 if inliers is None else float(np.sum(inliers & tracked) / max(tracked.sum(), 1))
