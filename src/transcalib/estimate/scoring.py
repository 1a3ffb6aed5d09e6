"""Scoring of robust hypotheses: every track triangulated with a hypothesised ``A``.

With ``A`` known the linear triangulation of point ``j`` (paper eq. 2 divided out, as in
:mod:`transcalib.geometry.triangulate`) is ``Y_j = G_j^-1 sum_i P_ij A T_i`` with
``P_ij = r_u r_u^T + r_v r_v^T``, ``r_u = (1, 0, -u)``, ``r_v = (0, 1, -v)`` and
``G_j = sum_i P_ij``: ``G_j^-1 P_ij`` do not depend on ``A`` and are computed once, so
scoring a hypothesis costs O(n_views n_points) multiply-adds, vectorised over
hypotheses and points.

The **error of a track** seen in ``k`` views is the sum of its squared reprojection
errors ``e_j^2 = sum_i |r_ij|^2`` (pixels^2; infinite when it lies behind the camera in
some view), with ``2 k - 3`` degrees of freedom: the inlier rule and the noise estimators
that judge it are in :mod:`.noise`.
"""

from __future__ import annotations

import numpy as np
from ..geometry.triangulate import triangulate
from .minimal import Problem

__all__ = ["Scorer", "point_errors"]

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

    def sse(self, A: np.ndarray) -> np.ndarray:
        """Track errors ``e_j^2`` (H, n) in **pixels^2** for normalised hypotheses ``A``
        (H, 3, 3); inf if behind the camera, NaN if not scorable."""
        out = np.empty((A.shape[0], self.n))
        step = max(1, SCORE_BLOCK // max(1, self.n * self.V))
        for lo in range(0, A.shape[0], step):
            out[lo: lo + step] = self._sse(A[lo: lo + step])
        out[:, ~self.ok] = np.nan
        return out / self.pb.scale**2

    def _sse(self, A):
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
        e2 = np.where(z > 0, du * du + dv * dv, np.inf)
        return np.where(seen, e2, 0.0).sum(axis=2)


def point_errors(A: np.ndarray, uv: np.ndarray, T: np.ndarray):
    """Reprojection errors of every track triangulated with a known ``A``.

    Parameters
    ----------
    A : (3, 3) float
        ``K R`` in pixels, any scale; the sign is chosen so that most depths are positive.
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float

    Returns
    -------
    sse : (n_points,) float
        Sum of squared reprojection errors over the views seeing the track (pixels^2);
        inf behind the camera, NaN if seen in fewer than 2 views.
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
    e2 = np.where(seen, np.sum(np.where(seen[..., None], res, 0.0) ** 2, axis=2), 0.0)
    e2 = np.where(seen & ~(p[..., 2] > 0), np.inf, e2)
    sse = e2.sum(axis=0)
    sse[~(seen.sum(axis=0) >= 2) | ~np.isfinite(X).all(axis=1)] = np.nan
    return sse, res
