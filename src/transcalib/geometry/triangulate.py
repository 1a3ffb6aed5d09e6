"""Scene points from known cameras (``A = K R``, one for every view or one per view) and centres.

With the camera known, each view gives two linear equations in ``X_j`` (paper eq. 2)::

    (A[0] - u_ij A[2]) (X_j - T_i) = 0,     (A[1] - v_ij A[2]) (X_j - T_i) = 0

(with ``A_i`` per view when the views have their own orientations).

Dividing each pair by the point's depth ``A[2] (X_j - T_i)`` (with ``||A[2]|| = 1``)
turns the algebraic error into the pixel reprojection error to first order, so the
weighted linear least-squares solution is close to the maximum-likelihood one. Two
passes: the first uses the depths given (or 1), the second the depths of the first.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .camera import pixels_to_rays

__all__ = ["triangulate"]


def solve_sym3(M: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve many symmetric 3x3 systems ``M_n x_n = b_n`` by the adjugate (vectorised).

    Parameters
    ----------
    M : (n, 3, 3) float, symmetric
    b : (n, 3) float

    Returns
    -------
    (n, 3) float
        NaN rows where ``M_n`` is singular (relative determinant below 1e-14).
    """
    return _solve_sym3(M[:, 0, 0], M[:, 0, 1], M[:, 0, 2], M[:, 1, 1], M[:, 1, 2], M[:, 2, 2], b.T).T


def _solve_sym3(a, bb, c, d, e, f, b) -> np.ndarray:
    """:func:`solve_sym3` from the six distinct entries of ``M`` ``[[a, bb, c], [bb, d, e],
    [c, e, f]]`` (each (n,)) and ``b`` (3, n); returns ``x`` (3, n)."""
    c00 = d * f - e * e
    c01 = c * e - bb * f
    c02 = bb * e - c * d
    c11 = a * f - c * c
    c12 = bb * c - a * e
    c22 = a * d - bb * bb
    det = a * c00 + bb * c01 + c * c02
    scale = np.abs(a * d * f) + 1e-300
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = np.where(np.abs(det) > 1e-14 * scale, 1.0 / det, np.nan)
    x = np.empty((3, a.size))
    x[0] = (c00 * b[0] + c01 * b[1] + c02 * b[2]) * inv_det
    x[1] = (c01 * b[0] + c11 * b[1] + c12 * b[2]) * inv_det
    x[2] = (c02 * b[0] + c12 * b[1] + c22 * b[2]) * inv_det
    return x


def triangulate(
    A: np.ndarray,
    uv: np.ndarray,
    T: np.ndarray,
    depth: np.ndarray | None = None,
    *,
    K: np.ndarray | None = None,
    dist=(),
    passes: int = 2,
) -> np.ndarray:
    """Triangulate every point from all views where it is seen.

    Parameters
    ----------
    A : (3, 3) or (n_views, 3, 3) float
        ``K R``, for every view or per view (any scale; rescaled so that ``||A[2]|| = 1``).
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen.
    T : (n_views, 3) float
        Camera centres (the robot translations, with one orientation).
    depth : (n_views, n_points) float, optional
        Initial depth estimates for the weights (e.g. the TLS depths).
    K : (3, 3) float, optional
        Needed only with ``dist``: pixels are undistorted first and ``A`` is taken as
        ``K R`` with ``R = K^-1 A``.
    dist : (k,) float, optional
        OpenCV distortion coefficients.
    passes : int
        Reweighting passes (2 is plenty).

    Returns
    -------
    X : (n_points, 3) float
        NaN for points seen in fewer than 2 views (or whose rays are parallel).
    """
    A = np.asarray(A, dtype=float)
    shared = A.ndim == 2
    A = A.reshape(-1, 3, 3)
    if np.asarray(dist).size:
        if K is None:
            raise ValueError("triangulate: K is required together with dist")
        A = np.linalg.inv(K) @ A  # = R up to scale: work in undistorted normalised coordinates
    A = A / np.linalg.norm(A[:, 2], axis=1)[:, None, None]
    # M = sum_v w (a_u a_u^T + a_v a_v^T) with a_u = A0 - u A2, a_v = A1 - v A2 expands
    # into four 3x3 matrices (per view, or shared) weighted by per-point sums of w, w u,
    # w v, w (u^2 + v^2); b = sum_v w (a_u a_u^T + a_v a_v^T) T_v likewise.
    A0, A1, A2 = A[:, 0], A[:, 1], A[:, 2]  # (m, 3) each, m = 1 or n_views
    outer = lambda x, y: x[:, :, None] * y[:, None, :]  # noqa: E731
    basis = np.stack([outer(A0, A0) + outer(A1, A1), -outer(A0, A2) - outer(A2, A0), -outer(A1, A2) - outer(A2, A1),
                      outer(A2, A2)], axis=1)  # (m, 4, 3, 3)
    per_view = np.einsum("vkab,vb->vka", np.broadcast_to(basis, (len(T), 4, 3, 3)), T)  # (V, 4, 3): basis_k T_v
    cams = _Cameras(basis.reshape(-1, 4, 9), per_view, np.broadcast_to(A2, (len(T), 3)), T, shared)
    X = np.empty((uv.shape[1], 3))
    for lo in range(0, uv.shape[1], _CHUNK):  # small temporaries: memory is reused
        c = slice(lo, min(lo + _CHUNK, uv.shape[1]))
        X[c] = _triangulate_chunk(uv[:, c], None if depth is None else depth[:, c], cams, K, dist, passes)
    return X


class _Cameras(NamedTuple):
    """What the chunks need of the cameras: ``basis (m, 4, 9)`` (m = 1: shared), ``per_view
    (V, 4, 3)``, the depth rows ``A2 (V, 3)``, the centres ``T (V, 3)``."""

    basis: np.ndarray
    per_view: np.ndarray
    A2: np.ndarray
    T: np.ndarray
    shared: bool


#: Points per chunk.
_CHUNK = 16384


def _triangulate_chunk(uv, depth, cams: _Cameras, K, dist, passes) -> np.ndarray:
    seen = np.isfinite(uv[..., 0])  # (V, n)
    if np.asarray(dist).size:
        rays = pixels_to_rays(K, np.where(seen[..., None], uv, 0.0), dist)
        u, v = rays[..., 0] / rays[..., 2], rays[..., 1] / rays[..., 2]
    else:
        u, v = np.where(seen, uv[..., 0], 0.0), np.where(seen, uv[..., 1], 0.0)
    w = seen.astype(float)
    if depth is not None:
        _inverse_square(depth, seen, out=w)
    V, n = seen.shape
    coef = np.empty((4, V, n))  # w, w u, w v, w (u^2 + v^2)
    r2 = u * u + v * v
    X = None
    for p in range(max(1, passes)):
        coef[0] = w
        np.multiply(w, u, out=coef[1])
        np.multiply(w, v, out=coef[2])
        np.multiply(w, r2, out=coef[3])
        if cams.shared:  # rows of the 3x3 systems (9, n)
            M = cams.basis[0].T @ coef.sum(axis=1)
        else:
            M = np.einsum("vkx,kvn->xn", cams.basis, coef)
        b = np.einsum("vka,kvn->an", cams.per_view, coef)
        X = _solve_sym3(M[0], M[1], M[2], M[4], M[5], M[8], b)
        if p + 1 < passes:  # weights from these depths for the next pass
            _inverse_square(cams.A2 @ X - np.einsum("va,va->v", cams.A2, cams.T)[:, None], seen, out=w)
    X[:, seen.sum(axis=0) < 2] = np.nan
    return X.T


def _inverse_square(z: np.ndarray, seen: np.ndarray, out: np.ndarray) -> None:
    """``out = 1 / z^2`` where seen and ``z`` is finite and non-zero; elsewhere ``out`` is
    kept where seen, 0 where unseen."""
    ok = seen & np.isfinite(z) & (z != 0)
    np.divide(1.0, z * z, out=out, where=ok)
    out *= seen
