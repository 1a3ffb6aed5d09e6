"""Where each view's camera (and, where known, the flange) was: the poses the 3-D view draws.

One function, :func:`view_poses`, turns a calibration into a camera pose per view
(rotation world -> camera and centre, in the frame of the calibration's points). The
viewer assumes nothing else about the motion, so a model that gives each view its own
orientation extends this function only.

Today's two models:

- **one orientation** (the paper's; :func:`transcalib.calibrate`): every view has the
  rotation ``cal.R`` and its centre at ``cal.T[i]``; the points are relative to the
  camera centre at robot position ``T = 0``. The flange is not drawn: the
  camera-to-flange offset is not observable from translations.
- **several orientations** (hand-eye, :func:`transcalib.calibrate_sessions`, whose
  ``camera.R`` is ``R_X^T`` and ``t_flange_camera`` is ``t_X``), when the flange
  rotations ``R_i`` are given: camera ``i`` has the rotation ``(R_i R_X)^T = R_X^T R_i^T``
  and its centre at ``T_i + R_i t_X``; the points and the flange poses ``(R_i, T_i)`` are
  in the robot base frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry.rotation import ROTATION_TOL, rotation_defect

__all__ = ["ViewPoses", "view_poses"]


@dataclass(frozen=True, eq=False)
class ViewPoses:
    """The camera of every view and, where known, the flange, in the points' frame.

    Attributes
    ----------
    R_cam_world : (n_views, 3, 3) float
        Rotation world -> camera of each view (rows: the camera's x, y, z axes in the world).
    centres : (n_views, 3) float
        Camera centres in the world (robot units).
    flange_R : (n_views, 3, 3) float or None
        Flange -> base rotations ``R_i`` where the flange is known, else None.
    flange_T : (n_views, 3) float or None
        Flange positions in the same frame as the points, else None.
    origin : str
        What the world origin is, for the page (``"the camera centre at robot position
        T = 0"`` or ``"the robot base"``).
    """

    R_cam_world: np.ndarray
    centres: np.ndarray
    flange_R: np.ndarray | None
    flange_T: np.ndarray | None
    origin: str

    @property
    def n_views(self) -> int:
        return len(self.centres)


def _flange_rotations(R, n_views: int) -> np.ndarray:
    """``R`` as ``(n_views, 3, 3)`` rotations, or :class:`InputError`."""
    try:
        R = np.asarray(R, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"flange_rotations must be an array of numbers ({exc})") from None
    if R.shape != (n_views, 3, 3):
        raise InputError(f"flange_rotations must have shape (n_views, 3, 3) = ({n_views}, 3, 3), got {R.shape}")
    bad = np.flatnonzero(~(rotation_defect(R) <= ROTATION_TOL))
    if bad.size:
        raise InputError(f"flange_rotations of views {bad[:10].tolist()} are not rotation matrices (orthonormal, "
                         "det +1); read the controller's orientations with transcalib.io.read_poses")
    return R


def view_poses(cal, flange_rotations=None) -> ViewPoses:
    """The camera pose of every view of ``cal`` (and the flange's where known).

    Parameters
    ----------
    cal : Calibration
    flange_rotations : (n_views, 3, 3) float, optional
        Flange -> base rotations ``R_i`` (:attr:`transcalib.io.Poses.R`). Used with a
        hand-eye calibration (``cal.t_flange_camera`` set): camera ``i`` is then
        ``R_cam_world = cal.R @ R_i^T`` at ``T_i + R_i t_X``. With one orientation they
        change nothing: the flange's position relative to the points is not observable.

    Returns
    -------
    ViewPoses

    Raises
    ------
    InputError
        ``flange_rotations`` of the wrong shape, or not rotations.
    """
    T = np.asarray(cal.T, float)
    n = len(T)
    if flange_rotations is not None:
        Rf = _flange_rotations(flange_rotations, n)
        if cal.t_flange_camera is not None:
            t = np.asarray(cal.t_flange_camera, float)
            return ViewPoses(R_cam_world=cal.R @ Rf.transpose(0, 2, 1), centres=T + Rf @ t, flange_R=Rf,
                             flange_T=T.copy(), origin="the robot base")
    return ViewPoses(R_cam_world=np.broadcast_to(cal.R, (n, 3, 3)).copy(), centres=T.copy(), flange_R=None,
                     flange_T=None, origin="the camera centre at robot position T = 0")
