"""Rotations, written once: the exponential map ``exp([w]x)`` and its inverse,
quaternions, KUKA Z-Y-X Euler angles, the rotation angle, ``A = K R``.

A rotation vector ``w`` (radians) maps to ``R = exp([w]x)`` by Rodrigues' formula::

    R = I + sin(t)/t [w]x + (1 - cos(t))/t^2 [w]x^2,      t = |w|

Every local rotation update in the project (``R <- exp([dw]x) R``) uses these. A unit
quaternion is ``(qx, qy, qz, qw)`` (Hamilton, scalar last, as ROS ``tf`` and scipy).

The conversions take one rotation or a stack: ``(3,)`` / ``(4,)`` / ``(3, 3)`` input gives
one result, ``(n, 3)`` / ``(n, 4)`` / ``(n, 3, 3)`` a stack of ``n``.
"""

from __future__ import annotations

import numpy as np

from ..errors import MirroredError

__all__ = ["rotvec_to_matrix", "matrix_to_rotvec", "quaternion_to_matrix", "matrix_to_quaternion",
           "euler_zyx_to_matrix", "skew", "rotation_angle_deg", "rotation_defect", "ROTATION_TOL", "rq_decompose", "nearest_rotation", "central_mean_rotation",
           "group_by_orientation"]

#: Largest ``max |R R^T - I|`` of an input matrix accepted as a rotation.
ROTATION_TOL = 1e-6
#: Below this angle (radians) Rodrigues' coefficients are their Taylor series (exact to rounding).
_SMALL_ANGLE = 1e-8


def skew(w: np.ndarray) -> np.ndarray:
    """``[w]x`` (..., 3, 3) of vectors ``w`` (..., 3): ``[w]x v = w x v``."""
    w = np.asarray(w, dtype=float)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return out


def rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """``exp([w]x)`` of rotation vectors (Rodrigues).

    Parameters
    ----------
    w : (3,) or (n, 3) float
        Rotation vectors ``angle * axis``, radians.

    Returns
    -------
    (3, 3) or (n, 3, 3) float
    """
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    Wx = skew(w)
    small = theta < _SMALL_ANGLE  # second-order series there
    t = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(t) / t)
    b = np.where(small, 0.5, (1.0 - np.cos(t)) / t**2)
    return np.eye(3) + a * Wx + (b * Wx) @ Wx


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rotvec_to_matrix`: rotation vectors with angle in ``[0, pi]``.

    ``w = 2 atan2(|v|, qw) v / |v|`` from the unit quaternion ``(v, qw)`` of ``R``
    (:func:`matrix_to_quaternion`, ``qw >= 0``): accurate for tiny angles and half turns.

    Parameters
    ----------
    R : (3, 3) or (n, 3, 3) float

    Returns
    -------
    (3,) or (n, 3) float
        Radians.
    """
    q = matrix_to_quaternion(R)
    v, qw = q[..., :3], q[..., 3]
    s = np.linalg.norm(v, axis=-1)
    scale = np.where(s > 0, 2.0 * np.arctan2(s, qw) / np.where(s > 0, s, 1.0), 2.0)  # 2 / qw = 2 at s = 0
    return v * scale[..., None]


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions ``(qx, qy, qz, qw)``.

    Parameters
    ----------
    q : (4,) or (n, 4) float
        Any non-zero norm (normalised here); ``q`` and ``-q`` give the same rotation.

    Returns
    -------
    (3, 3) or (n, 3, 3) float
    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """The unit quaternions ``(qx, qy, qz, qw)`` of rotation matrices, with ``qw >= 0``.

    Of ``4 qw^2 = 1 + tr R`` and ``4 qx^2 = 1 + R00 - R11 - R22`` (and likewise for y,
    z), the largest is taken for its square root; the other components follow from the
    off-diagonal sums and differences (Shepperd), accurate for every angle.

    Parameters
    ----------
    R : (3, 3) or (n, 3, 3) float

    Returns
    -------
    (4,) or (n, 4) float
    """
    R = np.asarray(R, dtype=float)
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = np.moveaxis(R.reshape(R.shape[:-2] + (9,)), -1, 0)
    t = r00 + r11 + r22
    # the unnormalised quaternion 4 q_k q of each choice k (rows: k = x, y, z, w)
    cands = np.stack([
        np.stack([1.0 + 2.0 * r00 - t, r10 + r01, r20 + r02, r21 - r12], -1),
        np.stack([r01 + r10, 1.0 + 2.0 * r11 - t, r21 + r12, r02 - r20], -1),
        np.stack([r02 + r20, r12 + r21, 1.0 + 2.0 * r22 - t, r10 - r01], -1),
        np.stack([r21 - r12, r02 - r20, r10 - r01, 1.0 + t], -1)], -2)
    k = np.argmax(np.stack([r00, r11, r22, t], -1), axis=-1)
    q = np.take_along_axis(cands, k[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:] < 0, -q, q)


def euler_zyx_to_matrix(abc_deg: np.ndarray) -> np.ndarray:
    """KUKA ``A, B, C`` angles to ``R = Rz(A) Ry(B) Rx(C)`` (intrinsic Z-Y-X).

    Parameters
    ----------
    abc_deg : (3,) or (n, 3) float
        Degrees.

    Returns
    -------
    (3, 3) or (n, 3, 3) float
    """
    a, b, c = np.moveaxis(np.radians(np.asarray(abc_deg, dtype=float)), -1, 0)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    return np.stack([
        np.stack([ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc], -1),
        np.stack([sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc], -1),
        np.stack([-sb, cb * sc, cb * cc], -1)], -2)


def rotation_angle_deg(R: np.ndarray):
    """Angle in degrees of rotation matrices, accurate for tiny and large angles:
    ``atan2(sin, cos)`` with ``sin`` from the skew part and ``cos = (tr R - 1) / 2``.

    The angle between two rotations ``Ra``, ``Rb`` is that of ``Ra^T Rb``.

    Parameters
    ----------
    R : (3, 3) or (..., 3, 3) float

    Returns
    -------
    float, or (...) float ndarray for a stack
    """
    R = np.asarray(R, dtype=float)
    sin = 0.5 * np.linalg.norm(np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                                         R[..., 1, 0] - R[..., 0, 1]], -1), axis=-1)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    angle = np.degrees(np.arctan2(sin, cos))
    return float(angle) if R.ndim == 2 else angle


def nearest_rotation(M: np.ndarray) -> np.ndarray:
    """The rotation nearest to ``M`` (3, 3) in the Frobenius norm (SVD, det +1)."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def central_mean_rotation(R: np.ndarray, tolerance_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """A mean that strays do not pull: the chordal mean of the rotations within
    ``tolerance_deg`` of the most central one (least median angle to the others; the first
    on a tie).

    Parameters
    ----------
    R : (k, 3, 3) float
    tolerance_deg : float

    Returns
    -------
    mean : (3, 3) float
    near : (k,) bool
        The rotations averaged.
    """
    R = np.asarray(R, dtype=float)
    angles = rotation_angle_deg(np.swapaxes(R[:, None], -1, -2) @ R[None, :])  # (k, k)
    centre = int(np.argmin(np.median(angles, axis=1)))
    near = angles[centre] <= tolerance_deg
    return nearest_rotation(R[near].sum(axis=0)), near


def group_by_orientation(R: np.ndarray, tolerance_deg: float) -> np.ndarray:
    """``(n,)`` group of each rotation of ``R (n, 3, 3)``, greedily in order: a rotation
    joins the group whose first member is nearest, if within ``tolerance_deg``, else it
    opens a new group (numbered in order of their first members)."""
    firsts, of = [], np.empty(len(R), int)
    for i in range(len(R)):
        angles = rotation_angle_deg(np.swapaxes(R[firsts], -1, -2) @ R[i]) if firsts else np.zeros(0)
        k = int(np.argmin(angles)) if firsts else -1
        if k < 0 or angles[k] > tolerance_deg:
            firsts.append(i)
            k = len(firsts) - 1
        of[i] = k
    return of


def rotation_defect(R: np.ndarray) -> np.ndarray:
    """How far matrices are from rotations: ``max |R R^T - I|``, ``inf`` where
    ``det R <= 0`` or an entry is not finite.

    Parameters
    ----------
    R : (..., 3, 3) float

    Returns
    -------
    (...) float
    """
    R = np.asarray(R, dtype=float)
    with np.errstate(invalid="ignore"):
        err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(axis=(-2, -1))
        det = np.linalg.det(np.where(np.isfinite(R), R, 0.0))
    return np.where(np.isfinite(err) & (det > 0), err, np.inf)


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
    return np.triu(K / K[2, 2]) + 0.0, R  # exact zeros below the diagonal (+0.0: no signed zeros)
