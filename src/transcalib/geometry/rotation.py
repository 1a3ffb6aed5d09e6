"""Rotations: the exponential map ``exp([w]x)`` and its inverse, angles, ``A = K R``.

A rotation vector ``w`` (radians) maps to ``R = exp([w]x)`` by Rodrigues' formula::

    R = I + sin(t)/t [w]x + (1 - cos(t))/t^2 [w]x^2,      t = |w|

Every local rotation update in the project (``R <- exp([dw]x) R``) uses these.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from ..errors import MirroredError

__all__ = ["rotvec_to_matrix", "matrix_to_rotvec", "skew", "rotation_angle_deg", "rq_decompose"]


def skew(w: np.ndarray) -> np.ndarray:
    """``[w]x`` (3, 3) of a vector ``w`` (3,): ``[w]x v = w x v``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """``exp([w]x)`` (3, 3) for a rotation vector ``w`` (3,) in radians (Rodrigues)."""
    w = np.asarray(w, dtype=float)
    theta = float(np.linalg.norm(w))
    Wx = skew(w)
    if theta < 1e-8:  # second-order series: exact to rounding there
        return np.eye(3) + Wx + 0.5 * Wx @ Wx
    return np.eye(3) + np.sin(theta) / theta * Wx + (1.0 - np.cos(theta)) / theta**2 * Wx @ Wx


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotvec_to_matrix`: the rotation vector (3,) of ``R`` (angle < pi)."""
    sin = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = float(np.linalg.norm(sin))
    theta = float(np.arctan2(s, (np.trace(R) - 1.0) / 2.0))
    return sin if s < 1e-12 else sin * (theta / s)


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle in degrees of rotation matrix ``R`` (3, 3), accurate for tiny angles too:
    ``atan2(sin, cos)`` with ``sin`` from the skew part and ``cos = (tr R - 1) / 2``."""
    sin = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    cos = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arctan2(sin, cos)))


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
            "the data imply a mirrored camera (det(K R) < 0). Either the robot frame is "
            "left-handed relative to the images (check that the robot axes x, y, z form a "
            "right-handed frame, that no two pose columns are swapped, and that the images "
            "are not flipped), or a few bad tracks dominate the linear estimate: mismatches, "
            "or tracks that barely move (far background, static overlays) - run the robust "
            "estimator (the default from 8 points) or remove such tracks; then run again."
        )
    K, R = scipy.linalg.rq(A)
    signs = np.sign(np.diag(K))
    signs[signs == 0] = 1.0
    K = K * signs[None, :]  # K D, with D = diag(signs) = D^-1
    R = signs[:, None] * R  # D R
    return K / K[2, 2], R
