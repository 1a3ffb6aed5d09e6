"""``calibrate()``: the one call users make.

    uv, T ──(robust: RANSAC on 2-point samples)──▶ inliers
          ──linear (paper TLS, O(n))──▶ LinearEstimate
          ──refine (ML bundle adjustment)──▶ every track judged again, refit
          ──diagnose──▶ Calibration with warnings

With more than ``subset_points`` tracks the stages up to the re-judging run on a random
subset of them; "all tracks" then judges every track with that camera and takes
Gauss-Newton steps with all of them (``_extend_to_all_tracks``). Input is checked here
once; the stages take checked arrays and options.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from .check import diagnose, skipped
from .errors import InputError
from .estimate.coplanar import fit_coplanar, fit_coplanar_robust
from .estimate.degeneracy import explain_span
from .estimate.linear import fit_linear
from .estimate.refine import climb_distortion, fit_refine
from .estimate.robust import fit_robust
from .estimate.noise import SIGMA_FLOOR_PX, inlier_rule, sigma_from_threshold, truncation_factor
from .geometry.camera import DIST_NAMES, Camera, camera_frame, project, project_camera_frame
from .geometry.triangulate import triangulate
from .types import (INTRINSIC_NAMES, SUBSET_POINTS, CalibrateOptions, Calibration, CalibrationStats, LinearEstimate,
                    RansacOptions, RefineOptions, report)
from .validate import COPLANAR_RTOL, as_uv_T

__all__ = ["calibrate"]

#: ``robust=None`` turns RANSAC on from this many points (2-point samples need spare points).
ROBUST_MIN_POINTS = 8
#: The refined camera's verdict refits only when it changes more than this fraction of
#: the inliers (borderline tracks trading places at the false-rejection rate do not count).
REJUDGE_FRACTION = 0.005
#: Tracks per block where every track is evaluated (small temporaries stay in cache).
TRACK_BLOCK = 32768
#: Gauss-Newton steps with every track after the fit of a subset (see _extend_to_all_tracks).
GAUSS_NEWTON_STEPS = 2


def calibrate(
    uv,
    T,
    *,
    refine: bool = True,
    robust: bool | None = None,
    distortion: str | None = None,
    sigma_T=None,
    fix=None,
    square_pixels: bool | None = None,
    ransac: RansacOptions | None = None,
    refinement: RefineOptions | None = None,
    check_rotation: bool = True,
    rotations=None,
    image_size=None,
    unit: str = "units",
    subset_points: int | None = SUBSET_POINTS,
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
        RANSAC over 2-point samples before the linear fit. ``None`` (default): on from
        ``ROBUST_MIN_POINTS`` points.
    distortion : {"auto", "none", "radial1", "radial2", "opencv5"}, optional
        Lens distortion model of the refinement (default ``refinement.distortion``,
        ``"auto"``: chosen from the data, see :class:`RefineOptions`).
    sigma_T : float or (n_views,) float, optional
        Robot translation precision (user units): translations become measurements.
    fix : mapping, optional
        Known parameters, e.g. ``{"cx": 320.0, "cy": 240.0, "skew": 0.0}``.
    square_pixels : bool, optional
        ``fx = fy``.
    ransac : RansacOptions, optional
        Options of the robust stage.
    refinement : RefineOptions, optional
        Options of the refinement; the keywords above override their fields.
    check_rotation : bool
        Test for views where the robot rotated (model violation); needs ``refine``.
    rotations : (n_views, 3, 3) float, optional
        Flange -> base rotations of the views as read (:attr:`transcalib.io.Poses.R`);
        checked to be constant (a ``pose_orientation`` warning otherwise).
    image_size : (width, height), optional
        Recorded in the result's camera.
    unit : str
        Name of the length unit of ``T``, used in messages.
    subset_points : int or None
        With more tracks, the iterative stages run on a random subset of this many and
        Gauss-Newton steps with every track finish (:class:`CalibrateOptions`). None:
        every stage uses every track.
    rng : seed or Generator
        Randomness of RANSAC.
    progress : callable, optional
        ``progress(event)`` with a :class:`~transcalib.types.ProgressEvent` after each
        stage (and each step of the long ones).

    Returns
    -------
    Calibration
        With ``diagnostics``, ``inliers`` (robust runs), ``cov``/``std``/``X_std``
        (refined runs), ``options`` and ``stats`` (stages, timings, the robust stage,
        the refinement).

    Raises
    ------
    InputError, DegenerateError, MirroredError
        See :func:`transcalib.estimate_linear`; ``InputError`` also for an option that
        would have no effect (e.g. ``sigma_T`` with ``refine=False``).
    """
    uv, T = as_uv_T(uv, T)
    opts = _options(refine, robust, distortion, sigma_T, fix, square_pixels, ransac, refinement,
                    check_rotation, unit, subset_points)
    timings = {}
    t0 = time.perf_counter()
    span = _explain_span(T, opts)  # degeneracy first: raises naming what the motion cannot determine
    subset = _fit_subset(uv, opts, rng)
    uv_sub = uv if subset is None else uv[:, subset]
    linear, inliers, stages, ransac_stats = _initial_estimate(uv_sub, T, opts, rng, progress,
                                                              coplanar=span is not None, image_size=image_size)
    timings[f"{stages[0]}_s"] = time.perf_counter() - t0
    rotation_data = None
    if opts.refine:
        t1 = time.perf_counter()
        cal, inliers, more = _refine_and_rejudge(uv_sub, T, linear, inliers, opts, progress)
        stages += more
        timings["refine_s"] = time.perf_counter() - t1
        if subset is not None:
            t1 = time.perf_counter()
            rotation_data = (_masked(uv_sub, inliers), cal)  # the rotation test runs on the subset's fit
            cal, inliers = _extend_to_all_tracks(uv, T, cal, inliers, opts, progress)
            linear = _widened(linear, subset, uv.shape[1])
            stages.append("all tracks")
            timings["all_tracks_s"] = time.perf_counter() - t1
    else:
        cal = from_linear(_masked(uv, inliers), T, linear)
    result = replace(cal, camera=replace(cal.camera, image_size=image_size), linear=linear, inliers=inliers,
                     residuals_px=_all_residuals(uv, cal, inliers), options=opts, diagnostics=())
    t2 = time.perf_counter()
    result = replace(result, stats=replace(cal.stats, stages=tuple(stages), timings_s=timings, ransac=ransac_stats))
    found = diagnose(uv, T, result, linear=linear, rotations=rotations,
                     check_rotation=opts.check_rotation and opts.refine, unit=unit, all_uv=uv,
                     rotation_data=rotation_data)
    if span is not None:  # the coplanar motion was understood: say what it allows instead
        found = [span] + [d for d in found if d.code not in ("translations_coplanar", "translations_small")]
    if opts.check_rotation and not opts.refine:
        found.append(skipped("rotation test (did the robot rotate between views?)",
                             "it needs the refined calibration (refine=False, CLI --no-refine)"))
    report(progress, "diagnostics", warnings=len(found))
    timings = {**result.stats.timings_s, "diagnostics_s": time.perf_counter() - t2}
    return replace(result, diagnostics=tuple(found), stats=replace(result.stats, timings_s=timings))


def _masked(uv: np.ndarray, inliers) -> np.ndarray:
    """``uv`` with the outlier tracks set to NaN (``inliers`` None: all kept)."""
    return uv if inliers is None else np.where(inliers[None, :, None], uv, np.nan)


def _fit_subset(uv: np.ndarray, opts: CalibrateOptions, rng) -> np.ndarray | None:
    """Sorted indices of the tracks the iterative stages use (``opts.subset_points`` of
    those seen in >= 2 views, drawn at random), or None when they use every track."""
    m = opts.subset_points
    if not opts.refine or m is None:
        return None
    tracked = np.flatnonzero(np.isfinite(uv[..., 0]).sum(axis=0) >= 2)
    if len(tracked) <= m:
        return None
    return np.sort(np.random.default_rng(rng).choice(tracked, m, replace=False))


def _camera_values(cal: Calibration) -> dict:
    """Intrinsics and the five distortion coefficients of ``cal`` by parameter name
    (``f`` too, for square pixels)."""
    cam = cal.camera
    values = dict(zip(INTRINSIC_NAMES + DIST_NAMES, np.concatenate([cam.intrinsics, cam.dist5])))
    return {**values, "f": values["fx"]}


def _widened(linear: LinearEstimate, subset: np.ndarray, n_points: int) -> LinearEstimate:
    """The linear estimate of the tracks ``subset`` with its per-point arrays over all
    ``n_points`` tracks (NaN / unused outside the subset)."""
    def spread(a, fill, axis):
        shape = list(np.shape(a))
        shape[axis] = n_points
        out = np.full(shape, fill, dtype=np.asarray(a).dtype)
        out[(slice(None),) * axis + (subset,)] = a
        return out

    return replace(linear, X=spread(linear.X, np.nan, 0), depth=spread(linear.depth, np.nan, 1),
                   used=spread(linear.used, False, 0),
                   static=None if linear.static is None else spread(linear.static, False, 0))


def _extend_to_all_tracks(uv, T, cal: Calibration, inliers, opts: CalibrateOptions, progress):
    """From the calibration of a subset of the tracks, the maximum-likelihood one of all
    of them: every track triangulated and judged by the subset's camera (the inlier rule
    of the robust stage), then :data:`GAUSS_NEWTON_STEPS` undamped steps of the camera
    and every inlier track jointly, with the covariance at that solution. The subset's
    solution is a few of its standard deviations from the full one, where the cost is
    nearly quadratic: the first step lands within a few hundredths of a standard
    deviation, the second within about 1e-4 (tests/test_pipeline.py). Returns
    ``(cal, inliers)``."""
    X_all = triangulate(cal.A, uv, cal.T, K=cal.K, dist=cal.dist)
    k = np.isfinite(uv[..., 0]).sum(axis=0)
    if inliers is not None:
        inliers = inlier_rule(_track_sse(uv, cal, X_all), k, _rule_sigma(cal, opts), opts.ransac.false_rejection)
    start = replace(cal, X=X_all if inliers is None else np.where(inliers[:, None], X_all, np.nan))
    step = replace(opts.refinement, distortion=cal.dist_model, max_iterations=GAUSS_NEWTON_STEPS)
    full = fit_refine(uv, T, start, step, near_solution=True)  # outliers have no X: not used
    if full.inliers is not None:  # the robust loss classified points too
        inliers = full.inliers if inliers is None else inliers & full.inliers
    if inliers is not None and opts.ransac.threshold_px is None and opts.refinement.sigma_px is None:
        full = _untruncated(full, k[inliers], opts.ransac.false_rejection)
    before, after = _camera_values(cal), _camera_values(full)
    moved = max((abs(after[k] - before[k]) / v for k, v in full.std.items() if v > 0 and k in before), default=0.0)
    subset = cal.stats.refine
    refined = replace(full.stats.refine, converged=True,
                      stop_reason=f"{full.stats.refine.iterations} Gauss-Newton step(s) from the fit of "
                                  f"{subset.n_points_used} tracks (which moved the camera by {moved:.2g} standard "
                                  "deviations at most)")
    stats = replace(full.stats, refine=refined, subset=subset, distortion_selection=cal.stats.distortion_selection)
    report(progress, "all tracks", points=refined.n_points_used, rms_px=full.rms_px)
    return replace(full, options=replace(full.options, refinement=opts.refinement), stats=stats), inliers


def _options(refine, robust, distortion, sigma_T, fix, square_pixels, ransac, refinement, check_rotation,
             unit, subset_points) -> CalibrateOptions:
    """The :class:`CalibrateOptions` of a call; keywords override ``refinement``'s fields."""
    r = refinement if refinement is not None else RefineOptions()
    overrides = {k: v for k, v in (("distortion", distortion), ("sigma_T", sigma_T), ("fix", fix),
                                   ("square_pixels", square_pixels)) if v is not None}
    if overrides:
        r = replace(r, **overrides)
    if not refine and r.distortion not in ("none", "auto"):
        raise InputError(f"distortion={r.distortion!r} needs refine=True: the linear estimate has no distortion")
    return CalibrateOptions(refine=bool(refine), robust=robust, ransac=ransac or RansacOptions(), refinement=r,
                            check_rotation=bool(check_rotation), unit=str(unit), subset_points=subset_points)


def _explain_span(T, opts: CalibrateOptions):
    """:func:`transcalib.estimate.degeneracy.explain_span` for the problem posed: None for
    translations spanning 3-D, a Diagnostic for coplanar ones that the known parameters
    make identifiable; raises :class:`DegenerateError` otherwise."""
    r = opts.refinement
    model = "none" if r.distortion == "auto" else r.distortion
    return explain_span(T, r.fix, r.square_pixels, opts.unit, estimate_skew=r.estimate_skew, distortion=model,
                        tol=COPLANAR_RTOL)


def _coplanar_start_fix(uv, fix, image_size) -> dict:
    """Known parameters for the coplanar linear start: the user's, plus the image centre
    as principal point when only the focal lengths are known (the refinement then frees
    it again; the start needs one)."""
    fix = dict(fix)
    if "cx" not in fix or "cy" not in fix:
        if image_size is not None:
            centre = (0.5 * (image_size[0] - 1), 0.5 * (image_size[1] - 1))
        else:  # the middle of the observed pixels
            lo, hi = np.nanmin(uv, axis=(0, 1)), np.nanmax(uv, axis=(0, 1))
            centre = tuple(0.5 * (lo + hi))
        fix.setdefault("cx", float(centre[0]))
        fix.setdefault("cy", float(centre[1]))
    return fix


def _initial_estimate(uv, T, opts: CalibrateOptions, rng, progress, coplanar: bool = False, image_size=None):
    """RANSAC (or the plain linear estimate): ``(linear, inliers or None, stages,
    RansacStats or None)``; coplanar translations take the known-parameter linear start."""
    n_tracked = int((np.isfinite(uv[..., 0]).sum(axis=0) >= 2).sum())
    robust = n_tracked >= ROBUST_MIN_POINTS if opts.robust is None else bool(opts.robust)
    if coplanar:
        r = replace(opts.refinement, fix=_coplanar_start_fix(uv, opts.refinement.fix, image_size))
        if robust:
            linear, inliers, stats = fit_coplanar_robust(uv, T, fix=r.fix, square_pixels=r.square_pixels,
                                                         options=opts.ransac, rng=rng, tol=COPLANAR_RTOL)
            report(progress, "robust (coplanar)", inliers=stats.n_inliers, trials=stats.trials, sigma_px=stats.sigma_px)
            return linear, inliers, ["robust"], stats
        linear = fit_coplanar(uv, T, fix=r.fix, square_pixels=r.square_pixels, tol=COPLANAR_RTOL)
        report(progress, "linear (coplanar)", points=linear.n_used_points)
        return linear, None, ["linear"], None
    if robust:
        rob = fit_robust(uv, T, opts.ransac, rng=rng)
        report(progress, "robust", inliers=rob.n_inliers, trials=rob.trials, sigma_px=rob.sigma_px)
        return rob.linear, rob.inliers, ["robust"], rob.stats
    linear = fit_linear(uv, T)
    report(progress, "linear", points=linear.n_used_points)
    return linear, None, ["linear"], None


def _refine_and_rejudge(uv, T, linear, inliers, opts: CalibrateOptions, progress):
    """Refine on the inliers; then judge every track again with the refined camera (RANSAC
    judged them with the linear, distortion-free one: this matters under strong
    distortion) and refit while the inlier set changes. Returns ``(cal, inliers, stages)``."""
    cal = fit_refine(_masked(uv, inliers), T, linear, opts.refinement)
    report(progress, "refine", iterations=cal.stats.refine.iterations, rms_px=cal.rms_px, distortion=cal.dist_model)
    stages = ["refine"]
    chosen = replace(opts.refinement, distortion=cal.dist_model)  # refits keep the model chosen
    selection = cal.stats.distortion_selection
    k = np.isfinite(uv[..., 0]).sum(axis=0)
    for _ in range(3 if inliers is not None else 0):  # until the inlier set settles
        X_all = triangulate(cal.A, uv, cal.T, K=cal.K, dist=cal.dist)
        again = inlier_rule(_track_sse(uv, cal, X_all), k, _rule_sigma(cal, opts), opts.ransac.false_rejection)
        # a few borderline tracks trading places change nothing: refit only for more
        if np.sum(again != inliers) <= max(2, REJUDGE_FRACTION * inliers.sum()) or again.sum() < 2:
            break
        inliers = again
        start = replace(cal, X=np.where(inliers[:, None], X_all, np.nan))
        cal = fit_refine(_masked(uv, inliers), T, start, chosen)
        stages.append("reclassify+refine")
    if opts.refinement.distortion == "auto" and stages[-1] != "refine":  # more tracks: more distortion?
        cal = climb_distortion(_masked(uv, inliers), T, cal, opts.refinement)
        cal = replace(cal, stats=replace(cal.stats, distortion_selection=selection + cal.stats.distortion_selection))
    if cal.inliers is not None:  # the robust loss classified points too
        inliers = cal.inliers if inliers is None else inliers & cal.inliers
    if inliers is not None and opts.ransac.threshold_px is None and opts.refinement.sigma_px is None:
        cal = _untruncated(cal, k[inliers], opts.ransac.false_rejection)
    return cal, inliers, stages


def _untruncated(cal: Calibration, k: np.ndarray, alpha: float) -> Calibration:
    """Undo the bias of a noise estimated on chi-square-selected inliers: the rule drops
    the largest ``alpha`` of the good tracks' errors, so ``sigma^2`` (and every variance
    scaled by it) comes out low by :func:`truncation_factor` (about 2 %)."""
    c = truncation_factor(k, alpha)
    root = float(np.sqrt(c))
    return replace(cal, sigma_px=float(cal.sigma_px / root), cov=cal.cov / c,
                   std={name: float(v / root) for name, v in cal.std.items()}, X_std=cal.X_std / root,
                   T_std=None if cal.T_std is None else cal.T_std / root,
                   stats=replace(cal.stats, sigma_truncation_factor=c))


def _track_sse(uv: np.ndarray, cal: Calibration, X: np.ndarray) -> np.ndarray:
    """Sum of squared reprojection errors (px^2) of each track over the views that see it
    (n_points,); inf for tracks that cannot be triangulated or fall behind the camera.
    Evaluated ``TRACK_BLOCK`` tracks at a time (small temporaries)."""
    out = np.empty(uv.shape[1])
    for lo in range(0, uv.shape[1], TRACK_BLOCK):
        b = slice(lo, lo + TRACK_BLOCK)
        xc = camera_frame(cal.R, np.nan_to_num(X[b]), cal.T)
        pred = project_camera_frame(cal.camera.intrinsics, cal.camera.dist5, xc).pred
        seen = np.isfinite(uv[:, b, 0])
        du, dv = uv[:, b, 0] - pred[0], uv[:, b, 1] - pred[1]
        sse = np.sum(du * du + dv * dv, axis=0, where=seen)
        behind = np.any(seen & (xc[2] <= 0), axis=0)
        out[b] = np.where(np.isfinite(X[b, 0]) & ~behind, sse, np.inf)
    return out


def _rule_sigma(cal: Calibration, opts: CalibrateOptions) -> float:
    """The sigma of the inlier rule after refinement: the refined estimate, or the one a
    user threshold implies."""
    if opts.ransac.threshold_px is not None:
        return sigma_from_threshold(opts.ransac.threshold_px, opts.ransac.false_rejection)
    return max(cal.sigma_px, SIGMA_FLOOR_PX)


def _all_residuals(uv, cal: Calibration, inliers) -> np.ndarray:
    """Residuals of every observation for reporting, outliers included: an outlier is
    triangulated with the final camera for that (its ``X`` stays NaN)."""
    if inliers is None:
        return cal.residuals_px
    out = cal.residuals_px.copy()
    missing = ~np.isfinite(cal.X[:, 0])  # only these need triangulating and projecting
    X = triangulate(cal.A, uv[:, missing], cal.T, K=cal.K, dist=cal.dist)
    res = uv[:, missing] - cal.camera.project(np.nan_to_num(X), cal.T)
    out[:, missing] = np.where(np.isfinite(X)[None, :, :1], res, np.nan)
    return out


def from_linear(uv: np.ndarray, T: np.ndarray, linear: LinearEstimate) -> Calibration:
    """A :class:`Calibration` holding the linear estimate alone (no distortion).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float
    linear : LinearEstimate
    """
    residuals = uv - project(linear.K, linear.R, np.nan_to_num(linear.X), T)
    residuals[:, ~linear.used] = np.nan
    r2 = np.sum(residuals**2, axis=2)
    rms = float(np.sqrt(np.nanmean(r2))) if np.isfinite(r2).any() else float("nan")
    return Calibration(camera=Camera(linear.K, linear.R), X=linear.X, residuals_px=residuals, rms_px=rms,
                       T=T.copy(), linear=linear, stats=CalibrationStats(stages=("linear",)))
