"""Values interpolated from image neighbours: the local fits every tracker stage shares.

Under pure translation a point's displacement along its epipolar line is ``rho``, its
inverse depth up to the pair's scale; on a plane ``rho`` is affine in the image, so the
neighbours of a point predict its ``rho`` (:func:`local_linear`, :func:`local_median`) and
a value far off its neighbours' trend marks a mismatch (:func:`detrended`). Smooth
deviations from straight epipolar lines (lens distortion, a tiny rotation) follow the
trend too, while a mismatch deviates alone.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["local_median", "local_linear", "local_affine", "detrended", "plain_window"]


def local_median(seeds_x: np.ndarray, seeds_v: np.ndarray, query: np.ndarray, k: int = 6) -> np.ndarray:
    """Median of the values ``seeds_v (m,)`` of the ``k`` nearest seeds ``seeds_x (m, 2)`` of
    each query point ``(q, 2)``; a seed at the query's own position is skipped, so a point
    never votes for itself. NaN where no seed is left."""
    if len(seeds_x) == 0 or len(query) == 0:
        return np.full(len(query), np.nan)
    kk = min(k + 1, len(seeds_x))
    dd, nn = cKDTree(seeds_x).query(query, k=kk)
    dd, nn = dd.reshape(len(query), kk), nn.reshape(len(query), kk)
    r = np.where(dd > 1e-9, seeds_v[np.minimum(nn, len(seeds_x) - 1)], np.nan)
    r = np.where(np.cumsum(np.isfinite(r), axis=1) <= k, r, np.nan)  # the k nearest non-self
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(r, axis=1)


def local_linear(seeds_x: np.ndarray, seeds_v: np.ndarray, query: np.ndarray, k: int = 10,
                 keep: float = 0.7, gradient: bool = False):
    """Value at each query from a trimmed local linear fit ``v = a + b du + c dv`` to its
    ``k`` nearest seeds (itself excluded).

    Exact for an affine field (the inverse depth of a plane), robust to a few bad seeds:
    two passes, each keeping the ``keep`` fraction of the neighbours best fitted.

    Parameters
    ----------
    seeds_x : (m, 2) float
    seeds_v : (m,) or (m, c) float
        One value per seed, or ``c`` (each column fitted alone, one neighbour search).
    query : (q, 2) float
    k : int
    keep : float

    gradient : bool
        Also return the fit's gradient ``(b, c)`` per px (one value per seed only).

    Returns
    -------
    (q,) or (q, c) float
        :func:`local_median` with fewer than 4 seeds (its gradient 0).
    (q, 2) float
        With ``gradient``.
    """
    seeds_v = np.asarray(seeds_v, float)
    m = len(seeds_x)
    if m < 4 or len(query) == 0:
        if seeds_v.ndim == 1:
            v = local_median(seeds_x, seeds_v, query, k)
            return (v, np.zeros((len(query), 2))) if gradient else v
        return np.column_stack([local_median(seeds_x, v, query, k) for v in seeds_v.T]).reshape(len(query), -1)
    kk = min(k + 1, m)
    dd, nn = cKDTree(seeds_x).query(query, k=kk)
    dd, nn = dd.reshape(len(query), kk), nn.reshape(len(query), kk)
    w0 = (dd > 1e-9).astype(float)
    w0 *= np.cumsum(w0, axis=1) <= k
    nn = np.minimum(nn, m - 1)
    du, dv = seeds_x[nn, 0] - query[:, None, 0], seeds_x[nn, 1] - query[:, None, 1]
    scale = np.maximum(np.sqrt((w0 * (du * du + dv * dv)).sum(1) / np.maximum(w0.sum(1), 1)), 1e-6)[:, None]
    du, dv = du / scale, dv / scale
    n_nb = np.maximum((w0 > 0).sum(1), 1)  # neighbours actually there (few seeds: fewer than k)
    rank = np.clip(np.maximum(3, (keep * np.minimum(n_nb, k)).astype(int)) - 1, 0, kk - 1)
    cols = seeds_v.reshape(m, -1)
    out = np.empty((len(query), cols.shape[1]))
    for c in range(cols.shape[1]):  # a few columns; vectorised over the queries
        y, w = cols[nn, c], w0
        for _ in range(2):
            a, b, cc = _weighted_plane(w, du, dv, y)
            r = np.where(w > 0, np.abs(a[:, None] + b[:, None] * du + cc[:, None] * dv - y), np.inf)
            cut = np.take_along_axis(np.sort(r, axis=1), rank[:, None], axis=1)
            w = w * (r <= cut)
        out[:, c] = a
    if gradient:
        return out[:, 0], np.column_stack([b, cc]) / scale
    return out[:, 0] if seeds_v.ndim == 1 else out


def local_affine(src_a: np.ndarray, src_b: np.ndarray, query: np.ndarray, k: int = 12, keep: float = 0.7,
                 return_residual: bool = False):
    """The local affine map of correspondences ``src_a -> src_b`` at each query point.

    A trimmed linear fit of each target coordinate to the ``k`` nearest sources (as
    :func:`local_linear`): ``x_b ~ p + J (x_a - q)`` near each query ``q``. The map of a
    small patch between views of any orientation (rotation, scale, foreshortening).

    Parameters
    ----------
    src_a, src_b : (m, 2) float
        Corresponding points of two views.
    query : (q, 2) float
        Points of the first view.
    k : int
    keep : float

    return_residual : bool
        Also return how far the neighbours are from the affine map.

    Returns
    -------
    p : (q, 2) float
        Predicted positions in the second view (NaN with fewer than 4 sources).
    J : (q, 2, 2) float
        Local Jacobians ``d x_b / d x_a``.
    residual : (q,) float
        With ``return_residual``: the largest misfit (px) of the neighbours kept by the
        trimming (large next to a depth discontinuity, where no affine map fits).
    """
    nq = len(query)
    if len(src_a) < 4 or nq == 0:
        none = (np.full((nq, 2), np.nan), np.full((nq, 2, 2), np.nan))
        return none + (np.full(nq, np.inf),) if return_residual else none
    kk = min(k, len(src_a))
    _, nn = cKDTree(src_a).query(query, k=kk)
    nn = nn.reshape(nq, kk)
    du, dv = src_a[nn, 0] - query[:, None, 0], src_a[nn, 1] - query[:, None, 1]
    scale = np.maximum(np.sqrt((du * du + dv * dv).mean(1)), 1e-6)[:, None]
    du, dv = du / scale, dv / scale
    rank = np.full(nq, max(3, int(keep * kk)) - 1)
    p, J, res = np.empty((nq, 2)), np.empty((nq, 2, 2)), np.zeros(nq)
    for c in range(2):
        y, w = src_b[nn, c], np.ones((nq, kk))
        for _ in range(2):
            a, b, cc = _weighted_plane(w, du, dv, y)
            r = np.abs(a[:, None] + b[:, None] * du + cc[:, None] * dv - y)
            cut = np.take_along_axis(np.sort(r, axis=1), rank[:, None], axis=1)
            w = (r <= cut).astype(float)
        p[:, c], J[:, c, 0], J[:, c, 1] = a, b / scale[:, 0], cc / scale[:, 0]
        res = np.maximum(res, np.max(np.where(w > 0, r, 0.0), axis=1))
    return (p, J, res) if return_residual else (p, J)


def _weighted_plane(w, du, dv, y, reg: float = 1e-6):
    """Weighted least squares ``y = a + b du + c dv`` per row (normal equations, Cramer's
    rule with a small ridge ``reg``): ``(a, b, c)``, each ``(q,)``."""
    s0, su, sv = w.sum(1) + reg, (w * du).sum(1), (w * dv).sum(1)
    suu, suv, svv = (w * du * du).sum(1) + reg, (w * du * dv).sum(1), (w * dv * dv).sum(1) + reg
    wy = np.nan_to_num(w * y)
    ty, tu, tv = wy.sum(1), (wy * du).sum(1), (wy * dv).sum(1)
    c00, c01, c02 = suu * svv - suv * suv, sv * suv - su * svv, su * suv - sv * suu
    det = s0 * c00 + su * c01 + sv * c02
    with np.errstate(divide="ignore", invalid="ignore"):
        a = (ty * c00 + tu * c01 + tv * c02) / det
        b = (ty * c01 + tu * (s0 * svv - sv * sv) + tv * (sv * su - s0 * suv)) / det
        c = (ty * c02 + tu * (su * sv - s0 * suv) + tv * (s0 * suu - su * su)) / det
    return a, b, c


def detrended(x: np.ndarray, r: np.ndarray, trusted: np.ndarray, k: int = 10) -> np.ndarray:
    """``|r - trend|`` ``(n,)``: ``trend`` the :func:`local_linear` fit, at each point ``x (n, 2)``,
    of the values ``r (n,)`` of the ``trusted (n,)`` points near it (itself excluded); inf
    where undefined. Fewer than 4 trusted points: ``|r|``."""
    sel = trusted & np.isfinite(r)
    if sel.sum() < 4:
        return np.abs(r)
    trend = local_linear(x[sel], r[sel], x, k=k)
    return np.nan_to_num(np.abs(r - trend), nan=np.inf)


#: A window is searched across views only where its map is nearly affine (its neighbours'
#: predictions within this many px of an affine map: no depth discontinuity) ...
MAX_LOCAL_MISFIT_PX = 1.0
#: ... and the window is not foreshortened much more in one view than in the other (ratio
#: of the singular values of the local map; a face seen at a grazing angle).
MAX_ANISOTROPY = 3.5


def plain_window(J: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Where a window can be found across the views: its local map ``J (m, 2, 2)`` is
    affine (``residual (m,)``), not too anisotropic, and keeps the orientation."""
    s = np.linalg.svd(np.nan_to_num(J), compute_uv=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        aniso = s[:, 0] / s[:, 1]
    return (np.isfinite(J).all((1, 2)) & (residual <= MAX_LOCAL_MISFIT_PX) & (aniso <= MAX_ANISOTROPY)
            & (np.linalg.det(np.nan_to_num(J)) > 0))
