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

from ..errors import InputError
from ..geometry.camera import K_from_params, project, undistort
from .degrade import Degradations, ViewEffects, degrade_view, draw_view_effects, overlay_box
from .simulate import Scene
from .textures import Checker, Constant, Noise, Squares, Tiled, _Framed

__all__ = [
    "Checker",
    "Squares",
    "Noise",
    "Constant",
    "Tiled",
    "Degradations",
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
    degrade: Degradations | None = None,
    dtype: str = "uint8",
    rng=None,
    return_effects: bool = False,
):
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
    degrade : Degradations or None
        Camera effects (vignetting, exposure, shot/read noise, JPEG, specular highlight,
        overlay; :mod:`transcalib.synth.degrade`). Needs ``dtype="uint8"``.
    dtype : {"uint8", "float"}
        ``uint8`` (rounded 0..255) or ``float64`` in 0..255 units.
    rng : seed or Generator
        For the noise and the per-view draws of ``degrade``.
    return_effects : bool
        Also return the :class:`~transcalib.synth.degrade.ViewEffects` drawn.

    Returns
    -------
    images : (n_views, height, width) uint8 or float
    effects : ViewEffects
        Only with ``return_effects``.
    """
    rng = np.random.default_rng(rng)
    K, R = np.asarray(K, float), np.asarray(R, float)
    T = np.atleast_2d(np.asarray(T, float))
    w, h = (int(image_size[0]), int(image_size[1]))
    _check_render_args(T, w, h, supersample, degrade, dtype)
    S = int(supersample)
    d = _rays(K, R, dist, (w, h), S)
    n = len(T)
    gain = np.ones(n) if gain is None else np.broadcast_to(np.asarray(gain, float), (n,))
    offset = np.zeros(n) if offset is None else np.broadcast_to(np.asarray(offset, float), (n,))
    opt = Degradations() if degrade is None else degrade
    effects = draw_view_effects(opt, n, (w, h), rng)
    out = np.empty((n, h, w), np.uint8 if dtype == "uint8" else float)
    for i in range(n):
        radiance = gain[i] * _render_view(surfaces, d, T[i], S, background, K, R, dist, (w, h)) + offset[i]
        if dtype == "uint8":
            out[i] = degrade_view(radiance, opt, i, effects, blur_sigma=blur_sigma, noise_std=noise_std, rng=rng)
        else:
            out[i] = _float_view(radiance, blur_sigma, noise_std, rng)
    return (out, effects) if return_effects else out


def _check_render_args(T, w, h, supersample, degrade, dtype):
    if T.shape[1] != 3 or w < 2 or h < 2 or supersample < 1:
        raise InputError(f"render: need T (n_views, 3), image_size >= 2 and supersample >= 1; got T {T.shape}, "
                         f"image_size {(w, h)}, supersample {supersample}")
    if dtype not in ("uint8", "float"):
        raise InputError(f"render: dtype must be 'uint8' or 'float', got {dtype!r}")
    if degrade is not None and not isinstance(degrade, Degradations):
        raise InputError(f"render: degrade must be a Degradations or None, got {type(degrade).__name__}")
    if degrade is not None and degrade.active() and dtype != "uint8":
        raise InputError("render: degradations model an 8-bit camera; use dtype='uint8'")


def _float_view(radiance, blur_sigma, noise_std, rng):
    """Unquantised view (0..255 floats): the exact radiance plus optional blur and noise."""
    img = radiance * 255.0
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma, borderType=cv2.BORDER_REPLICATE)
    if noise_std > 0:
        img = img + rng.normal(0.0, noise_std, img.shape)
    return img


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


SCENE_KINDS = ("checker", "natural", "board", "mixed", "repetitive")


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
    degrade: Degradations | None = None,
    supersample: int = 2,
    rng=None,
) -> Rendered:
    """Render a preset scene with ground truth.

    Parameters
    ----------
    kind : {"checker", "natural", "board", "mixed", "repetitive"}
        ``checker``: a large checkerboard and a checkered box in front of a plain wall;
        ``natural``: a noise-textured wall and two textured boxes at other depths;
        ``board``: the paper's six black squares on a white board in front of a textured
        wall; ``mixed``: textured wall, checkerboard, paper board and a textured box;
        ``repetitive``: a wall of identical tiles, a tilted tiled panel in front of it
        and a small textured box (descriptors match the wrong tile easily).
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
        Relative gain change between views: gains ``1 + U(-b, b)`` (the same as
        ``degrade.exposure``; kept for existing callers).
    degrade : Degradations or None
        Camera effects, see :mod:`transcalib.synth.degrade`. Where the overlay and the
        highlights are drawn is in ``meta["overlay_box"]`` and ``meta["specular_uv"]``.
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
    K, R, T = _default_camera(K, R, T, (w, h), n_views, baseline * distance, rng)
    seed = int(rng.integers(2**31))
    surfaces_c, corners_c, kinds = _SCENE_BUILDERS[kind](distance, K, (w, h), seed)
    surfaces, corners = _camera0_to_world(surfaces_c, corners_c, R, T[0])
    gain = 1.0 + rng.uniform(-brightness, brightness, len(T)) if brightness > 0 else None
    images, effects = render(surfaces, K, R, T, (w, h), dist=dist, supersample=supersample, noise_std=noise_std,
                             blur_sigma=blur_sigma, gain=gain, degrade=degrade, rng=rng, return_effects=True)
    opt = Degradations() if degrade is None else degrade
    meta = {"kind": kind, "noise_std": noise_std, "blur_sigma": blur_sigma, "degrade": opt.active(),
            "overlay_box": overlay_box(opt, (w, h)), "specular_uv": effects.specular_uv,
            "exposure_gain": effects.gain}
    return Rendered(images=images, K=K, R=R, dist=np.asarray(dist, float), T=T, surfaces=surfaces,
                    corners=corners, corner_kind=np.array(kinds, dtype=object), image_size=(int(w), int(h)),
                    meta=meta)


def _default_camera(K, R, T, image_size, n_views, length, rng):
    """``K``, ``R``, ``T`` as given, or the defaults of :func:`render_scene`."""
    w, h = image_size
    if K is None:
        fx = 0.95 * w
        K = K_from_params(fx, 1.04 * fx, w / 2 - 0.5 + 0.04 * w, h / 2 - 0.5 - 0.03 * h)
    if R is None:
        R = Rotation.from_euler("xyz", rng.uniform(-180, 180, 3), degrees=True).as_matrix()
    if T is None:
        T = robot_translations(n_views, length, rng)
    return np.asarray(K, float), np.asarray(R, float), np.asarray(T, float)


def _camera0_to_world(surfaces_c, corners_c, R, T0):
    """Move surfaces and corners built in the camera-0 frame to the world:
    ``X_w = R^T X_c + T_0`` (axes rotate likewise)."""
    Rt = R.T
    surfaces = [Surface(Rt @ sf.origin + T0, Rt @ sf.axis_s, Rt @ sf.axis_t, sf.size, sf.texture, sf.name,
                        sf.cull_back) for sf in surfaces_c]
    corners = (np.vstack(corners_c) @ R + T0) if corners_c else np.zeros((0, 3))
    return surfaces, corners


def _tilt(ax, ay):
    return Rotation.from_euler("xy", [ax, ay], degrees=True).as_matrix()


def _frame(D, K, image_size):
    """Field of view at distance ``D`` (camera-0 frame), the wall's depth and size."""
    w, h = image_size
    fov_w, fov_h = D * w / K[0, 0], D * h / K[1, 1]
    return fov_w, fov_h, 1.35 * D, (3.0 * fov_w * 1.35, 3.0 * fov_h * 1.35)


def _scene_checker(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    surfaces = [plane([0, 0, wall_z], _tilt(0, 0), wall_size, Constant(0.55), "wall")]
    cell = fov_w / 16
    sb, cb = checker_board([0.05 * fov_w, 0.02 * fov_h, D], _tilt(12, -18), cell, 13, 9, margin=0.6)
    surfaces.append(sb)
    cell2 = fov_w / 30
    surfaces += box([-0.25 * fov_w, 0.2 * fov_h, 0.8 * D], _tilt(25, 30), [5 * cell2] * 3, Checker(cell2), "cbox")
    return surfaces, [cb], ["checker"] * len(cb)


def _scene_natural(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    surfaces = [plane([0, 0, wall_z], _tilt(8, -6), wall_size, Noise(texel * 1.35, wall_size, seed), "wall")]
    for b, (c, dims, rot) in enumerate([
        ([-0.18 * fov_w, 0.1 * fov_h, 0.85 * D], [0.3 * fov_w] * 3, _tilt(20, 35)),
        ([0.2 * fov_w, -0.12 * fov_h, 0.7 * D], [0.22 * fov_w, 0.3 * fov_h, 0.2 * fov_w], _tilt(-15, -25)),
    ]):
        ext = (max(dims) * 1.1, max(dims) * 1.1)
        tex = [Noise(texel * 0.9, ext, seed + 10 * b + f) for f in range(6)]
        surfaces += box(c, rot, dims, tex, f"box{b}")
    return surfaces, [], []


def _scene_board(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    surfaces = [plane([0, 0, wall_z], _tilt(5, 5), wall_size, Noise(texel * 1.35, wall_size, seed), "wall")]
    sq = fov_w / 9
    sb, cb = paper_board([0, 0, D], _tilt(15, -10), square=sq, gap=0.66 * sq, margin=0.8 * sq)
    surfaces.append(sb)
    return surfaces, [cb], ["board"] * len(cb)


def _scene_mixed(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    surfaces = [plane([0, 0, wall_z], _tilt(6, -4), wall_size, Noise(texel * 1.35, wall_size, seed), "wall")]
    cell = fov_w / 24
    sb, cb = checker_board([-0.2 * fov_w, -0.17 * fov_h, 0.95 * D], _tilt(10, 20), cell, 8, 6, margin=0.5)
    sq = fov_w / 20
    pb, pc = paper_board([0.22 * fov_w, 0.2 * fov_h, 0.9 * D], _tilt(-12, -15), square=sq, gap=0.66 * sq,
                         margin=0.8 * sq)
    surfaces += [sb, pb]
    tex = [Noise(texel * 0.9, (0.25 * fov_w,) * 2, seed + f + 1) for f in range(6)]
    surfaces += box([0.22 * fov_w, -0.2 * fov_h, 0.8 * D], _tilt(25, 35), [0.2 * fov_w] * 3, tex, "box")
    return surfaces, [cb, pc], ["checker"] * len(cb) + ["board"] * len(pc)


def _scene_repetitive(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    tile = fov_w / 7  # ~7 identical tiles across the image
    wall_tex = Tiled(Noise(texel * 1.35, (tile, tile), seed), tile, grout=0.06 * tile)
    surfaces = [plane([0, 0, wall_z], _tilt(6, -8), wall_size, wall_tex, "wall")]
    tile2 = fov_w / 12
    panel_tex = Tiled(Noise(texel * 0.9, (tile2, tile2), seed + 1), tile2, grout=0.08 * tile2)
    surfaces.append(plane([-0.12 * fov_w, 0.05 * fov_h, 0.9 * D], _tilt(15, 25), (0.55 * fov_w, 0.5 * fov_h),
                          panel_tex, "panel"))
    tex = [Noise(texel * 0.9, (0.2 * fov_w,) * 2, seed + f + 2) for f in range(6)]
    surfaces += box([0.25 * fov_w, -0.15 * fov_h, 0.75 * D], _tilt(-20, 30), [0.15 * fov_w] * 3, tex, "box")
    return surfaces, [], []


_SCENE_BUILDERS = {"checker": _scene_checker, "natural": _scene_natural, "board": _scene_board,
                   "mixed": _scene_mixed, "repetitive": _scene_repetitive}
