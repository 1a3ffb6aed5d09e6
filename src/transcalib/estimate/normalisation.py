"""Hartley normalisation of pixels and translations (paper §2.2; Hartley 1997), written once.

The linear estimators (the TLS of :mod:`.linear`, the minimal solver of :mod:`.minimal`)
work in coordinates where the numbers are of order one::

    u' = H u,   H = [[k, 0, -k c_u], [0, k, -k c_v], [0, 0, 1]],   k = sqrt(2) / mean_ij |uv_ij - c|
    T' = (T - mean_i T_i) / t_scale,                                t_scale = mean_i |T_i - mean T|

with ``c`` the mean of the used observations, so that they have zero mean and mean
distance ``sqrt(2)`` from the origin and the translations unit mean norm. A solution
``A'`` in these coordinates maps back as ``A ∝ H^-1 A' / t_scale``.

Two chunked passes over the pixels (the mean, then the mean distance from it): the
temporaries are O(chunk), whatever the number of points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Normalisation", "hartley"]

#: Points per chunk: temporaries of a few MB, reused rather than freshly mapped.
CHUNK = 16384


@dataclass(frozen=True)
class Normalisation:
    """``u' = H u`` (pixels) and ``T' = (T - T_mean) / t_scale`` (translations).

    Attributes
    ----------
    H : (3, 3) float
        The pixel similarity, ``scale`` normalised units per pixel.
    T : (n_views, 3) float
        Normalised translations: zero mean, unit mean norm.
    t_scale : float
        Mean distance of the translations from their mean (translation units).
    """

    H: np.ndarray
    T: np.ndarray
    t_scale: float

    @property
    def scale(self) -> float:
        """Normalised units per pixel."""
        return float(self.H[0, 0])


def hartley(uv: np.ndarray, T: np.ndarray, used: np.ndarray | None = None) -> Normalisation:
    """The Hartley normalisation of the used observations and of the translations.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen.
    T : (n_views, 3) float
        Translations, not all equal.
    used : (n_points,) bool, optional
        Points whose observations count (default: every observation).

    Returns
    -------
    Normalisation
        Pixels of the used points to zero mean and mean distance ``sqrt(2)``; with no
        spread (one pixel position) the scale is 1.
    """
    total, count = np.zeros(2), 0
    for c, ok in _observed(uv, used):
        x = uv[:, c]
        total += [np.sum(x[..., 0], where=ok), np.sum(x[..., 1], where=ok)]
        count += np.count_nonzero(ok)
    centre = total / max(count, 1)
    spread = 0.0
    for c, ok in _observed(uv, used):
        x = uv[:, c]
        du, dv = x[..., 0] - centre[0], x[..., 1] - centre[1]
        spread += np.sum(np.sqrt(du * du + dv * dv), where=ok)
    spread /= max(count, 1)
    scale = np.sqrt(2.0) / spread if spread > 0 else 1.0
    H = np.array([[scale, 0.0, -scale * centre[0]], [0.0, scale, -scale * centre[1]], [0.0, 0.0, 1.0]])
    T_mean = T.mean(axis=0)
    t_scale = float(np.linalg.norm(T - T_mean, axis=1).mean())
    return Normalisation(H=H, T=(T - T_mean) / t_scale, t_scale=t_scale)


def _observed(uv: np.ndarray, used: np.ndarray | None):
    """Chunks of points and their used observations: ``(slice, (n_views, m) bool)``."""
    for lo in range(0, uv.shape[1], CHUNK):
        c = slice(lo, min(lo + CHUNK, uv.shape[1]))
        ok = np.isfinite(uv[:, c, 0])
        yield c, ok if used is None else ok & used[c]
