"""``transcalib.dense``: depth maps of reference views and their fused metric cloud.

For each reference view: its session's other views are the sources (:mod:`.views`);
the images are prepared (:mod:`.images`); the depth range comes from the caller or from
a coarse sweep at a quarter of the resolution over the whole range in front of the
cameras; the full-resolution sweep (:mod:`.sweep`) gives the minimum of every pixel,
:mod:`.depth` the depth, confidence and matching uncertainty, :mod:`.uncertainty` the
calibration's part. :mod:`.fuse` makes the cloud.
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from ..errors import DegenerateError, InputError
from ..types import Poses
from ..types.progress import report
from .depth import depth_from_sweep
from .fuse import fuse
from .images import grey, image_motion_px, make_canvas, noise_std, normalise, rgb
from .options import DenseOptions, DenseResult, DepthMap, DepthStats, default_best_k
from .sweep import SweepInput, sweep
from .uncertainty import calibration_depth_std
from .views import ViewCameras, central_view, check_baselines, cloud_frame, view_cameras

__all__ = ["dense"]

#: Downsampling of the coarse sweep that finds the depth range, and its hypotheses.
COARSE_FACTOR, COARSE_DEPTHS = 4, 64
#: Widest disparity (fraction of the image width) the coarse sweep searches.
COARSE_MAX_DISPARITY = 0.3
#: Disparity (pixels, longest baseline) that ``c2`` keeps away from the best hypothesis.
EXCLUSION_PX = 2.0
#: Image motion (pixels) below which a source's rotation relative to the reference is
#: left out (a third of the sweep's noise-free accuracy, 0.011-0.017 px).
ROTATION_PX = 0.005


def dense(calibration, images, poses, *, reference_views=None, depth_limits=None, options: DenseOptions | None = None,
          progress=None) -> DenseResult:
    """Dense metric reconstruction from calibrated views under known translations.

    Multi-baseline stereo in inverse depth (Okutomi & Kanade 1993) on each reference
    view's original pixel grid: the cost of every depth hypothesis is summed over the
    best-k other views of the reference's session (module :mod:`transcalib.dense.sweep`).

    Parameters
    ----------
    calibration : Calibration or Camera
        ``transcalib.load(DIR)``; its covariance, when it has one, enters ``depth_std``.
    images : sequence of (H, W) or (H, W, 3|4) uint8/uint16 arrays, or of paths
        One per view, in the order of ``poses`` (colour as OpenCV reads it: BGR).
    poses : Poses or (n_views, 3) float
        ``transcalib.io.read_poses(...)`` (view ids, flange positions ``T``,
        orientations, sessions), or the positions alone (view ids ``"0"``, ``"1"``,
        ...), in the calibration's unit. A calibration made with orientations needs
        them: each view's camera is the calibration's ``camera_poses`` of its flange
        pose (:func:`~transcalib.dense.views.view_cameras`).
    reference_views : sequence of str, optional
        View ids (as in ``poses.views``: canonical, ``01`` is ``1``). Default: the most
        central view of the largest session (:func:`~transcalib.dense.views.central_view`).
    depth_limits : (near, far) float, optional
        Depth range along the optical axis (robot units; ``far`` may be ``inf``).
        Default: found by a coarse sweep.
    options : DenseOptions, optional
    progress : callable, optional
        Receives ``ProgressEvent`` s (``transcalib.types.ProgressEvent``).

    Returns
    -------
    DenseResult

    Raises
    ------
    InputError
        Wrong counts, shapes or sizes of images, unknown reference views, bad depth
        limits, orientations that the calibration cannot place (:func:`view_cameras`).
    DegenerateError
        No baseline in a reference view's session, or no depth found without limits.
    """
    t0 = time.perf_counter()
    opts = DenseOptions() if options is None else options
    if not isinstance(opts, DenseOptions):
        raise InputError(f"options must be a DenseOptions, got {type(opts).__name__}")
    poses = _poses(poses)
    ids = [str(v) for v in poses.views]
    unit = poses.unit or getattr(getattr(calibration, "options", None), "unit", None)
    imgs = _images(images, poses.n_views, getattr(calibration, "camera", calibration))
    cams = view_cameras(calibration, poses)
    refs = _references(reference_views, ids, cams)
    limits = _limits(depth_limits)
    cache: dict = {}
    maps = [_reconstruct_view(calibration, imgs, cams, ids, ref, limits, opts, cache, progress) for ref in refs]
    t_fuse = time.perf_counter()
    cloud = fuse(maps, opts.consistency_rel)
    report(progress, "dense: cloud", points=len(cloud.points), rejected=cloud.n_rejected)
    timings = {f"view_{m.view}_s": m.stats.time_s for m in maps}
    timings.update(fuse_s=time.perf_counter() - t_fuse, total_s=time.perf_counter() - t0)
    return DenseResult(maps=tuple(maps), points=cloud.points, colors=cloud.colors, point_view=cloud.view,
                       point_confidence=cloud.confidence, point_std=cloud.std, n_rejected=cloud.n_rejected,
                       unit=unit, options=opts, frame=cloud_frame(calibration), timings_s=timings)


# --------------------------------------------------------------------------------------
# input checks
# --------------------------------------------------------------------------------------


def _poses(poses) -> Poses:
    """``poses`` as a :class:`~transcalib.types.Poses` of at least two views."""
    if not isinstance(poses, Poses):
        try:
            T = np.asarray(poses, dtype=float)
        except (TypeError, ValueError):
            raise InputError("poses must be a Poses (transcalib.io.read_poses) or robot positions (n_views, 3)") \
                from None
        if T.ndim != 2 or T.shape[1] != 3 or not np.isfinite(T).all():
            raise InputError(f"poses: need finite robot positions, shape (n_views, 3); got {T.shape}")
        poses = Poses.of(T)
    if poses.n_views < 2:
        raise InputError(f"poses: need at least 2 views, got {poses.n_views}")
    return poses


def _read(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"image {str(path)!r} is not an image OpenCV can read")
    return img


def _images(images, n_views: int, camera) -> list:
    """The images as arrays, checked: one per view, one size (the calibration's)."""
    imgs = [_read(im) if isinstance(im, (str, Path)) else np.asarray(im) for im in images]
    if len(imgs) != n_views:
        raise InputError(f"{len(imgs)} images but {n_views} poses; give one image per view, in the poses' order")
    for k, im in enumerate(imgs):
        if im.dtype not in (np.uint8, np.uint16) or im.ndim not in (2, 3) or (im.ndim == 3 and im.shape[2] not in
                                                                              (1, 3, 4)):
            raise InputError(f"image {k}: need an 8- or 16-bit grey, BGR or BGRA image, got {im.dtype} of shape "
                             f"{im.shape}")
    sizes = {(im.shape[1], im.shape[0]) for im in imgs}
    if len(sizes) > 1:
        raise InputError(f"the images have different sizes {sorted(sizes)}; give the views of one camera")
    size = sizes.pop()
    if camera.image_size is not None and tuple(camera.image_size) != size:
        raise InputError(f"the images are {size[0]}x{size[1]} px but the camera was calibrated at "
                         f"{camera.image_size[0]}x{camera.image_size[1]}; give images of the calibrated camera")
    if min(size) < 16:
        raise InputError(f"the images are {size[0]}x{size[1]} px; dense matching needs at least 16x16")
    return imgs


def _references(reference_views, ids, cams: ViewCameras) -> list[int]:
    if reference_views is None:
        return [central_view(cams)]
    if isinstance(reference_views, (str, int, np.integer)):
        reference_views = [reference_views]
    wanted = [str(v).strip() for v in reference_views]
    missing = [v for v in wanted if v not in ids]
    if missing:
        raise InputError(f"reference view(s) {', '.join(missing)} not among the views {', '.join(ids[:20])}"
                         + (" ..." if len(ids) > 20 else ""))
    if len(set(wanted)) != len(wanted) or not wanted:
        raise InputError(f"reference views must be distinct and at least one, got {wanted}")
    return [ids.index(v) for v in wanted]


def _limits(depth_limits):
    if depth_limits is None:
        return None
    try:
        near, far = (float(v) for v in depth_limits)
    except (TypeError, ValueError):
        raise InputError(f"depth_limits must be two numbers (near, far), got {depth_limits!r}") from None
    if not (np.isfinite(near) and near > 0 and far > near):
        raise InputError(f"depth_limits need 0 < near < far (far may be inf), got near {near:g}, far {far:g}")
    return near, far


# --------------------------------------------------------------------------------------
# one reference view
# --------------------------------------------------------------------------------------


def _prepared(imgs, view: int, canvas, window: int, cache: dict):
    """``(normalised, local_std, noise, canvas)`` of ``view``: the normalised image and
    its local grey-level std on the view's own grid, the image noise (grey levels), and
    the normalised image on the pinhole canvas (the same array without distortion);
    cached by view."""
    if view not in cache:
        g = grey(imgs[view])
        noise = max(noise_std(g), 0.25)
        n, local = normalise(g, window, 2.0 * noise)
        src = n if canvas.maps is None else normalise(canvas.undistort(g), window, 2.0 * noise)[0]
        cache[view] = (n, local, noise, src)
    return cache[view]


def _source(imgs, view: int, R: np.ndarray, canvas, window: int, cache: dict) -> np.ndarray:
    """The normalised source ``view`` on the canvas in the reference's axes: the cached
    canvas image when its rotation ``R`` against the reference moves the image by less
    than :data:`ROTATION_PX`, else resampled once through :meth:`Canvas.turned` (cached
    by view and rotation)."""
    n, _, noise, src = _prepared(imgs, view, canvas, window, cache)
    if image_motion_px(R, canvas) < ROTATION_PX:
        return src
    key = ("turned", view, R.tobytes())
    if key not in cache:
        cache[key] = normalise(canvas.undistort(grey(imgs[view]), canvas.turned(R)), window, 2.0 * noise)[0]
    return cache[key]


def _reconstruct_view(calibration, imgs, cams: ViewCameras, ids, ref: int, limits, opts: DenseOptions, cache,
                      progress) -> DepthMap:
    """The :class:`DepthMap` of reference view ``ref`` (module docstring)."""
    t0 = time.perf_counter()
    camera = getattr(calibration, "camera", calibration)
    sources = cams.sources(ref, opts.max_turn_deg)
    check_baselines(cams, ref, sources, ids)
    h, w = imgs[ref].shape[:2]
    key = ("canvas",)
    if key not in cache:
        cache[key] = make_canvas(camera, (w, h))
    canvas = cache[key]
    ref_n, local, noise, _ = _prepared(imgs, ref, canvas, opts.window_px, cache)
    R_rel, t_j = cams.relative(ref, sources)
    t = np.einsum("kba,kb->ka", R_rel, t_j)  # the sources' centres in the reference's frame: R_ref (C_j - C_ref)
    e = t @ canvas.K.T
    src = [_source(imgs, j, R, canvas, opts.window_px, cache) for j, R in zip(sources, R_rel)]
    k = opts.best_k if opts.best_k is not None else default_best_k(len(sources))
    k = min(k, len(sources))
    rho_range = _rho_range(ref_n, src, e, canvas, opts, k, progress) if limits is None else \
        (0.0 if np.isinf(limits[1]) else 1.0 / limits[1], 1.0 / limits[0])
    rho = np.linspace(rho_range[0], rho_range[1], opts.n_depths)
    step_px = (rho[1] - rho[0]) * _disparity_rate(e, canvas, (w, h))
    exclusion = int(np.clip(np.ceil(EXCLUSION_PX / max(step_px, 1e-9)), 1, opts.n_depths // 4))
    inp = SweepInput(ref=ref_n, sources=src, epipoles=e, offset=canvas.offset, ref_canvas=canvas.ref, rho=rho,
                     window=opts.window_px, best_k=k, exclusion=exclusion)
    res = _run_sweep(inp, opts, progress, f"dense: sweep view {ids[ref]}")
    est = depth_from_sweep(res, rho, local, noise, opts, k)
    ref_camera = type(camera)(camera.K, cams.R[ref], camera.dist, camera.dist_model, (w, h))
    rel = calibration_depth_std(calibration, ref_camera, t, rho_range, (h, w), est.rho)
    std_cal = None if rel is None else (rel * est.depth).astype(np.float32)
    std = est.std if std_cal is None else np.sqrt(est.std**2 + std_cal**2).astype(np.float32)
    near, far = 1.0 / rho_range[1], (np.inf if rho_range[0] <= 0 else 1.0 / rho_range[0])
    stats = DepthStats(known_fraction=float(np.isfinite(est.depth).mean()),
                       textured_fraction=float(est.textured.mean()), noise_dn=float(noise),
                       hypothesis_step_px=float(step_px), exclusion=exclusion, time_s=time.perf_counter() - t0)
    report(progress, f"dense: view {ids[ref]}", known=round(stats.known_fraction, 4), near=near, far=far,
           seconds=round(stats.time_s, 2))
    return DepthMap(view=ids[ref], index=ref, depth=est.depth, confidence=est.confidence, depth_std=std,
                    depth_std_calibration=std_cal, camera=ref_camera, centre=cams.C[ref], image=rgb(imgs[ref]),
                    sources=tuple(ids[j] for j in sources), depth_limits=(near, far), best_k=k, stats=stats)


def _run_sweep(inp: SweepInput, opts: DenseOptions, progress, stage: str):
    """The sweep on ``opts.n_threads()`` threads of our own (OpenCV's own threads are set
    to one meanwhile, so that the two do not compete for the cores)."""
    threads = opts.n_threads()
    before = cv2.getNumThreads()
    if threads > 1:
        cv2.setNumThreads(1)
    try:
        return sweep(inp, threads, progress, stage)
    finally:
        cv2.setNumThreads(before)


def _disparity_rate(e: np.ndarray, canvas, size) -> float:
    """Largest image motion per unit inverse depth over the sources, at the image
    corners and centre: ``|u~ e_z - e_xy|`` (pixels per unit of ``rho``)."""
    w, h = size
    pts = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1], [(w - 1) / 2, (h - 1) / 2]], float) + canvas.offset
    return float(np.max(np.linalg.norm(pts[None] * e[:, None, 2:3] - e[:, None, :2], axis=-1)))


def _rho_range(ref_n, src, e, canvas, opts: DenseOptions, k: int, progress) -> tuple[float, float]:
    """Inverse depths to search when no limits are given: a coarse sweep over every
    hypothesis that moves the image by up to ``COARSE_MAX_DISPARITY`` of its width (in
    front of every source camera), then the 1st-99th percentile of what it finds away
    from the border, widened by 5 % of that range and one and a half coarse steps on
    each side."""
    h, w = ref_n.shape
    s = COARSE_FACTOR
    rate = _disparity_rate(e, canvas, (w, h))
    rho_max = COARSE_MAX_DISPARITY * w / rate
    if np.any(e[:, 2] > 0):
        rho_max = min(rho_max, 0.9 / e[:, 2].max())
    rho = np.linspace(0.0, rho_max, COARSE_DEPTHS)

    def small(a):
        return cv2.resize(a, (max(a.shape[1] // s, 8), max(a.shape[0] // s, 8)), interpolation=cv2.INTER_AREA)

    A = np.array([[1 / s, 0, 0.5 / s - 0.5], [0, 1 / s, 0.5 / s - 0.5], [0, 0, 1]])
    ref_canvas = None if canvas.ref is None else small(canvas.ref) / s + np.float32(0.5 / s - 0.5)
    inp = SweepInput(ref=small(ref_n), sources=[small(x) for x in src], epipoles=e @ A.T, offset=canvas.offset / s,
                     ref_canvas=ref_canvas, rho=rho, window=opts.window_px, best_k=k, exclusion=2)
    res = _run_sweep(inp, opts, progress, "dense: depth range")
    step = rho[1] - rho[0]
    ok = np.isfinite(res.index) & (res.c1 < 0.5) & (res.c1 < 0.7 * res.c2)
    # not within a window of the border: there the windows leave the image, and the
    # replicated edge (darkest under vignetting) matches at no motion: a cluster at
    # rho ~ 0 that put the far limit at infinity
    r = opts.window_px // 2 + 1
    ok[:r], ok[-r:], ok[:, :r], ok[:, -r:] = False, False, False, False
    if ok.mean() < 0.01:
        raise DegenerateError("could not find the depth range of the scene (too little texture, or no overlap "
                              "between the views); give depth_limits (--depth-limits NEAR,FAR)")
    lo, hi = np.percentile(res.index[ok] * step, [1.0, 99.0])
    pad = 0.05 * (hi - lo) + 1.5 * step
    return max(lo - pad, 0.0), hi + pad
