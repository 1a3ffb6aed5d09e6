"""Rotations: the exponential map ``exp([w]x)`` and its inverse, quaternions, angles,
``A = K R``.

A rotation vector ``w`` (radians) maps to ``R = exp([w]x)`` by Rodrigues' formula::

    R = I + sin(t)/t [w]x + (1 - cos(t))/t^2 [w]x^2,      t = |w|

Every local rotation update in the project (``R <- exp([dw]x) R``) uses these.
"""

from __future__ import annotations

import numpy as np

from ..errors import MirroredError

__all__ = ["rotvec_to_matrix", "matrix_to_rotvec", "matrix_to_quaternion", "skew", "rotation_angle_deg",
           "rq_decompose"]


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


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """The unit quaternion ``(qx, qy, qz, qw)`` of a rotation matrix ``R`` (3, 3), with
    ``qw >= 0``.

    Of ``4 qw^2 = 1 + tr R`` and ``4 qx^2 = 1 + R00 - R11 - R22`` (and likewise for y,
    z), the largest is taken for its square root; the other components follow from the
    off-diagonal sums and differences (Shepperd), accurate for every angle.
    """
    R = np.asarray(R, dtype=float)
    t = np.trace(R)
    diag = np.array([R[0, 0], R[1, 1], R[2, 2]])
    k = int(np.argmax([*diag, t]))
    if k == 3:
        q = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], 1.0 + t])
    else:
        i, j, m = k, (k + 1) % 3, (k + 2) % 3
        q = np.empty(4)
        q[i] = 1.0 + 2.0 * R[i, i] - t
        q[j] = R[j, i] + R[i, j]
        q[m] = R[m, i] + R[i, m]
        q[3] = R[m, j] - R[j, m]
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


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
    # RQ from QR: with P the row reversal, (P A)^T = Q U gives A = (P U^T P)(P Q^T)
    Q, U = np.linalg.qr(A[::-1].T)
    K, R = U.T[::-1, ::-1], Q.T[::-1]
    signs = np.sign(np.diag(K))
    signs[signs == 0] = 1.0
    K = K * signs[None, :]  # K D, with D = diag(signs) = D^-1
    R = signs[:, None] * R  # D R
    return K / K[2, 2], R
