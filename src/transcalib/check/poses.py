"""Check of the robot orientations reported with the poses: they must be constant."""

from __future__ import annotations

import numpy as np

from ..errors import Diagnostic, InputError
from ..geometry.rotation import ROTATION_TOL, rotation_angle_deg, rotation_defect


def check_pose_orientations(rotations, tol_deg: float = 0.1) -> list:
    """Warn when the robot's reported orientation is not constant.

    The angle of view ``i`` is that of ``R_0^T R_i`` (:func:`rotation_angle_deg`).

    Parameters
    ----------
    rotations : (n_views, 3, 3) float
        Flange -> base rotations ``R_i`` per view, as read
        (:attr:`transcalib.io.Poses.R`).
    tol_deg : float
        Largest acceptable rotation angle from view 0's orientation (degrees).

    Returns
    -------
    list of Diagnostic
        ``pose_orientation`` listing each view beyond ``tol_deg`` with its angle.

    Raises
    ------
    InputError
        Wrong shape, or matrices that are not rotations.
    """
    try:
        R = np.asarray(rotations, dtype=float)
    except (TypeError, ValueError):
        raise InputError("rotations must be numbers, one 3x3 rotation matrix per view") from None
    if R.ndim != 3 or R.shape[1:] != (3, 3):
        raise InputError(f"rotations must have shape (n_views, 3, 3) (flange -> base); got shape {R.shape}")
    bad = np.flatnonzero(rotation_defect(R) > ROTATION_TOL)
    if bad.size:
        raise InputError(f"rotations of views {bad[:10].tolist()} are not rotation matrices (finite, orthonormal, "
                         "det +1); give the orientation of every pose (or none at all), e.g. as read by "
                         "transcalib.io.read_poses")
    angle = rotation_angle_deg(np.swapaxes(R[:1], -1, -2) @ R)
    bad = np.flatnonzero(angle > tol_deg)
    if not len(bad):
        return []
    detail = ", ".join(f"view {i}: {angle[i]:.3g} deg" for i in bad[:20])
    return [Diagnostic(
        "pose_orientation",
        f"the robot's orientation is not constant: {len(bad)} pose(s) differ from view 0's by more than "
        f"{tol_deg:g} deg ({detail}). The method assumes pure translations; command the moves with a fixed "
        "tool orientation, or leave those views out.")]
