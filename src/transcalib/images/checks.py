"""Checks of refined tracks of one session: observations a pure translation cannot explain go.

In the order :func:`check_session` runs them:

1. **depth smoothness** (:func:`smoothness_check`): an observation whose ``rho`` (inverse
   depth along the pair's epipolar line) is more than ``smooth_px`` (in the image) off a
   trimmed local linear fit to its 10 neighbours' (one tile off on a repetitive texture);
2. **epipoles from the refined tracks** (:func:`epipolar_check`): each pair's epipole
   re-estimated from the refined points (:func:`~.epipoles.epipole_ransac`, detrended:
   lens distortion bends the lines smoothly); an observation off its line goes;
3. **multi-view depth** (:func:`multiview_check`): a track in 3+ views has one inverse
   depth ``w`` (``q_j = s_j w``, :func:`~.propagate.depth_scales`); the observation that
   ``w`` from the other views predicts worst, beyond ``3 x`` the epipolar threshold, goes
   (the smooth part of the misfits, lens distortion, capped at :data:`MAX_TREND_PX`);
4. **static tracks** (:func:`drop_static`): a track that does not move while the scene
   does (a burnt-in timestamp, dust on the lens, the static background behind an object
   carried by the robot) carries no information on K;
5. duplicates merged, too short tracks dropped, the best spread kept (:func:`keep_tracks`).
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial import cKDTree

from .epipoles import direction, epipole_ransac, residuals, signed_distance
from .local import local_linear
from .propagate import STATIC_MIN_FACTOR, STATIC_PX, depth_scales, static_tracks

__all__ = ["smoothness_check", "epipolar_check", "multiview_check", "drop_static", "merge_duplicates",
           "select_spread", "keep_tracks", "n_observations", "check_session", "check_added", "MAX_TREND_PX", "STATIC_PX"]

#: Largest smooth misfit (px) of the multi-view depth prediction attributed to lens
#: distortion (k1 = -0.12 at 640 x 480 gives under 2 px); beyond it, a mismatch.
MAX_TREND_PX = 4.0


def n_observations(uv: np.ndarray) -> int:
    """Observations of the tracks seen at least twice."""
    s = np.isfinite(uv[..., 0])
    return int(s[:, s.sum(0) >= 2].sum())


def _drop(out, bad, i, j, ref):
    """Drop the non-reference observation of each bad track of pair ``(i, j)``."""
    drop_j = ref[bad] != j
    out[j, bad[drop_j]] = np.nan
    out[i, bad[~drop_j]] = np.nan


def smoothness_check(uv: np.ndarray, epi: dict, thr_px: float, k: int = 10) -> np.ndarray:
    """Drop observations whose ``rho`` differs from its neighbours' trend by more than
    ``thr_px`` in the image (stage 1 of the module docstring)."""
    out = uv.copy()
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    for (i, j), e in epi.items():
        both = np.flatnonzero(seen[i] & seen[j])
        if e is None or len(both) < k + 1:
            continue
        xi, xj = uv[i, both], uv[j, both]
        _, rho = residuals(e, xi, xj)
        dev = np.abs(rho - local_linear(xi, rho, xi, k=k)) * np.linalg.norm(direction(e, xi), axis=1)
        _drop(out, both[~(np.nan_to_num(dev, nan=np.inf) <= thr_px)], i, j, ref)
    return out


def epipolar_check(uv: np.ndarray, thr_px: float, rng, min_shared: int = 8) -> tuple[np.ndarray, dict]:
    """Re-estimate every pair's epipole from the refined tracks; drop observations off
    their line (stage 2). Returns the checked ``uv`` and the epipoles ``{(i, j): e}``."""
    n = uv.shape[0]
    epi, out = {}, uv.copy()
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    for i in range(n):
        for j in range(i + 1, n):
            both = seen[i] & seen[j]
            if both.sum() < min_shared:
                continue
            e, inl, _ = epipole_ransac(uv[i, both], uv[j, both], threshold_px=thr_px, rng=rng, detrend=True)
            if e is None:
                continue
            epi[(i, j)] = e
            _drop(out, np.flatnonzero(both)[~inl], i, j, ref)
    return out, epi


def _misfits(out, epi, r, sel):
    """Multi-view misfits ``(n_views, m)`` (px) of the tracks ``sel`` with reference ``r``
    (leave-one-out predictions; smooth trend capped at :data:`MAX_TREND_PX`); None if
    the depth relation cannot be set up."""
    n = out.shape[0]
    q, s, E = depth_scales(out, epi, r, sel)
    if not np.isfinite(s).any():
        return None
    xr = out[r, sel]
    with np.errstate(divide="ignore", invalid="ignore"):
        w_all = q / s[:, None]
    res = np.zeros((n, len(sel)))
    for j, e in E.items():
        if not np.isfinite(s[j]):
            continue
        others = np.delete(w_all, j, axis=0)  # w from the other views: a bad view cannot hide
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            w = np.nanmedian(others, axis=0) if others.size else np.full(len(sel), np.nan)
            rho_h = 1.0 / (1.0 / (s[j] * w) - e[2])
        R = xr + rho_h[:, None] * direction(e, xr) - out[j, sel]
        fin = np.isfinite(R).all(1)
        if fin.sum() >= 12:  # remove the smooth part (lens distortion), keep isolated misfits
            trend = local_linear(xr[fin], R[fin], xr, k=10)
            tn = np.linalg.norm(trend, axis=1, keepdims=True)
            R = R - trend * np.minimum(1.0, MAX_TREND_PX / np.maximum(tn, 1e-12))
        res[j] = np.where(np.isfinite(q[j]), np.linalg.norm(R, axis=1), 0.0)
    return np.nan_to_num(res, nan=0.0)


def multiview_check(uv: np.ndarray, epi: dict, thr_px: float, passes: int = 3) -> np.ndarray:
    """Depth consistency of tracks seen in 3+ views (stage 3): per pass, per track, the
    worst-predicted observation beyond ``thr_px`` goes."""
    out = uv.copy()
    n = uv.shape[0]
    for _ in range(passes):
        seen = np.isfinite(out[..., 0])
        ref = np.argmax(seen, axis=0)
        changed = False
        for r in range(n):
            sel = np.flatnonzero((ref == r) & (seen.sum(0) >= 3))
            if len(sel) < 5:
                continue
            res = _misfits(out, epi, r, sel)
            if res is None:
                continue
            worst = np.argmax(res, axis=0)
            bad = res[worst, np.arange(len(sel))] > thr_px
            if bad.any():
                changed = True
                out[worst[bad], sel[bad]] = np.nan
        if not changed:
            break
    return out


def drop_static(uv: np.ndarray, static_px: float = STATIC_PX, factor: float = STATIC_MIN_FACTOR):
    """Drop tracks that do not move while the scene does (stage 4,
    :func:`~.propagate.static_tracks`). Returns the kept ``uv`` and the number dropped."""
    static = static_tracks(uv, static_px, factor)
    return uv[:, ~static], int(static.sum())


def merge_duplicates(uv: np.ndarray, tol: float = 0.75, min_shared: int = 1) -> np.ndarray:
    """One track for tracks that coincide (within ``tol`` px in every view both see, and
    at least ``min_shared`` such views): the union of their observations (the first
    track's where both see it). Returns the merged ``uv`` (fewer tracks)."""
    n_views, n_pts = uv.shape[:2]
    if n_pts < 2:
        return uv
    seen = np.isfinite(uv[..., 0])
    parent = np.arange(n_pts)
    for v in range(n_views):
        idx = np.flatnonzero(seen[v])
        if len(idx) < 2:
            continue
        for a, b in cKDTree(uv[v, idx]).query_pairs(tol, output_type="ndarray"):
            pa, pb = idx[a], idx[b]
            both = seen[:, pa] & seen[:, pb]
            if both.sum() >= min_shared and np.all(np.linalg.norm(uv[both, pa] - uv[both, pb], axis=1) < tol):
                ra, rb = _root(parent, pa), _root(parent, pb)
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([_root(parent, p) for p in range(n_pts)])
    if np.all(roots == np.arange(n_pts)):
        return uv
    out = uv.copy()
    for p in np.flatnonzero(roots != np.arange(n_pts)):  # few duplicates: a loop over them
        fill = ~np.isfinite(out[:, roots[p], 0]) & seen[:, p]
        out[fill, roots[p]] = uv[fill, p]
    return out[:, roots == np.arange(n_pts)]


def _root(parent, a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


def select_spread(uv: np.ndarray, k: int, shape, return_index: bool = False):
    """Keep ``k`` tracks: most views first, spread over a 16 x 16 grid of the reference image."""
    h, w = shape
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    p = uv[ref, np.arange(uv.shape[1])]
    g = 16
    cell = (np.clip(p[:, 0] / w * g, 0, g - 1).astype(int) * g + np.clip(p[:, 1] / h * g, 0, g - 1).astype(int))
    order = np.lexsort((-seen.sum(0), cell))
    rank = np.empty(len(order), int)
    cs = cell[order]
    start = np.r_[0, np.flatnonzero(np.diff(cs)) + 1]
    rank[order] = np.arange(len(order)) - np.repeat(start, np.diff(np.r_[start, len(order)]))
    pick = np.sort(np.argsort(rank * 10 - seen.sum(0), kind="stable")[:k])
    return pick if return_index else uv[:, pick]


def keep_tracks(uv: np.ndarray, min_views: int, max_tracks: int | None, shape) -> np.ndarray:
    """Merge duplicates, keep tracks seen in ``min_views``+ views, at most ``max_tracks``."""
    uv = merge_duplicates(uv)
    uv = uv[:, np.isfinite(uv[..., 0]).sum(0) >= min_views]
    if max_tracks is not None and uv.shape[1] > max_tracks:
        uv = select_spread(uv, max_tracks, shape)
    return uv


def check_added(uv: np.ndarray, added: np.ndarray, guess: np.ndarray, epi: dict, thr_px: float,
                smooth_px: float) -> np.ndarray:
    """Checks of observations ``added (n_views, n_tracks)`` to checked tracks: each must lie
    on its epipolar line from the track's reference view (against the trend of the
    pair's other observations), agree with its neighbours' depth within ``smooth_px``
    and with the depth of its own track (within ``3 thr_px`` of the position ``guess``
    that depth predicted). Returns ``uv`` without the added observations that fail."""
    out = uv.copy()
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen & ~added, axis=0)
    bad = added & ~(np.linalg.norm(uv - guess, axis=-1) <= 3.0 * thr_px)
    for (i, j), e in epi.items():
        for r, v, sign in ((i, j, 1.0), (j, i, -1.0)):
            new = np.flatnonzero(added[v] & (ref == r) & seen[r])
            old = np.flatnonzero(seen[v] & ~added[v] & seen[r])
            if len(new) == 0 or len(old) < 4:
                continue
            ev = sign * e
            xo, yo, xn, yn = uv[r, old], uv[v, old], uv[r, new], uv[v, new]
            _, rho_o = residuals(ev, xo, yo)
            _, rho_n = residuals(ev, xn, yn)
            fit = local_linear(xo, np.column_stack([rho_o, signed_distance(ev, xo, yo)]), xn, k=10)
            off_line = np.abs(signed_distance(ev, xn, yn) - fit[:, 1])
            off_depth = np.abs(rho_n - fit[:, 0]) * np.linalg.norm(direction(ev, xn), axis=1)
            bad[v, new] |= ~((off_line <= thr_px) & (off_depth <= smooth_px))
    out[bad] = np.nan
    return out


def check_session(uv, epi, thr_px, smooth_px, rng, counts: dict):
    """Stages 1-3 (module docstring) on refined tracks; fills ``counts`` with the
    observations left after each; returns ``uv`` and the re-estimated epipoles."""
    uv = smoothness_check(uv, epi, smooth_px)
    counts["smooth"] = n_observations(uv)
    uv, epi_final = epipolar_check(uv, thr_px, rng)
    counts["epipolar"] = n_observations(uv)
    uv = multiview_check(uv, epi_final, 3.0 * thr_px)
    counts["multiview"] = n_observations(uv)
    return uv, epi_final
