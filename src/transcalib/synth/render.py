"""Rendering of textured planar scenes seen by a translated camera, with exact truth.

A scene is a list of :class:`Surface` rectangles (planes, box faces, boards) with a
procedural texture each. :func:`render` ray-casts every pixel of every view::

    pixel (u, v)  ->  distorted normalised (x_d, y_d) = K^-1 [u, v, 1]
                  ->  undistorted (x, y)            (camera.undistort, OpenCV model)
                  ->  world ray  T_i + z R^T [x, y, 1]
                  ->  nearest surface hit (s, t) in the surface's own coordinates
                  ->  texture value, box-filtered analytically over the sample footprint

so a scene point ``X`` appears exactly at ``camera.project(K, R, X, T, dist)``: the
centre of the top-left pixel is (0, 0) (OpenCV). Anti-aliasing combines ``S x S``
supersampling of each pixel with analytic box filtering of the textures (checkers and
squares are integrated in closed form; the noise texture is band-limited). The filter
is symmetric, so an edge or corner renders centred where the projection says.

>>> from transcalib import render
>>> r = render.render_scene("checker", n_views=4, image_size=(320, 240), rng=0)
>>> r.images.shape, r.images.dtype
((4, 240, 320), dtype('uint8'))
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.camera import K_from_params, project, undistort
from .simulate import Scene
from ..types import InputError

__all__ = [
    "Checker",
    "Squares",
    "Noise",
    "Constant",
    "Surface",
    "plane",
    "box",
    "paper_board",
    "checker_board",
    "render",
    "Rendered",
    "render_scene",
    "robot_translations",
    "SCENE_KINDS",
]


# --------------------------------------------------------------------------- textures
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


# --------------------------------------------------------------------------- geometry
@dataclass(frozen=True, eq=False)
class Surface:
    """A textured rectangle ``origin + s * axis_s + t * axis_t``, ``0 <= s <= size[0]``,
    ``0 <= t <= size[1]``; ``axis_s``, ``axis_t`` orthonormal (world frame).

    Attributes
    ----------
    origin, axis_s, axis_t : (3,) float
    size : (2,) float
        Extent along ``axis_s`` and ``axis_t`` (world units).
    texture : callable ``(s, t, ws, wt) -> value in [0, 1]``
        ``ws, wt`` are the sample footprint widths for box filtering.
    name : str
    cull_back : bool
        Invisible from the side opposite its normal ``axis_s x axis_t`` (faces of a
        closed solid); skipped when the camera is behind it, to save time.
    """

    origin: np.ndarray
    axis_s: np.ndarray
    axis_t: np.ndarray
    size: tuple[float, float]
    texture: object
    name: str = ""
    cull_back: bool = False

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.axis_s, self.axis_t)

    def point(self, st: np.ndarray) -> np.ndarray:
        """World points ``(n, 3)`` of surface coordinates ``st`` ``(n, 2)``."""
        st = np.asarray(st, float)
        return self.origin + st[:, :1] * self.axis_s + st[:, 1:2] * self.axis_t


def plane(center, normal_rot, size, texture, name: str = "") -> Surface:
    """A rectangle centred at ``center`` (3,), with axes the first two columns of the
    rotation ``normal_rot`` (3, 3) (its third column is the normal), extent ``size``."""
    Rm = np.asarray(normal_rot, float)
    a, b = Rm[:, 0], Rm[:, 1]
    w, h = size
    origin = np.asarray(center, float) - 0.5 * w * a - 0.5 * h * b
    return Surface(origin, a, b, (float(w), float(h)), texture, name)


def box(center, rot, dims, textures, name: str = "box") -> list[Surface]:
    """The six faces of a box of ``dims`` (dx, dy, dz) centred at ``center``.

    ``rot`` (3, 3): box axes in the world; ``textures``: one texture or a list of six.
    """
    Rm = np.asarray(rot, float)
    c = np.asarray(center, float)
    d = np.asarray(dims, float)
    if not isinstance(textures, (list, tuple)):
        textures = [textures] * 6
    faces = []
    ex, ey, ez = Rm[:, 0], Rm[:, 1], Rm[:, 2]
    # (normal axis index, sign): face centre c + sign * d[k]/2 * e_k, face axes the other two
    axes = [ex, ey, ez]
    for f, (k, sign) in enumerate([(0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)]):
        i, j = [m for m in range(3) if m != k]
        a, b = axes[i], axes[j]
        if np.dot(np.cross(a, b), sign * axes[k]) < 0:
            b = -b  # outward normal, for back-face culling
        fr = np.column_stack([a, b, np.cross(a, b)])
        sf = plane(c + sign * 0.5 * d[k] * axes[k], fr, (d[i], d[j]), textures[f], f"{name}{f}")
        faces.append(Surface(sf.origin, sf.axis_s, sf.axis_t, sf.size, sf.texture, sf.name, cull_back=True))
    return faces


def paper_board(center, rot, square: float = 30.0, gap: float = 20.0, cols: int = 3, rows: int = 2,
                margin: float = 25.0, name: str = "board") -> tuple[Surface, np.ndarray]:
    """The paper's target: ``cols x rows`` black squares of side ``square`` on a white board.

    Returns
    -------
    surface : Surface
    corners : (4 * cols * rows, 3) float
        Exact world corners, square by square (row-major from the board's (s, t)
        origin), each square's corners in the order (s0,t0), (s1,t0), (s1,t1), (s0,t1).
    """
    pitch = square + gap
    W = 2 * margin + cols * square + (cols - 1) * gap
    H = 2 * margin + rows * square + (rows - 1) * gap
    rects, corners = [], []
    for r in range(rows):
        for c in range(cols):
            s0, t0 = margin + c * pitch, margin + r * pitch
            rects.append([s0, t0, s0 + square, t0 + square])
            corners += [[s0, t0], [s0 + square, t0], [s0 + square, t0 + square], [s0, t0 + square]]
    surf = plane(center, rot, (W, H), Squares(np.array(rects)), name)
    return surf, surf.point(np.array(corners))


def checker_board(center, rot, cell: float, cols: int, rows: int, margin: float = 0.0,
                  name: str = "checker") -> tuple[Surface, np.ndarray]:
    """A ``cols x rows``-cell checkerboard (with a light margin of ``margin`` cells).

    Returns the surface and its interior corners ``((cols-1)*(rows-1), 3)`` (world).
    """
    W, H = (cols + 2 * margin) * cell, (rows + 2 * margin) * cell
    inner = Checker(cell)
    if margin > 0:
        m = margin * cell
        tex = _Framed(inner, m, W - m, H - m)
    else:
        tex = inner
    surf = plane(center, rot, (W, H), tex, name)
    ii, jj = np.meshgrid(np.arange(1, cols), np.arange(1, rows))
    st = np.column_stack([ii.ravel(), jj.ravel()]) * cell + margin * cell
    return surf, surf.point(st)


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


# --------------------------------------------------------------------------- rendering
def _rays(K, R, dist, image_size, S):
    """World ray directions of the sub-pixel samples: three arrays ``(H*S, W*S)``."""
    w, h = image_size
    off = (np.arange(S) + 0.5) / S - 0.5
    u = (np.arange(w)[:, None] + off[None, :]).ravel()
    v = (np.arange(h)[:, None] + off[None, :]).ravel()
    fx, sk, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    y = ((v - cy) / fy)[:, None]
    x = (u[None, :] - cx - sk * y) / fx
    y = np.broadcast_to(y, x.shape)
    if np.asarray(dist).size and np.any(np.asarray(dist) != 0):
        xy = undistort(np.stack([x, y], axis=-1), dist)
        x, y = xy[..., 0], xy[..., 1]
    # R^T [x, y, 1]: camera z = 1 at unit ray parameter
    return [x * R[0, k] + y * R[1, k] + R[2, k] for k in range(3)]


def _crop(sf, K, R, dist, C, image_size, S):
    """Sample-grid rows/cols slice covering surface ``sf`` in the view at ``C``."""
    w, h = image_size
    if sf.cull_back and np.dot(sf.normal, C - sf.origin) <= 0:
        return None  # back face of a closed solid: hidden by the front faces
    full = (slice(0, h * S), slice(0, w * S))
    if np.asarray(dist).size and np.any(np.asarray(dist) != 0):
        return full  # distortion can fold far-off points: render the whole frame
    P = sf.point(np.array([[0, 0], [sf.size[0], 0], [sf.size[0], sf.size[1]], [0, sf.size[1]]], float))
    Xc = (P - C) @ R.T
    if np.any(Xc[:, 2] <= 1e-9 * np.abs(Xc).max()):
        return full
    uv = Xc[:, :2] / Xc[:, 2:] @ K[:2, :2].T + K[:2, 2]
    lo = np.floor((uv.min(0) - 2.0 + 0.5) * S - 0.5).astype(int)
    hi = np.ceil((uv.max(0) + 2.0 + 0.5) * S - 0.5).astype(int) + 1
    if hi[0] <= 0 or hi[1] <= 0 or lo[0] >= w * S or lo[1] >= h * S:
        return None
    return (slice(max(lo[1], 0), min(hi[1], h * S)), slice(max(lo[0], 0), min(hi[0], w * S)))


def _surface_coords(sf, d, C, sl):
    """Depth ``z`` and surface coordinates ``s, t`` of the rays ``d[sl]`` from ``C``."""
    dx, dy, dz = d[0][sl], d[1][sl], d[2][sl]
    n = sf.normal
    a, b = sf.axis_s, sf.axis_t
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (n @ (sf.origin - C)) / (dx * n[0] + dy * n[1] + dz * n[2])
    s = z * (dx * a[0] + dy * a[1] + dz * a[2]) + (C - sf.origin) @ a
    t = z * (dx * b[0] + dy * b[1] + dz * b[2]) + (C - sf.origin) @ b
    return z, s, t


def _render_view(surfaces, d, C, S, background, K, R, dist, image_size):
    """Supersampled intensity of one view: rays ``d`` (3 arrays ``(Hs, Ws)``), centre ``C``."""
    Hs, Ws = d[0].shape
    best = np.full((Hs, Ws), np.inf)
    owner = np.full((Hs, Ws), -1, dtype=np.int32)
    crops, coords = [], []
    for k, sf in enumerate(surfaces):  # pass 1: z-buffer
        sl = _crop(sf, K, R, dist, C, image_size, S)
        crops.append(sl)
        if sl is None:
            coords.append(None)
            continue
        z, s, t = _surface_coords(sf, d, C, sl)
        hit = (z > 0) & (s >= 0) & (s <= sf.size[0]) & (t >= 0) & (t <= sf.size[1]) & (z < best[sl])
        best[sl][hit] = z[hit]
        owner[sl][hit] = k
        coords.append((s, t) if hit.any() else None)
    out = np.full((Hs, Ws), float(background))
    for k, sf in enumerate(surfaces):  # pass 2: texture of the visible samples
        sl = crops[k]
        if sl is None or coords[k] is None:
            continue
        m = owner[sl] == k
        if not m.any():
            continue
        s, t = coords[k]
        # footprint of one sample in surface units: bounding box of its parallelogram
        with np.errstate(invalid="ignore"):
            ws = np.abs(np.gradient(s, axis=1)[m]) + np.abs(np.gradient(s, axis=0)[m]) if min(s.shape) > 1 else 0 * s[m]
            wt = np.abs(np.gradient(t, axis=1)[m]) + np.abs(np.gradient(t, axis=0)[m]) if min(t.shape) > 1 else 0 * t[m]
        ws = np.where(np.isfinite(ws), ws, 0.0)
        wt = np.where(np.isfinite(wt), wt, 0.0)
        out[sl][m] = sf.texture(s[m], t[m], ws, wt)
    return out.reshape(Hs // S, S, Ws // S, S).mean(axis=(1, 3))


def render(
    surfaces,
    K: np.ndarray,
    R: np.ndarray,
    T: np.ndarray,
    image_size: tuple[int, int],
    *,
    dist=(),
    supersample: int = 2,
    background: float = 0.5,
    noise_std: float = 0.0,
    blur_sigma: float = 0.0,
    gain=None,
    offset=None,
    dtype: str = "uint8",
    rng=None,
) -> np.ndarray:
    """Render grey images of ``surfaces`` from the camera at each translation.

    Parameters
    ----------
    surfaces : list of Surface
    K, R : (3, 3) float
        Intrinsics and rotation world -> camera.
    T : (n_views, 3) float
        Camera centres (robot translations), world units.
    image_size : (width, height)
    dist : (k,) float
        OpenCV distortion coefficients of the lens (applied exactly, per sample).
    supersample : int
        ``S``: ``S x S`` samples per pixel (plus analytic box filtering of textures).
    background : float
        Intensity (0..1) where no surface is hit.
    noise_std : float
        Gaussian noise standard deviation, in grey levels of 0..255.
    blur_sigma : float
        Gaussian blur (pixels) applied after integration (optics defocus).
    gain, offset : (n_views,) float or None
        Brightness change per view: ``I' = gain * I + offset`` (offset in 0..1 units).
    dtype : {"uint8", "float"}
        ``uint8`` (rounded 0..255) or ``float64`` in 0..255 units.
    rng : seed or Generator
        For the noise.

    Returns
    -------
    images : (n_views, height, width) uint8 or float
    """
    rng = np.random.default_rng(rng)
    T = np.atleast_2d(np.asarray(T, float))
    w, h = (int(image_size[0]), int(image_size[1]))
    if T.shape[1] != 3 or w < 2 or h < 2 or supersample < 1:
        raise InputError(f"render: need T (n_views, 3), image_size >= 2 and supersample >= 1; got T {T.shape}, "
                         f"image_size {image_size}, supersample {supersample}")
    d = _rays(np.asarray(K, float), np.asarray(R, float), dist, (w, h), int(supersample))
    n = len(T)
    gain = np.ones(n) if gain is None else np.broadcast_to(np.asarray(gain, float), (n,))
    offset = np.zeros(n) if offset is None else np.broadcast_to(np.asarray(offset, float), (n,))
    out = np.empty((n, h, w), np.uint8 if dtype == "uint8" else float)
    for i in range(n):
        img = _render_view(surfaces, d, T[i], int(supersample), background, np.asarray(K, float),
                           np.asarray(R, float), dist, (w, h))
        img = (gain[i] * img + offset[i]) * 255.0
        if blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), blur_sigma, borderType=cv2.BORDER_REPLICATE)
        if noise_std > 0:
            img = img + rng.normal(0.0, noise_std, img.shape)
        out[i] = np.clip(np.rint(img), 0, 255) if dtype == "uint8" else img
    return out


# --------------------------------------------------------------------------- scenes
@dataclass(frozen=True, eq=False)
class Rendered:
    """Rendered images with their exact ground truth.

    Attributes
    ----------
    images : (n_views, height, width) uint8
    K, R : (3, 3) float
    dist : (k,) float
    T : (n_views, 3) float
        Exact camera translations.
    surfaces : list of Surface
    corners : (n_corners, 3) float
        Exact 3-D feature points (checker inner corners, board square corners).
    corner_kind : (n_corners,) str
        ``"checker"`` or ``"board"`` per corner.
    image_size : (width, height)
    """

    images: np.ndarray
    K: np.ndarray
    R: np.ndarray
    dist: np.ndarray
    T: np.ndarray
    surfaces: list
    corners: np.ndarray
    corner_kind: np.ndarray
    image_size: tuple[int, int]
    meta: dict = field(default_factory=dict)

    def project(self, X: np.ndarray) -> np.ndarray:
        """Exact pixels ``(n_views, n, 2)`` of world points ``X`` ``(n, 3)``."""
        return project(self.K, self.R, np.asarray(X, float).reshape(-1, 3), self.T, self.dist)

    def backproject(self, view: int, uv: np.ndarray, return_surface: bool = False):
        """World points ``(n, 3)`` seen at pixels ``uv`` ``(n, 2)`` of ``view`` (NaN: background).

        With ``return_surface``, also the index ``(n,)`` into ``surfaces`` of the surface
        hit (-1: none).
        """
        uv = np.asarray(uv, float).reshape(-1, 2)
        fx, sk, cx, fy, cy = self.K[0, 0], self.K[0, 1], self.K[0, 2], self.K[1, 1], self.K[1, 2]
        y = (uv[:, 1] - cy) / fy
        x = (uv[:, 0] - cx - sk * y) / fx
        xy = undistort(np.column_stack([x, y]), self.dist)
        d = np.column_stack([xy, np.ones(len(uv))]) @ self.R
        C = self.T[view]
        best = np.full(len(uv), np.inf)
        which = np.full(len(uv), -1)
        for k, sf in enumerate(self.surfaces):
            n = sf.normal
            with np.errstate(divide="ignore", invalid="ignore"):
                z = (n @ (sf.origin - C)) / (d @ n)
            s = z * (d @ sf.axis_s) + (C - sf.origin) @ sf.axis_s
            t = z * (d @ sf.axis_t) + (C - sf.origin) @ sf.axis_t
            hit = (z > 0) & (s >= 0) & (s <= sf.size[0]) & (t >= 0) & (t <= sf.size[1]) & (z < best)
            best[hit] = z[hit]
            which[hit] = k
        X = C + best[:, None] * d
        X[~np.isfinite(best)] = np.nan
        return (X, which) if return_surface else X

    def track_truth(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth of tracks ``uv (n_views, n, 2)``: the world point ``(n, 3)`` seen at
        each track's first observation, and ``(n,)`` bool, True where that observation is
        next to an occlusion edge (a T-junction of two depths has no fixed 3-D point)."""
        seen = np.isfinite(uv[..., 0])
        first = np.argmax(seen, axis=0)
        X = np.full((uv.shape[1], 3), np.nan)
        junction = np.zeros(uv.shape[1], bool)
        for v in range(uv.shape[0]):
            mine = first == v
            X[mine] = self.backproject(v, uv[v, mine])
            junction[mine] = self.near_occlusion(v, uv[v, mine])
        return X, junction

    def near_occlusion(self, view: int, uv: np.ndarray, radius_px: float = 10.0) -> np.ndarray:
        """``(n,)`` bool: a different surface (or background) lies within ``radius_px`` of
        pixels ``uv`` in ``view`` - features there may be occlusion ghosts (T-junctions),
        which have no fixed 3-D point."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        if len(uv) == 0:
            return np.zeros(0, bool)
        ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        offs = np.concatenate([f * radius_px * np.column_stack([np.cos(ang), np.sin(ang)]) for f in (0.5, 1.0)])
        _, s0 = self.backproject(view, uv, return_surface=True)
        _, s = self.backproject(view, (uv[:, None, :] + offs[None]).reshape(-1, 2), return_surface=True)
        return np.any(s.reshape(len(uv), -1) != s0[:, None], axis=1)

    def visible(self, X: np.ndarray, margin_px: float = 0.0, tol: float = 1e-6) -> np.ndarray:
        """``(n_views, n)`` bool: point inside the image (by ``margin_px``) and not occluded."""
        X = np.asarray(X, float).reshape(-1, 3)
        uv = self.project(X)
        w, h = self.image_size
        vis = ((uv[..., 0] >= margin_px - 0.5) & (uv[..., 0] <= w - 0.5 - margin_px)
               & (uv[..., 1] >= margin_px - 0.5) & (uv[..., 1] <= h - 0.5 - margin_px))
        scale = np.linalg.norm(X - self.T.mean(0), axis=1)
        for i in range(len(self.T)):
            Xb = self.backproject(i, uv[i])
            err = np.linalg.norm(Xb - X, axis=1)
            vis[i] &= np.isfinite(err) & (err <= tol * scale + 1e-9 + 1e-4 * scale)
        return vis

    def scene(self, X: np.ndarray | None = None) -> Scene:
        """A :class:`transcalib.simulate.Scene` of points ``X`` (default: ``corners``).

        ``uv`` is the exact projection, NaN where a point is outside the image or occluded.
        """
        X = self.corners if X is None else np.asarray(X, float).reshape(-1, 3)
        uv_true = self.project(X)
        uv = uv_true.copy()
        uv[~self.visible(X)] = np.nan
        return Scene(K=self.K, R=self.R, dist=np.asarray(self.dist, float), T_true=self.T.copy(), X=X,
                     T=self.T.copy(), uv=uv, uv_true=uv_true, image_size=self.image_size,
                     meta={"preset": "rendered", **self.meta})


SCENE_KINDS = ("checker", "natural", "board", "mixed")


def robot_translations(n_views: int, length: float, rng) -> np.ndarray:
    """``(n_views, 3)`` translations: view 0 at the origin, then three orthogonal moves of
    ``length`` (random directions), further views random with lengths ``U(0.6, 1) * length``."""
    rng = np.random.default_rng(rng)
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0].T
    dirs = [q for q in Q]
    for _ in range(max(0, n_views - 4)):
        v = rng.normal(size=3)
        dirs.append(v / np.linalg.norm(v) * rng.uniform(0.6, 1.0))
    T = np.vstack([np.zeros(3)] + [length * d for d in dirs])
    return T[:n_views]


def render_scene(
    kind: str = "mixed",
    n_views: int = 5,
    image_size: tuple[int, int] = (800, 600),
    *,
    K: np.ndarray | None = None,
    R: np.ndarray | None = None,
    T: np.ndarray | None = None,
    dist=(),
    distance: float = 1000.0,
    baseline: float = 0.12,
    noise_std: float = 1.0,
    blur_sigma: float = 0.0,
    brightness: float = 0.0,
    supersample: int = 2,
    rng=None,
) -> Rendered:
    """Render a preset scene with ground truth.

    Parameters
    ----------
    kind : {"checker", "natural", "board", "mixed"}
        ``checker``: a large checkerboard and a checkered box in front of a plain wall;
        ``natural``: a noise-textured wall and two textured boxes at other depths;
        ``board``: the paper's six black squares on a white board in front of a textured
        wall; ``mixed``: textured wall, checkerboard, paper board and a textured box.
    n_views : int
        Number of views (>= 2).
    image_size : (width, height)
    K, R, T : arrays, optional
        Camera (default: fx ~ 0.95 w, fy = 1.04 fx (non-square pixels), principal point
        off centre), orientation world -> camera (default: random), translations
        (default: :func:`robot_translations` of length ``baseline * distance``).
    dist : (k,) float
        Lens distortion (OpenCV).
    distance : float
        Distance of the scene from the camera (mm).
    noise_std, blur_sigma : float
        See :func:`render`.
    brightness : float
        Relative gain change between views: gains ``1 + U(-b, b)``.
    supersample : int
    rng : seed or Generator

    Returns
    -------
    Rendered
    """
    if kind not in SCENE_KINDS:
        raise InputError(f"unknown scene kind {kind!r}; expected one of {SCENE_KINDS}")
    rng = np.random.default_rng(rng)
    w, h = image_size
    if K is None:
        fx = 0.95 * w
        K = K_from_params(fx, 1.04 * fx, w / 2 - 0.5 + 0.04 * w, h / 2 - 0.5 - 0.03 * h)
    K = np.asarray(K, float)
    if R is None:
        R = Rotation.from_euler("xyz", rng.uniform(-180, 180, 3), degrees=True).as_matrix()
    R = np.asarray(R, float)
    if T is None:
        T = robot_translations(n_views, baseline * distance, rng)
    T = np.asarray(T, float)
    D = distance
    # half-extent of the field of view at distance D (camera-0 frame)
    fov_w = D * w / K[0, 0]
    fov_h = D * h / K[1, 1]

    def tilt(ax, ay):
        return Rotation.from_euler("xy", [ax, ay], degrees=True).as_matrix()

    surfaces_c: list[Surface] = []  # built in the camera-0 frame, moved to the world below
    corners_c, kinds = [], []
    wall_z = 1.35 * D
    wall_size = (3.0 * fov_w * 1.35, 3.0 * fov_h * 1.35)
    seed = int(rng.integers(2**31))
    if kind == "checker":
        surfaces_c.append(plane([0, 0, wall_z], tilt(0, 0), wall_size, Constant(0.55), "wall"))
        cell = fov_w / 16
        sb, cb = checker_board([0.05 * fov_w, 0.02 * fov_h, D], tilt(12, -18), cell, 13, 9, margin=0.6)
        surfaces_c.append(sb)
        corners_c.append(cb)
        kinds += ["checker"] * len(cb)
        cell2 = fov_w / 30
        faces = box([-0.25 * fov_w, 0.2 * fov_h, 0.8 * D], tilt(25, 30), [5 * cell2, 5 * cell2, 5 * cell2],
                    Checker(cell2), "cbox")
        surfaces_c += faces
    elif kind == "natural":
        texel = D / K[0, 0] * 1.4
        surfaces_c.append(plane([0, 0, wall_z], tilt(8, -6), wall_size,
                                Noise(texel * 1.35, wall_size, seed), "wall"))
        for b, (c, dims, rot) in enumerate([
            ([-0.18 * fov_w, 0.1 * fov_h, 0.85 * D], [0.3 * fov_w] * 3, tilt(20, 35)),
            ([0.2 * fov_w, -0.12 * fov_h, 0.7 * D], [0.22 * fov_w, 0.3 * fov_h, 0.2 * fov_w], tilt(-15, -25)),
        ]):
            ext = (max(dims) * 1.1, max(dims) * 1.1)
            tex = [Noise(texel * 0.9, ext, seed + 10 * b + f) for f in range(6)]
            surfaces_c += box(c, rot, dims, tex, f"box{b}")
    elif kind == "board":
        texel = D / K[0, 0] * 1.4
        surfaces_c.append(plane([0, 0, wall_z], tilt(5, 5), wall_size, Noise(texel * 1.35, wall_size, seed), "wall"))
        sq = fov_w / 9
        sb, cb = paper_board([0, 0, D], tilt(15, -10), square=sq, gap=0.66 * sq, margin=0.8 * sq)
        surfaces_c.append(sb)
        corners_c.append(cb)
        kinds += ["board"] * len(cb)
    else:  # mixed
        texel = D / K[0, 0] * 1.4
        surfaces_c.append(plane([0, 0, wall_z], tilt(6, -4), wall_size, Noise(texel * 1.35, wall_size, seed), "wall"))
        cell = fov_w / 24
        sb, cb = checker_board([-0.2 * fov_w, -0.17 * fov_h, 0.95 * D], tilt(10, 20), cell, 8, 6, margin=0.5)
        surfaces_c.append(sb)
        corners_c.append(cb)
        kinds += ["checker"] * len(cb)
        sq = fov_w / 20
        pb, pc = paper_board([0.22 * fov_w, 0.2 * fov_h, 0.9 * D], tilt(-12, -15), square=sq, gap=0.66 * sq,
                             margin=0.8 * sq)
        surfaces_c.append(pb)
        corners_c.append(pc)
        kinds += ["board"] * len(pc)
        dims = [0.2 * fov_w] * 3
        tex = [Noise(texel * 0.9, (0.25 * fov_w,) * 2, seed + f + 1) for f in range(6)]
        surfaces_c += box([0.22 * fov_w, -0.2 * fov_h, 0.8 * D], tilt(25, 35), dims, tex, "box")

    # camera-0 frame -> world: X_w = R^T X_c (+ T_0); axes rotate likewise
    Rt = R.T
    T0 = T[0]
    surfaces = [Surface(Rt @ sf.origin + T0, Rt @ sf.axis_s, Rt @ sf.axis_t, sf.size, sf.texture, sf.name,
                        sf.cull_back) for sf in surfaces_c]
    corners = (np.vstack(corners_c) @ R + T0) if corners_c else np.zeros((0, 3))
    n = len(T)
    gain = 1.0 + rng.uniform(-brightness, brightness, n) if brightness > 0 else None
    images = render(surfaces, K, R, T, (w, h), dist=dist, supersample=supersample, noise_std=noise_std,
                    blur_sigma=blur_sigma, gain=gain, rng=rng)
    return Rendered(images=images, K=K, R=R, dist=np.asarray(dist, float), T=T, surfaces=surfaces,
                    corners=corners, corner_kind=np.array(kinds, dtype=object), image_size=(int(w), int(h)),
                    meta={"kind": kind, "noise_std": noise_std, "blur_sigma": blur_sigma})
