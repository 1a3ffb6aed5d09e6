"""Still frames: which images were taken while the flange stood still, grouped into
stops (one view each), vectorised over the images and the tf samples.

An image at stamp ``s`` is *still* when, over every tf sample in the window
``[s - w/2, s + w/2]``, the flange stays within ``still_mm`` of its pose at ``s`` and
turns by at most ``still_deg`` (the angle of ``R_s^T R_k``). Its window must lie within
the time span of the tf chain (else it is *uncovered*). Consecutive still images form
one stop unless an image that is not still lies between them or their poses differ by
more than the same limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ...geometry.rotation import rotation_angle_deg
from .options import BagOptions
from .tf import Chain

__all__ = ["StillSelection", "select_still", "sharpness"]


@dataclass(frozen=True, eq=False)
class StillSelection:
    """The verdict on every image of the topic, in the order given.

    Attributes
    ----------
    stop : (n_images,) int
        Stop index of each still image (0, 1, ... in time order), -1 for the others.
    moved : (n_images,) bool
        The flange moved more than the limits within the image's window.
    uncovered : (n_images,) bool
        The window reaches beyond the tf samples of the chain.
    T : (n_images, 3) float
        Flange position at each stamp (metres; NaN where uncovered).
    R : (n_images, 3, 3) float
        Flange -> base rotation at each stamp.
    max_move_mm, max_turn_deg : (n_images,) float
        Largest distance and angle from the pose at the stamp within the window.
    """

    stop: np.ndarray
    moved: np.ndarray
    uncovered: np.ndarray
    T: np.ndarray
    R: np.ndarray
    max_move_mm: np.ndarray
    max_turn_deg: np.ndarray

    @property
    def n_stops(self) -> int:
        return int(self.stop.max()) + 1 if len(self.stop) and self.stop.max() >= 0 else 0


def _window_indices(times: np.ndarray, lo_t: np.ndarray, hi_t: np.ndarray):
    """Indices ``(n, m)`` into ``times`` of the samples within ``[lo_t, hi_t]`` per row,
    and the mask of the real ones (rows padded to the longest window)."""
    lo = np.searchsorted(times, lo_t, side="left")
    hi = np.searchsorted(times, hi_t, side="right")
    width = max(int((hi - lo).max(initial=0)), 1)
    idx = lo[:, None] + np.arange(width)
    mask = idx < hi[:, None]
    return np.minimum(idx, max(len(times) - 1, 0)), mask


def _needed_samples(times: np.ndarray, lo_t: np.ndarray, hi_t: np.ndarray) -> np.ndarray:
    """Mask of the samples that lie in at least one window (difference array)."""
    marks = np.zeros(len(times) + 1, int)
    np.add.at(marks, np.searchsorted(times, lo_t, side="left"), 1)
    np.add.at(marks, np.searchsorted(times, hi_t, side="right"), -1)
    return np.cumsum(marks)[:-1] > 0


def _deviation(T_s, R_s, T_k, R_k):
    """Distance (metres) and angle (degrees) of poses ``(n, m, ...)`` from ``(n, ...)``."""
    dist = np.linalg.norm(T_k - T_s[:, None], axis=-1)
    return dist, rotation_angle_deg(np.swapaxes(R_s, 1, 2)[:, None] @ R_k)


def _window_motion(chain: Chain, stamps_ns, T_s, R_s, half_ns: int):
    """Largest distance (metres) and angle (degrees) from the pose at each stamp over
    its window ``(n,)``, ``(n,)``: at the tf samples within it and at its two ends (the
    chain interpolates between samples, so these bound the motion)."""
    n = len(stamps_ns)
    times = chain.sample_times_ns()
    if len(times) == 0 or n == 0:
        return np.zeros(n), np.zeros(n)
    lo, hi = stamps_ns - half_ns, stamps_ns + half_ns
    T_e, R_e, _ = chain.pose_at(np.concatenate([lo, hi]))
    dist, angle = _deviation(T_s, R_s, T_e.reshape(2, n, 3).swapaxes(0, 1), R_e.reshape(2, n, 3, 3).swapaxes(0, 1))
    times = times[_needed_samples(times, lo, hi)]
    if len(times):
        T_k, R_k, _ = chain.pose_at(times)
        idx, mask = _window_indices(times, lo, hi)
        d, a = _deviation(T_s, R_s, T_k[idx], R_k[idx])
        dist, angle = np.hstack([dist, np.where(mask, d, 0.0)]), np.hstack([angle, np.where(mask, a, 0.0)])
    return dist.max(axis=1), angle.max(axis=1)


def _stops(still: np.ndarray, order: np.ndarray, T, R, options: BagOptions) -> np.ndarray:
    """Stop index per image (-1 if not still): a new stop at each still image whose
    predecessor in time is not still or whose pose differs from the previous still one."""
    stop = np.full(len(still), -1)
    still_t = still[order]
    prev_still = np.concatenate([[False], still_t[:-1]])
    seq = order[still_t]  # still images in time order
    jump = np.zeros(len(seq), bool)
    if len(seq) > 1:
        step = np.linalg.norm(T[seq[1:]] - T[seq[:-1]], axis=1)
        turn = rotation_angle_deg(np.swapaxes(R[seq[:-1]], 1, 2) @ R[seq[1:]])
        jump[1:] = (step > options.still_m) | (turn > options.still_deg)
    new = ~prev_still[still_t] | jump
    stop[seq] = np.cumsum(new) - 1
    return stop


def select_still(chain: Chain, stamps_ns, options: BagOptions) -> StillSelection:
    """Judge every image stamp ``(n,)`` int64 ns against the chain's tf (see module)."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    half_ns = int(round(options.still_window_s * 5e8))
    T_s, R_s, valid = chain.pose_at(stamps_ns)
    span = chain.span_ns()
    covered = valid if span is None else valid & (stamps_ns - half_ns >= span[0]) & (stamps_ns + half_ns <= span[1])
    move, turn = _window_motion(chain, stamps_ns, T_s, R_s, half_ns)
    moved = covered & ((move > options.still_m) | (turn > options.still_deg))
    still = covered & ~moved
    order = np.argsort(stamps_ns, kind="stable")
    stop = _stops(still, order, T_s, R_s, options)
    T_s = np.where(covered[:, None], T_s, np.nan)
    return StillSelection(stop, moved, ~covered, T_s, np.array(R_s), move * 1000.0, turn)


def sharpness(image: np.ndarray) -> float:
    """Variance of the Laplacian of the image's grey levels (0..255 scale for 8-bit,
    0..65535 for 16-bit): larger is sharper."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return float(cv2.Laplacian(grey.astype(np.float64), cv2.CV_64F).var())
