"""Checks of the tracks themselves: tracks that do not move, low parallax, few inliers, a
threshold too small for the noise, implausible intrinsics.

Thresholds are in units of the pixel noise ``sigma`` estimated from the data, never in
pixels: a track whose largest image motion from its first view is below
``LOW_PARALLAX_SIGMAS * sigma`` carries (almost) no information about the depth and so
about K (a static overlay, dust on the lens, a far background).
"""

from __future__ import annotations

import numpy as np

from ..errors import Diagnostic
from ..estimate.distributions import chi2_sf
from ..estimate.linear import reference_motion
from ..estimate.noise import observation_quantile
from .common import fmt_list

__all__ = ["check_parallax", "check_inliers", "check_threshold", "check_intrinsics"]

#: Tracks moving less than this many noise sigmas are low-parallax.
LOW_PARALLAX_SIGMAS = 5.0
#: Warn when fewer of the tracked points are inliers.
MIN_INLIER_FRACTION = 0.5
#: A track erring by this much or more is matched to the wrong place: the tracker's
#: features are at least its smoothing (sigma 1 px) across, a smaller error stays on them.
WRONG_MATCH_PX = 1.0


def track_motion_px(uv: np.ndarray, sessions=None) -> np.ndarray:
    """Largest image motion (pixels) of each track from its first view (n_points,), within
    a session (``sessions (n_views,)``: views of one flange orientation, where image
    motion is parallax; default: all views one session); NaN for tracks seen in fewer
    than 2 views of any session."""
    sessions = np.zeros(uv.shape[0], int) if sessions is None else np.asarray(sessions)
    out = np.full(uv.shape[1], np.nan)
    for s in np.unique(sessions):
        part = uv[sessions == s]
        seen = np.isfinite(part[..., 0])
        largest = np.max(reference_motion(part)[0], axis=0, where=seen, initial=0.0)
        out = np.fmax(out, np.where(seen.sum(axis=0) >= 2, largest, np.nan))
    return out


def check_parallax(uv: np.ndarray, sigma_px: float, sessions=None) -> list:
    """Warn about tracks that do not move at all (they are left out: their depth is
    undetermined) and tracks with low parallax.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
    sigma_px : float
        Pixel noise per coordinate (estimated).
    sessions : (n_views,) int, optional
        Session of each view: the motion is measured within the sessions.

    Returns
    -------
    list of Diagnostic
        ``static_tracks``, ``low_parallax``.
    """
    out = []
    motion = track_motion_px(uv, sessions)
    moving = np.isfinite(motion) & (motion > 0)
    scale = float(np.median(motion[moving])) if moving.any() else 0.0
    static = np.isfinite(motion) & (motion <= 1e-9 * scale)
    if static.any():
        idx = np.flatnonzero(static)
        out.append(Diagnostic(
            "static_tracks",
            f"{len(idx)} track(s) do not move at all between views (points {fmt_list(idx)}): a static overlay "
            "(timestamp, logo), dust on the lens or a reflection. They were left out; mask them in the images "
            "if there are many."))
    low = np.isfinite(motion) & (motion < LOW_PARALLAX_SIGMAS * sigma_px) & ~static
    if low.any():
        idx = np.flatnonzero(low)
        out.append(Diagnostic(
            "low_parallax",
            f"{len(idx)} track(s) move less than {LOW_PARALLAX_SIGMAS:g} x the pixel noise ({sigma_px:.2g} px) "
            f"between views (points {fmt_list(idx)}): they carry almost no information on K and R (far "
            "background, static overlays, dust); the linear estimate weights them down. Larger robot moves "
            "or nearer points make them count."))
    return out


def check_inliers(inliers, uv: np.ndarray, residuals_px=None, sigma_px=None) -> list:
    """Warn when few of the tracked points are inliers (``inliers_few``), saying whether the
    others are wrong (an error of :data:`WRONG_MATCH_PX` or more) or only less precise
    than the best tracks (``residuals_px (n_views, n_points, 2)``, the fit's
    ``sigma_px``; without them the others are taken as wrong)."""
    if inliers is None:
        return []
    tracked = np.isfinite(uv[..., 0]).sum(axis=0) >= 2
    frac = float(np.sum(inliers & tracked) / max(tracked.sum(), 1))
    if frac >= MIN_INLIER_FRACTION:
        return []
    head = f"only {100 * frac:.0f} % of the tracked points are inliers"
    others = tracked & ~inliers
    worst = np.full(int(others.sum()), np.inf)
    if residuals_px is not None:
        e = np.linalg.norm(np.asarray(residuals_px, float)[:, others], axis=-1)
        seen = np.isfinite(e).any(axis=0)
        worst[seen] = np.nanmax(e[:, seen], axis=0)
    sizes = ""
    if np.isfinite(worst).any():
        lo, med, hi = np.percentile(worst[np.isfinite(worst)], [10, 50, 90])
        sizes = (f"; the others' largest residuals are {lo:.2g}-{hi:.2g} px (median {med:.2g}; 10th-90th "
                 "percentile)")
    wrong = float(np.sum(~(worst < WRONG_MATCH_PX)) / max(tracked.sum(), 1))
    if sigma_px and wrong <= 1 - MIN_INLIER_FRACTION:
        return [Diagnostic(
            "inliers_few",
            f"{head} at the precision of the best tracks ({sigma_px:.2g} px per coordinate){sizes}, less than "
            f"{WRONG_MATCH_PX:g} px: tracks less precise than the best (aliasing, blur, weak texture), not wrong "
            f"ones{f' ({100 * wrong:.0f} % of the tracked points err by more)' if wrong else ''}. The calibration "
            "leaves them out (its std is that of the inliers); sharper images or more texture would keep more.")]
    return [Diagnostic(
        "inliers_few",
        f"{head} (at most {100 * (1 - MIN_INLIER_FRACTION):.0f} % outliers are expected of a tracker){sizes}: "
        "the tracks are mostly wrong (repetitive texture, moving objects) or the camera rotated; check the "
        "tracks, or the robot's orientation.")]


def check_threshold(sigma_px: float, rule_sigma_px: float, threshold_px, alpha: float) -> list:
    """Warn when a user threshold is small for the noise the data show (``threshold_small``):
    the rule then rejects good tracks far more often than ``alpha``."""
    if threshold_px is None or not sigma_px > 1.2 * rule_sigma_px:
        return []
    q = observation_quantile(alpha) ** 2  # chi2_2(1 - alpha)
    rejected = float(chi2_sf(q * (rule_sigma_px / sigma_px) ** 2, 2))
    return [Diagnostic(
        "threshold_small",
        f"the inlier threshold {threshold_px:g} px is small for the pixel noise the data show ({sigma_px:.2g} px "
        f"per coordinate): it rejects about {100 * rejected:.0f} % of the good observations instead of "
        f"{100 * alpha:g} %. Leave the threshold out (the noise then sets it) or raise it to about "
        f"{np.sqrt(q) * sigma_px:.2g} px.")]


def check_intrinsics(K: np.ndarray, image_size=None) -> list:
    """Warn about intrinsics no real camera has (``implausible_intrinsics``): very unequal
    focal lengths, or (with the image size) a focal length far from the image size or a
    principal point outside the image. Usually the tracks are wrong."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    problems = []
    if not 0.5 < fx / fy < 2.0:
        problems.append(f"fx / fy = {fx / fy:.2f}")
    if image_size is not None:
        w, h = image_size
        diag = float(np.hypot(w, h))
        if not 0.1 * diag < 0.5 * (fx + fy) < 20 * diag:
            problems.append(f"focal length {0.5 * (fx + fy):.0f} px for a {w}x{h} image")
        if not (-0.5 <= cx <= w - 0.5 and -0.5 <= cy <= h - 0.5):
            problems.append(f"principal point ({cx:.0f}, {cy:.0f}) outside the image")
    if not problems:
        return []
    return [Diagnostic(
        "implausible_intrinsics",
        f"the intrinsics are implausible ({'; '.join(problems)}): the tracks are probably wrong (repetitive "
        "texture matched one period off, moving objects) or the poses do not belong to the images. Check "
        "the tracks and the order of the poses.")]
