"""Camera model: pinhole projection with OpenCV lens distortion, and ``A -> (K, R)``.

Projection of scene point ``X_j`` in view ``i`` (paper eq. 2, OpenCV distortion)::

    x_cam = R (X_j - T_i)                      camera frame, z forward
    (x, y) = x_cam[:2] / x_cam[2]              normalised image coordinates
    (x', y') = distort(x, y; k1, k2, p1, p2, k3)
    u = fx x' + s y' + cx,   v = fy y' + cy

Distortion coefficients follow OpenCV's order and meaning; padded to five values
(``Calibration.dist_opencv``) they go to ``cv2.undistort`` / ``cv2.projectPoints`` as they
are (OpenCV has no skew: keep ``s = 0`` when mixing the two).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ..types import MirroredError

__all__ = [
    "DIST_MODELS",
    "dist_size",
    "distort",
    "undistort",
    "project",
    "pixels_to_rays",
    "K_from_params",
    "rq_decompose",
    "rotation_angle_deg",
]

#: Number of distortion coefficients of each model (OpenCV order k1, k2, p1, p2, k3).
DIST_MODELS = {"none": 0, "radial2": 2, "opencv5": 5}


def dist_size(model: str) -> int:
    """Number of coefficients of distortion ``model`` (raises ``ValueError`` if unknown)."""
    try:
        return DIST_MODELS[model]
    except KeyError:
        raise ValueError(f"unknown distortion model {model!r}; expected one of {sorted(DIST_MODELS)}") from None


def _dist5(dist) -> np.ndarray:
    """Pad coefficients ``(k,)`` of any supported model to OpenCV's five."""
    d = np.zeros(5)
    dist = np.asarray(dist, dtype=float).ravel()
    if dist.size == 2:  # radial2: k1, k2
        d[:2] = dist
    elif dist.size in (0, 4, 5):
        d[: dist.size] = dist
    else:
        raise ValueError(f"distortion must have 0, 2, 4 or 5 coefficients, got {dist.size}")
    return d


def distort(xy: np.ndarray, dist) -> np.ndarray:
    """Apply OpenCV lens distortion to normalised image coordinates.

    Parameters
    ----------
    xy : (..., 2) float
        Undistorted normalised coordinates ``(x/z, y/z)``.
    dist : (k,) float
        ``k1, k2[, p1, p2[, k3]]``.

    Returns
    -------
    (..., 2) float
        ``x' = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)``,
        ``y' = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y``.
    """
    k1, k2, p1, p2, k3 = _dist5(dist)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def undistort(xy_d: np.ndarray, dist, iterations: int = 20) -> np.ndarray:
    """Invert :func:`distort` by fixed-point iteration (as ``cv2.undistortPoints``).

    Parameters
    ----------
    xy_d : (..., 2) float
        Distorted normalised coordinates.
    dist : (k,) float
        Distortion coefficients.

    Returns
    -------
    (..., 2) float
        Undistorted normalised coordinates.
    """
    d = _dist5(dist)
    xy_d = np.asarray(xy_d, dtype=float)
    if not d.any():
        return xy_d.copy()
    k1, k2, p1, p2, k3 = d
    xy = xy_d.copy()
    for _ in range(iterations):
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        xy = np.stack([(xy_d[..., 0] - dx) / radial, (xy_d[..., 1] - dy) / radial], axis=-1)
    return xy


def project(K: np.ndarray, R: np.ndarray, X: np.ndarray, T: np.ndarray, dist=()) -> np.ndarray:
    """Project scene points into every view.

    Parameters
    ----------
    K, R : (3, 3) float
        Intrinsics and rotation world -> camera.
    X : (n_points, 3) float
        Scene points, world frame.
    T : (n_views, 3) float
        Camera translations (camera centre of view i is ``T_i``).
    dist : (k,) float, optional
        OpenCV distortion coefficients.

    Returns
    -------
    uv : (n_views, n_points, 2) float
        Pixel coordinates, ``lam [u, v, 1] = K distort(R (X - T_i))`` (paper eq. 2).
    """
    Xc = np.einsum("ab,vnb->vna", R, X[None, :, :] - T[:, None, :])
    xy = Xc[..., :2] / Xc[..., 2:3]
    if np.asarray(dist).size:
        xy = distort(xy, dist)
    u = K[0, 0] * xy[..., 0] + K[0, 1] * xy[..., 1] + K[0, 2]
    v = K[1, 1] * xy[..., 1] + K[1, 2]
    return np.stack([u, v], axis=-1)


def pixels_to_rays(K: np.ndarray, uv: np.ndarray, dist=()) -> np.ndarray:
    """Homogeneous normalised coordinates ``[x, y, 1]`` of pixels (undistorted).

    Parameters
    ----------
    K : (3, 3) float
    uv : (..., 2) float
    dist : (k,) float, optional

    Returns
    -------
    (..., 3) float
        ``K^-1 [u, v, 1]`` corrected for distortion: the camera-frame ray direction.
    """
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    y = (uv[..., 1] - cy) / fy
    x = (uv[..., 0] - cx - s * y) / fx
    xy = np.stack([x, y], axis=-1)
    if np.asarray(dist).size:
        xy = undistort(xy, dist)
    return np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)


def K_from_params(fx: float, fy: float, cx: float, cy: float, skew: float = 0.0) -> np.ndarray:
    """``[[fx, skew, cx], [0, fy, cy], [0, 0, 1]]``."""
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def rq_decompose(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split ``A = K R`` into upper-triangular ``K`` (positive diagonal, ``K[2,2] = 1``)
    and a rotation ``R`` (det +1).

    Parameters
    ----------
    A : (3, 3) float
        The paper's affine matrix, any non-zero scale with ``det A > 0``.

    Returns
    -------
    K, R : (3, 3) float

    Raises
    ------
    MirroredError
        If ``det A < 0``: no rotation can explain the data, the frame is mirrored.
    """
    A = np.asarray(A, dtype=float)
    if np.linalg.det(A) <= 0:
        raise MirroredError(
            "the data imply a mirrored camera (det(K R) < 0): the robot frame looks "
            "left-handed relative to the images. Check that the robot axes x, y, z form a "
            "right-handed frame, that no two pose columns are swapped, and that the "
            "images are not flipped; then run again."
        )
    K, R = scipy.linalg.rq(A)
    signs = np.sign(np.diag(K))
    signs[signs == 0] = 1.0
    K = K * signs[None, :]  # K D, with D = diag(signs) = D^-1
    R = signs[:, None] * R  # D R
    R_det = np.linalg.det(R)
    if R_det < 0:  # only if det A < 0, excluded above; keep the invariant explicit
        raise MirroredError("RQ decomposition produced det R = -1")
    return K / K[2, 2], R


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle in degrees of rotation matrix ``R`` (3, 3), accurate for tiny angles too:
    ``atan2(sin, cos)`` with ``sin`` from the skew part and ``cos = (tr R - 1) / 2``."""
    sin = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    cos = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arctan2(sin, cos)))
