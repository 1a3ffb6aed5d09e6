"""Chaining: each point followed through every view of its session along its epipolar lines.

A point is seeded once, at a corner of the first view that sees it (its reference view
``r``), and searched for in every other view ``j`` of the session where it should be:
on its epipolar line ``x_j = x_r + rho (e3 x_r - e_xy)``, at the ``rho`` its neighbours
have (:func:`~.local.local_linear` of the verified matches of the pair and of the points
already tracked: inverse depth is smooth on surfaces). Pyramidal Lucas-Kanade
(``cv2.calcOpticalFlowPyrLK``) starts there; a result is
kept when it comes back to the seed (forward-backward within ``fb_px``) and lies on its
epipolar line (its distance judged against the trend of the verified matches nearby,
which tolerates lens distortion). The seeds of a pair are searched nearest-to-the-known
first, in rounds, and the points found join the sources of the next round, so a
repetitive texture (a checkerboard) is crossed step by step, never predicted from afar.

Views after the first seed only the corners no earlier track covers. Tracks found here
are aligned precisely later (:mod:`.refine`); :func:`predict_missing` proposes where the
views a track still lacks should see it (its depth from all its views), for the same
alignment: re-detection along the epipolar lines.
"""

from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .detect import n_threads, to_u8
from .epipoles import MOVING_PX, direction, pair_epipole, residuals, signed_distance
from .local import local_linear

__all__ = ["PropagateOptions", "Pyramids", "propagate", "predict_missing", "depth_scales", "static_tracks"]

#: A track moving less than this (px) in every view while the scene moves at least
#: ``STATIC_MIN_FACTOR`` times more between the same views is static.
STATIC_PX = 1.0
STATIC_MIN_FACTOR = 10.0


@dataclass(frozen=True)
class PropagateOptions:
    """How points are followed through a session.

    Attributes
    ----------
    window_px : int
        Side of the pyramidal Lucas-Kanade window.
    levels : int
        Pyramid levels above the image.
    fb_px : float
        Largest forward-backward error of a kept result.
    threshold_px : float
        Largest distance from the epipolar line (against the local trend).
    max_seeds : int
        Seeds of the whole session, at most (spread over the images).
    min_spacing_px : float
        A corner nearer than this to a point already tracked in its view is not seeded.
    rounds : int
        Batches of seeds per view pair, nearest to the sources first.
    """

    window_px: int = 21
    levels: int = 3
    fb_px: float = 0.75
    threshold_px: float = 1.5
    max_seeds: int = 2000
    min_spacing_px: float = 5.0
    rounds: int = 3


class Pyramids:
    """The views as 8-bit images for pyramidal Lucas-Kanade (OpenCV's Python binding
    builds the pyramids on each call), with the window and the number of levels."""

    def __init__(self, grey: list, window_px: int, levels: int):
        self.images = [to_u8(g) for g in grey]
        self.win, self.levels = (window_px, window_px), levels

    def __getitem__(self, v: int) -> np.ndarray:
        return self.images[v]


def _lk(pyr: Pyramids, a: int, b: int, pts: np.ndarray, guess: np.ndarray, levels: int):
    """Pyramidal LK of ``pts`` in view ``a`` into view ``b`` from ``guess``: ``(found (m, 2), ok (m,))``."""
    if len(pts) == 0:
        return np.zeros((0, 2)), np.zeros(0, bool)
    p0 = np.ascontiguousarray(pts, np.float32).reshape(-1, 1, 2)
    p1 = np.ascontiguousarray(guess, np.float32).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    p1, st, _ = cv2.calcOpticalFlowPyrLK(pyr[a], pyr[b], p0, p1, winSize=pyr.win, maxLevel=levels,
                                         criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    found = p1.reshape(-1, 2).astype(float)
    return found, st.ravel().astype(bool) & np.all(np.isfinite(found), axis=1)


def _identity(v, x):
    return x


def _follow(pyr, r, j, seeds, sources, e, static, opts, shape, to_model=_identity, to_image=_identity):
    """Search ``seeds`` of view ``r`` in view ``j``: ``(m, 2)`` image positions, NaN where not found.

    ``sources``: ``(x_r (k, 2), x_j (k, 2))`` verified correspondences of the pair, in
    model pixels (derotated: :class:`~.derotate.Derotation`), where ``e`` holds;
    ``to_model(view, x)``, ``to_image(view, x)`` map between the two.
    """
    h, w = shape
    out = np.full(seeds.shape, np.nan)
    src_r, src_j = sources
    if static:  # no motion between these views: the point stays where it is
        found, ok = _lk(pyr, r, j, seeds, seeds, 1)
        ok &= np.linalg.norm(found - seeds, axis=1) < 2 * MOVING_PX
        out[ok] = found[ok]
        return out
    if e is None or len(src_r) < 4 or len(seeds) == 0:
        return out
    seeds_m = to_model(r, seeds)
    d_near = cKDTree(src_r).query(seeds_m)[0]
    order = np.argsort(d_near, kind="stable")
    # far from every source (a checkerboard without descriptor matches): step by step
    rounds = opts.rounds if np.median(d_near) > 3 * opts.window_px else 1
    for batch in np.array_split(order, max(1, min(rounds, len(seeds) // 50 + 1))):
        x = seeds_m[batch]
        _, rho_src = residuals(e, src_r, src_j)
        # the neighbours' inverse depth and their trend of epipolar distances (lens distortion)
        fit = local_linear(src_r, np.column_stack([rho_src, signed_distance(e, src_r, src_j)]), x, k=10)
        rho, trend = fit[:, 0], fit[:, 1]
        pred = to_image(j, x + np.nan_to_num(rho, nan=0.0)[:, None] * direction(e, x))
        inside = (np.isfinite(rho) & (pred[:, 0] >= 0) & (pred[:, 0] <= w - 1) & (pred[:, 1] >= 0)
                  & (pred[:, 1] <= h - 1))
        x_img = seeds[batch][inside]
        found, ok = _lk(pyr, r, j, x_img, pred[inside], pyr.levels)
        # back at the finest level only, from the seed itself: a consistent track leads
        # back there within fb_px (the pyramid's coarse search is the forward one's need;
        # the chain's LK CPU 0.24 -> 0.14 s, 13 of 5366 observations fewer on the speed
        # benchmark's 4 views of 800 x 600)
        back, okb = _lk(pyr, j, r, found, x_img, 0)
        ok &= okb & (np.linalg.norm(back - x_img, axis=1) < opts.fb_px)
        idx = np.flatnonzero(inside)[ok]
        if len(idx) == 0:
            continue
        xi, yj, yj_img = x[idx], to_model(j, found[ok]), found[ok]
        _, rho_f = residuals(e, xi, yj)
        dev = np.abs(signed_distance(e, xi, yj) - np.nan_to_num(trend[idx], nan=np.inf))
        moving = np.linalg.norm(yj - xi, axis=1) >= MOVING_PX
        good = (dev < opts.threshold_px) & ((rho_f > 0) | ~moving)
        out[batch[idx[good]]] = yj_img[good]
        src_r, src_j = np.vstack([src_r, xi[good]]), np.vstack([src_j, yj[good]])
    return out


def _spread(points: np.ndarray, k: int, shape, cells: int = 24) -> np.ndarray:
    """Indices of at most ``k`` of ``points`` (ordered strongest first), spread over a grid:
    round-robin over the occupied cells, strongest first within each."""
    if len(points) <= k:
        return np.arange(len(points))
    h, w = shape
    cell = (np.clip(points[:, 0] / w * cells, 0, cells - 1).astype(int) * cells
            + np.clip(points[:, 1] / h * cells, 0, cells - 1).astype(int))
    order = np.lexsort((np.arange(len(points)), cell))
    cs = cell[order]
    start = np.r_[0, np.flatnonzero(np.diff(cs)) + 1]
    rank = np.empty(len(points), int)
    rank[order] = np.arange(len(points)) - np.repeat(start, np.diff(np.r_[start, len(points)]))
    return np.sort(np.lexsort((np.arange(len(points)), rank))[:k])


def propagate(pyr: Pyramids, corners: list, geo: dict, sources: dict, opts: PropagateOptions, shape,
              report=None, derotation=None) -> np.ndarray:
    """Tracks of one session: ``uv (n_views, n_tracks, 2)`` image pixels, NaN where not found.

    Parameters
    ----------
    pyr : Pyramids
        Of the session's views ``0 .. n_views - 1``.
    corners : list of (m_v, 2) float
        Corners of each view, strongest first.
    geo : dict ``(i, j) -> PairGeometry``
        The verified pairs (``i < j``).
    sources : dict ``(i, j) -> (x_i, x_j)``
        Verified matches of each pair (``i < j``), in model pixels.
    opts : PropagateOptions
    shape : (h, w)
    report : callable ``(stage, done, total)``, optional
    derotation : Derotation, optional
        Image <-> model pixels (:mod:`.derotate`): the epipoles of ``geo`` hold between
        model pixels; the corners, Lucas-Kanade and the result are in image pixels.
    """
    to_model = _identity if derotation is None else derotation.to_model
    to_image = _identity if derotation is None else derotation.to_image
    n = len(corners)
    uv = np.zeros((n, 0, 2))
    steps, done = n * (n - 1), 0
    with ThreadPoolExecutor(n_threads()) as pool:  # the views j of one reference on both cores
        for r in range(n):
            cand = np.asarray(corners[r], float).reshape(-1, 2)
            seen_r = np.isfinite(uv[r, :, 0])
            if seen_r.any() and len(cand):
                cand = cand[cKDTree(uv[r, seen_r]).query(cand)[0] >= opts.min_spacing_px]
            seeds = cand[_spread(cand, max(0, opts.max_seeds - uv.shape[1]), shape)]
            obs = np.full((n, len(seeds), 2), np.nan)
            obs[r] = seeds

            def follow(j, r=r, seeds=seeds):
                g = geo.get((min(r, j), max(r, j)))
                return _follow(pyr, r, j, seeds, _sources(sources, uv, r, j, to_model), pair_epipole(geo, r, j),
                               bool(g is not None and g.static), opts, shape, to_model, to_image)

            others = [j for j in range(n) if j != r]
            for j, found in zip(others, pool.map(follow, others) if len(seeds) else [None] * len(others)):
                done += 1
                if found is not None:
                    obs[j] = found
                if report is not None:
                    report("chain", done, steps)
            # static points (the background behind an object the robot carries) go now:
            # they would take the seeds of the moving ones
            static = static_tracks(np.concatenate([uv, obs], axis=1))[uv.shape[1]:]  # judged among all tracks
            keep = (np.isfinite(obs[..., 0]).sum(0) >= 2) & ~static
            uv = np.concatenate([uv, obs[:, keep]], axis=1)
    return uv


def _sources(sources: dict, uv: np.ndarray, r: int, j: int, to_model=_identity):
    """Correspondences ``(x_r, x_j)`` of views ``r``, ``j`` in model pixels: the pair's
    verified matches and the tracks (image pixels ``uv``) already seen in both."""
    if (r, j) in sources:
        a, b = sources[(r, j)]
    elif (j, r) in sources:
        b, a = sources[(j, r)]
    else:
        a = b = np.zeros((0, 2))
    both = np.isfinite(uv[r, :, 0]) & np.isfinite(uv[j, :, 0])
    return np.vstack([a, to_model(r, uv[r, both])]), np.vstack([b, to_model(j, uv[j, both])])


def static_tracks(uv: np.ndarray, static_px: float = STATIC_PX, factor: float = STATIC_MIN_FACTOR) -> np.ndarray:
    """``(n_tracks,)`` bool: the tracks that do not move while the scene does.

    A static point is consistent with every epipole (``rho = 0``), so the epipolar tests
    pass it; under pure translation only a point at infinity stays put, and it carries no
    information on K (a burnt-in overlay, dust on the lens, the static background behind
    an object carried by the robot). A track is static when it moves less than
    ``static_px`` between every two of its views while the moving tracks (those moving
    more than ``static_px``) seen in the same two views move at least
    ``factor * static_px`` (median).
    """
    n_views, n_pts = uv.shape[:2]
    seen = np.isfinite(uv[..., 0])
    moved, expected = np.zeros(n_pts), np.zeros(n_pts)
    for i in range(n_views):
        for j in range(i + 1, n_views):
            both = np.flatnonzero(seen[i] & seen[j])
            disp = np.linalg.norm(uv[j, both] - uv[i, both], axis=1)
            moved[both] = np.maximum(moved[both], disp)
            if (disp >= static_px).sum() >= 5:
                expected[both] = np.maximum(expected[both], np.median(disp[disp >= static_px]))
    return (moved < static_px) & (expected >= factor * static_px)


def depth_scales(uv: np.ndarray, epi: dict, r: int, sel: np.ndarray):
    """The multi-view depth relation of the tracks ``sel`` with reference view ``r``.

    With ``x_j = x_r + rho_j (e3 x_r - e_xy)`` for the pair's unit epipole ``e`` (true
    epipole ``s_j e``), ``q_j = 1 / (1 / rho_j + e3) = s_j w`` exactly, ``w`` the point's
    inverse depth in view ``r``. Returns ``q (n_views, m)`` (NaN where unseen), the scales
    ``s (n_views,)`` relative to the view seeing most (robust medians of ratios, NaN where
    unknown) and the epipoles ``{j: e_rj}``.
    """
    n = uv.shape[0]
    xr = uv[r, sel]
    q = np.full((n, len(sel)), np.nan)
    E = {}
    for j in range(n):
        e = pair_epipole(epi, r, j) if j != r else None
        if e is None:
            continue
        E[j] = e
        _, rho = residuals(e, xr, uv[j, sel])
        with np.errstate(divide="ignore", invalid="ignore"):
            q[j] = 1.0 / (1.0 / rho + e[2])
    s = np.full(n, np.nan)
    cnt = np.isfinite(q).sum(1)
    if cnt.max(initial=0) < 5:
        return q, s, E
    j0 = int(np.argmax(cnt))
    s[j0] = 1.0
    for j in E:
        both = np.isfinite(q[j]) & np.isfinite(q[j0]) & (np.abs(q[j0]) > 1e-12)
        if j != j0 and both.sum() >= 5:
            s[j] = np.median(q[j, both] / q[j0, both])
    return q, s, E


def predict_missing(uv: np.ndarray, epi: dict, shape, margin_px: float) -> np.ndarray:
    """Where each track should be seen in the views it lacks: ``(n_views, n_tracks, 2)``,
    NaN where no prediction (or outside the image by ``margin_px``).

    The track's inverse depth ``w`` in its reference view is the median of ``q_j / s_j``
    over its views (:func:`depth_scales`); in a view ``j`` it lacks,
    ``rho_j = 1 / (1 / (s_j w) - e3)`` puts it on its epipolar line.
    """
    n, m = uv.shape[:2]
    h, w = shape
    out = np.full(uv.shape, np.nan)
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    for r in range(n):
        sel = np.flatnonzero((ref == r) & (seen.sum(0) >= 2))
        if len(sel) == 0:
            continue
        q, s, E = depth_scales(uv, epi, r, sel)
        with np.errstate(all="ignore"):
            wq = q / s[:, None]
        if not np.isfinite(wq).any():
            continue
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: no prediction, wanted
            w_pt = np.nanmedian(wq, axis=0)
        xr = uv[r, sel]
        for j, e in E.items():
            if not np.isfinite(s[j]):
                continue
            miss = ~seen[j, sel] & np.isfinite(w_pt)
            if not miss.any():
                continue
            with np.errstate(all="ignore"):
                rho = 1.0 / (1.0 / (s[j] * w_pt[miss]) - e[2])
            p = xr[miss] + rho[:, None] * direction(e, xr[miss])
            ok = (np.isfinite(p).all(1) & (p[:, 0] >= margin_px) & (p[:, 0] <= w - 1 - margin_px)
                  & (p[:, 1] >= margin_px) & (p[:, 1] <= h - 1 - margin_px))
            out[j, sel[miss][ok]] = p[ok]
    return out
