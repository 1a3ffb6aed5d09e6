"""Checks of points and views: points behind the camera, views with few points or
outlying residuals, gross outliers left in the residuals."""

from __future__ import annotations

import numpy as np

from ..errors import Diagnostic
from ..estimate.distributions import f_sf
from ..estimate.noise import median_sigma
from .common import camera_poses, depths, fmt_list, squared_norms

MIN_VIEW_POINTS = 6
VIEW_RESIDUAL_RATIO = 2.0
OUTLIER_MIN_PX = 1.0

def check_points_behind(uv, T, calibration) -> list:
    """Warn about reconstructed points behind the camera in a view that sees them.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float
    calibration : Calibration or LinearEstimate
        Its cameras and ``X`` (points with non-finite ``X``, and outside its ``inliers``,
        are skipped).

    Returns
    -------
    list of Diagnostic
        ``points_behind_camera``.
    """
    uv, T = np.asarray(uv, float), np.asarray(T, float)
    X = np.asarray(calibration.X, float)
    seen = np.isfinite(uv[..., 0])
    R_cam, C = camera_poses(calibration, T)
    z = depths(R_cam, X, C)
    with np.errstate(invalid="ignore"):
        behind = np.any(seen & np.isfinite(z) & (z <= 0), axis=0)
    if getattr(calibration, "inliers", None) is not None:
        behind &= calibration.inliers  # outliers are left out of the calibration
    if not behind.any():
        return []
    idx = np.flatnonzero(behind)
    return [Diagnostic(
        "points_behind_camera",
        f"{len(idx)} reconstructed point(s) lie behind the camera in a view that sees them (points {fmt_list(idx)}): "
        "these tracks are almost certainly mismatches (or the robot moved the other way than the poses "
        "say). Remove them or run the robust estimator (calibrate(..., robust=True), CLI --robust); check "
        "the sign convention of the poses if there are many.")]


def check_views(uv, residuals_px, *, used=None, min_points: int = MIN_VIEW_POINTS,
                residual_ratio: float = VIEW_RESIDUAL_RATIO, alpha: float = 1e-4,
                min_excess_px: float = 0.1, left_out=None) -> list:
    """Warn about views with very few points and views whose residuals stand out.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Observations (NaN where unseen).
    residuals_px : (n_views, n_points, 2) float
        Residuals of the calibration (NaN where unseen or unused).
    used : (n_points,) bool, optional
        Points that count (e.g. the inliers); default: points with finite residuals.
    min_points : int
        Warn when a view sees fewer used points than this.
    residual_ratio : float
        A view's mean squared residual must exceed this many times that of the other
        views (practical significance) ...
    alpha : float
        ... the ratio must be significant at this level (F test with the numbers of
        residuals as degrees of freedom) ...
    min_excess_px : float
        ... and the view's RMS must exceed the others' by this much (very precise tracks
        make harmless differences of hundredths of a pixel significant).
    left_out : (n_views,) bool, optional
        Views left out on purpose (already reported): not counted as having few points.

    Returns
    -------
    list of Diagnostic
        ``view_few_points``, ``view_residuals``.
    """
    uv = np.asarray(uv, float)
    res = np.asarray(residuals_px, float)
    n_views = uv.shape[0]
    ok = np.isfinite(res[..., 0]) & np.isfinite(uv[..., 0])
    if used is not None:
        ok &= np.asarray(used, bool)[None, :]
    counts = ok.sum(axis=1)
    out = []
    few = np.flatnonzero((counts < min_points) & (True if left_out is None else ~np.asarray(left_out, bool)))
    if len(few):
        detail = ", ".join(f"view {i}: {counts[i]}" for i in few[:10])
        out.append(Diagnostic(
            "view_few_points",
            f"{len(few)} view(s) see very few usable points ({detail}; fewer than {min_points}): they constrain "
            "the calibration weakly and their errors go unnoticed. Track more points in those views (check the "
            "scene is in the field of view there) or drop those views."))
    sse = np.sum(squared_norms(res), axis=1, where=ok)
    n_res = 2 * counts
    flagged = []
    for i in range(n_views):  # one F test per view (few views)
        others = np.arange(n_views) != i
        if n_res[i] < 4 or n_res[others].sum() < 4:
            continue
        ms_i = sse[i] / n_res[i]
        ms_o = sse[others].sum() / n_res[others].sum()
        if ms_o <= 0:
            continue
        f = ms_i / ms_o
        if (f > residual_ratio and np.sqrt(ms_i) - np.sqrt(ms_o) >= min_excess_px
                and f_sf(f, n_res[i], n_res[others].sum()) < alpha):
            flagged.append((i, np.sqrt(ms_i), np.sqrt(ms_o)))
    if flagged:
        detail = ", ".join(f"view {i}: {a:.3g} px vs {b:.3g} px" for i, a, b in flagged)
        out.append(Diagnostic(
            "view_residuals",
            f"the residuals of {len(flagged)} view(s) stand out from the others (RMS per coordinate, {detail}): "
            "that view's image or pose is inconsistent with the rest. Check its robot pose (typo, wrong "
            "units, a move that did not finish), whether the robot also rotated there, motion blur or a "
            "tracking failure in that image; re-take it or drop it."))
    return out


def check_outliers(residuals_px, *, used=None, k_sigma: float = 5.0, min_px: float = OUTLIER_MIN_PX,
                   max_fraction: float = 0.001) -> list:
    """Warn when the residuals have gross outliers (heavy tails) the fit did not remove.

    Parameters
    ----------
    residuals_px : (n_views, n_points, 2) float
        Residuals of the calibration (NaN where unseen or unused).
    used : (n_points,) bool, optional
        Points that count (e.g. the inliers).
    k_sigma : float
        An observation is gross when its residual norm exceeds ``k_sigma`` times the
        robust noise per coordinate ``sigma = sqrt(median(|r|^2) / (2 ln 2))``
        (:func:`transcalib.estimate.noise.median_sigma`: the median of a chi-square with 2
        degrees of freedom is ``2 ln 2``; Gaussian: probability
        ``exp(-k^2 / 2)``, 4e-6 for k = 5) ...
    min_px : float
        ... and ``min_px`` pixels: with very precise tracks (0.02 px) small tracking errors
        are many sigmas but harmless.
    max_fraction : float
        Warn when more than this fraction of the observations (and at least 3) are gross.

    Returns
    -------
    list of Diagnostic
        ``outliers``.
    """
    e2 = squared_norms(np.asarray(residuals_px, float))  # one pass: NaN where unseen
    ok = np.isfinite(e2)
    if used is not None:
        ok &= np.asarray(used, bool)[None, :]
    n_obs = int(ok.sum())
    if n_obs < 10:
        return []
    sigma = median_sigma(e2[ok], 2, floor=0.0)
    if not sigma > 0:
        return []
    limit = max(k_sigma * sigma, min_px)
    beyond = ok & (e2 > limit * limit)
    gross = int(beyond.sum())
    if gross < 3 or gross <= max_fraction * n_obs:
        return []
    pts = np.flatnonzero(beyond.any(axis=0))
    return [Diagnostic(
        "outliers",
        f"{gross} of {n_obs} observations ({100 * gross / n_obs:.1f}%, in {len(pts)} points: {fmt_list(pts)}) have "
        f"residuals beyond {limit:.3g} px ({k_sigma:g} sigma, robust sigma {sigma:.3g} px): the tracks contain "
        "mismatches, which "
        "bias the calibration. Run the robust estimator (calibrate(..., robust=True), CLI --robust) or remove "
        "those tracks.")]
