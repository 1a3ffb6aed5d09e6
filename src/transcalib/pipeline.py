"""``calibrate()``: the one call users make.

    uv, T ──(robust: RANSAC on 2-point samples)──▶ inliers
          ──estimate_linear (paper TLS, O(n))──▶ LinearEstimate
          ──refine (ML bundle adjustment)──▶ Calibration ──diagnose──▶ warnings
"""

from __future__ import annotations

import time

import numpy as np

from .estimate.refine import refine as ml_refine
from dataclasses import replace

from .geometry.camera import project
from .check.diagnostics import diagnose
from .estimate.linear import estimate_linear
from .geometry.triangulate import triangulate
from .estimate.robust import estimate_robust
from .types import Calibration, InputError, LinearEstimate
from .validate import as_uv_T

__all__ = ["calibrate", "from_linear", "ROBUST_MIN_POINTS"]

#: ``robust=None`` turns RANSAC on from this many points (2-point samples need spare points).
ROBUST_MIN_POINTS = 8


def from_linear(uv: np.ndarray, T: np.ndarray, linear: LinearEstimate) -> Calibration:
    """A :class:`Calibration` holding the linear estimate alone (no distortion).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float
    linear : LinearEstimate
    """
    predicted = project(linear.K, linear.R, np.nan_to_num(linear.X), T)
    residuals = uv - predicted
    residuals[:, ~linear.used] = np.nan
    r2 = np.sum(residuals**2, axis=2)
    rms = float(np.sqrt(np.nanmean(r2))) if np.isfinite(r2).any() else float("nan")
    return Calibration(
        K=linear.K, R=linear.R, X=linear.X, dist=np.zeros(0), dist_model="none",
        residuals_px=residuals, rms_px=rms, T=T.copy(), linear=linear,
        info={"stage": "linear"},
    )


def _point_errors(uv: np.ndarray, cal: Calibration, X: np.ndarray) -> np.ndarray:
    """Largest reprojection error (px) of each point over the views that see it (n_points,);
    inf for points that cannot be triangulated."""
    r = uv - project(cal.K, cal.R, np.nan_to_num(X), cal.T, cal.dist)
    e = np.sqrt(np.sum(r**2, axis=2))
    e = np.where(np.isfinite(e), e, 0.0).max(axis=0)
    return np.where(np.isfinite(X[:, 0]), e, np.inf)


def calibrate(
    uv,
    T,
    *,
    refine: bool = True,
    robust: bool | None = None,
    distortion: str = "none",
    estimate_skew: bool = False,
    sigma_T=None,
    loss: str = "linear",
    loss_scale_px: float = 1.0,
    sigma_px: float | None = None,
    threshold_px: float = 2.0,
    quaternions=None,
    check_rotation: bool = True,
    unit: str = "units",
    rng=None,
    progress=None,
) -> Calibration:
    """Calibrate the camera and reconstruct the scene from tracks and known translations.

    Parameters
    ----------
    uv : array_like (n_views, n_points, 2)
        Pixel coordinates (centre of the top-left pixel is (0, 0)), NaN where unseen.
    T : array_like (n_views, 3)
        Robot translations of the views (robot frame; every output length is in its unit).
    refine : bool
        Maximum-likelihood refinement after the linear estimate (default). ``False``
        returns the paper's linear estimate, triangulated.
    robust : bool or None
        RANSAC over 2-point samples before the linear fit, then refinement on the
        inliers. ``None`` (default): on when at least ``ROBUST_MIN_POINTS`` points.
    distortion : {"none", "radial2", "opencv5"}
        Lens distortion model of the refinement (OpenCV convention).
    estimate_skew : bool
        Estimate the skew (else fixed at 0).
    sigma_T : float or (n_views,) float, optional
        Robot translation precision (user units): translations become measurements.
    loss : {"linear", "huber", "cauchy"}
        Loss of the refinement; ``loss_scale_px`` its scale.
    sigma_px : float, optional
        Known pixel noise per coordinate; by default estimated from the residuals.
    threshold_px : float
        RANSAC inlier threshold: a point is an inlier when its reprojection error is
        below this in every view that sees it.
    quaternions : (n_views, 4) float, optional
        Robot orientations ``qx, qy, qz, qw``; checked to be constant.
    check_rotation : bool
        Test for views where the robot rotated (model violation); needs ``refine``.
    unit : str
        Name of the length unit of ``T``, used in the diagnostics' messages.
    rng : seed or Generator
        Randomness of RANSAC.
    progress : callable, optional
        ``progress(stage: str, info: dict)`` after each stage.

    Returns
    -------
    Calibration
        With ``diagnostics`` (warnings naming the cause and what to do), ``inliers``
        (robust runs), ``cov``/``std``/``X_std`` (refined runs) and ``info["stages"]``.

    Raises
    ------
    InputError, DegenerateError, MirroredError
        See :func:`transcalib.estimate_linear`.
    """
    uv, T = as_uv_T(uv, T)
    if distortion != "none" and not refine:
        raise InputError(f"distortion={distortion!r} needs refine=True: the linear estimate has no distortion")
    notify = progress or (lambda stage, info: None)
    n_tracked = int((np.isfinite(uv[..., 0]).sum(axis=0) >= 2).sum())
    robust = n_tracked >= ROBUST_MIN_POINTS if robust is None else bool(robust)
    stages, timings = [], {}

    t0 = time.perf_counter()
    inliers = None
    if robust:
        rob = estimate_robust(uv, T, threshold_px=threshold_px, rng=rng)
        linear, inliers = rob.linear, rob.inliers
        stages.append("robust")
        timings["robust_s"] = time.perf_counter() - t0
        notify("robust", {"inliers": int(inliers.sum()), "trials": rob.trials})
    else:
        linear = estimate_linear(uv, T)
        stages.append("linear")
        timings["linear_s"] = time.perf_counter() - t0
        notify("linear", {"points": linear.n_used_points})

    uv_fit = uv if inliers is None else np.where(inliers[None, :, None], uv, np.nan)
    if refine:
        t1 = time.perf_counter()
        cal = ml_refine(
            uv_fit, T, linear, distortion=distortion, estimate_skew=estimate_skew,
            sigma_T=sigma_T, loss=loss, loss_scale_px=loss_scale_px, sigma_px=sigma_px,
        )
        stages.append("refine")
        timings["refine_s"] = time.perf_counter() - t1
        notify("refine", {"iterations": cal.info.get("iterations"), "rms_px": cal.rms_px})
    else:
        cal = from_linear(uv_fit, T, linear)
    if refine and inliers is not None:
        # RANSAC judged points with the linear, distortion-free camera; judge every track
        # again with the refined one (this matters under strong distortion) and refit if
        # the inlier set changes.
        X_all = triangulate(cal.A, uv, cal.T, K=cal.K, dist=cal.dist)
        error = _point_errors(uv, cal, X_all)
        again = error < threshold_px  # the rule of estimate_robust
        if np.any(again != inliers) and again.sum() >= 2:
            inliers = again
            uv_fit = np.where(inliers[None, :, None], uv, np.nan)
            cal = ml_refine(
                uv_fit, T, replace(cal, X=np.where(inliers[:, None], X_all, np.nan)), distortion=distortion,
                estimate_skew=estimate_skew, sigma_T=sigma_T, loss=loss, loss_scale_px=loss_scale_px,
                sigma_px=sigma_px,
            )
            stages.append("reclassify+refine")
    if cal.inliers is not None:  # the robust loss classified points too
        inliers = cal.inliers if inliers is None else inliers & cal.inliers

    # residuals of every observation for reporting, outliers included: an outlier is
    # triangulated with the final camera for that (its X stays NaN)
    residuals = cal.residuals_px
    if inliers is not None:
        X_eval = np.where(np.isfinite(cal.X), cal.X, triangulate(cal.A, uv, cal.T, K=cal.K, dist=cal.dist))
        full = uv - project(cal.K, cal.R, np.nan_to_num(X_eval), cal.T, cal.dist)
        residuals = np.where(np.isfinite(X_eval)[None, :, :1], full, np.nan)

    info = dict(cal.info)
    info.update(stages=stages, **timings)
    result = Calibration(
        K=cal.K, R=cal.R, X=cal.X, dist=cal.dist, dist_model=cal.dist_model,
        residuals_px=residuals, rms_px=cal.rms_px, diagnostics=[], T=cal.T, linear=linear,
        cov=cal.cov, std=cal.std, param_names=cal.param_names, X_std=cal.X_std,
        inliers=inliers, info=info,
    )
    t2 = time.perf_counter()
    found = diagnose(uv_fit, T, result, linear=linear, quaternions=quaternions,
                     check_rotation=check_rotation and refine, unit=unit)
    result.diagnostics.extend(found)
    info["diagnostics_s"] = time.perf_counter() - t2
    notify("diagnostics", {"warnings": len(found)})
    return result
