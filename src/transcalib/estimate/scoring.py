"""Scoring of robust hypotheses: every point triangulated with a hypothesised ``A``.

With ``A`` known the linear triangulation of point ``j`` (paper eq. 2 divided out, as in
:mod:`transcalib.triangulate`) is ``Y_j = G_j^-1 sum_i P_ij A T_i`` with
``P_ij = r_u r_u^T + r_v r_v^T``, ``r_u = (1, 0, -u)``, ``r_v = (0, 1, -v)`` and
``G_j = sum_i P_ij``: ``G_j^-1 P_ij`` do not depend on ``A`` and are computed once, so
scoring a hypothesis costs O(n_views n_points) multiply-adds, vectorised over
hypotheses and points. The **error of a point** is the largest reprojection error (pixel
norm) over the views that see it, infinite when it lies behind the camera in some view;
a point is an **inlier** when that error is below ``threshold_px``. Hypotheses are ranked
by the MSAC cost ``sum_j min(e_j^2, threshold_px^2)``.
"""

from __future__ import annotations

import numpy as np

from ..geometry.triangulate import triangulate
from .minimal import Problem

__all__ = ["Scorer", "msac_cost", "point_errors", "SCORE_BLOCK"]

#: Largest number of (hypothesis x view x point) entries scored at once (memory bound).
SCORE_BLOCK = 2_000_000


class Scorer:
    """Precomputes ``L_ij = G_j^-1 P_ij`` (module docstring) for the scorable points."""

    def __init__(self, pb: Problem):
        self.pb = pb
        x, seen = pb.x, pb.seen
        n, V = seen.shape
        P = np.zeros((n, V, 3, 3))
        P[..., 0, 0] = P[..., 1, 1] = 1.0
        P[..., 0, 2] = P[..., 2, 0] = -x[..., 0]
        P[..., 1, 2] = P[..., 2, 1] = -x[..., 1]
        P[..., 2, 2] = x[..., 0] ** 2 + x[..., 1] ** 2
        P *= seen[..., None, None]
        G = P.sum(axis=1)
        # points seen in >= 2 views with non-parallel rays can be triangulated
        det = np.linalg.det(G)
        self.ok = (seen.sum(axis=1) >= 2) & (np.abs(det) > 1e-12 * np.abs(np.einsum("naa->n", G)) ** 3)
        G[~self.ok] = np.eye(3)
        L = np.linalg.solve(G[:, None], P)  # (n, V, 3, 3)
        L[~self.ok] = 0.0
        del P, G
        # as one matrix (3 n, 3 V): Y = L2 @ vec(A T_i) is a BLAS product per batch
        self.L2 = np.ascontiguousarray(L.transpose(0, 2, 1, 3).reshape(3 * n, 3 * V))
        self.n, self.V = n, V

    def errors(self, A: np.ndarray) -> np.ndarray:
        """Largest reprojection error per point (H, n) in **pixels** for normalised
        hypotheses ``A`` (H, 3, 3); inf if behind the camera, NaN if not scorable."""
        pb = self.pb
        Hn = A.shape[0]
        out = np.empty((Hn, self.n))
        step = max(1, SCORE_BLOCK // max(1, self.n * self.V))
        for lo in range(0, Hn, step):
            out[lo: lo + step] = self._errors(A[lo: lo + step])
        out[:, ~self.ok] = np.nan
        return out / pb.scale

    def _errors(self, A):
        pb = self.pb
        c = np.einsum("hab,vb->hva", A, pb.T)  # A T_i: (H, V, 3)
        Y = (self.L2 @ c.reshape(len(A), -1).T).T.reshape(len(A), self.n, 3)  # (H, n, 3)
        p = Y[:, :, None, :] - c[:, None, :, :]  # (H, n, V, 3) = A (X_j - T_i)
        z = p[..., 2]
        seen = pb.seen[None]
        # fix each hypothesis' sign so that most depths are positive
        sign = np.sign(np.sum(np.where(seen, np.sign(z), 0.0), axis=(1, 2)))
        sign[sign == 0] = 1.0
        z = z * sign[:, None, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = sign[:, None, None] / z
            du = p[..., 0] * inv - pb.x[None, ..., 0]
            dv = p[..., 1] * inv - pb.x[None, ..., 1]
        e2 = du * du + dv * dv
        e2 = np.where(z > 0, e2, np.inf)
        e2 = np.where(seen, e2, 0.0)
        return np.sqrt(e2.max(axis=2))


def _msac_cost(err: np.ndarray, thr: float) -> np.ndarray:
    """``sum_j min(e_j^2, thr^2)`` over scorable points, per hypothesis (H,)."""
    e2 = np.minimum(np.nan_to_num(err, nan=0.0, posinf=np.inf) ** 2, thr * thr)
    e2 = np.where(np.isnan(err), 0.0, e2)
    return e2.sum(axis=-1)


def _to_pixels(pb: Problem, a: np.ndarray) -> np.ndarray:
    """Normalised ``a`` (..., 9) -> pixel ``A`` (..., 3, 3), ``||A[2]|| = 1`` (sign kept)."""
    A = np.linalg.solve(pb.H, a.reshape(-1, 3, 3)) / pb.t_scale
    return A / np.linalg.norm(A[:, 2], axis=1)[:, None, None]


def msac_cost(err: np.ndarray, thr: float) -> np.ndarray:
    """``sum_j min(e_j^2, thr^2)`` over scorable points, per hypothesis (H,)."""
    e2 = np.minimum(np.nan_to_num(err, nan=0.0, posinf=np.inf) ** 2, thr * thr)
    e2 = np.where(np.isnan(err), 0.0, e2)
    return e2.sum(axis=-1)


def point_errors(A: np.ndarray, uv: np.ndarray, T: np.ndarray):
    """Reprojection errors of every point triangulated with a known ``A``.

    Parameters
    ----------
    A : (3, 3) float
        ``K R`` in pixels, any scale; the sign is chosen so that most depths are positive.
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float

    Returns
    -------
    error_px : (n_points,) float
        Largest reprojection error over the views seeing the point (pixels); inf behind
        the camera, NaN if seen in fewer than 2 views.
    residuals_px : (n_views, n_points, 2) float
        Observed minus predicted, NaN where unseen.
    """
    A = A / np.linalg.norm(A[2])
    X = triangulate(A, uv, T)
    p = np.einsum("ab,vnb->vna", A, X[None] - T[:, None])
    seen = np.isfinite(uv[..., 0])
    z = p[..., 2][seen & np.isfinite(p[..., 2])]
    if z.size and np.median(z) < 0:  # A given with the other sign: most depths negative
        p = -p
    with np.errstate(divide="ignore", invalid="ignore"):
        pred = p[..., :2] / p[..., 2:3]
    res = uv - pred
    e = np.where(seen, np.hypot(res[..., 0], res[..., 1]), 0.0)
    e = np.where(seen & ~(p[..., 2] > 0), np.inf, e)
    err = e.max(axis=0)
    err[~(seen.sum(axis=0) >= 2) | ~np.isfinite(X).all(axis=1)] = np.nan
    return err, res


