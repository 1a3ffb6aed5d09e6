"""Image front-end: images taken at pure translations -> point tracks.

Stages (each timed in ``Tracks.info["time_s"]``):

1. **detect** - SIFT keypoints and descriptors, plus Shi-Tomasi corners refined with
   ``cv2.cornerSubPix`` (corners carry repetitive textures such as checkerboards).
2. **match** - SIFT descriptors between **all** view pairs (exact nearest neighbours
   from one matrix product per pair), with Lowe's ratio test and a mutual check.
3. **verify** - under pure translation the fundamental matrix of every view pair is
   ``F = [e]_x``: the epipole ``e`` is the same point in both images and ``x``, ``x'``,
   ``e`` are collinear. Two correspondences fix ``e`` (the intersection of the lines
   ``x1 x1'`` and ``x2 x2'``), so a 2-point RANSAC rejects mismatches. Writing
   ``x' = x + rho (e3 x - e_xy)``, ``rho = 1 / depth'`` must have one sign for all
   points (cheirality). The epipoles of all pairs must be consistent: ``e_ik`` lies on
   the line through ``e_ij`` and ``e_jk`` (``t_ik = t_ij + t_jk``); a pair that fails
   this in every triplet (repetitive textures can make a wrong epipole win) is
   re-estimated by a 1-point RANSAC on that line. Corners, whose descriptors are
   ambiguous on repetitive textures, are then matched **guided by the epipole**: their
   ``rho`` is interpolated from the verified matches nearby, the prediction is snapped to
   the nearest corner of the other view (only if clearly nearer than the second
   nearest, and both ways), and matches whose depth disagrees with their neighbours'
   are dropped.
4. **chain** - verified matches, best first, are joined into tracks by union-find; an
   edge that would put two features of one view into a track is skipped, so a mismatch
   cannot glue two tracks together.
5. **refine** - every observation is aligned to the track's reference view (its first)
   by Lucas-Kanade with an affine warp and gain/offset (batched Gauss-Newton over all
   tracks, bicubic sampling): sub-pixel accuracy, insensitive to brightness changes.
   Observations that do not converge or correlate poorly are dropped. Then checks on
   the refined tracks: local depth smoothness, epipoles re-estimated from the refined
   points (each observation judged against its neighbours' trend, which tolerates lens
   distortion), and depth consistency across 3+ views
   (``q_j = 1 / (1 / rho_j + e3) = s_j w`` with one inverse depth ``w`` per point).

Coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..types import DegenerateError, InputError
from ..validate import COPLANAR_RTOL
from .frames import Tracks, _progress_fn, load_images

__all__ = ["track_features", "epipole_ransac", "RotatedViewsError"]


class RotatedViewsError(DegenerateError):
    """Some view pairs were taken with a rotation between them: the pure-translation
    tracker cannot track them (a :class:`DegenerateError`; the message names the pairs)."""

log = logging.getLogger("transcalib.tracks")


# --------------------------------------------------------------------------- epipole
def _direction(e: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``e3 x - e_xy`` ``(n, 2)``: direction of the epipolar line from ``e`` through ``x``."""
    return e[2] * x - e[:2]


def _epi_residual(e: np.ndarray, x: np.ndarray, y: np.ndarray):
    """Distance of ``y`` from the epipolar line through ``x`` (px) and ``rho`` per match.

    ``y = x + rho (e3 x - e_xy) + perpendicular residual``.
    """
    d = _direction(e, x)
    nd = np.linalg.norm(d, axis=-1)
    disp = y - x
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.abs(d[..., 0] * disp[..., 1] - d[..., 1] * disp[..., 0]) / nd
        rho = (disp * d).sum(-1) / nd**2
    small = np.linalg.norm(disp, axis=-1) < 0.5  # negligible motion: any line fits
    dist = np.where(small, np.linalg.norm(disp, axis=-1) * 0.0, dist)
    dist = np.where(np.isfinite(dist), dist, np.inf)
    return dist, rho


def _normalised_lines(x, y):
    """Lines through ``x`` and ``y`` (homogeneous, unit normal)."""
    xh = np.column_stack([x, np.ones(len(x))])
    yh = np.column_stack([y, np.ones(len(y))])
    L = np.cross(xh, yh)
    n = np.linalg.norm(L[:, :2], axis=1, keepdims=True)
    return L / np.where(n > 0, n, 1.0)


def _fit_epipole(x, y, scale):
    """Least-squares common point of the lines ``x_k y_k`` (unit 3-vector)."""
    L = _normalised_lines(x, y)
    Hn = np.diag([1.0 / scale, 1.0 / scale, 1.0])  # condition: image units ~ 1
    # line l in pixels, point e in pixels: l . e ; with e = Hinv e_n  ->  (Hinv^T l) . e_n
    Ln = L @ np.linalg.inv(Hn).T
    e_n = np.linalg.svd(Ln, full_matrices=False)[2][-1]
    e = np.linalg.inv(Hn) @ e_n
    return e / np.linalg.norm(e)


def _hypothesis_residuals(E: np.ndarray, x: np.ndarray, y: np.ndarray):
    """Epipolar distance and signed displacement of matches ``x -> y`` (m, 2) under each
    hypothesised epipole ``E`` (h, 3, homogeneous): ``(dist (h, m), rho (h, m))``."""
    d = E[:, None, 2:3] * x[None] - E[:, None, :2]  # direction from the epipole to x
    dv = (y - x)[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.abs(d[..., 0] * dv[..., 1] - d[..., 1] * dv[..., 0]) / np.linalg.norm(d, axis=-1)
    return dist, (dv * d).sum(-1)


def epipole_ransac(x: np.ndarray, y: np.ndarray, *, threshold_px: float = 1.5, iterations: int = 400, rng=None,
                   detrend: bool = False):
    """Epipole of a pure translation from correspondences ``x -> y`` (2-point RANSAC).

    Parameters
    ----------
    x, y : (n, 2) float
        Matched pixels in two views.
    threshold_px : float
        Inlier distance of ``y`` from the epipolar line through ``x``.
    iterations : int
    rng : seed or Generator
    detrend : bool
        Measure each match's epipolar distance against the local trend of its
        neighbours' (smooth deviations from straight epipolar lines come from lens
        distortion; mismatches deviate alone).

    Returns
    -------
    e : (3,) float or None
        Homogeneous epipole, unit norm, signed so that ``rho > 0`` (``e ~ A (T_j - T_i)``);
        None if there are fewer than 3 inliers.
    inliers : (n,) bool
    rho : (n,) float
        ``y = x + rho (e3 x - e_xy)``: ``rho`` is proportional to the inverse depth in
        the second view.
    """
    rng = np.random.default_rng(rng)
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    n = len(x)
    none = (None, np.zeros(n, bool), np.full(n, np.nan))
    if n < 3:
        return none
    disp = np.linalg.norm(y - x, axis=1)
    if np.median(disp) < 0.5:  # no motion between these views: nothing to verify
        return none
    scale = max(np.abs(x).max(), 1.0)
    L = _normalised_lines(x, y)
    moving = disp >= 0.5
    idx = np.flatnonzero(moving)
    if len(idx) < 2:
        return none
    pairs = rng.integers(0, len(idx), size=(iterations, 2))
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    E = np.cross(L[idx[pairs[:, 0]]], L[idx[pairs[:, 1]]])
    En = np.linalg.norm(E, axis=1)
    E = E[En > 1e-12] / En[En > 1e-12, None]
    if len(E) == 0:
        return none
    # score every hypothesis on every match (vectorised): count inliers with rho of the majority sign
    dist, rho = _hypothesis_residuals(E, x, y)
    ok = (dist < threshold_px) | ~moving[None]
    pos = (ok & ((rho > 0) | ~moving[None])).sum(1)
    neg = (ok & ((rho < 0) | ~moving[None])).sum(1)
    score = np.maximum(pos, neg)
    b = int(np.argmax(score))
    e = E[b] * (1.0 if pos[b] >= neg[b] else -1.0)
    for _ in range(3):  # refit on inliers, then re-score
        dist, rho = _epi_residual(e, x, y)
        inl = (dist < threshold_px) & ((rho > 0) | ~moving)
        if inl.sum() < 3:
            return none
        m = inl & moving
        if m.sum() >= 2:
            e_new = _fit_epipole(x[m], y[m], scale)
            # keep the sign: majority rho > 0
            _, r_new = _epi_residual(e_new, x[m], y[m])
            e = e_new if np.sum(r_new > 0) >= np.sum(r_new < 0) else -e_new
    dist, rho = _epi_residual(e, x, y)
    inl = (dist < threshold_px) & ((rho > 0) | ~moving)
    if detrend and inl.sum() >= 12:
        # lens distortion bends epipolar lines smoothly: judge each match against the
        # local trend of its neighbours' signed residuals, not against the straight line
        for _ in range(2):
            dev = _detrended(x, _epi_signed(e, x, y), inl)
            inl = (dev < threshold_px) & ((rho > 0) | ~moving)
    return e, inl, rho


def _epi_signed(e, x, y):
    """Signed distance (px) of ``y`` from the epipolar line through ``x``."""
    d = _direction(e, x)
    disp = y - x
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (d[:, 0] * disp[:, 1] - d[:, 1] * disp[:, 0]) / np.linalg.norm(d, axis=1)
    return np.where(np.linalg.norm(disp, axis=1) < 0.5, 0.0, r)


def _detrended(x, r, trusted, k=10):
    """``|r - trend|``: ``trend`` a local linear fit to the ``trusted`` points' values
    ``r`` near each point (itself excluded)."""
    sel = trusted & np.isfinite(r)
    if sel.sum() < 4:
        return np.abs(r)
    trend = _local_rho_linear(x[sel], r[sel], x, k=k)
    return np.nan_to_num(np.abs(r - trend), nan=np.inf)


# --------------------------------------------------------------------------- detection
def _to_u8(g):
    return np.clip(np.rint(g), 0, 255).astype(np.uint8)


def _detect(grey, max_features, max_corners, corner_quality):
    sift = cv2.SIFT_create(nfeatures=max_features, contrastThreshold=0.02)
    feats = []
    for g in grey:
        u8 = _to_u8(g)
        kps, desc = sift.detectAndCompute(u8, None)
        pts = np.array([k.pt for k in kps], float).reshape(-1, 2)
        size = np.array([k.size for k in kps], float)
        if desc is None:
            desc = np.zeros((0, 128), np.float32)
        c = cv2.goodFeaturesToTrack(g, maxCorners=max_corners, qualityLevel=corner_quality, minDistance=6,
                                    blockSize=5)
        if c is None:
            corners = np.zeros((0, 2), float)
        else:
            c = cv2.cornerSubPix(g, c.astype(np.float32), (4, 4), (-1, -1),
                                 (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-3))
            corners = c.reshape(-1, 2).astype(float)
        feats.append({"sift": pts, "size": size, "desc": desc, "corners": corners})
    return feats


def _match_pair(d1, d2, ratio):
    """Mutual nearest neighbours passing the ratio test: index pairs ``(k, 2)``.

    Exact (brute force): squared distances from one matrix product, whose row and
    column minima give both matching directions.
    """
    if len(d1) < 2 or len(d2) < 2:
        return np.zeros((0, 2), int)
    a = np.ascontiguousarray(d1, np.float32)
    b = np.ascontiguousarray(d2, np.float32)
    D = (a * a).sum(1)[:, None] + (b * b).sum(1)[None] - 2.0 * (a @ b.T)
    np.maximum(D, 0.0, out=D)
    r2 = np.float32(ratio * ratio)

    def best_two(D, axis):
        arg = D.argmin(axis)
        idx = (np.arange(D.shape[0]), arg) if axis == 1 else (arg, np.arange(D.shape[1]))
        best = D[idx].copy()
        D[idx] = np.inf
        second = D.min(axis)
        D[idx] = best
        return arg, best < r2 * second

    ja, ok_a = best_two(D, 1)
    ib, ok_b = best_two(D, 0)
    i = np.flatnonzero(ok_a)
    j = ja[i]
    mutual = ok_b[j] & (ib[j] == i)
    return np.column_stack([i[mutual], j[mutual]])


def _local_rho(seeds_x, seeds_rho, query, k=6):
    """Median ``rho`` of the ``k`` nearest seeds of each query point (a seed at the
    query's own position is skipped, so a point never votes for itself)."""
    tree = cKDTree(seeds_x)
    kk = min(k + 1, len(seeds_x))
    dd, nn = tree.query(query, k=kk)
    dd, nn = dd.reshape(len(query), kk), nn.reshape(len(query), kk)
    r = np.where(dd > 1e-9, seeds_rho[np.minimum(nn, len(seeds_x) - 1)], np.nan)
    # keep the k nearest non-self neighbours
    r = np.where(np.cumsum(np.isfinite(r), axis=1) <= k, r, np.nan)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(r, axis=1) if r.size else np.zeros(len(query))


def _local_rho_linear(seeds_x, seeds_rho, query, k=10, keep=0.7):
    """``rho`` at each query from a trimmed local linear fit ``rho = a + b du + c dv`` to
    its ``k`` nearest seeds (itself excluded): inverse depth is affine in the image on a
    plane, so this is exact for planar surfaces and robust to a few mismatches."""
    m = len(seeds_x)
    if m < 4:
        return _local_rho(seeds_x, seeds_rho, query, k)
    kk = min(k + 1, m)
    dd, nn = cKDTree(seeds_x).query(query, k=kk)
    dd, nn = dd.reshape(len(query), kk), nn.reshape(len(query), kk)
    w = (dd > 1e-9).astype(float)
    w *= np.cumsum(w, axis=1) <= k
    nn = np.minimum(nn, m - 1)
    d = seeds_x[nn] - query[:, None, :]
    scale = np.maximum(np.sqrt((w * (d**2).sum(-1)).sum(1) / np.maximum(w.sum(1), 1)), 1e-6)[:, None, None]
    A = np.concatenate([np.ones(d.shape[:2] + (1,)), d / scale], axis=-1)
    y = seeds_rho[nn]
    reg = 1e-6 * np.eye(3)
    n_nb = np.maximum((w > 0).sum(1), 1)  # neighbours actually there (few seeds: fewer than k)
    rank = np.clip(np.maximum(3, (keep * np.minimum(n_nb, k)).astype(int)) - 1, 0, kk - 1)
    for _ in range(2):
        Aw = A * w[..., None]
        coef = np.linalg.solve(np.einsum("nka,nkb->nab", Aw, A) + reg, np.einsum("nka,nk->na", Aw, y)[..., None])[..., 0]
        r = np.abs(np.einsum("nka,na->nk", A, coef) - y)
        r = np.where(w > 0, r, np.inf)
        cut = np.take_along_axis(np.sort(r, axis=1), rank[:, None], axis=1)
        w = w * (r <= cut)
    return coef[:, 0]


def _predict(e, seeds_x, seeds_rho, query, k=6):
    """Predict positions in the other view of ``query`` points from nearby seeds' rho."""
    rho = _local_rho(seeds_x, seeds_rho, query, k)
    return query + np.nan_to_num(rho)[:, None] * _direction(e, query)


def _guided_corners(ci, cj, e, xi, xj, threshold_px, rounds=2):
    """Match corners ``ci`` (view i) to ``cj`` (view j) guided by the epipole ``e``.

    Seeds ``xi -> xj`` (verified descriptor matches) give ``rho`` (inverse depth) near
    each corner; matched corners then become seeds themselves (``rounds`` times), and a
    match whose ``rho`` disagrees with its neighbours' is dropped (depth smoothness),
    which rejects the one-cell shifts that repetitive textures invite.
    """
    none = np.zeros((0, 2), int)
    if len(ci) == 0 or len(cj) == 0 or len(xi) < 3:
        return none
    pairs = _guided_once(ci, cj, e, xi, xj, threshold_px)
    sp = _spacing(cj)
    for _ in range(rounds):
        if len(pairs) == 0:
            return pairs
        si = np.vstack([xi, ci[pairs[:, 0]]])
        sj = np.vstack([xj, cj[pairs[:, 1]]])
        pairs = _guided_once(ci, cj, e, si, sj, threshold_px)
        if len(pairs) == 0:
            return pairs
        # smoothness: rho of each match vs the median of its matched neighbours
        mi, mj = ci[pairs[:, 0]], cj[pairs[:, 1]]
        _, rho = _epi_residual(e, mi, mj)
        _, rho_s = _epi_residual(e, xi, xj)
        rho_nb = _local_rho(np.vstack([xi, mi]), np.r_[rho_s, rho], mi, k=6)
        dev = np.abs(rho - rho_nb) * np.linalg.norm(_direction(e, mi), axis=1)
        pairs = pairs[np.nan_to_num(dev, nan=np.inf) < 0.3 * sp]
    return pairs


def _spacing(c):
    if len(c) < 2:
        return 10.0
    return float(np.median(cKDTree(c).query(c, k=2)[0][:, 1]))


def _guided_once(ci, cj, e, xi, xj, threshold_px):
    _, rho_ij = _epi_residual(e, xi, xj)
    _, rho_ji = _epi_residual(-e, xj, xi)
    pred_j = _predict(e, xi, rho_ij, ci)
    pred_i = _predict(-e, xj, rho_ji, cj)
    tj, ti = cKDTree(cj), cKDTree(ci)
    # accept the nearest corner only if it is much nearer than the second nearest (so a
    # repeated neighbour is never taken) and within ``max_radius`` px; both ways
    max_radius = 40.0

    def nearest(tree, pts, n_tree):
        d, nn = tree.query(pts, k=min(2, n_tree))
        d, nn = d.reshape(len(pts), -1), nn.reshape(len(pts), -1)
        d2 = d[:, 1] if d.shape[1] > 1 else np.full(len(pts), np.inf)
        return nn[:, 0], (d[:, 0] < max_radius) & (d[:, 0] < 0.5 * d2)

    nj, okj = nearest(tj, pred_j, len(cj))
    ni, oki = nearest(ti, pred_i, len(ci))
    a = np.arange(len(ci))
    njc = np.minimum(nj, len(cj) - 1)
    ok = okj & oki[njc] & (ni[njc] == a)
    pairs = np.column_stack([a[ok], nj[ok]])
    if len(pairs):
        mi, mj = ci[pairs[:, 0]], cj[pairs[:, 1]]
        _, rho = _epi_residual(e, mi, mj)
        allx = np.vstack([xi, mi])
        r = np.r_[_epi_signed(e, xi, xj), _epi_signed(e, mi, mj)]
        trusted = np.r_[np.ones(len(xi), bool), np.zeros(len(mi), bool)]
        dev = _detrended(allx, r, trusted)[len(xi):]
        pairs = pairs[(dev < threshold_px) & (rho > -1e-3)]
    return pairs


# --------------------------------------------------------------------------- refinement
def _sample(img, x, y):
    """Bicubic samples of ``img`` at float arrays ``x, y`` of shape (m, P) (m*P any)."""
    m, P = x.shape
    out = np.empty((m, P), np.float32)
    step = max(1, 30000 // max(P, 1))
    for r0 in range(0, m, step):
        out[r0:r0 + step] = cv2.remap(img, x[r0:r0 + step].astype(np.float32), y[r0:r0 + step].astype(np.float32),
                                      cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    return out


def _lk_affine(ref_img, ref_gx, tgt, tgt_gx, tgt_gy, p_ref, p0, M0, radius, iterations=15):
    """Batched Lucas-Kanade: align patches of ``tgt`` to template patches of ``ref_img``.

    Warp: ``x_tgt = p + M o`` for template offsets ``o`` around ``p_ref``; photometric
    ``a I_tgt + b``. Returns refined ``p (m, 2)``, ``M (m, 2, 2)``, ``ncc (m,)``,
    ``min_eig (m,)`` (texture strength), ``converged (m,)``.
    """
    m = len(p_ref)
    r = np.arange(-radius, radius + 1, dtype=float)
    ox, oy = [a.ravel() for a in np.meshgrid(r, r)]
    sig = 0.5 * radius + 0.5
    wgt = np.exp(-(ox**2 + oy**2) / (2 * sig**2))
    Tm = _sample(ref_img, p_ref[:, :1] + ox[None], p_ref[:, 1:2] + oy[None]).astype(float)
    p = p0.astype(float).copy()
    M = M0.astype(float).copy()
    a = np.ones(m)
    b = np.zeros(m)
    conv = np.zeros(m, bool)
    active = np.ones(m, bool)
    last_step = np.full(m, np.inf)
    for _ in range(iterations):
        ia = np.flatnonzero(active)
        if len(ia) == 0:
            break
        wx = p[ia, :1] + M[ia, 0, :1] * ox[None] + M[ia, 0, 1:2] * oy[None]
        wy = p[ia, 1:2] + M[ia, 1, :1] * ox[None] + M[ia, 1, 1:2] * oy[None]
        I = _sample(tgt, wx, wy).astype(float)
        Gx = _sample(tgt_gx, wx, wy).astype(float)
        Gy = _sample(tgt_gy, wx, wy).astype(float)
        aa = a[ia, None]
        res = aa * I + b[ia, None] - Tm[ia]
        J = np.empty((len(ia), 8, I.shape[1]))
        J[:, 0], J[:, 1] = aa * Gx, aa * Gy
        J[:, 2], J[:, 3] = J[:, 0] * ox, J[:, 0] * oy
        J[:, 4], J[:, 5] = J[:, 1] * ox, J[:, 1] * oy
        J[:, 6], J[:, 7] = I, 1.0
        Jw = J * wgt
        H = Jw @ J.transpose(0, 2, 1)
        g = (Jw @ res[..., None])[..., 0]
        H = H + 1e-9 * np.trace(H, axis1=1, axis2=2)[:, None, None] * np.eye(8)
        try:
            delta = -np.linalg.solve(H, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            delta = -np.einsum("mab,mb->ma", np.linalg.pinv(H), g)
        step = np.linalg.norm(delta[:, :2], axis=1)
        step = np.where(np.isfinite(step), step, np.inf)
        lim = np.minimum(1.0, 2.0 / np.maximum(step, 1e-12))  # at most 2 px per step
        delta = np.where(np.isfinite(delta), delta, 0.0) * lim[:, None]
        p[ia] += delta[:, :2]
        M[ia] += delta[:, 2:6].reshape(-1, 2, 2)
        a[ia] += delta[:, 6]
        b[ia] += delta[:, 7]
        last_step[ia] = step
        done = step < 2e-3
        conv[ia[done]] = True
        active[ia[done]] = False
    conv |= last_step < 0.01  # still creeping by < 0.01 px: good enough
    # final quality: weighted NCC and the translation block's smallest eigenvalue
    wx = p[:, :1] + M[:, 0, :1] * ox[None] + M[:, 0, 1:2] * oy[None]
    wy = p[:, 1:2] + M[:, 1, :1] * ox[None] + M[:, 1, 1:2] * oy[None]
    I = _sample(tgt, wx, wy).astype(float)
    ncc = _wncc(I, Tm, wgt)
    Gx = _sample(tgt_gx, wx, wy).astype(float)
    Gy = _sample(tgt_gy, wx, wy).astype(float)
    hxx, hxy, hyy = (wgt * Gx * Gx).sum(1), (wgt * Gx * Gy).sum(1), (wgt * Gy * Gy).sum(1)
    min_eig = 0.5 * (hxx + hyy - np.sqrt((hxx - hyy) ** 2 + 4 * hxy**2)) / wgt.sum()
    return p, M, ncc, min_eig, conv


def _wncc(I, T, w):
    w = w / w.sum()
    Ic = I - (I * w).sum(1, keepdims=True)
    Tc = T - (T * w).sum(1, keepdims=True)
    num = (w * Ic * Tc).sum(1)
    den = np.sqrt((w * Ic * Ic).sum(1) * (w * Tc * Tc).sum(1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / den, 0.0)


# --------------------------------------------------------------------------- main
#: A view pair whose matches a general fundamental matrix explains (at least this
#: fraction of the matches, ``ROTATION_MIN_F_FRACTION``) far better than a pure
#: translation (fewer than ``ROTATION_MAX_E_RATIO`` of the F-inliers) was taken with a
#: rotation between the views. Measured (5-view renders, 640 x 480): pure translations,
#: also with lens distortion, JPEG and noise, give ratios >= 0.97; repetitive textures
#: give low ratios but F then explains < 75 % of the matches; 10-20 deg rotations give
#: 0.3-0.9 with F explaining > 98 %.
ROTATION_MIN_F_FRACTION = 0.85
ROTATION_MAX_E_RATIO = 0.85
#: A track moving less than this (px) in every view while the median track of the same
#: view pairs moves ``STATIC_MIN_MEDIAN_FACTOR`` times more is static (a burnt-in
#: overlay, dust on the lens, a point at infinity): it carries no information on K.
STATIC_PX = 1.0
STATIC_MIN_MEDIAN_FACTOR = 10.0


@dataclass
class _Nodes:
    """All features of all views numbered consecutively: per view SIFT then corners."""

    offsets: list
    view: np.ndarray  # (n_nodes,) view of each node
    pos: np.ndarray  # (n_nodes, 2) pixel of each node
    is_corner: np.ndarray  # (n_nodes,) bool

    @classmethod
    def of(cls, feats):
        offsets, pos, kind, off = [], [], [], 0
        for f in feats:
            offsets.append(off)
            pos.append(np.vstack([f["sift"], f["corners"]]))
            kind.append(np.r_[np.zeros(len(f["sift"]), bool), np.ones(len(f["corners"]), bool)])
            off += len(f["sift"]) + len(f["corners"])
        view = np.concatenate([np.full(len(p), i) for i, p in enumerate(pos)]).astype(int)
        return cls(offsets, view, np.vstack(pos) if off else np.zeros((0, 2)), np.concatenate(kind))


class _Timer:
    """``with timer("stage"):`` adds the stage's wall time to ``times[stage]``."""

    def __init__(self):
        self.times = {}

    def __call__(self, stage):
        self._stage = stage
        return self

    def __enter__(self):
        self._t0 = time.perf_counter()

    def __exit__(self, *exc):
        self.times[self._stage] = self.times.get(self._stage, 0.0) + time.perf_counter() - self._t0


def track_features(images, *, method, max_features, max_corners, corner_quality, ratio, threshold_px, refine,
                    window_radius, min_ncc, final_threshold_px, smooth_px, min_views, min_tracks, max_tracks,
                    progress, rng, static_px=STATIC_PX, T=None) -> Tracks:
    """Feature tracking (the body of :func:`track`; options as there)."""
    rng = np.random.default_rng(rng)
    report = _progress_fn(progress)
    timer = _Timer()
    grey, rgb, names = load_images(images)
    n, (h, w) = len(grey), grey[0].shape
    with timer("detect"):
        feats = _detect_all(grey, method, max_features, max_corners, corner_quality)
        report("detect", n, n)
    nodes = _Nodes.of(feats)
    with timer("match"):
        raw = _match_all(feats, ratio, report)
    with timer("verify"):
        epi, found, repaired, bad_pairs = _verify_pairs(feats, raw, n, threshold_px, rng, report)
        _check_pure_translation(feats, raw, found, threshold_px)
        replaced = []
        if T is not None:
            epi, found, replaced = _enforce_translations(epi, found, feats, raw, T, threshold_px, w, h, rng)
        edges, scores, n_verified = _pair_edges(feats, raw, epi, found, nodes, method, threshold_px)
    with timer("chain"):
        uv, n_conflicts, counts = _chain(edges, scores, nodes, n, n_verified, max_tracks, w, h)
        report("chain", 1, 1)
    with timer("refine"):
        if refine and uv.shape[1]:
            uv = _refine(grey, uv, epi, window_radius, min_ncc, report)
    with timer("final"):
        thr = final_threshold_px if refine else threshold_px
        uv, epi_final, n_static = _final_checks(uv, epi, n, thr, smooth_px, static_px, rng, counts)
        uv = _keep_tracks(uv, min_views, max_tracks, w, h)
    if uv.shape[1] < min_tracks:
        raise DegenerateError(_too_few_msg(uv.shape[1], n_verified, min_tracks))
    info = {
        "time_s": timer.times,
        "n_matches_raw": {f"{i}-{j}": int(len(v)) for (i, j), v in raw.items()},
        "n_matches_verified": {f"{i}-{j}": v for (i, j), v in n_verified.items()},
        "epipoles": {f"{i}-{j}": e.tolist() for (i, j), e in epi_final.items()},
        "n_conflicts_dropped": n_conflicts,
        "n_observations": counts,
        "n_static_dropped": n_static,
        "inconsistent_pairs": [f"{i}-{j}" for i, j in bad_pairs],
        "repaired_pairs": [f"{i}-{j}" for i, j in repaired],
        "pairs_set_by_translations": [f"{i}-{j}" for i, j in replaced],
    }
    return Tracks(uv=uv, ids=np.arange(uv.shape[1]), colors=_colors(rgb, uv), view_names=names, info=info)


def _detect_all(grey, method, max_features, max_corners, corner_quality):
    """Stage 1: SIFT (+ corners unless ``method == "sift"``) of every view."""
    feats = _detect(grey, max_features, 1 if method == "sift" else max_corners, corner_quality)
    if method == "sift":
        for f in feats:
            f["corners"] = np.zeros((0, 2))
    return feats


def _match_all(feats, ratio, report):
    """Stage 2: SIFT matches ``{(i, j): (k, 2) index pairs}`` of every view pair ``i < j``."""
    n = len(feats)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    raw = {}
    for k, (i, j) in enumerate(pairs):
        raw[(i, j)] = _match_pair(feats[i]["desc"], feats[j]["desc"], ratio)
        report("match", k + 1, len(pairs))
    return raw


def _matched_xy(feats, raw, i, j):
    m = raw[(i, j)]
    return feats[i]["sift"][m[:, 0]], feats[j]["sift"][m[:, 1]]


def _verify_pairs(feats, raw, n, threshold_px, rng, report):
    """Stage 3a: epipole of every pair (2-point RANSAC), then the pairs inconsistent
    with the others (``e_ik`` on the line ``e_ij e_jk``) re-estimated on that line.

    Returns ``epi {(i, j): e}``, ``found {(i, j): (e or None, inliers)}``, the repaired
    pairs and the pairs whose epipole could not be trusted.
    """
    found = {}
    for k, (i, j) in enumerate(raw):
        xi, xj = _matched_xy(feats, raw, i, j)
        e, inl, _ = epipole_ransac(xi, xj, threshold_px=threshold_px, rng=rng, detrend=True)
        found[(i, j)] = (e, inl)
        report("verify", k + 1, len(raw))
    epi = {p: e for p, (e, inl) in found.items() if e is not None and inl.sum() >= 8}
    # repetitive textures can make a wrong epipole win a pair's RANSAC: repair the odd ones
    bad_pairs = _inconsistent_pairs(epi, n)
    good = {p: e for p, e in epi.items() if p not in bad_pairs}
    repaired = []
    for (i, j) in raw:
        if (i, j) in good:
            continue
        xi, xj = _matched_xy(feats, raw, i, j)
        e, inl = _repair_pair(i, j, good, xi, xj, threshold_px)
        epi.pop((i, j), None)
        if e is not None and inl.sum() >= 4:
            epi[(i, j)] = e
            found[(i, j)] = (e, inl)
            repaired.append((i, j))
    if bad_pairs:
        log.info("view pairs with inconsistent epipoles: %s; repaired: %s", bad_pairs, repaired)
    bad_pairs = [p for p in raw if p not in epi and found[p][0] is not None]
    return epi, found, repaired, bad_pairs


def _check_pure_translation(feats, raw, found, threshold_px, min_matches=50):
    """Stage 3b: raise :class:`DegenerateError` when some view pair was taken with a
    rotation: a general fundamental matrix (``cv2.USAC_MAGSAC``) explains almost all of
    its matches, a pure translation (``F = [e]x``) clearly fewer."""
    rotated = []
    for (i, j), (e, inl) in found.items():
        xi, xj = _matched_xy(feats, raw, i, j)
        if len(xi) < min_matches or np.median(np.linalg.norm(xj - xi, axis=1)) < 2.0:
            continue
        F, mask = cv2.findFundamentalMat(xi.astype(np.float64), xj.astype(np.float64), cv2.USAC_MAGSAC,
                                         threshold_px, 0.999, 2000)
        n_f = 0 if mask is None or F is None else int(mask.sum())
        n_e = int(inl.sum()) if e is not None else 0
        if n_f >= max(min_matches, ROTATION_MIN_F_FRACTION * len(xi)) and n_e < ROTATION_MAX_E_RATIO * n_f:
            rotated.append(f"{i}-{j} (general epipolar geometry: {n_f} of {len(xi)} matches, "
                           f"pure translation: {n_e})")
    if rotated:
        raise RotatedViewsError(
            "the views are not related by pure translations: the camera rotated between views "
            + "; ".join(rotated[:6]) + ("; ..." if len(rotated) > 6 else "")
            + ". The pure-translation tracker needs one camera orientation for all views. If the robot turned "
            "the wrist between groups of views, track each group (session) alone, or use "
            "transcalib.images.track_sessions(images, session_of_view); otherwise check that the robot "
            "did not rotate")


def _pair_edges(feats, raw, epi, found, nodes, method, threshold_px):
    """Stage 3c: verified SIFT matches and epipole-guided corner matches of every pair
    as node edges, each with its epipolar distance as a score (smaller is better)."""
    edges, scores, n_verified = [], [], {}
    for (i, j) in raw:
        xi, xj = _matched_xy(feats, raw, i, j)
        e, inl = found[(i, j)]
        if e is None and len(xi) and np.median(np.linalg.norm(xj - xi, axis=1)) < 0.5:
            m = raw[(i, j)]  # no motion between these views: keep the matches as they are
            edges.append(np.column_stack([nodes.offsets[i] + m[:, 0], nodes.offsets[j] + m[:, 1]]))
            scores.append(np.linalg.norm(xj - xi, axis=1))
        if (i, j) not in epi:
            n_verified[(i, j)] = 0
            continue
        n_verified[(i, j)] = int(inl.sum())
        mi = raw[(i, j)][inl]
        edges.append(np.column_stack([nodes.offsets[i] + mi[:, 0], nodes.offsets[j] + mi[:, 1]]))
        scores.append(_epi_residual(e, xi[inl], xj[inl])[0])
        if method != "sift":
            ci, cj = feats[i]["corners"], feats[j]["corners"]
            cp = _guided_corners(ci, cj, e, xi[inl], xj[inl], threshold_px)
            ns_i, ns_j = len(feats[i]["sift"]), len(feats[j]["sift"])
            edges.append(np.column_stack([nodes.offsets[i] + ns_i + cp[:, 0], nodes.offsets[j] + ns_j + cp[:, 1]]))
            scores.append(_epi_residual(e, ci[cp[:, 0]], cj[cp[:, 1]])[0])
    return edges, scores, n_verified


def _chain(edges, scores, nodes, n, n_verified, max_tracks, w, h):
    """Stage 4: union-find over the edges, best first -> ``uv (n, n_tracks, 2)``."""
    E = np.vstack(edges) if edges else np.zeros((0, 2), int)
    score = np.concatenate(scores) if scores else np.zeros(0)
    if len(E) == 0:
        raise DegenerateError(_too_few_msg(0, n_verified))
    label, n_conflicts = _union_find(E[np.argsort(score, kind="stable")], nodes.view, len(nodes.view))
    used = np.flatnonzero(label >= 0)
    comp, comp_idx = np.unique(label[used], return_inverse=True)
    uv = np.full((n, len(comp), 2), np.nan)
    uv[nodes.view[used], comp_idx] = nodes.pos[used]
    uv = uv[:, np.isfinite(uv[..., 0]).sum(0) >= 2]
    counts = {"chained": _n_obs(uv)}
    if max_tracks is not None and uv.shape[1] > int(1.3 * max_tracks):
        uv = uv[:, _select_spread(uv, int(1.3 * max_tracks), w, h, return_index=True)]
    return uv, n_conflicts, counts


def _final_checks(uv, epi, n, thr, smooth_px, static_px, rng, counts):
    """Stage 6: depth smoothness, epipoles re-estimated from the refined points,
    multi-view depth consistency, static tracks. Fills ``counts`` (observations left
    after each check); returns ``uv``, the final epipoles and the number of static
    tracks dropped."""
    counts["refined"] = _n_obs(uv)
    uv = _smoothness_check(uv, epi, smooth_px)
    counts["smooth"] = _n_obs(uv)
    uv, epi_final = _final_check(uv, n, thr, rng)
    counts["epipolar"] = _n_obs(uv)
    uv = _multiview_check(uv, epi_final, 3.0 * thr)
    counts["multiview"] = _n_obs(uv)
    uv, n_static = _drop_static(uv, static_px)
    counts["static"] = _n_obs(uv)
    return uv, epi_final, n_static


def _drop_static(uv, static_px=STATIC_PX, factor=STATIC_MIN_MEDIAN_FACTOR):
    """Drop tracks that do not move while the epipolar geometry says they should.

    A static point (a burnt-in timestamp, dust on the lens) is consistent with every
    epipole (``rho = 0``), so the epipolar tests pass it. Under pure translation only a
    point at infinity stays put, and such a point carries no information on K. A track
    is dropped when its largest displacement from its reference view is below
    ``static_px`` while the median displacement of all tracks between the same views is
    at least ``factor * static_px``.

    Returns the kept ``uv`` and the number of tracks dropped.
    """
    n_views, n_pts = uv.shape[:2]
    if n_pts == 0:
        return uv, 0
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    disp = np.linalg.norm(uv - uv[ref, np.arange(n_pts)][None], axis=-1)  # (n_views, n_pts), NaN unseen
    expected = np.zeros(n_pts)
    for r in range(n_views):
        mine = ref == r
        for j in range(n_views):
            both = mine & seen[j]
            if j != r and both.sum() >= 5:  # median motion of the pair r -> j
                expected[both] = np.maximum(expected[both], np.median(disp[j, both]))
    moved = np.max(np.where(seen, disp, 0.0), axis=0)
    static = (moved < static_px) & (expected >= factor * static_px)
    return uv[:, ~static], int(static.sum())


def _keep_tracks(uv, min_views, max_tracks, w, h):
    """Deduplicate, keep tracks seen in ``min_views``+ views, at most ``max_tracks``."""
    uv = _dedupe(uv, w, h)
    uv = uv[:, np.isfinite(uv[..., 0]).sum(0) >= min_views]
    if max_tracks is not None and uv.shape[1] > max_tracks:
        uv = _select_spread(uv, max_tracks, w, h)
    return uv


# --------------------------------------------------------------------------- known translations
def _span_basis(T, tol=COPLANAR_RTOL):
    """Orthonormal basis ``(3, k)`` of the span of the relative translations ``T - T_0``."""
    D = np.asarray(T, float) - np.asarray(T, float)[0]
    if len(D) < 2 or not np.any(D):
        return np.zeros((3, 0))
    _, s, Vt = np.linalg.svd(D, full_matrices=False)
    return Vt[: int(np.sum(s > tol * s[0]))].T


def _fit_A(epi_list, t_list, scale):
    """Least-squares ``M`` (3, k) with ``e_p x (M b_p) = 0`` for normalised epipoles
    ``e_p`` and translation coordinates ``b_p``: DLT, right singular vector."""
    k = t_list.shape[1]
    Hn = np.array([1.0 / scale, 1.0 / scale, 1.0])
    rows = []
    for e, b in zip(epi_list, t_list):
        en = e * Hn
        en = en / np.linalg.norm(en)
        ex = np.array([[0, -en[2], en[1]], [en[2], 0, -en[0]], [-en[1], en[0], 0]])
        rows.append(ex @ np.kron(np.eye(3), b[None]))  # M b = (I3 kron b^T) vec_row(M)
    M = np.linalg.svd(np.vstack(rows))[2][-1].reshape(3, k)
    return M / Hn[:, None]  # back to pixels: e = Hn^-1 M_n b


def _support(e, x, y, thr):
    """Matches ``x -> y`` consistent with the epipole ``e``: on its line, positive rho."""
    dist, rho = _epi_residual(e, x, y)
    moving = np.linalg.norm(y - x, axis=1) >= 0.5
    return (dist < thr) & ((rho > 0) | ~moving)


def _enforce_translations(epi, found, feats, raw, T, threshold_px, w, h, rng, trials=200):
    """Known robot translations: every epipole is ``e_ij ~ A (T_j - T_i)`` with one
    ``A = K R``. Fit ``A`` (restricted to the span of the translations) robustly to
    the pairs' epipoles, scoring a hypothesis by the matches of **all** pairs that its
    predicted epipoles explain; pairs whose own epipole disagrees (a repetitive texture
    can make a wrong epipole win a pair, consistently for one view, which the triplet
    test cannot see) get the predicted epipole and its inliers.

    Returns the updated ``epi`` and ``found`` and the pairs replaced.
    """
    B = _span_basis(T)
    k = B.shape[1]
    pairs = sorted(epi)
    if k < 2 or len(pairs) < k + 2:
        return epi, found, []
    coords = {p: B.T @ (np.asarray(T[p[1]], float) - T[p[0]]) for p in raw}
    scale = float(max(w, h))
    xy = {p: _matched_xy(feats, raw, *p) for p in raw}
    n_min = int(np.ceil((3 * k - 1) / 2))
    best, best_M = -1, None
    subsets = [rng.choice(len(pairs), n_min, replace=False) for _ in range(trials)]
    for sub in subsets:
        M = _fit_A([epi[pairs[s]] for s in sub], np.array([coords[pairs[s]] for s in sub]), scale)
        score = 0
        for p in raw:
            e = M @ coords[p]
            score += int(max(_support(e, *xy[p], threshold_px).sum(), _support(-e, *xy[p], threshold_px).sum()))
        if score > best:
            best, best_M = score, M
    consistent = [p for p in pairs if _agrees(best_M @ coords[p], epi[p], *xy[p], found[p][1], threshold_px)]
    if len(consistent) >= n_min:
        best_M = _fit_A([epi[p] for p in consistent], np.array([coords[p] for p in consistent]), scale)
    replaced = []
    for p in raw:
        if p in consistent:
            continue
        e = best_M @ coords[p]
        e = e / np.linalg.norm(e)
        inl_pos, inl_neg = _support(e, *xy[p], threshold_px), _support(-e, *xy[p], threshold_px)
        e, inl = (e, inl_pos) if inl_pos.sum() >= inl_neg.sum() else (-e, inl_neg)
        if inl.sum() >= 4:
            epi[p], found[p] = e, (e, inl)
            replaced.append(p)
    return epi, found, replaced


def _agrees(e_pred, e, x, y, inliers, thr, min_fraction=0.8):
    """The pair's own RANSAC inliers are (mostly) explained by the predicted epipole."""
    if inliers.sum() == 0:
        return False
    e_pred = e_pred / np.linalg.norm(e_pred)
    s = max(_support(e_pred, x[inliers], y[inliers], thr).mean(), _support(-e_pred, x[inliers], y[inliers], thr).mean())
    return s >= min_fraction


def _union_find(E, node_view, n_nodes):
    """Chain matches into tracks: union-find over edges ``E`` ``(m, 2)`` (best first).

    An edge that would put two features of one view into a track is skipped (a
    conflict), so mismatches cannot glue tracks together. Returns the track label of
    every node (-1 for nodes in no edge) and the number of skipped edges.
    """
    parent = np.arange(n_nodes)
    mask = {}  # root -> bitmask of views in its track
    conflicts = 0
    par = parent.tolist()
    nv = node_view.tolist()

    def find(a):
        while par[a] != a:
            par[a] = par[par[a]]
            a = par[a]
        return a

    for a, b in E.tolist():  # one pass over the edges; near-constant time per edge
        ra, rb = find(a), find(b)
        if ra == rb:
            continue
        ma = mask.get(ra, 1 << nv[a])
        mb = mask.get(rb, 1 << nv[b])
        if ma & mb:
            conflicts += 1
            continue
        par[rb] = ra
        mask[ra] = ma | mb
    roots = np.array([find(a) for a in range(n_nodes)])
    in_edge = np.zeros(n_nodes, bool)
    in_edge[E.ravel()] = True
    return np.where(in_edge, roots, -1), conflicts


def _n_obs(uv):
    """Number of observations in tracks seen at least twice."""
    s = np.isfinite(uv[..., 0])
    return int(s[:, s.sum(0) >= 2].sum())


def _too_few_msg(n_pts, n_verified, min_tracks=8):
    per_pair = ", ".join(f"{i}-{j}: {v}" for (i, j), v in n_verified.items())
    return (f"tracking found only {n_pts} usable tracks (need >= {min_tracks}); verified matches per view pair: "
            f"{per_pair}. Use images of a well-textured scene (not blank walls), keep a large overlap between "
            "views (translations of a few percent of the scene distance), avoid motion blur, or pass "
            "target='squares' for a board of black squares")


def _repair_pair(i, k, good, x, y, thr):
    """Epipole of pair ``(i, k)`` constrained by consistent pairs: for any view j with
    ``e_ij`` and ``e_jk`` known, ``e_ik = a e_ij + b e_jk``; one match fixes ``(a, b)``,
    so a 1-point RANSAC over all matches and all such j picks it."""
    n_match = len(x)
    if n_match < 3:
        return None, np.zeros(n_match, bool)
    views = {a for p in good for a in p}
    L = _normalised_lines(x, y)
    moving = np.linalg.norm(y - x, axis=1) >= 0.5
    best = (-1, None)
    for j in sorted(views - {i, k}):
        p = _pair_epipole(good, i, j)
        q = _pair_epipole(good, j, k)
        if p is None or q is None:
            continue
        ab = np.column_stack([L @ q, -(L @ p)])[moving]
        E = ab[:, :1] * p + ab[:, 1:] * q
        nE = np.linalg.norm(E, axis=1)
        E = E[nE > 1e-12] / nE[nE > 1e-12, None]
        if len(E) == 0:
            continue
        dist, rho = _hypothesis_residuals(E, x, y)
        ok = dist < thr
        pos, neg = (ok & (rho > 0)).sum(1), (ok & (rho < 0)).sum(1)
        score = np.maximum(pos, neg)
        b = int(np.argmax(score))
        if score[b] > best[0]:
            best = (score[b], E[b] * (1.0 if pos[b] >= neg[b] else -1.0))
    e = best[1]
    if e is None:
        return None, np.zeros(n_match, bool)
    dist, rho = _epi_residual(e, x, y)
    return e, (dist < thr) & ((rho > 0) | ~moving)


def _inconsistent_pairs(epi, n, tol=2e-3):
    """Pairs whose epipole disagrees with most triplets: ``e_ik`` must lie on the line
    ``e_ij e_jk`` (``t_ik = t_ij + t_jk``)."""
    votes = {}
    for i in range(n):
        for j in range(i + 1, n):
            for k in range(j + 1, n):
                if (i, j) in epi and (j, k) in epi and (i, k) in epi:
                    d = abs(np.linalg.det(np.array([epi[(i, j)], epi[(j, k)], epi[(i, k)]])))
                    for p in [(i, j), (j, k), (i, k)]:
                        v = votes.setdefault(p, [0, 0])
                        v[0] += d > tol
                        v[1] += 1
    return sorted(p for p, (bad, tot) in votes.items() if tot >= 2 and bad == tot)


def _refine(grey, uv, epi, radius, min_ncc, report):
    n = len(grey)
    sm = [cv2.GaussianBlur(g, (0, 0), 1.0) for g in grey]
    gx = [cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8) for g in sm]
    gy = [cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8) for g in sm]
    h, w = grey[0].shape
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    out = uv.copy()
    margin = radius + 2
    inside = ((uv[..., 0] >= margin) & (uv[..., 0] <= w - 1 - margin) & (uv[..., 1] >= margin)
              & (uv[..., 1] <= h - 1 - margin))
    steps = [(r, j) for r in range(n) for j in range(n) if j != r]
    for k, (r, j) in enumerate(steps):
        sel = np.flatnonzero((ref == r) & seen[j])
        if len(sel) == 0:
            continue
        ok_in = inside[r, sel] & inside[j, sel]
        p_ref = uv[r, sel]
        p0 = uv[j, sel]
        # initial scale from the epipole: dx'/dx ~ (1 + rho e3) I
        e = epi.get((r, j)) if r < j else (-epi[(j, r)] if (j, r) in epi else None)
        M0 = np.repeat(np.eye(2)[None], len(sel), axis=0)
        if e is not None:
            _, rho = _epi_residual(e, p_ref, p0)
            s = 1.0 + np.nan_to_num(rho) * e[2]
            s = np.clip(s, 0.5, 2.0)
            M0 = M0 * s[:, None, None]
        p, M, ncc, min_eig, conv = _lk_affine(sm[r], None, sm[j], gx[j], gy[j], p_ref, p0, M0, radius)
        det = np.linalg.det(M)
        good = (ok_in & conv & (ncc >= min_ncc) & (np.linalg.norm(p - p0, axis=1) < 4.0)
                & (det > 0.25) & (det < 4.0) & (min_eig > 1.0))
        out[j, sel] = np.where(good[:, None], p, np.nan)
        out[r, sel[~inside[r, sel]]] = np.nan  # no template: the reference goes too
        report("refine", k + 1, len(steps))
    return out


def _smoothness_check(uv, epi, thr_px, k=8):
    """Drop observations whose inverse depth ``rho`` (w.r.t. the pair's epipole) differs
    from the median of the ``k`` nearest tracks by more than ``thr_px`` in the image."""
    out = uv.copy()
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    for (i, j), e in epi.items():
        both = np.flatnonzero(seen[i] & seen[j])
        if len(both) < k + 1:
            continue
        xi, xj = uv[i, both], uv[j, both]
        _, rho = _epi_residual(e, xi, xj)
        rho_nb = _local_rho_linear(xi, rho, xi, k=10)
        dev = np.abs(rho - rho_nb) * np.linalg.norm(_direction(e, xi), axis=1)
        bad = both[~(np.nan_to_num(dev, nan=np.inf) <= thr_px)]
        drop_j = ref[bad] != j
        out[j, bad[drop_j]] = np.nan
        out[i, bad[~drop_j]] = np.nan
    return out


def _pair_epipole(epi, i, j):
    """Epipole of pair ``(i, j)`` signed as ``A (T_j - T_i)``, from the ``i < j`` table."""
    if (i, j) in epi:
        return epi[(i, j)]
    if (j, i) in epi:
        return -epi[(j, i)]
    return None


#: Largest smooth misfit (px) of the multi-view depth prediction attributed to lens
#: distortion (k1 = -0.12 at 640 x 480 gives under 2 px); beyond it, a mismatch.
MAX_TREND_PX = 4.0


def _multiview_check(uv, epi, thr_px, passes=3):
    """Depth consistency of tracks seen in 3+ views.

    With the reference view r and ``x_j = x_r + rho_j (e3 x_r - e_xy)`` for the pair's
    unit epipole ``e`` (true epipole ``s_j e``), ``q_j = 1 / (1 / rho_j + e3) = s_j w``
    exactly, where ``w`` is the point's inverse depth in view r. The scales ``s_j`` are
    common to all points (robust medians of ratios), so ``w`` from some views predicts
    the others; observations predicted worse than ``thr_px`` are dropped, worst first.
    """
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
            xr = out[r, sel]
            q = np.full((n, len(sel)), np.nan)
            E = {}
            for j in range(n):
                e = _pair_epipole(epi, r, j) if j != r else None
                if e is None:
                    continue
                E[j] = e
                _, rho = _epi_residual(e, xr, out[j, sel])
                with np.errstate(divide="ignore", invalid="ignore"):
                    q[j] = 1.0 / (1.0 / rho + e[2])
            cnt = np.isfinite(q).sum(1)
            if cnt.max() < 5:
                continue
            j0 = int(np.argmax(cnt))
            s = np.full(n, np.nan)
            s[j0] = 1.0
            for j in E:
                both = np.isfinite(q[j]) & np.isfinite(q[j0]) & (np.abs(q[j0]) > 1e-12)
                if j != j0 and both.sum() >= 5:
                    s[j] = np.median(q[j, both] / q[j0, both])
            with np.errstate(divide="ignore", invalid="ignore"):
                w_all = q / s[:, None]
            res = np.zeros((n, len(sel)))
            for j in E:
                if not np.isfinite(s[j]):
                    continue
                # leave-one-out: w from the other views, so a bad view cannot hide
                others = np.delete(w_all, j, axis=0)
                with np.errstate(all="ignore"), warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns give NaN: wanted
                    w = np.nanmedian(others, axis=0) if others.size else np.full(len(sel), np.nan)
                    qh = s[j] * w
                    rho_h = 1.0 / (1.0 / qh - E[j][2])
                pred = xr + rho_h[:, None] * _direction(E[j], xr)
                R = pred - out[j, sel]
                fin = np.isfinite(R).all(1)
                if fin.sum() >= 12:  # remove the smooth part (lens distortion), keep isolated misfits
                    trend = np.column_stack([_local_rho_linear(xr[fin], R[fin, c], xr, k=10) for c in range(2)])
                    # lens distortion bends the prediction by a few px; a larger "trend" is a
                    # region of consistent mismatches (one tile off on a repetitive texture)
                    tn = np.linalg.norm(trend, axis=1, keepdims=True)
                    R = R - trend * np.minimum(1.0, MAX_TREND_PX / np.maximum(tn, 1e-12))
                res[j] = np.where(np.isfinite(q[j]), np.linalg.norm(R, axis=1), 0.0)
            res = np.nan_to_num(res, nan=0.0)
            worst = np.argmax(res, axis=0)
            bad = res[worst, np.arange(len(sel))] > thr_px
            if bad.any():
                changed = True
                wv, bk = worst[bad], sel[bad]
                out[wv, bk] = np.nan
        if not changed:
            break
    return out


def _final_check(uv, n, thr, rng):
    """Re-estimate the epipoles from the refined tracks; drop observations off their line."""
    epi = {}
    out = uv.copy()
    seen = np.isfinite(out[..., 0])
    ref = np.argmax(seen, axis=0)
    for i in range(n):
        for j in range(i + 1, n):
            both = seen[i] & seen[j]
            if both.sum() < 8:
                continue
            e, inl, _ = epipole_ransac(uv[i, both], uv[j, both], threshold_px=thr, rng=rng, detrend=True)
            if e is None:
                continue
            epi[(i, j)] = e
            bad = np.flatnonzero(both)[~inl]
            # drop the non-reference observation of a bad pair
            drop_j = ref[bad] != j
            out[j, bad[drop_j]] = np.nan
            out[i, bad[~drop_j]] = np.nan
    return out, epi


def _dedupe(uv, w, h, tol=0.75):
    """Drop tracks that coincide (within ``tol`` px in every shared view) with an earlier one."""
    n_pts = uv.shape[1]
    if n_pts < 2:
        return uv
    seen = np.isfinite(uv[..., 0])
    keep = np.ones(n_pts, bool)
    for v in range(uv.shape[0]):
        idx = np.flatnonzero(seen[v] & keep)
        if len(idx) < 2:
            continue
        tree = cKDTree(uv[v, idx])
        for a, b in tree.query_pairs(tol, output_type="ndarray"):
            pa, pb = idx[a], idx[b]
            both = seen[:, pa] & seen[:, pb]
            if np.all(np.linalg.norm(uv[both, pa] - uv[both, pb], axis=1) < tol):
                # keep the track seen in more views
                loser = pb if seen[:, pa].sum() >= seen[:, pb].sum() else pa
                keep[loser] = False
    return uv[:, keep]


def _select_spread(uv, k, w, h, return_index=False):
    """Keep ``k`` tracks: most views first, spread over a grid of the reference image."""
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    p = uv[ref, np.arange(uv.shape[1])]
    g = 16
    cell = (np.clip(p[:, 0] / w * g, 0, g - 1).astype(int) * g + np.clip(p[:, 1] / h * g, 0, g - 1).astype(int))
    order = np.lexsort((-seen.sum(0), cell))
    rank = np.empty(len(order), int)
    cs = cell[order]
    start = np.r_[0, np.flatnonzero(np.diff(cs)) + 1]
    within = np.arange(len(order)) - np.repeat(start, np.diff(np.r_[start, len(order)]))
    rank[order] = within
    pick = np.sort(np.argsort(rank * 10 - seen.sum(0), kind="stable")[:k])
    return pick if return_index else uv[:, pick]


def _colors(rgb, uv):
    if any(c is None for c in rgb) or uv.shape[1] == 0:
        return None
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    p = uv[ref, np.arange(uv.shape[1])]
    h, w = rgb[0].shape[:2]
    x = np.clip(np.rint(p[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.rint(p[:, 1]).astype(int), 0, h - 1)
    stack = np.stack(rgb)
    return stack[ref, y, x].astype(np.uint8)
