"""Views left out because their images contradict their recorded poses.

**A single view's orientation.**
The start judges each single view's orientation with the start's camera, which has no
lens distortion: with a distorted lens the image pose of a view turned far from the
others is a little off, and a view can look off that is not. After the refinement (the
lens, the points and the hand-eye pose of every other view) the views left out are judged
again with the same rule (:func:`transcalib.handeye.join.judge_orientations`) on
undistorted pixels; the views that now agree come back into the fit, the others stay out,
named with their angle (``pose_orientation_off``).

**Any view's pose** (:func:`transcalib.check.poses.find_pose_outliers`). After the
refinement the view whose image contradicts its recorded pose most significantly is left
out and the calibration refitted without it, until the test names none or
:func:`max_left_out` views are out (``pose_left_out``, with the size of each error). A
wrong pose biases every parameter and, with the robot error in the model, inflates its
scale and so every reported std.
"""

from __future__ import annotations

import numpy as np

from ..check.poses import describe_pose_outlier, repeated_pairs, view_name
from ..errors import Diagnostic
from ..handeye.join import judge_orientations, view_pose
from .motion import Motion

__all__ = ["rejudge_views", "orientation_off", "max_left_out", "pose_left_out", "MAX_LEFT_OUT_FRACTION"]

#: At most this fraction of the views (at least one) is left out for contradicting its pose.
MAX_LEFT_OUT_FRACTION = 0.25


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
