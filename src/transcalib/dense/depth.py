"""From the sweep's minimum to depth, confidence and the matching part of its uncertainty.

With hypotheses ``rho_k = rho_0 + k d`` (inverse depth, uniform) and the refined
fractional index ``i`` of the minimum, the depth is ``z = 1 / (rho_0 + i d)``.

**Confidence** (0-1) is ``(1 - c1 / 2) (1 - c1 / c2)``: ``c1`` the mean truncated
squared difference of normalised intensities at the minimum (``1 - c1 / 2`` is about the
normalised correlation of the best-k views there), ``c2`` the best cost away from the
minimum (``1 - c1 / c2``: how distinct the minimum is; a repeated or flat texture has
``c2`` near ``c1``).

**Standard deviation from the cost's curvature**: near the minimum the mean cost is
``E(i) = c1 + E'' (i - i*)^2 / 2``. Least squares over ``N`` residual samples of
variance ``s^2 = c1 N / (N - 1)`` (``N = k A``: ``k`` views summed, windows of ``A``
pixels) gives ``var(i) = 2 s^2 / (N E'')``, times ``(k + 1) / 2`` because the
reference's pixels enter every view's residual (the ``k`` residuals of a pixel are not
independent). Then ``sigma_rho = sqrt(var(i)) d`` and ``sigma_z = sigma_rho z^2``.

A pixel is **unknown** (NaN) when its window is untextured (local standard deviation
below ``min_texture`` times the image noise), its minimum lies at an end of the range,
or its confidence is below ``min_confidence``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .sweep import SweepResult

__all__ = ["DepthEstimate", "depth_from_sweep"]


@dataclass(frozen=True, eq=False)
class DepthEstimate:
    """``(H, W)`` float32 maps: ``depth`` (NaN unknown), ``confidence`` (0 unknown),
    ``std`` (matching part, NaN unknown), ``rho`` (inverse depth, NaN unknown) and the
    bool ``textured``."""

    depth: np.ndarray
    confidence: np.ndarray
    std: np.ndarray
    rho: np.ndarray
    textured: np.ndarray


def depth_from_sweep(res: SweepResult, rho: np.ndarray, local_std: np.ndarray, noise: float, options,
                     best_k: int) -> DepthEstimate:
    """Depth, confidence and standard deviation (module docstring).

    Parameters
    ----------
    res : SweepResult
    rho : (n_depths,) float
        The hypotheses (uniform, increasing).
    local_std : (H, W) float32
        Grey-level standard deviation of the reference over the window.
    noise : float
        Image noise (grey levels).
    options : DenseOptions
    best_k : int
    """
    step = float(rho[1] - rho[0])
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        r = (rho[0] + res.index.astype(float) * step)
        conf = np.clip(1.0 - res.c1 / 2.0, 0.0, 1.0) * np.clip(1.0 - res.c1 / res.c2, 0.0, 1.0)
        conf = np.where(np.isfinite(conf), conf, 0.0)
        textured = local_std >= options.min_texture * noise
        known = np.isfinite(r) & (r > 0) & textured & (conf >= options.min_confidence)
        n = float(best_k * options.window_px**2)
        var_i = 2.0 * res.c1 * (n / (n - 1.0)) / (n * res.curvature) * (best_k + 1) / 2.0
        z = np.where(known, 1.0 / r, np.nan)
        std = np.sqrt(var_i) * step * z * z
    return DepthEstimate(depth=z.astype(np.float32), confidence=np.where(known, conf, 0.0).astype(np.float32),
                         std=np.where(known, std, np.nan).astype(np.float32),
                         rho=np.where(known, r, np.nan).astype(np.float32), textured=textured)
