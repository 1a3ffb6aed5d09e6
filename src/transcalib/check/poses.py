"""Check of the robot orientations reported with the poses: they must be constant."""

from __future__ import annotations

import numpy as np

from ..errors import Diagnostic, InputError

def check_pose_orientations(quaternions, tol_deg: float = 0.1) -> list:
    """Warn when the robot's reported orientation is not constant.

    Parameters
    ----------
    quaternions : (n_views, 4) float
        Tool orientation per view as ``qx, qy, qz, qw`` (any norm; ``q`` and ``-q`` are
        the same orientation).
    tol_deg : float
        Largest acceptable rotation angle from view 0's orientation (degrees).

    Returns
    -------
    list of Diagnostic
        ``pose_orientation`` listing each view beyond ``tol_deg`` with its angle.

    Raises
    ------
    InputError
        Wrong shape, non-finite or zero quaternions.
    """
    try:
        q = np.asarray(quaternions, dtype=float)
    except (TypeError, ValueError):
        raise InputError("quaternions must be numbers, one row qx, qy, qz, qw per view") from None
    if q.ndim != 2 or q.shape[1] != 4:
        raise InputError(f"quaternions must have shape (n_views, 4) as qx, qy, qz, qw; got shape {q.shape}")
    if not np.isfinite(q).all():
        raise InputError("quaternions contain NaN or inf; give the orientation of every pose (or none at all)")
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm < 1e-12):
        raise InputError(f"quaternions of views {np.flatnonzero(norm < 1e-12).tolist()} are zero; "
                         "each must be a rotation qx, qy, qz, qw")
    q = q / norm[:, None]
    c = np.clip(np.abs(q @ q[0]), 0.0, 1.0)
    s = np.linalg.norm(np.cross(q[:, :3], q[0, :3]) + q[0, 3] * q[:, :3] - q[:, 3:4] * q[0, :3], axis=1)
    angle = np.degrees(2.0 * np.arctan2(s, c))  # accurate for small angles too
    bad = np.flatnonzero(angle > tol_deg)
    if not len(bad):
        return []
    detail = ", ".join(f"view {i}: {angle[i]:.3g} deg" for i in bad[:20])
    return [Diagnostic(
        "pose_orientation",
        f"the robot's orientation is not constant: {len(bad)} pose(s) differ from view 0's by more than "
        f"{tol_deg:g} deg ({detail}). The method assumes pure translations; command the moves with a fixed "
        "tool orientation, or leave those views out.")]
