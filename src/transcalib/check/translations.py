"""Checks of the robot translations: coplanar or tiny motions (before any estimation)."""

from __future__ import annotations

import numpy as np

from ..errors import Diagnostic
from ..validate import WEAK_SPAN_RATIO
from .common import fmt_vec

MIN_PARALLAX_PX = 20.0

def check_translations(T, *, focal_px: float | None = None, distance: float | None = None,
                       coplanar_ratio: float = WEAK_SPAN_RATIO, min_parallax_px: float = MIN_PARALLAX_PX,
                       unit: str = "units", frame: str = "robot") -> list:
    """Warn when the translations are nearly coplanar or tiny for the scene distance.

    Parameters
    ----------
    T : (n_views, 3) float
        Robot translations.
    focal_px : float, optional
        Focal length in pixels (e.g. ``(fx + fy) / 2``); with ``distance`` enables the
        parallax check.
    distance : float, optional
        Typical distance of the scene from the camera (median depth, units of ``T``).
    coplanar_ratio : float
        Warn when ``s3 / s1 < coplanar_ratio``, ``s_k`` the singular values of the
        centred translations ``T_i - mean(T)`` (default
        :data:`transcalib.validate.WEAK_SPAN_RATIO`, as the planner).
    min_parallax_px : float
        Warn when the image motion produced by the translations along their weakest
        direction ``v3``, ``focal_px * extent(T . v3) / distance``, is below this.
    unit : str
        Length unit named in the messages.
    frame : str
        The axes ``T`` is in, named in the messages ("robot", "flange", ...).

    Returns
    -------
    list of Diagnostic
        ``translations_coplanar``, ``translations_small``; each suggests moving the robot
        along ``v3`` (axes of ``frame``) and by how much.
    """
    T = np.asarray(T, dtype=float)
    t = T - T.mean(axis=0)
    _, s, Vt = np.linalg.svd(t, full_matrices=True)
    s = np.concatenate([s, np.zeros(3 - s.size)])[:3]
    v3 = Vt[2]
    v3 = v3 * np.sign(v3[np.argmax(np.abs(v3))])
    extent = np.ptp(t @ v3)
    longest = np.ptp(t @ Vt[0])
    out = []
    if s[0] > 0 and s[2] < coplanar_ratio * s[0]:
        out.append(Diagnostic(
            "translations_coplanar",
            f"the {'robot' if frame == 'robot' else 'robot (' + frame + ' frame)'} translations nearly lie in a plane (singular values {s[0]:.3g}, {s[1]:.3g}, {s[2]:.3g} "
            f"{unit}; ratio {s[2] / s[0]:.3f} < {coplanar_ratio}), so K and R are poorly determined. Add views "
            f"displaced along the {frame} direction (x, y, z) = {fmt_vec(v3)}, by about {longest:.3g} {unit} "
            f"(as far as the widest motion so far)."))
    if focal_px is not None and distance is not None and distance > 0:
        parallax = focal_px * extent / distance
        if parallax < min_parallax_px:
            need = min_parallax_px * 5 * distance / focal_px
            out.append(Diagnostic(
                "translations_small",
                f"the translations are tiny compared with the scene distance: along their weakest direction "
                f"({frame} x, y, z) = {fmt_vec(v3)} they span {extent:.3g} {unit} at a distance of {distance:.3g} {unit}, "
                f"i.e. only {parallax:.3g} px of image motion, so the estimate is ill-conditioned. Move the robot "
                f"along that direction by about {need:.3g} {unit} (>= {5 * min_parallax_px:.0f} px of motion), "
                f"or bring the scene closer."))
    return out
