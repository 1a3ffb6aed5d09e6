"""Small helpers shared by the checks: formatting of vectors and index lists."""

from __future__ import annotations

import numpy as np


def fmt_vec(v) -> str:
    return "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"


def fmt_list(idx, limit: int = 10) -> str:
    idx = [int(i) for i in idx]
    s = ", ".join(map(str, idx[:limit]))
    return s + (f", ... ({len(idx)} in all)" if len(idx) > limit else "")


def depths(R, X, T):
    """Camera z of every point in every view (n_views, n_points): ``R`` one rotation world
    -> camera (3, 3) or one per view (n_views, 3, 3), ``T`` the camera centres."""
    R = np.asarray(R)
    if R.ndim == 2:
        return (X @ R[2])[None, :] - (T @ R[2])[:, None]
    return R[:, 2] @ X.T - np.einsum("va,va->v", R[:, 2], T)[:, None]


def camera_poses(calibration, T):
    """Rotations world -> camera (per view, or one for every view) and centres of a
    Calibration (:meth:`~transcalib.types.Calibration.camera_poses`) or a LinearEstimate
    (one rotation, centres ``T``)."""
    robot = getattr(calibration, "robot_error", None)
    if hasattr(calibration, "camera_poses") and (getattr(calibration, "flange_rotations", None) is not None
                                                 or (robot is not None and robot.active)):
        return calibration.camera_poses()
    return np.asarray(calibration.R, float), np.asarray(T, float)


def squared_norms(res: np.ndarray) -> np.ndarray:
    """``|r|^2`` of each residual ``res (..., 2)`` (NaN where the residual is), in one pass."""
    return np.einsum("...k,...k->...", res, res)


def inlier_uv(uv, calibration) -> np.ndarray:
    """``uv (n_views, n_points, 2)`` as float with the tracks outside
    ``calibration.inliers`` (when it has them) set to NaN: the data a refit uses."""
    uv = np.asarray(uv, float)
    if calibration.inliers is None:
        return uv
    return np.where(np.asarray(calibration.inliers, bool)[None, :, None], uv, np.nan)
