"""Procedural textures of rendered surfaces, box-filtered so that renders are alias-free.

A texture is a callable ``(s, t, ws, wt) -> value in [0, 1]``: ``s, t`` are surface
coordinates of the samples, ``ws, wt`` the widths of their footprints. Checkers and
squares integrate the box filter in closed form (so edges land exactly where the
projection says); :class:`Noise` is a band-limited multi-scale noise (a natural-looking
texture); :class:`Tiled` repeats one patch periodically (a repetitive texture whose
descriptors are ambiguous, like tiles or bricks).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["Checker", "Squares", "Noise", "Constant", "Tiled"]

def _box_integral_periodic(x: np.ndarray, a: float) -> np.ndarray:
    """Integral from 0 to x of the square wave that is 1 on [a, 2a) mod 2a, else 0."""
    period = 2.0 * a
    k = np.floor(x / period)
    return a * k + np.clip(x - k * period - a, 0.0, a)


def _filtered(F, x: np.ndarray, w: np.ndarray, direct) -> np.ndarray:
    """Box filter of width ``w`` centred at ``x`` of the function with integral ``F``."""
    w = np.asarray(w)
    tiny = w < 1e-9
    w_safe = np.where(tiny, 1.0, w)
    out = (F(x + 0.5 * w_safe) - F(x - 0.5 * w_safe)) / w_safe
    if np.any(tiny):
        out = np.where(tiny, direct(x), out)
    return out


@dataclass(frozen=True)
class Checker:
    """Checkerboard of square cells of side ``cell`` (surface units).

    The cell whose lower corner is the surface origin is ``light``.
    """

    cell: float
    dark: float = 0.08
    light: float = 0.92

    def __call__(self, s, t, ws, wt):
        a = self.cell
        F = lambda x: _box_integral_periodic(x, a)  # noqa: E731
        direct = lambda x: (np.floor(x / a) % 2 == 1).astype(float)  # noqa: E731
        fs, ft = _filtered(F, s, ws, direct), _filtered(F, t, wt, direct)
        odd = fs + ft - 2.0 * fs * ft  # box filter of xor, exact since separable
        return self.light + (self.dark - self.light) * odd


@dataclass(frozen=True, eq=False)
class Squares:
    """Dark axis-aligned rectangles on a light ground (the paper's target board).

    ``rects`` is ``(n, 4)``: ``s0, t0, s1, t1`` in surface units.
    """

    rects: np.ndarray
    dark: float = 0.06
    light: float = 0.9

    def __call__(self, s, t, ws, wt):
        cover = np.zeros(np.shape(s))
        for s0, t0, s1, t1 in np.asarray(self.rects, float):  # few rectangles; vectorised over pixels
            Fs = lambda x, lo=s0, hi=s1: np.clip(x - lo, 0.0, hi - lo)  # noqa: E731
            Ft = lambda x, lo=t0, hi=t1: np.clip(x - lo, 0.0, hi - lo)  # noqa: E731
            ds = lambda x, lo=s0, hi=s1: ((x >= lo) & (x < hi)).astype(float)  # noqa: E731
            dt = lambda x, lo=t0, hi=t1: ((x >= lo) & (x < hi)).astype(float)  # noqa: E731
            cover += _filtered(Fs, s, ws, ds) * _filtered(Ft, t, wt, dt)
        return self.light + (self.dark - self.light) * np.clip(cover, 0.0, 1.0)


@dataclass(frozen=True, eq=False)
class Noise:
    """Natural-looking texture: multi-scale smoothed Gaussian noise (1/f-like).

    A grid of ``texel``-spaced values covering ``extent`` (surface units), the sum of
    white noise smoothed at ``texel * 2**k`` for ``k = 0..octaves-1``, then
    interpolated bicubically. Choose ``texel`` so that it spans at least ~1 pixel in
    the images (the texture is band-limited at that scale, hence alias-free).
    """

    texel: float
    extent: tuple[float, float]
    seed: int = 0
    octaves: int = 5
    mean: float = 0.5
    contrast: float = 0.18
    _grid: np.ndarray = field(default=None, repr=False)

    def __post_init__(self):
        rng = np.random.default_rng(self.seed)
        nw = int(np.ceil(self.extent[0] / self.texel)) + 8
        nh = int(np.ceil(self.extent[1] / self.texel)) + 8
        acc = np.zeros((nh, nw))
        for k in range(self.octaves):
            sigma = 1.0 * 2.0**k
            layer = cv2.GaussianBlur(rng.normal(size=(nh, nw)).astype(np.float32), (0, 0), sigma,
                                     borderType=cv2.BORDER_REFLECT).astype(float)
            acc += layer / layer.std() * 0.8**k
        acc = self.mean + self.contrast * acc / acc.std()
        # prefiltered levels (Gaussian sigma 0, 1, 2, 4, 8 texels) against aliasing where a
        # sample's footprint spans several texels (grazing views, far surfaces)
        acc = acc.astype(np.float32)
        levels = [acc] + [cv2.GaussianBlur(acc, (0, 0), 2.0**k, borderType=cv2.BORDER_REPLICATE) for k in range(4)]
        object.__setattr__(self, "_grid", levels)

    def __call__(self, s, t, ws, wt):
        x = (np.asarray(s) / self.texel + 4.0).astype(np.float32).ravel()
        y = (np.asarray(t) / self.texel + 4.0).astype(np.float32).ravel()
        foot = np.maximum(np.asarray(ws), np.asarray(wt)).ravel() / self.texel
        level = np.clip(np.rint(np.log2(np.maximum(foot, 1e-9))) + 1, 0, len(self._grid) - 1).astype(int)
        out = np.empty(x.size)
        for k in np.unique(level):  # a handful of levels, vectorised within each
            m = level == k
            out[m] = _remap_points(self._grid[k], x[m], y[m])
        return out.reshape(np.shape(s))


@dataclass(frozen=True)
class Constant:
    """Uniform grey ``value``."""

    value: float = 0.5

    def __call__(self, s, t, ws, wt):
        return np.full(np.shape(s), float(self.value))


def _remap_points(img: np.ndarray, x: np.ndarray, y: np.ndarray, interp=cv2.INTER_CUBIC) -> np.ndarray:
    """Sample ``img`` at float32 points ``x, y`` (1-D) with cv2.remap (any count)."""
    n = x.size
    width = 1024
    rows = max(1, -(-n // width))
    pad = rows * width - n
    mx = np.concatenate([x, np.zeros(pad, np.float32)]).reshape(rows, width)
    my = np.concatenate([y, np.zeros(pad, np.float32)]).reshape(rows, width)
    out = np.empty((rows, width), np.float32)
    step = 30000  # cv2 map dimensions must stay below 32767
    for r0 in range(0, rows, step):
        out[r0:r0 + step] = cv2.remap(img, mx[r0:r0 + step], my[r0:r0 + step], interp,
                                      borderMode=cv2.BORDER_REPLICATE)
    return out.ravel()[:n]


@dataclass(frozen=True)
class _Framed:
    """A texture inside ``[m, s1] x [m, t1]`` and ``light`` outside (box-filtered)."""

    inner: Checker
    m: float
    s1: float
    t1: float

    def __call__(self, s, t, ws, wt):
        Fs = lambda x: np.clip(x - self.m, 0.0, self.s1 - self.m)  # noqa: E731
        Ft = lambda x: np.clip(x - self.m, 0.0, self.t1 - self.m)  # noqa: E731
        ds = lambda x: ((x >= self.m) & (x < self.s1)).astype(float)  # noqa: E731
        dt = lambda x: ((x >= self.m) & (x < self.t1)).astype(float)  # noqa: E731
        inside = _filtered(Fs, s, ws, ds) * _filtered(Ft, t, wt, dt)
        # shift so that the checker's cell grid starts at the frame's corner
        v = self.inner(s - self.m, t - self.m, ws, wt)
        return self.inner.light + inside * (v - self.inner.light)


@dataclass(frozen=True)
class Tiled:
    """``inner`` repeated with period ``period`` (surface units) in ``s`` and ``t``, with
    dark grout lines of width ``grout`` between tiles: a repetitive texture whose tiles
    are identical, so descriptors alone cannot tell them apart.

    ``inner`` is sampled on ``[0, period)^2``; give it an ``extent`` of at least that.
    """

    inner: object
    period: float
    grout: float = 0.0
    dark: float = 0.15

    def __call__(self, s, t, ws, wt):
        p = self.period
        v = self.inner(np.mod(s, p), np.mod(t, p), ws, wt)
        if self.grout <= 0:
            return v
        g = self.grout
        # coverage of the grout (a square wave of duty g/p in each axis), box-filtered
        Fg = lambda x: p * np.floor(x / p) * (g / p) + np.clip(np.mod(x, p) - (p - g), 0.0, g)  # noqa: E731
        dg = lambda x: (np.mod(x, p) >= p - g).astype(float)  # noqa: E731
        gs, gt = _filtered(Fg, s, ws, dg), _filtered(Fg, t, wt, dg)
        cover = gs + gt - gs * gt
        return v + (self.dark - v) * cover
