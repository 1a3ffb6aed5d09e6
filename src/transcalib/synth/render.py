"""Rendering of textured planar scenes seen by a translated camera, with exact truth.

A scene is a list of :class:`Surface` rectangles (planes, box faces, boards;
:mod:`.surfaces`) with a procedural texture each (:mod:`.textures`). :func:`render`
ray-casts every sample of every pixel of every view (:mod:`.raycast`), so a scene point
``X`` appears exactly at ``camera.project(K, R, X, T, dist)``: the centre of the
top-left pixel is (0, 0) (OpenCV). Anti-aliasing combines ``S x S`` supersampling of
each pixel with analytic box filtering of the textures (checkers and squares are
integrated in closed form; the noise texture is band-limited). The filter is
symmetric, so an edge or corner renders centred where the projection says. The camera
effects follow (:mod:`.degrade`). :func:`render_scene` renders a preset scene
(:mod:`.presets`) and returns it as :class:`Rendered`, with the ground truth of every
pixel.

This module is the renderer's public face: it also offers the surfaces, textures and
scene helpers under their names (``render.plane``, ``render.Noise``, ...).

>>> from transcalib import render
>>> r = render.render_scene("checker", n_views=4, image_size=(320, 240), rng=0)
>>> r.images.shape, r.images.dtype
((4, 240, 320), dtype('uint8'))
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import InputError
from ..geometry.camera import pixels_to_rays, project
from .degrade import Degradations, degrade_view, draw_view_effects, overlay_box
from .raycast import nearest_hits, render_view, sample_rays
from .presets import SCENE_KINDS, default_camera, preset_scene, ring_translations, robot_translations
from .simulate import Scene
from .surfaces import Sphere, Surface, box, checker_board, paper_board, plane, sphere
from .textures import Checker, Constant, Noise, Squares, Tiled

__all__ = [
    "Checker",
    "Squares",
    "Noise",
    "Constant",
    "Tiled",
    "Degradations",
    "Surface",
    "Sphere",
    "plane",
    "sphere",
    "box",
    "paper_board",
    "checker_board",
    "render",
    "Rendered",
    "render_scene",
    "robot_translations",
    "ring_translations",
    "SCENE_KINDS",
]


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
    d = sample_rays(K, R, dist, (w, h), S)
    n = len(T)
    gain = np.ones(n) if gain is None else np.broadcast_to(np.asarray(gain, float), (n,))
    offset = np.zeros(n) if offset is None else np.broadcast_to(np.asarray(offset, float), (n,))
    opt = Degradations() if degrade is None else degrade
    effects = draw_view_effects(opt, n, (w, h), rng)
    out = np.empty((n, h, w), np.uint8 if dtype == "uint8" else float)
    for i in range(n):
        radiance = gain[i] * render_view(surfaces, d, T[i], S, background, K, R, dist, (w, h)) + offset[i]
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


class PixelTruth:
    """The ground truth of tracked pixels, for a rendering whose ``backproject(view, uv,
    return_surface=True)`` gives the point seen at each pixel (NaN: none) and the index of
    its surface (-1: none): :class:`Rendered` and
    :class:`~transcalib.synth.robot.RobotRendered`."""

    def track_truth(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ground truth of tracks ``uv (n_views, n, 2)``: the point ``(n, 3)`` (in the frame
        of ``backproject``; NaN: background) seen at each track's first observation, and
        ``(n,)`` bool, True where that observation is next to an occlusion edge (a
        T-junction of two depths has no fixed 3-D point)."""
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


@dataclass(frozen=True, eq=False)
class Rendered(PixelTruth):
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
        d = pixels_to_rays(self.K, uv, self.dist) @ self.R  # world directions, unit camera z
        C = self.T[view]
        best, which = nearest_hits(self.surfaces, d.T, C)  # as in the render
        X = C + best[:, None] * d
        X[~np.isfinite(best)] = np.nan
        return (X, which) if return_surface else X

    def depth_map(self, view: int, return_surface: bool = False):
        """The exact depth of every pixel of ``view``: ``(height, width)`` float, the
        camera z (along the optical axis, world units) of the scene point seen at the
        pixel's centre (through the lens, distortion included), NaN where no surface is
        hit - the truth of dense reconstruction.

        With ``return_surface``, also ``(height, width)`` int: the index into
        ``surfaces`` of the surface seen (-1: none). The images are not touched.
        """
        d = sample_rays(self.K, self.R, self.dist, self.image_size, 1)  # unit camera z
        z, owner = nearest_hits(self.surfaces, d, self.T[view])
        z = np.where(np.isfinite(z), z, np.nan)
        return (z, owner) if return_surface else z

    def textured(self) -> np.ndarray:
        """``(n_surfaces,)`` bool: the surface has a texture (anything but
        :class:`~transcalib.synth.textures.Constant`)."""
        return np.array([not isinstance(sf.texture, Constant) for sf in self.surfaces], bool)

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
    kind : {"checker", "natural", "board", "mixed", "repetitive", "floor", "workspace"}
        ``checker``: a large checkerboard and a checkered box in front of a plain wall;
        ``natural``: a noise-textured wall and two textured boxes at other depths;
        ``board``: the paper's six black squares on a white board in front of a textured
        wall; ``mixed``: textured wall, checkerboard, paper board and a textured box;
        ``repetitive``: a wall of identical tiles, a tilted tiled panel in front of it
        and a small textured box (descriptors match the wrong tile easily); ``floor``: a
        checkered floor seen obliquely (depths 0.8-1.25 x ``distance``) with a textured
        cube and a textured sphere on it.
        ``workspace``: surfaces from 0.5 to 1.5 ``distance`` (a textured wall, a
        slanted textured table top, three textured boxes, one untextured panel) for
        dense reconstruction, whose truth is :meth:`Rendered.depth_map`.
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
    K, R, T = default_camera(K, R, T, (w, h), n_views, baseline * distance, rng)
    seed = int(rng.integers(2**31))
    surfaces, corners, kinds = preset_scene(kind, distance, K, R, T[0], (w, h), seed)
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
