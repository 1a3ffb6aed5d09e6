"""The camera of every view, in one place: orientation, centre, session, reference view.

Dense matching needs each view's camera pose in the frame of the calibration's points.
It is made here and nowhere else, by :func:`view_cameras`, with the one model of every
robot motion (``pipeline.motion``: eye-to-hand poses inverted once) and the
calibration's own :meth:`~transcalib.types.Calibration.camera_poses`::

    R_cam,i = R R_i^T,    C_i = T_i + R_i t          (R = R_X^T, t = the hand-eye t_X)

A view the calibration saw (same flange orientation, position within six of its
standard deviations when the robot noise was modelled) takes the calibration's own pose
(its refined position). A calibration without orientations holds for the one flange
orientation it was made at, which it does not record: views whose orientations differ
from each other by more than :data:`ORIENTATION_TOL_DEG` are refused. The views of the
reference view's **session** (one flange orientation, grouped as ``calibrate`` groups
them: within ``session_tolerance_deg``, or the poses' ``session`` column) are its
sources; each keeps its own orientation (a small rotation within the session enters
the sweep as a homography).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DegenerateError, InputError
from ..geometry.rotation import rotation_angle_deg
from ..handeye.sessions import SESSION_TOLERANCE_DEG
from ..pipeline.motion import motion_of
from ..types import Poses

__all__ = ["ViewCameras", "view_cameras", "central_view", "cloud_frame", "ORIENTATION_TOL_DEG"]

#: Largest angle (degrees) between the views' orientations with a calibration made at one
#: orientation (which it does not record).
ORIENTATION_TOL_DEG = 0.1
#: A view is one the calibration saw when its orientation is within this angle (degrees)
#: and its position within ``KNOWN_SIGMAS`` standard deviations of the refined one.
KNOWN_ANGLE_DEG, KNOWN_SIGMAS = 1e-3, 6.0


@dataclass(frozen=True, eq=False)
class ViewCameras:
    """Pose of every view's camera in the calibration's frame.

    Attributes
    ----------
    R : (n_views, 3, 3) float
        World -> camera rotation of each view.
    C : (n_views, 3) float
        Camera centres (robot units).
    session : (n_views,) int
        Session (one flange orientation) of each view, numbered in order of appearance.
    known : (n_views,) int
        The calibration's view each view is (its pose taken from the calibration), -1 for
        views it did not see.
    """

    R: np.ndarray
    C: np.ndarray
    session: np.ndarray
    known: np.ndarray

    @property
    def n_views(self) -> int:
        return len(self.C)

    def session_of(self, view: int) -> np.ndarray:
        """Indices of the views in ``view``'s session (itself included), ascending."""
        return np.flatnonzero(self.session == self.session[view])

    def sources(self, ref: int, max_turn_deg: float | None = None) -> np.ndarray:
        """The views matched with ``ref`` (ascending, ``ref`` left out): its session's,
        or with ``max_turn_deg`` every view whose camera is turned by at most that angle
        against ``ref``'s."""
        if max_turn_deg is None:
            views = self.session_of(ref)
        else:
            views = np.flatnonzero(rotation_angle_deg(self.R @ self.R[ref].T) <= max_turn_deg)
        return views[views != ref]

    def relative(self, ref: int, views) -> tuple[np.ndarray, np.ndarray]:
        """Pose of ``views`` relative to ``ref``: ``R_rel (k, 3, 3) = R_j R_ref^T`` and
        ``t (k, 3) = R_j (C_j - C_ref)``, so that a point ``x`` of ``ref``'s camera frame
        is ``R_rel x - t`` in view ``j``'s."""
        views = np.asarray(views, int)
        R_rel = self.R[views] @ self.R[ref].T
        return R_rel, np.einsum("kab,kb->ka", self.R[views], self.C[views] - self.C[ref])


def _as_poses(poses) -> Poses:
    if isinstance(poses, Poses):
        return poses
    try:
        return Poses.of(np.asarray(poses, dtype=float))
    except (TypeError, ValueError):
        raise InputError("poses must be a Poses (transcalib.io.read_poses) or robot positions (n_views, 3)") from None


def _setup(calibration) -> tuple[str, float]:
    """``(setup, session tolerance in degrees)`` the calibration was made with."""
    he, opts = getattr(calibration, "hand_eye", None), getattr(calibration, "options", None)
    setup = he.setup if he is not None else getattr(opts, "setup", "eye-in-hand")
    return setup, float(getattr(opts, "session_tolerance_deg", SESSION_TOLERANCE_DEG))


def _known_views(calibration, T: np.ndarray, R) -> np.ndarray:
    """For each view, the calibration's view at the same flange pose (-1: none); only
    with refined robot positions (else the poses are the calibration's already)."""
    T_std = getattr(calibration, "T_std", None)
    if T_std is None:
        return np.full(len(T), -1)
    cal_T, cal_R = np.asarray(calibration.T), calibration.flange_rotations
    scale = max(np.abs(cal_T).max(), 1.0)
    close = np.all(np.abs(T[:, None] - cal_T[None]) <= KNOWN_SIGMAS * np.asarray(T_std)[None] + 1e-9 * scale,
                   axis=-1)
    if cal_R is not None and R is not None:
        close &= rotation_angle_deg(np.transpose(R, (0, 2, 1))[:, None] @ np.asarray(cal_R)[None]) <= KNOWN_ANGLE_DEG
    return np.where(close.any(axis=1), np.argmax(close, axis=1), -1)


def _one_orientation(R, ids) -> None:
    """Refuse orientations that differ from each other (a calibration of one orientation)."""
    if R is None:
        return
    angle = rotation_angle_deg(R[0].T @ R)
    off = np.flatnonzero(angle > ORIENTATION_TOL_DEG)
    if off.size:
        detail = ", ".join(f"view {ids[i]} at {angle[i]:.3g} deg" for i in off[:8])
        raise InputError(f"the poses hold several flange orientations but the calibration has one (its R holds for "
                         f"the orientation it was made at): {detail} from view {ids[0]}; give only views at the "
                         f"calibration's orientation (within {ORIENTATION_TOL_DEG:g} deg), or calibrate with "
                         "orientations in the poses")


def view_cameras(calibration, poses) -> ViewCameras:
    """The camera of every view (module docstring).

    Parameters
    ----------
    calibration : Calibration or Camera
        A bare ``Camera`` is a calibration of one orientation (``R`` robot -> camera).
    poses : Poses or (n_views, 3) float
        Flange poses of the views (:func:`transcalib.io.read_poses`), in the
        calibration's unit, or the positions alone.

    Raises
    ------
    InputError
        Orientations that a one-orientation calibration cannot place; a calibration with
        orientations and poses without; bad shapes.
    """
    poses = _as_poses(poses)
    setup, tolerance = _setup(calibration)
    with_orientations = getattr(calibration, "flange_rotations", None) is not None
    if with_orientations and poses.R is None:
        raise InputError("the calibration was made with flange orientations: the poses need the orientation of "
                         "every view (qx,qy,qz,qw, rx,ry,rz or a,b,c columns)")
    if not with_orientations:  # the calibration's one orientation, as calibrate saw it: translations only
        _one_orientation(poses.R, [str(v) for v in poses.views])
        poses = Poses.of(poses.T, views=poses.views)
    motion = motion_of(poses, setup, tolerance)
    T, R = motion.T, motion.R
    known = _known_views(calibration, T, R)
    if np.any(known >= 0):
        T = np.where((known >= 0)[:, None], np.asarray(calibration.T)[known], T)
        if R is not None:
            R = np.where((known >= 0)[:, None, None], np.asarray(calibration.flange_rotations)[known], R)
    if hasattr(calibration, "camera_poses"):
        R_cam, C = calibration.camera_poses(T, R)
    else:  # a bare Camera: one orientation
        R_cam, C = np.broadcast_to(calibration.R, (len(T), 3, 3)).copy(), np.array(T, dtype=float)
    return ViewCameras(R=R_cam, C=C, session=np.asarray(motion.session_of_view, int), known=known)


def cloud_frame(calibration) -> str:
    """The frame of the calibration's points (and of the dense cloud), in words."""
    if getattr(calibration, "flange_rotations", None) is None:
        return "robot axes, relative to the camera centre at T = 0 (the calibration's points)"
    he = calibration.hand_eye
    if he is not None and he.setup == "eye-to-hand":
        frame = "the flange frame (eye-to-hand: the scene moves with the flange)"
    else:
        frame = "the robot base frame"
    k = 0 if he is None else np.asarray(he.undetermined).shape[1]
    if k:
        d = ", ".join("(" + ", ".join(f"{x:+.3f}" for x in col) + ")" for col in np.asarray(he.undetermined).T)
        frame += (f", up to a shift along {d} (the hand-eye offset's undetermined direction{'s' * (k > 1)}, "
                  "zero there as in the calibration)")
    return frame


def central_view(cams: ViewCameras) -> int:
    """The default reference view: in the largest session (the first of equal ones),
    the view with the least summed distance to the session's others (its medoid)."""
    counts = np.bincount(cams.session)
    members = np.flatnonzero(cams.session == int(np.argmax(counts)))
    C = cams.C[members]
    return int(members[np.argmin(np.linalg.norm(C[:, None] - C[None], axis=-1).sum(axis=1))])


def check_baselines(cams: ViewCameras, ref: int, sources: np.ndarray, view_ids) -> None:
    """Raise :class:`InputError` when the reference view is alone in its session and
    :class:`DegenerateError` when no other view of the session moved."""
    if len(sources) == 0:
        raise InputError(f"reference view {view_ids[ref]} has no other view at its orientation to match; give at "
                         "least two views of one session, or allow views turned against it (max_turn_deg, "
                         "--max-turn-deg DEG)")
    base = np.linalg.norm(cams.C[sources] - cams.C[ref], axis=1)
    if np.all(base <= 1e-9 * max(np.abs(cams.C).max(), 1.0)):
        raise DegenerateError(f"the views of reference view {view_ids[ref]}'s session are all at its position: "
                              "no baseline, no depth; move the robot between the views")
