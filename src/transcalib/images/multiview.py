"""Tracks across views that are each at their own orientation (general motion, no session).

Without a session there is no pure-translation geometry to chain along: every view pair
has only its general epipolar geometry. The tracks are built from the views' SIFT
keypoints (:func:`track_general`):

1. **Match and verify** every view pair (:func:`~.detect.match_pair`, both cores) and fit
   its fundamental matrix (:func:`~.link.fundamental`, USAC MAGSAC; matches moving less
   than 1 px, a static background behind an object carried by the flange, are never
   inliers).
2. **Join** the verified matches into tracks: the connected components of the graph whose
   nodes are ``(view, keypoint)`` and whose edges are the verified matches. A component
   with two different keypoints in one view is contradictory and goes.
3. **Reference**: each track's reference view is the one of its views verified with the
   most of its other views (ties: the first).
4. **Refine** every observation against the reference by affine Lucas-Kanade
   (:func:`~.refine.lk_affine`), the start warp the local affine map of the pair's
   verified matches around the point (:func:`~.local.local_affine`); kept when it
   converged, correlates (NCC), is textured and moved less than ``max_shift_px`` from its
   keypoint.
5. **Extend**: a track is searched in each view it lacks whose pair with the reference is
   verified, where the local affine map of the pair's refined correspondences puts it,
   and aligned the same way (only where that map is nearly affine and not too
   anisotropic: no depth edge, no grazing face).
6. **Epipolar check**: each verified pair's ``F`` is fitted again to the refined
   observations of the tracks both views see; an observation farther than
   ``final_threshold_px`` from its line (against the smooth trend of its neighbours'
   signed distances: lens distortion bends lines smoothly) goes.
7. Static tracks, tracks in fewer than ``min_views`` views go; duplicates merge; at most
   ``max_tracks``, long ones first, spread over the image (:func:`~.checks.keep_tracks`).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .checks import drop_static, keep_tracks, n_observations, select_spread
from .detect import Features, match_pair, n_threads
from .frames import PairInfo
from .link import MIN_LINK_MATCHES, STATIC_LINK_PX, fundamental
from .local import local_affine, local_linear, plain_window
from .refine import SmoothedImages, lk_affine

__all__ = ["GeneralOptions", "GeneralResult", "track_general"]


@dataclass(frozen=True)
class GeneralOptions:
    """Rules of :func:`track_general`.

    Attributes
    ----------
    ratio : float
        Lowe's ratio test of the descriptor matches.
    threshold_px : float
        Epipolar distance (px) of a match accepted by the fundamental matrix.
    final_threshold_px : float
        Epipolar distance (px, detrended) of a refined observation, at most.
    window_radius : int
        Half-size (px) of the Lucas-Kanade window.
    min_ncc : float
        Smallest normalised cross-correlation of an aligned window with its template.
    max_shift_px : float
        Largest move of a refined observation from its keypoint or predicted position.
    iterations : int
        Gauss-Newton steps of the alignment, at most.
    extend : bool
        Search each track in the verified views it lacks (step 5).
    """

    ratio: float = 0.8
    threshold_px: float = 1.5
    final_threshold_px: float = 0.5
    window_radius: int = 8
    min_ncc: float = 0.9
    max_shift_px: float = 4.0
    iterations: int = 24
    extend: bool = True


@dataclass(frozen=True, eq=False)
class GeneralResult:
    """What :func:`track_general` found.

    Attributes
    ----------
    uv : (n_views, n_tracks, 2) float
        Refined tracks, NaN where unseen.
    pairs : tuple of PairInfo
        Every view pair: descriptor matches and those verified by ``F``
        (``source`` ``"fundamental"`` or ``"none"``).
    counts : dict str -> int
        Observations (of tracks in 2+ views) after each step.
    time_s : dict str -> float
        Wall time of each step.
    n_static_dropped : int
    n_conflicting : int
        Components of the match graph with two keypoints in one view (dropped).
    """

    uv: np.ndarray
    pairs: tuple
    counts: dict
    time_s: dict
    n_static_dropped: int
    n_conflicting: int


#: Before the extension (the costliest step) at most this many times ``max_tracks`` tracks
#: are kept, the longest first, spread over the image.
PRESELECT = 2


def _verify(feats: list[Features], opts: GeneralOptions, report):
    """Matches of every pair ``(a, b)``, ``a < b``: ``{(a, b): (F (3, 3), idx (k, 2) int)}``
    (verified keypoint index pairs) and the pairs' :class:`PairInfo`."""
    n = len(feats)
    steps = [(a, b) for a in range(n) for b in range(a + 1, n)]

    def one(ab):
        a, b = ab
        m = match_pair(feats[a].descriptors, feats[b].descriptors, opts.ratio)
        if len(m) < MIN_LINK_MATCHES:
            return ab, len(m), None, m[:0]
        F, inl = fundamental(feats[a].keypoints[m[:, 0]], feats[b].keypoints[m[:, 1]], opts.threshold_px)
        return ab, len(m), F, m[inl] if F is not None else m[:0]

    verified, infos = {}, []
    with ThreadPoolExecutor(n_threads()) as pool:
        for k, (ab, n_m, F, m) in enumerate(pool.map(one, steps)):
            if F is not None:
                verified[ab] = (F, m)
            infos.append(PairInfo(views=ab, n_matches=int(n_m), n_verified=int(len(m)),
                                  source="fundamental" if F is not None else "none"))
            report("match", k + 1, len(steps))
    return verified, tuple(infos)


def _join(feats: list[Features], verified: dict) -> tuple[np.ndarray, int]:
    """Tracks ``uv (n_views, m, 2)`` (keypoint positions) from the connected components of
    the verified matches; components with two keypoints in one view dropped (their count)."""
    n = len(feats)
    off = np.r_[0, np.cumsum([f.n_keypoints for f in feats])]
    view_of = np.repeat(np.arange(n), np.diff(off))
    pos = np.concatenate([f.keypoints for f in feats]) if off[-1] else np.zeros((0, 2))
    edges = [np.column_stack([off[a] + m[:, 0], off[b] + m[:, 1]]) for (a, b), (_, m) in verified.items()]
    edges = np.concatenate(edges) if edges else np.zeros((0, 2), int)
    g = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(off[-1], off[-1]))
    _, comp = connected_components(g, directed=False)
    size = np.bincount(comp)
    node = np.flatnonzero(size[comp] >= 2)
    c, v = comp[node], view_of[node]
    key = c * n + v
    dup = np.bincount(key, minlength=(comp.max() + 1) * n if len(comp) else 0) > 1
    bad = np.zeros(len(size), bool)
    bad[np.unique(key[dup[key]] // n)] = True
    node = node[~bad[c]]
    ids, col = np.unique(comp[node], return_inverse=True)
    uv = np.full((n, len(ids), 2), np.nan)
    uv[view_of[node], col] = pos[node]
    return uv, int(bad.sum())


def _verified_matrix(verified: dict, n: int) -> np.ndarray:
    V = np.zeros((n, n), bool)
    for a, b in verified:
        V[a, b] = V[b, a] = True
    return V


def _references(seen: np.ndarray, V: np.ndarray) -> np.ndarray:
    """``(m,)`` reference view of each track: its view verified with most of its other views."""
    score = np.where(seen, (V.astype(int) @ seen.astype(int)) * 2 + 1, -1)
    return np.argmax(score - np.arange(len(seen))[:, None] * 1e-3, axis=0)


def _pair_points(uv: np.ndarray, verified: dict, feats, a: int, b: int):
    """Correspondences ``(xa, xb)`` of views ``a``, ``b``: the tracks both see, else the
    pair's verified keypoint matches."""
    both = np.isfinite(uv[a, :, 0]) & np.isfinite(uv[b, :, 0])
    if both.sum() >= 12:
        return uv[a, both], uv[b, both]
    F, m = verified[(min(a, b), max(a, b))]
    xa, xb = feats[min(a, b)].keypoints[m[:, 0]], feats[max(a, b)].keypoints[m[:, 1]]
    return (xa, xb) if a < b else (xb, xa)


def _align(smoothed, r, v, x, p0, J, opts: GeneralOptions, shape):
    """Affine LK of the windows at ``x (k, 2)`` of view ``r`` into view ``v`` from ``p0`` with
    start warps ``J (k, 2, 2)``: positions ``(k, 2)``, NaN where not accepted."""
    h, w = shape
    mg = opts.window_radius + 2
    out = np.full((len(x), 2), np.nan)

    def inside(p):
        return (p[:, 0] >= mg) & (p[:, 0] <= w - 1 - mg) & (p[:, 1] >= mg) & (p[:, 1] <= h - 1 - mg)

    ok = np.isfinite(p0).all(1) & np.isfinite(J).all((1, 2)) & inside(x) & inside(np.nan_to_num(p0))
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return out
    p, M, ncc, min_eig, conv = lk_affine(smoothed.plain(r), smoothed[v], x[idx], p0[idx], J[idx], opts.window_radius,
                                         opts.iterations)
    det = np.linalg.det(M)
    good = (conv & (ncc >= opts.min_ncc) & (min_eig > 1.0) & (det > 0.2) & (det < 5.0) & inside(p)
            & (np.linalg.norm(p - p0[idx], axis=1) < opts.max_shift_px))
    out[idx[good]] = p[good]
    return out


#: A pixel is static between two views when a 5 x 5 window around it correlates better than
#: this at zero motion and is textured (local standard deviation above STATIC_MIN_STD in both)
STATIC_NCC = 0.95
STATIC_MIN_STD = 2.0
#: An observation whose window has more than this (Gaussian-weighted) share of static pixels
#: goes: next to the silhouette of an object carried before a static background, or under
#: a burnt-in overlay, part of the window does not move with the point.
MAX_STATIC_SHARE = 0.05


def _static_map(ga: np.ndarray, gb: np.ndarray, radius: int) -> np.ndarray:
    """``(h, w)`` float32: the share of the LK window (Gaussian weights, as
    :func:`~.refine.lk_affine`) around each pixel made of pixels that did not move between
    the grey views ``ga``, ``gb``."""
    a, b = np.asarray(ga, np.float32), np.asarray(gb, np.float32)
    box = (5, 5)
    ma, mb = cv2.blur(a, box), cv2.blur(b, box)
    va = np.maximum(cv2.blur(a * a, box) - ma * ma, 0.0)
    vb = np.maximum(cv2.blur(b * b, box) - mb * mb, 0.0)
    cov = cv2.blur(a * b, box) - ma * mb
    with np.errstate(divide="ignore", invalid="ignore"):
        ncc = cov / np.sqrt(va * vb)
    static = ((ncc > STATIC_NCC) & (np.minimum(va, vb) > STATIC_MIN_STD**2)).astype(np.float32)
    return cv2.GaussianBlur(static, (2 * radius + 1, 2 * radius + 1), 0.5 * radius + 0.5,
                            borderType=cv2.BORDER_REPLICATE)


def _at(img: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Values of ``img (h, w)`` at the nearest pixels of ``x (k, 2)``."""
    h, w = img.shape
    xi = np.clip(np.rint(np.nan_to_num(x[:, 0])).astype(int), 0, w - 1)
    yi = np.clip(np.rint(np.nan_to_num(x[:, 1])).astype(int), 0, h - 1)
    return img[yi, xi]


def _static_windows(grey, uv, ref, V, radius: int, pool) -> np.ndarray:
    """``(n_views, n_tracks)`` bool: the window of the track's reference observation is
    partly static (share above :data:`MAX_STATIC_SHARE`) between its reference view and
    that view; one map per verified pair."""
    n = uv.shape[0]
    out = np.zeros(uv.shape[:2], bool)

    def one(ab):
        a, b = ab
        share = _static_map(grey[a], grey[b], radius)
        ja, jb = np.flatnonzero(ref == a), np.flatnonzero(ref == b)
        return ab, ja, _at(share, uv[a, ja]) > MAX_STATIC_SHARE, jb, _at(share, uv[b, jb]) > MAX_STATIC_SHARE

    for (a, b), ja, fa, jb, fb in pool.map(one, [(a, b) for a in range(n) for b in range(a + 1, n) if V[a, b]]):
        out[b, ja], out[a, jb] = fa, fb
    return out


def _refine(smoothed, uv, ref, fixed, verified, feats, V, opts, shape, pool, report, extend: bool):
    """Step 4 (``extend=False``: the observations there, from their keypoints) or step 5
    (``extend=True``: the verified views a track lacks, from the local affine prediction)."""
    n = uv.shape[0]
    seen = np.isfinite(uv[..., 0])
    steps = [(r, v) for r in range(n) for v in range(n) if v != r and V[r, v]]

    def one(rv):
        r, v = rv
        sel = np.flatnonzero((ref == r) & (~seen[v] if extend else seen[v]) & ~fixed[v])
        if len(sel) == 0:
            return rv, sel, None
        xa, xb = _pair_points(uv, verified, feats, r, v)
        pred, J, res = local_affine(xa, xb, uv[r, sel], return_residual=True)
        if extend:  # only where the window maps nearly affinely, as the links across orientations
            J = np.where(plain_window(J, res)[:, None, None], J, np.nan)
            p0 = pred
        else:
            p0 = uv[v, sel]
        p = _align(smoothed, r, v, uv[r, sel], p0, J, opts, shape)
        moved = np.linalg.norm(p - uv[r, sel], axis=1) >= STATIC_LINK_PX  # NaN (not found) stays NaN
        return rv, sel, np.where(moved[:, None], p, np.nan)

    out = uv.copy()
    if not extend:
        out[~(ref[None] == np.arange(n)[:, None])] = np.nan  # every non-reference observation is found again
    for k, ((r, v), sel, p) in enumerate(pool.map(one, steps)):
        if p is not None:
            out[v, sel] = p
        report("extend" if extend else "refine", k + 1, len(steps))
    return out


def _signed_line_distance(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Signed distance (px) of ``xb (k, 2)`` from the epipolar lines ``F xa``."""
    L = np.column_stack([xa, np.ones(len(xa))]) @ F.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return ((L[:, :2] * xb).sum(1) + L[:, 2]) / np.linalg.norm(L[:, :2], axis=1)


def _epipolar_check(uv, ref, V, opts: GeneralOptions):
    """Step 6: ``uv`` without the observations off their refitted, detrended epipolar line
    with the reference view."""
    n = uv.shape[0]
    out = uv.copy()
    seen = np.isfinite(uv[..., 0])
    for r in range(n):  # a loop over view pairs, vectorised over points
        for v in range(n):
            if v == r or not V[r, v]:
                continue
            both = seen[r] & seen[v]
            mine = both & (ref == r)
            if not mine.any():
                continue
            if both.sum() < MIN_LINK_MATCHES:
                out[v, mine] = np.nan
                continue
            xa, xb = uv[r, both], uv[v, both]
            F, inl = fundamental(xa, xb, max(opts.threshold_px, 2 * opts.final_threshold_px))
            if F is None:
                out[v, mine] = np.nan
                continue
            d = _signed_line_distance(F, xa, xb)
            trust = inl & np.isfinite(d)
            dev = np.abs(d - local_linear(xa[trust], d[trust], xa, k=10)) if trust.sum() >= 4 else np.abs(d)
            bad = ~(np.nan_to_num(dev, nan=np.inf) <= opts.final_threshold_px)
            idx = np.flatnonzero(both)
            out[v, idx[bad & (ref[idx] == r)]] = np.nan
    return out


def track_general(grey: list, feats: list[Features], opts: GeneralOptions, min_views: int, max_tracks: int | None,
                  report) -> GeneralResult:
    """Tracks over views at different orientations (module docstring).

    Parameters
    ----------
    grey : list of (h, w) float32
        The views.
    feats : list of Features
        Their SIFT keypoints and descriptors (:func:`~.detect.detect_all`).
    opts : GeneralOptions
    min_views : int
        Fewest views of a track kept.
    max_tracks : int or None
        Most tracks kept (longest first, spread over the image).
    report : callable ``(stage, done, total)``

    Returns
    -------
    GeneralResult
        ``uv (n_views, n_tracks, 2)`` px, NaN where unseen.
    """
    times, counts = {}, {}
    shape = grey[0].shape[:2]
    n = len(grey)
    t0 = time.perf_counter()
    verified, infos = _verify(feats, opts, report)
    times["match"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    uv, n_conflicting = _join(feats, verified)
    counts["joined"] = n_observations(uv)
    times["chain"] = time.perf_counter() - t0
    V = _verified_matrix(verified, n)
    ref = _references(np.isfinite(uv[..., 0]), V)
    smoothed = SmoothedImages(grey)
    for v in range(n):  # built before the threads share them
        smoothed[v]
    t0 = time.perf_counter()
    with ThreadPoolExecutor(n_threads()) as pool:
        fixed = _static_windows(grey, uv, ref, V, opts.window_radius, pool)
        uv = _refine(smoothed, uv, ref, fixed, verified, feats, V, opts, shape, pool, report, extend=False)
        keep = np.isfinite(uv[..., 0]).sum(0) >= 2
        if max_tracks is not None and keep.sum() > PRESELECT * max_tracks:  # the longest, spread: fewer to extend
            keep = np.flatnonzero(keep)[select_spread(uv[:, keep], PRESELECT * max_tracks, shape, return_index=True)]
        uv, ref, fixed = uv[:, keep], ref[keep], fixed[:, keep]
        counts["refine"] = n_observations(uv)
        times["refine"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        if opts.extend:
            uv = _refine(smoothed, uv, ref, fixed, verified, feats, V, opts, shape, pool, report, extend=True)
            counts["extend"] = n_observations(uv)
        times["extend"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    uv = _epipolar_check(uv, ref, V, opts)
    counts["epipolar"] = n_observations(uv)
    uv = uv[:, np.isfinite(uv[..., 0]).sum(0) >= 2]
    uv, n_static = drop_static(uv)
    uv = keep_tracks(uv, min_views, max_tracks, shape)
    counts["kept"] = n_observations(uv)
    times["checks"] = time.perf_counter() - t0
    return GeneralResult(uv=uv, pairs=infos, counts=counts, time_s=times, n_static_dropped=n_static,
                         n_conflicting=n_conflicting)
