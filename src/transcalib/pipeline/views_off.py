"""Single views whose recorded orientation their images contradict: judged at the start,
judged again after the refinement.

The start judges each single view's orientation with the start's camera, which has no
lens distortion: with a distorted lens the image pose of a view turned far from the
others is a little off, and a view can look off that is not. After the refinement (the
lens, the points and the hand-eye pose of every other view) the views left out are judged
again with the same rule (:func:`transcalib.handeye.join.judge_orientations`) on
undistorted pixels; the views that now agree come back into the fit, the others stay out,
named with their angle (``pose_orientation_off``).
"""

from __future__ import annotations

import numpy as np

from ..errors import Diagnostic
from ..handeye.join import judge_orientations, view_pose
from .motion import Motion

__all__ = ["rejudge_views", "left_out_mask", "orientation_off"]


def left_out_mask(off_views, n_views: int) -> np.ndarray:
    """``(n_views,)`` bool: the views of ``off_views`` ((view, degrees), ...)."""
    mask = np.zeros(n_views, bool)
    mask[[v for v, _ in off_views]] = True
    return mask


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
