"""Checks made once at the public boundary: shapes, finiteness, enough data, span.

Every failure raises :class:`InputError` or :class:`DegenerateError` with a message that
says what was expected, what came, and what to do.
"""

from __future__ import annotations

import numpy as np

from .types import DegenerateError, InputError

__all__ = ["as_uv_T", "translation_singular_values", "check_translations_span", "SPAN_RTOL", "COPLANAR_RTOL",
           "WEAK_SPAN_RATIO"]

#: Three independent translations need four views.
MIN_VIEWS = 4

# Tolerances on the singular values ``s_1 >= s_2 >= s_3`` of the translations, one per
# concept; every module imports them from here.

#: Numerical rank of the translations (what the solvers can use): ``s_k <= SPAN_RTOL s_1``
#: counts as zero. Exactly coplanar (or collinear) translations leave ``s_3 / s_1`` at
#: rounding level (~1e-16), far below; the solvers use any larger motion.
SPAN_RTOL = 1e-6
#: Measured translations that count as a plane (or a line): out-of-plane motion below
#: ``COPLANAR_RTOL s_1`` is robot jitter (an XY table whose measured height wanders by
#: 0.01 mm over moves of 10 mm and more), not a third direction that could determine K.
#: Used where the data decide how to calibrate (the coplanar start, the tracker).
COPLANAR_RTOL = 1e-3
#: Weak geometry (a warning, not an error): ``s_3 / s_1`` of the centred translations
#: below this leaves K and R poorly determined (little motion along the weakest
#: direction). The diagnostics (``translations_coplanar``) and the planner
#: (``coplanar_moves``) warn at the same ratio, so that a design the planner accepts does
#: not draw the warning after calibration.
WEAK_SPAN_RATIO = 0.2


def _as_float_array(name: str, value) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be an array of numbers; could not convert it ({exc})") from None
    return arr


def as_uv_T(uv, T, *, min_views: int = MIN_VIEWS) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert observations and translations.

    Parameters
    ----------
    uv : array_like (n_views, n_points, 2)
        Pixel coordinates, NaN where a point is not seen (both coordinates NaN).
    T : array_like (n_views, 3)
        Robot translations, finite.
    min_views : int
        Minimum number of views.

    Returns
    -------
    uv : (n_views, n_points, 2) float64 array (the input itself when it already is one:
        callers never modify it)
    T : (n_views, 3) float64 array
    """
    uv = _as_float_array("uv", uv)
    T = _as_float_array("T", T)
    if uv.ndim != 3 or uv.shape[2] != 2:
        raise InputError(f"uv must have shape (n_views, n_points, 2); got shape {uv.shape}")
    if T.ndim != 2 or T.shape[1] != 3:
        raise InputError(f"T must have shape (n_views, 3), one robot translation per view; got shape {T.shape}")
    if T.shape[0] != uv.shape[0]:
        raise InputError(
            f"uv has {uv.shape[0]} views but T has {T.shape[0]} translations; give one translation per view"
        )
    bad_T = ~np.isfinite(T).all(axis=1)
    if bad_T.any():
        raise InputError(
            f"translations of views {np.flatnonzero(bad_T).tolist()} are not finite (NaN or inf); "
            "every view needs a measured robot position"
        )
    if np.isinf(uv).any():
        where = np.argwhere(np.isinf(uv).any(axis=2))[:5].tolist()
        raise InputError(f"uv contains infinite values at (view, point) {where}; use NaN for points not seen")
    half = np.isnan(uv[..., 0]) != np.isnan(uv[..., 1])
    if half.any():
        where = np.argwhere(half)[:5].tolist()
        raise InputError(
            f"uv has one coordinate NaN and the other finite at (view, point) {where}; "
            "mark unseen points with NaN in both u and v"
        )
    if uv.shape[0] < min_views:
        raise InputError(
            f"need at least {min_views} views (three independent translations), got {uv.shape[0]}; "
            "move the robot to more positions"
        )
    if uv.shape[1] == 0:
        raise InputError("uv has no points; track at least 2 points through the views")
    return uv, T


def translation_singular_values(T: np.ndarray) -> np.ndarray:
    """Singular values (descending, 3) of the relative translations ``T_i - T_0``."""
    t = T[1:] - T[0]
    s = np.linalg.svd(t, compute_uv=False)
    return np.concatenate([s, np.zeros(3 - s.size)])[:3]


def check_translations_span(T: np.ndarray) -> np.ndarray:
    """Raise :class:`DegenerateError` unless the translations span 3-D.

    Parameters
    ----------
    T : (n_views, 3) float
        Translations of the views that observe points.

    Returns
    -------
    (3,) float
        Singular values of ``T_i - T_0``, descending.
    """
    s = translation_singular_values(T)
    if s[0] == 0 or s[2] <= SPAN_RTOL * s[0]:
        raise DegenerateError(
            "the robot translations do not span 3-D (singular values of T_i - T_0: "
            + ", ".join(f"{v:.3g}" for v in s)
            + "); K and R are not determined. Move the robot along three independent "
            "directions, e.g. along x, y and z."
        )
    return s
