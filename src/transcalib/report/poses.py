"""Where each view's camera (and, where known, the robot's other frame) was: what the 3-D view draws.

One function, :func:`view_poses`, turns a calibration into a camera pose per view
(rotation world -> camera and centre, in the frame of the calibration's points, from
:meth:`~transcalib.types.Calibration.camera_poses`) and, where the hand-eye pose is
known, the robot frame that moves relative to the points in each view. The viewer
assumes nothing else about the motion.

- **No orientations** (the paper's case): every view has the rotation ``cal.R`` and its
  centre at ``cal.T[i]``; the points are relative to the camera centre at robot
  position ``T = 0``, in robot axes. No flange is drawn: the camera-to-flange offset is
  not observable from translations.
- **Eye-in-hand with orientations**: camera ``i`` has the rotation ``R_X^T R_i^T`` and
  its centre at ``T_i + R_i t_X``; the points are in the robot base frame, and the
  flange of view ``i`` is the frame ``(R_i, T_i)``.
- **Eye-to-hand**: the points are in the flange frame (the object the flange carries);
  ``cal.T`` and ``cal.flange_rotations`` are the robot base's origin and rotation
  (base -> flange) in that frame, one per view, so the drawn frame of each view is the
  robot base as the object sees it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ViewPoses", "view_poses"]


@dataclass(frozen=True, eq=False)
class ViewPoses:
    """The camera of every view and, where known, the robot's moving frame, in the points' frame.

    Attributes
    ----------
    R_cam_world : (n_views, 3, 3) float
        Rotation world -> camera of each view (rows: the camera's x, y, z axes in the world).
    centres : (n_views, 3) float
        Camera centres in the world (robot units).
    frame_R : (n_views, 3, 3) float or None
        Rotation of each view's robot frame (columns: its axes in the world), where known.
    frame_T : (n_views, 3) float or None
        Its origin in the world.
    origin : str
        What the world origin and axes are, for the page.
    frames : str
        What ``frame_R``, ``frame_T`` are, for the page (empty when None).
    """

    R_cam_world: np.ndarray
    centres: np.ndarray
    frame_R: np.ndarray | None
    frame_T: np.ndarray | None
    origin: str
    frames: str = ""

    @property
    def n_views(self) -> int:
        return len(self.centres)


def view_poses(cal) -> ViewPoses:
    """The camera pose of every view of ``cal`` and, with a hand-eye pose, the flange
    (eye-in-hand) or the robot base (eye-to-hand) of every view.

    Parameters
    ----------
    cal : Calibration

    Returns
    -------
    ViewPoses
    """
    R_cam, C = cal.camera_poses()
    he = getattr(cal, "hand_eye", None)
    if cal.flange_rotations is None or he is None:
        return ViewPoses(R_cam, C, None, None, origin="the robot axes at the camera centre of robot position T = 0")
    free = he.undetermined.shape[1]
    note = "" if not free else (f" (the camera's position t of the hand-eye pose is undetermined along {free} "
                                f"direction{'s' if free > 1 else ''}: drawn with no component there)")
    R_f, T_f = np.asarray(cal.flange_rotations, float), np.asarray(cal.T, float)
    if he.setup == "eye-to-hand":
        return ViewPoses(R_cam, C, R_f, T_f, origin="the flange axes at its origin (eye-to-hand: the points are "
                         "on the object the flange carries)", frames="the robot base of every view, as the "
                         f"flange sees it{note}")
    return ViewPoses(R_cam, C, R_f, T_f, origin="the robot base axes at its origin",
                     frames=f"the flange of every view{note}")
