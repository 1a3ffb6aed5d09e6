"""Photometric degradations of rendered views: what a real camera does to the radiance.

:func:`degrade_view` turns the ideal radiance image of one view (0..1, exact geometry)
into what a real camera writes to disk, in the order the camera applies them::

    radiance -> vignetting x per-view exposure -> + specular highlight
             -> optics blur -> shot noise + read noise -> quantise to 8 bit
             -> burnt-in overlay (timestamp) -> JPEG compression

None of them moves a scene point, so the ground truth of :mod:`.render` stays exact.
Two of them add image features that are *not* scene points: the **specular highlight**
(a bright blob whose image position follows the camera, not the scene) and the
**overlay** (text at the same pixels in every frame, i.e. zero disparity). Where they
are drawn is returned, so tests can check that the tracker drops them.

All options live in the frozen dataclass :class:`Degradations`; every random draw
(exposures, noise, highlight positions) comes from the ``rng`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import cv2
import numpy as np

from ..errors import InputError

__all__ = ["Degradations", "REALISTIC", "degrade_view", "draw_view_effects"]


@dataclass(frozen=True)
class Degradations:
    """Options of the camera model applied after ray casting (all off by default).

    Attributes
    ----------
    vignetting : float
        Relative loss of brightness at the image corners: gain ``1 - v (r / r_c)^2``
        with ``r`` the distance from the image centre and ``r_c`` that of a corner.
    exposure : float
        Per-view exposure/gain change: view gains ``1 + U(-exposure, exposure)``.
    full_well_e : float or None
        Shot noise: electrons at white (255); the variance in grey levels is
        ``I * 255 / full_well_e``. None: no shot noise.
    read_noise_dn : float
        Read noise, Gaussian standard deviation in grey levels (0..255).
    jpeg_quality : int or None
        JPEG-compress every view at this quality (``cv2.imencode``, 1..100).
    specular : float
        Peak brightness (0..1 of white) of a specular highlight: a Gaussian blob that
        moves with the camera, not with the scene. 0: none.
    specular_sigma_px : float
        Gaussian radius of the highlight (pixels).
    specular_drift_px : float
        The highlight sits near a fixed image position and wanders by up to this many
        pixels between views, in no relation to the epipolar geometry.
    overlay : str or None
        Text burnt into every frame at the same pixels (bottom-left), e.g.
        ``"2026-12-01 19:48:{view:02d}"``; ``{view}`` is replaced by the view index
        (a clock that ticks), the rest stays fixed.
    overlay_scale : float
        ``cv2.putText`` font scale (0.8 for a 640-pixel-wide image).
    """

    vignetting: float = 0.0
    exposure: float = 0.0
    full_well_e: float | None = None
    read_noise_dn: float = 0.0
    jpeg_quality: int | None = None
    specular: float = 0.0
    specular_sigma_px: float = 12.0
    specular_drift_px: float = 25.0
    overlay: str | None = None
    overlay_scale: float = 0.8

    def __post_init__(self):
        bad = []
        if not 0.0 <= self.vignetting < 1.0:
            bad.append(f"vignetting {self.vignetting} (need 0 <= v < 1)")
        if not 0.0 <= self.exposure < 1.0:
            bad.append(f"exposure {self.exposure} (need 0 <= e < 1)")
        if self.full_well_e is not None and not self.full_well_e > 0:
            bad.append(f"full_well_e {self.full_well_e} (need > 0 or None)")
        if self.read_noise_dn < 0 or self.specular < 0 or self.specular_sigma_px <= 0 or self.specular_drift_px < 0:
            bad.append("read_noise_dn, specular, specular_drift_px must be >= 0 and specular_sigma_px > 0")
        if self.jpeg_quality is not None and not 1 <= int(self.jpeg_quality) <= 100:
            bad.append(f"jpeg_quality {self.jpeg_quality} (need 1..100 or None)")
        if bad:
            raise InputError("Degradations: " + "; ".join(bad))

    def active(self) -> tuple[str, ...]:
        """Names of the degradations that are switched on."""
        off = Degradations()
        skip = {"specular_sigma_px", "specular_drift_px", "overlay_scale"}
        return tuple(f.name for f in fields(self) if f.name not in skip and getattr(self, f.name) != getattr(off, f.name))


#: Every degradation at once, at levels typical of an industrial or web camera.
REALISTIC = Degradations(vignetting=0.35, exposure=0.2, full_well_e=4000.0, read_noise_dn=1.5, jpeg_quality=85,
                         specular=0.8, overlay="2026-12-01 19:48:{view:02d}")


@dataclass(frozen=True)
class ViewEffects:
    """Per-view random draws of :class:`Degradations` (drawn once per render).

    Attributes
    ----------
    gain : (n_views,) float
        Exposure gain of each view.
    specular_uv : (n_views, 2) float
        Pixel centre of the highlight in each view (NaN when there is none).
    """

    gain: np.ndarray
    specular_uv: np.ndarray


def draw_view_effects(opt: Degradations, n_views: int, image_size, rng) -> ViewEffects:
    """Draw exposure gains and highlight positions of ``n_views`` views."""
    w, h = image_size
    gain = 1.0 + rng.uniform(-opt.exposure, opt.exposure, n_views) if opt.exposure > 0 else np.ones(n_views)
    if opt.specular > 0:
        centre = rng.uniform([0.3 * w, 0.25 * h], [0.7 * w, 0.6 * h])
        ang = rng.uniform(0, 2 * np.pi, n_views)
        rad = opt.specular_drift_px * np.sqrt(rng.uniform(0, 1, n_views))
        uv = centre + rad[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    else:
        uv = np.full((n_views, 2), np.nan)
    return ViewEffects(gain=gain, specular_uv=uv)


def _vignetting_gain(v: float, w: int, h: int) -> np.ndarray:
    """``(h, w)`` gain ``1 - v (r / r_corner)^2`` about the image centre."""
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    r2 = (xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2
    return 1.0 - v * r2 / ((w - 1) ** 2 / 4 + (h - 1) ** 2 / 4)


def _specular(uv: np.ndarray, peak: float, sigma: float, w: int, h: int) -> np.ndarray:
    """``(h, w)`` Gaussian blob of height ``peak`` centred at pixel ``uv``."""
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    return peak * np.exp(-((xx - uv[0]) ** 2 + (yy - uv[1]) ** 2) / (2 * sigma**2))


def _overlay(img_u8: np.ndarray, text: str, scale: float) -> np.ndarray:
    """Burn ``text`` (white with a black outline) into the bottom-left corner."""
    h = img_u8.shape[0]
    org = (int(0.02 * img_u8.shape[1]) + 2, h - int(0.03 * h) - 2)
    thick = max(1, int(round(2 * scale)))
    # the returned image: older OpenCV (4.8) draws into a copy of a non-contiguous array
    img_u8 = cv2.putText(img_u8, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, 0, thick + 2, cv2.LINE_AA)
    return cv2.putText(img_u8, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, 255, thick, cv2.LINE_AA)


def overlay_box(opt: Degradations, image_size) -> tuple[int, int, int, int] | None:
    """Pixel box ``(u0, v0, u1, v1)`` that the overlay can touch (None without overlay)."""
    if opt.overlay is None:
        return None
    w, h = image_size
    text = opt.overlay.format(view=0)
    thick = max(1, int(round(2 * opt.overlay_scale)))
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, opt.overlay_scale, thick + 2)
    u0, vb = int(0.02 * w) + 2, h - int(0.03 * h) - 2
    return (u0 - 4, vb - th - 4, u0 + tw + 4, vb + base + 4)


def degrade_view(radiance: np.ndarray, opt: Degradations, view: int, effects: ViewEffects, *, blur_sigma: float = 0.0,
                 noise_std: float = 0.0, rng) -> np.ndarray:
    """The 8-bit image a camera records of the ideal ``radiance`` of one view.

    Parameters
    ----------
    radiance : (h, w) float
        Ideal image, 0..1 (already scaled by any legacy ``gain``/``offset``).
    opt : Degradations
    view : int
        View index (for per-view effects and the overlay's ``{view}``).
    effects : ViewEffects
        Per-view draws from :func:`draw_view_effects`.
    blur_sigma : float
        Optics blur (pixels), applied before the sensor noise.
    noise_std : float
        Extra Gaussian noise in grey levels (the renderer's simple noise model).
    rng : Generator

    Returns
    -------
    (h, w) uint8
    """
    h, w = radiance.shape
    img = radiance * effects.gain[view]
    if opt.vignetting > 0:
        img = img * _vignetting_gain(opt.vignetting, w, h)
    if opt.specular > 0:
        img = img + _specular(effects.specular_uv[view], opt.specular, opt.specular_sigma_px, w, h)
    # the sensor saturates before its noise (without degradations: the legacy order,
    # clip only at the end, so existing renders stay byte-identical)
    img = (np.clip(img, 0.0, 1.0) if opt.active() else img) * 255.0
    if blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma, borderType=cv2.BORDER_REPLICATE)
    var = np.full(img.shape, noise_std**2 + opt.read_noise_dn**2)
    if opt.full_well_e is not None:
        var = var + np.maximum(img, 0.0) * (255.0 / opt.full_well_e)
    if np.any(var > 0):
        img = img + rng.normal(size=img.shape) * np.sqrt(var)
    out = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if opt.overlay is not None:
        out = _overlay(out, opt.overlay.format(view=view), opt.overlay_scale)
    if opt.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(opt.jpeg_quality)])
        out = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    return out
