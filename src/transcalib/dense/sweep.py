"""The multi-baseline plane sweep in inverse depth (Okutomi & Kanade 1993).

Views of one session are pure translations of the reference view, so a hypothesis of
inverse depth ``rho`` (``1 / z``, ``z`` along the reference's optical axis) at a
reference pixel with ray ``r = [x, y, 1]`` (lens included) lands in source view ``j`` at::

    x_j = r / rho - t_j                            camera frame of view j (reference axes)
    u_j = (u~ - rho e_j) / (1 - rho t_j,z)          e_j = K_c t_j,  u~ = K_c r

on the source's pinhole canvas (:mod:`.images`: the source undistorted once, intrinsics
``K_c``, and turned to the reference's axes when a session's small rotation moves it):
a scaling about the epipole. Without distortion ``u~`` is the pixel itself
plus the canvas offset, and the warp is affine (``cv2.warpAffine``); with distortion
``u~`` is computed once per pixel and the warp is a remap.

The cost of a hypothesis at a pixel is, for each source view, the sum over the window of
the truncated squared difference of the locally normalised images (``min(d^2, 2)``:
about ``2 (1 - ZNCC)`` per pixel, robust to exposure and vignetting); the ``best_k``
smallest of the views' costs are summed (occlusion handling). Hypotheses stream through
a band of rows at a time, so the cost volume is never held: per pixel we keep the best
cost ``c1`` and its index, its two neighbours (parabolic sub-hypothesis refinement) and
``c2``, the best cost at least ``exclusion`` hypotheses away from the best (the
distinctness of the minimum), computed exactly with a running minimum lagged by
``exclusion + 1`` steps. Bands run on ``threads`` threads (OpenCV releases the GIL).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from ..types.progress import report

__all__ = ["SweepInput", "SweepResult", "sweep", "warp_matrix", "TRUNCATION"]

#: Truncation of the squared difference of normalised intensities (per pixel).
TRUNCATION = 2.0
#: Rows of a band (plus the window's halo).
BAND_ROWS = 64
_INF = np.float32(np.inf)


@dataclass(frozen=True, eq=False)
class SweepInput:
    """What the sweep needs, in float32.

    Attributes
    ----------
    ref : (H, W) float32
        The normalised reference image (original pixel grid).
    sources : list of (Hc, Wc) float32
        The normalised source views on their pinhole canvas.
    epipoles : (n_sources, 3) float
        ``e_j = K_c t_j`` of each source.
    offset : (2,) float
        Canvas offset: ``u~ = pixel + offset`` when ``ref_canvas`` is None.
    ref_canvas : (H, W, 2) float32 or None
        ``u~`` of every reference pixel (a lens with distortion).
    rho : (n_depths,) float
        Inverse depths, increasing.
    window : int
    best_k : int
    exclusion : int
        Hypotheses on each side of the best that ``c2`` skips.
    """

    ref: np.ndarray
    sources: list
    epipoles: np.ndarray
    offset: np.ndarray
    ref_canvas: np.ndarray | None
    rho: np.ndarray
    window: int
    best_k: int
    exclusion: int


@dataclass(frozen=True, eq=False)
class SweepResult:
    """Per pixel ``(H, W)`` float32: ``c1`` the best cost (mean per window pixel and view,
    ``inf`` where none), ``c2`` the best cost away from it (``inf``: none), ``index`` the
    refined (fractional) hypothesis index of the minimum (NaN at the ends of the range),
    ``curvature`` the cost's second difference there (per hypothesis step squared)."""

    c1: np.ndarray
    c2: np.ndarray
    index: np.ndarray
    curvature: np.ndarray


def warp_matrix(e: np.ndarray, rho: float, offset, row0: int = 0) -> np.ndarray:
    """``M`` (2, 3): the canvas position of the hypothesis ``rho`` of reference pixel
    ``(u, v)`` (row ``v - row0`` of a band starting at ``row0``) in the source with
    epipole ``e = K_c t`` is ``M [u, v - row0, 1]`` - the module docstring's
    ``(u~ - rho e) / (1 - rho e_z)`` with ``u~ = pixel + offset`` (a lens without
    distortion)."""
    s = 1.0 / (1.0 - rho * e[2])
    return np.array([[s, 0.0, (offset[0] - rho * e[0]) * s], [0.0, s, (offset[1] + row0 - rho * e[1]) * s]])


def _warp(src: np.ndarray, inp: SweepInput, j: int, rho: float, a0: int, rows: int, w: int, buf) -> np.ndarray:
    """Source ``j`` sampled at hypothesis ``rho`` for reference rows ``a0 .. a0 + rows``
    (out of its canvas: 0, the truncation makes it the worst match)."""
    e = inp.epipoles[j]
    if 1.0 - rho * e[2] < 0.05:  # the hypothesis is behind (or at) the source camera: nothing to see
        return np.full((rows, w), 1e3, np.float32)
    if inp.ref_canvas is None:
        return cv2.warpAffine(src, warp_matrix(e, rho, inp.offset, a0), (w, rows),
                              flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=1e3)
    maps = cv2.transform(inp.ref_canvas[a0:a0 + rows], warp_matrix(e, rho, (0.0, 0.0)), buf)  # s u~ - rho s e
    return cv2.remap(src, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=1e3)


def _hypothesis_cost(inp: SweepInput, rho: float, a0: int, rows: int, bufs) -> np.ndarray:
    """Sum of the ``best_k`` smallest windowed costs over the sources ``(rows, W)``: the
    ``best_k`` smallest kept sorted as they stream in, or, when fewer are left out, the
    total minus the ``n - best_k`` largest (whichever needs fewer operations)."""
    w, win = inp.ref.shape[1], inp.window
    ref = inp.ref[a0:a0 + rows]
    drop = len(inp.sources) - inp.best_k
    keep_small = inp.best_k <= drop
    slots, total = [None] * (inp.best_k if keep_small else drop), None
    first, second = (cv2.min, cv2.max) if keep_small else (cv2.max, cv2.min)
    for j, src in enumerate(inp.sources):  # a loop over the few source views
        d = cv2.subtract(ref, _warp(src, inp, j, rho, a0, rows, w, bufs))
        d = cv2.min(cv2.multiply(d, d), TRUNCATION)
        c = cv2.boxFilter(d, -1, (win, win), normalize=False, borderType=cv2.BORDER_REFLECT)
        if not keep_small:
            total = c if total is None else cv2.add(total, c)
        for t in range(len(slots)):
            if slots[t] is None:
                slots[t] = c
                break
            slots[t], c = first(slots[t], c), second(slots[t], c)
    if keep_small:
        total = slots[0]
        for s in slots[1:]:
            total = cv2.add(total, s)
        return total
    for s in slots:
        total = cv2.subtract(total, s)
    return total


def _band(inp: SweepInput, r0: int, r1: int) -> tuple:
    """Stream every hypothesis through rows ``r0 .. r1`` (module docstring)."""
    H, W = inp.ref.shape
    halo = inp.window // 2
    a0, a1 = max(r0 - halo, 0), min(r1 + halo, H)
    keep = slice(r0 - a0, r0 - a0 + (r1 - r0))
    shape = (r1 - r0, W)
    bufs = np.empty((a1 - a0, W, 2), np.float32)
    c1, c2, left, right = (np.full(shape, _INF, np.float32) for _ in range(4))
    best = np.full(shape, -1.0, np.float32)  # index of c1
    running = np.full(shape, _INF, np.float32)  # min of the costs so far
    lagged = [running.copy() for _ in range(inp.exclusion + 1)]  # ring: running min exclusion + 1 steps ago
    prev = np.full(shape, _INF, np.float32)
    for k, rho in enumerate(inp.rho):
        c = _hypothesis_cost(inp, float(rho), a0, a1 - a0, bufs)[keep]
        far = (best < k - inp.exclusion).view(np.uint8)
        cv2.copyTo(cv2.min(c2, c), far, c2)
        better = (c < c1).view(np.uint8)
        cv2.copyTo(lagged[k % len(lagged)], better, c2)  # the costs before k - exclusion
        cv2.copyTo(prev, better, left)
        cv2.copyTo(c, better, c1)
        cv2.copyTo(np.full(shape, k, np.float32), better, best)
        cv2.copyTo(c, (best == k - 1).view(np.uint8), right)
        cv2.min(running, c, running)
        lagged[k % len(lagged)] = running.copy()
        prev = c
    return r0, c1, c2, best, left, right


def sweep(inp: SweepInput, threads: int = 1, progress=None, stage: str = "dense: sweep") -> SweepResult:
    """Run the plane sweep over every hypothesis (module docstring).

    Parameters
    ----------
    inp : SweepInput
    threads : int
        Bands processed at once.
    progress : callable, optional
        Receives a ``ProgressEvent`` per band done.

    Returns
    -------
    SweepResult
    """
    H, W = inp.ref.shape
    bands = [(r0, min(r0 + BAND_ROWS, H)) for r0 in range(0, H, BAND_ROWS)]
    out = {name: np.empty((H, W), np.float32) for name in ("c1", "c2", "best", "left", "right")}
    pool = ThreadPoolExecutor(max(1, threads))
    try:
        with np.errstate(invalid="ignore", over="ignore"):
            for done, (r0, *parts) in enumerate(pool.map(lambda b: _band(inp, *b), bands), start=1):
                for name, part in zip(("c1", "c2", "best", "left", "right"), parts):
                    out[name][r0:r0 + len(part)] = part
                report(progress, stage, done, len(bands))
    except BaseException:  # an interrupt: drop the bands not started, do not wait for them
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    return _refine_minimum(out, len(inp.rho), inp.best_k * inp.window**2)


def _refine_minimum(out: dict, n_depths: int, samples: int) -> SweepResult:
    """Parabola through the best cost and its neighbours: the fractional index
    ``i + (l - r) / (2 (l - 2 c + r))``; NaN at the ends of the range (the depth may lie
    beyond the limits). Costs become means per sample."""
    c1, l, r, best = out["c1"], out["left"], out["right"], out["best"]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        den = l - 2.0 * c1 + r
        inner = (best > 0) & (best < n_depths - 1) & np.isfinite(den) & (den > 0)
        frac = np.where(inner, 0.5 * (l - r) / np.where(inner, den, 1.0), np.nan)
    index = (best + np.clip(frac, -0.5, 0.5)).astype(np.float32)
    scale = np.float32(1.0 / samples)
    return SweepResult(c1=c1 * scale, c2=out["c2"] * scale, index=index,
                       curvature=np.where(inner, den, np.nan).astype(np.float32) * scale)
