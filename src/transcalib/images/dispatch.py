"""``track``: the one entry of the image front-end, for every robot motion.

Views are grouped by camera orientation (the flange rotations ``rotations``, or given
``sessions``): a group of 2+ views is a **session** of pure translations, tracked with the
epipolar geometry ``F = [e]x`` (:mod:`.session`); a group of one view is a **single view**
at its own orientation. Images are read and detected once (:mod:`.detect`, two threads);
the groups are then linked across orientations (:mod:`.link`), so that a point keeps one
index across every view it is seen in. When **no two views share an orientation** (general
motion: every group a single view) there is no session to chain along: SIFT keypoints are
matched in every view pair, verified by a fundamental matrix, joined into tracks and
aligned by affine Lucas-Kanade (:mod:`.multiview`). Without rotations all views are one
session, today's pure-translation tracker; ``target="squares"`` (or ``method="auto"`` on a scene
that is only a board of dark squares) runs the target mode (:mod:`.target`).
"""

from __future__ import annotations

import importlib
import threading
import time
from dataclasses import replace

import numpy as np

from ..errors import DegenerateError, InputError
from ..handeye.sessions import SESSION_TOLERANCE_DEG
from .detect import DetectOptions, detect_all
from .frames import GroupInfo, PairInfo, TrackInfo, Tracks, load_images, progress_fn

__all__ = ["track"]

#: The stages that import SciPy (half a second on the project's machine): imported where
#: they are used, by :func:`_load_stages` on a second thread while the main thread decodes
#: the images and detects the features (OpenCV releases the GIL meanwhile); the sessions'
#: stages, or under general motion (every group a single view) the multi-view tracker's.
_STAGES = {False: ("session", "link"), True: ("multiview",)}

#: With fewer feature tracks seen in 3+ views, ``track(method="auto")`` tries the target mode.
AUTO_MIN_LONG_TRACKS = 30


def track(
    images,
    *,
    T=None,
    rotations=None,
    sessions=None,
    session_tolerance_deg: float = SESSION_TOLERANCE_DEG,
    method: str = "auto",
    target: str | None = None,
    max_features: int = 2000,
    max_corners: int = 2000,
    corner_quality: float = 0.02,
    ratio: float = 0.8,
    threshold_px: float = 1.5,
    refine: bool = True,
    window_radius: int = 8,
    min_ncc: float = 0.9,
    final_threshold_px: float = 0.5,
    smooth_px: float = 2.5,
    min_views: int = 2,
    min_tracks: int = 8,
    max_tracks: int | None = 1500,
    progress=None,
    rng=0,
) -> Tracks:
    """Track points across images taken by a robot: pure translations, any mix of
    pure-translation sessions and single views at other orientations, or views each at
    its own orientation (general motion).

    General motion (no two views within ``session_tolerance_deg``, or every ``sessions``
    label used once) runs :func:`.multiview.track_general`: SIFT keypoints are the points
    tracked (``method`` and ``max_corners`` do not apply), every observation is aligned by
    affine LK whatever ``refine`` says, ``T`` is not used; ``info.method`` is
    ``"features (general motion)"``, ``info.pairs`` holds every view pair (``source``
    ``"fundamental"`` when its ``F`` was verified).

    Parameters
    ----------
    images : sequence of path or array, or array (n_views, h, w[, 3])
        The views, in order (the order of the robot poses). Arrays: grey or RGB.
    T : (n_views, 3) float, optional
        The robot (flange) positions. Inside a session every epipole is
        ``e_ij ~ A (T_j - T_i)`` for one ``A``: pairs whose epipole disagrees with the
        others' (a repetitive texture can make a wrong epipole win, consistently for all
        pairs of one view) get the predicted one (``info.pairs_set_by_translations``).
        Recommended.
    rotations : (n_views, 3, 3) float, optional
        Flange -> base rotations of the views (``Poses.R`` of
        :func:`transcalib.io.read_poses`). Views whose orientations agree within
        :data:`SESSION_TOLERANCE_DEG` form a session; every other view is a single view.
        None (and no ``sessions``): all views are one pure-translation session.
    sessions : (n_views,) labels, optional
        The session of each view, overriding the grouping by ``rotations`` (a label used
        once makes a single view).
    session_tolerance_deg : float
        Largest angle (degrees) between the orientations of two views of one session.
    method : {"auto", "sift", "corners"}
        The points tracked: ``"corners"`` Shi-Tomasi corners, ``"sift"`` SIFT keypoints;
        ``"auto"`` corners, and when fewer than ``AUTO_MIN_LONG_TRACKS`` tracks reach 3
        views (a scene that is only a board of dark squares), the target mode if it
        tracks more. Epipoles and links always come from SIFT.
    target : None or "squares"
        ``"squares"``: the paper's target mode instead of feature tracking
        (:func:`transcalib.images.track_squares`).
    max_features, max_corners : int
        Caps on SIFT keypoints and corners per image.
    corner_quality : float
        ``qualityLevel`` of ``cv2.goodFeaturesToTrack``.
    ratio : float
        Lowe's ratio-test threshold.
    threshold_px : float
        Epipolar distance for accepting a match before refinement (the noise of the
        epipole RANSAC's rule follows from it).
    refine : bool
        Sub-pixel refinement by affine Lucas-Kanade against the reference view.
    window_radius : int
        Half-size of the refinement window (pixels).
    min_ncc : float
        Minimum normalised cross-correlation of a refined observation with its template.
    final_threshold_px : float
        Epipolar distance after refinement above which an observation is dropped.
    smooth_px : float
        A match whose displacement differs by more than this from the one its
        neighbours' depths predict is dropped (catches repeated-texture mismatches).
    min_views : int
        Minimum number of views per track.
    min_tracks : int
        Fewer final tracks raise :class:`DegenerateError`.
    max_tracks : int or None
        Keep at most this many tracks per session (the best spread over the image).
    progress : None, True or callable
        Called with a :class:`~transcalib.types.ProgressEvent` per step of each stage
        (``done`` of ``total``; every bar reaches its total); ``True`` prints to stderr.
    rng : seed or Generator
        For RANSAC.

    Returns
    -------
    Tracks
        ``uv (n_views, n_points, 2)`` over all views; ``info`` a :class:`TrackInfo`.

    Raises
    ------
    InputError
        Fewer than 2 images, unreadable files, images of different sizes, bad options.
    RotatedViewsError
        The views of a session are not pure translations of each other (a
        :class:`DegenerateError` naming the view pairs).
    DegenerateError
        Too few tracks survive: the message says what to change.
    """
    if target is not None:
        if target != "squares":
            raise InputError(f"track: target must be None or 'squares', got {target!r}")
        from .target import track_squares
        return track_squares(images, progress=progress)
    if method not in ("auto", "sift", "corners"):
        raise InputError(f"track: method must be 'auto', 'sift' or 'corners', got {method!r}")
    if min_views < 2:
        raise InputError(f"track: min_views must be >= 2, got {min_views}")
    n_images = len(images) if hasattr(images, "__len__") and not isinstance(images, str) else None
    T = _check_T(T, n_images)
    groups, labels = _groups(rotations, sessions, n_images, session_tolerance_deg)
    _load_stages(general=groups is not None and max(len(g) for g in groups) < 2)
    opts = dict(ratio=ratio, threshold_px=threshold_px, final_threshold_px=final_threshold_px, smooth_px=smooth_px,
                refine=refine, session_tolerance_deg=session_tolerance_deg, window_radius=window_radius,
                min_ncc=min_ncc, max_seeds=2000 if max_tracks is None else int(1.3 * max_tracks))
    detect = DetectOptions(max_features=max_features, max_corners=max_corners, corner_quality=corner_quality)
    run = dict(T=T, rotations=rotations, groups=groups, labels=labels, method=method, opts=opts, detect=detect, min_views=min_views,
               min_tracks=min_tracks, max_tracks=max_tracks, progress=progress, rng=rng)
    if method != "auto" or (groups is not None and len(groups) > 1):
        return _track_features(images, **run)
    try:  # auto: features; a scene that is only a board of dark squares -> the target mode
        tracks, failure = _track_features(images, **run), None
    except DegenerateError as exc:
        from .rotation import RotatedViewsError
        if isinstance(exc, RotatedViewsError):
            raise  # the target mode would track the corners, but the views are not pure translations
        tracks, failure = None, exc
    n_features = 0 if tracks is None else _n_long(tracks.uv)
    if n_features < AUTO_MIN_LONG_TRACKS:
        from .target import track_squares
        try:
            squares = track_squares(images, progress=progress)
        except DegenerateError:
            squares = None
        if squares is not None and _n_long(squares.uv) > n_features:
            return replace(squares, info=replace(squares.info, method="squares (auto: too few feature tracks)"))
    if failure is not None:
        raise failure
    return tracks


def _load_stages(general: bool) -> None:
    """Import the :data:`_STAGES` of sessions or of ``general`` motion on a daemon thread
    (a failed import is left for the main thread's own import to report)."""
    def work():
        for name in _STAGES[general]:
            try:
                importlib.import_module(f".{name}", __package__)
            except Exception:  # noqa: BLE001 - reported where the stage is imported
                return

    threading.Thread(target=work, name="tracker stages", daemon=True).start()


def _session_options(*, ratio, threshold_px, final_threshold_px, smooth_px, refine, session_tolerance_deg,
                     window_radius, min_ncc, max_seeds):
    """The :class:`~.session.SessionOptions` of :func:`track`'s arguments."""
    from .propagate import PropagateOptions
    from .refine import RefineOptions
    from .session import SessionOptions

    return SessionOptions(ratio=ratio, threshold_px=threshold_px, final_threshold_px=final_threshold_px,
                          smooth_px=smooth_px, refine=refine, session_tolerance_deg=session_tolerance_deg,
                          propagate=PropagateOptions(threshold_px=threshold_px, max_seeds=max_seeds),
                          refinement=RefineOptions(window_radius=window_radius, min_ncc=min_ncc))


def _track_features(images, *, T, rotations, groups, labels, method, opts, detect, min_views, min_tracks, max_tracks, progress,
                    rng) -> Tracks:
    """Feature tracking of every group, then the links between groups (``opts``: the
    arguments of :func:`_session_options`, built once the images are detected)."""
    report = progress_fn(progress)
    t0 = time.perf_counter()
    grey, rgb, names = load_images(images)
    if groups is None:
        groups, labels = [list(range(len(grey)))], ["0"]
    if max(len(g) for g in groups) < 2:  # every view at its own orientation: general motion
        return _track_general(grey, rgb, names, groups, labels, _session_options(**opts), detect, min_views,
                              min_tracks, max_tracks, report, {"load": time.perf_counter() - t0})
    times = {"load": time.perf_counter() - t0}
    t0 = time.perf_counter()
    if method == "sift":
        detect = replace(detect, max_corners=0)
    feats = detect_all(grey, detect, report)
    if method == "sift":
        feats = [replace(f, corners=f.keypoints) for f in feats]
    times["detect"] = time.perf_counter() - t0
    rng = np.random.default_rng(rng)  # after the detection: numpy.random is imported by then, beside it
    from .checks import keep_tracks
    from .link import link_groups
    from .session import track_session
    opts = _session_options(**opts)
    shape = grey[0].shape[:2]
    per, epis, derots, info_pairs, counts, n_static, flags, rot = [], [], [], [], {}, 0, ([], [], []), []
    for g, views in enumerate(groups):
        if len(views) < 2:
            per.append(None)
            epis.append(None)
            derots.append(None)
            continue
        res = track_session([grey[v] for v in views], [feats[v] for v in views], opts, rng,
                            _prefixed(report, labels[g], len(groups)), T=None if T is None else T[views],
                            names=[names[v] for v in views])
        uv = keep_tracks(res.uv, min_views, max_tracks, shape)
        per.append(uv)
        epis.append(res.epipoles)
        derots.append(res.derotation)
        rot.append(res.rotation)
        _merge_times(times, res.time_s)
        for k, v in res.counts.items():
            counts[k] = counts.get(k, 0) + v
        n_static += res.n_static_dropped
        info_pairs += _pair_infos(res, views)
        for lst, src in zip(flags, (res.inconsistent, res.repaired, res.set_by_translations)):
            lst += [(views[a], views[b]) for a, b in src]
    t0 = time.perf_counter()
    uv, links = link_groups(grey, feats, groups, labels, per, epis, opts, rng, report, T=T,
                            rotations=None if rotations is None else np.asarray(rotations, float), derotations=derots)
    times["link"] = time.perf_counter() - t0
    uv = uv[:, np.isfinite(uv[..., 0]).sum(0) >= min_views]
    if uv.shape[1] < min_tracks:
        raise DegenerateError(_too_few_msg(uv.shape[1], info_pairs, min_tracks))
    group_info = tuple(_group_info(labels[g], views, per[g], derots[g]) for g, views in enumerate(groups))
    in_groups = np.array([np.isfinite(uv[views, :, 0]).any(axis=0) for views in groups])
    info = TrackInfo(method="features", time_s=times, pairs=tuple(info_pairs), n_observations=counts,
                     n_static_dropped=n_static, inconsistent_pairs=tuple(flags[0]), repaired_pairs=tuple(flags[1]),
                     pairs_set_by_translations=tuple(flags[2]), groups=group_info, links=tuple(links),
                     n_shared_points=int((in_groups.sum(0) >= 2).sum()), rotation_tests=tuple(rot))
    return Tracks(uv=uv, ids=np.arange(uv.shape[1]), colors=_colors(rgb, uv), view_names=names, info=info)


def _track_general(grey, rgb, names, groups, labels, opts, detect, min_views, min_tracks, max_tracks, report,
                   times) -> Tracks:
    """Every view at its own orientation: SIFT keypoints matched in every pair, joined into
    tracks and aligned by affine LK (:func:`.multiview.track_general`)."""
    from .multiview import GeneralOptions, track_general
    t0 = time.perf_counter()
    feats = detect_all(grey, replace(detect, max_corners=0), report)
    times["detect"] = time.perf_counter() - t0
    gopts = GeneralOptions(ratio=opts.ratio, threshold_px=opts.threshold_px,
                           final_threshold_px=opts.final_threshold_px, window_radius=opts.refinement.window_radius,
                           min_ncc=opts.refinement.min_ncc, max_shift_px=opts.refinement.max_shift_px)
    res = track_general(grey, feats, gopts, min_views, max_tracks, report)
    _merge_times(times, res.time_s)
    uv = res.uv
    if uv.shape[1] < min_tracks:
        raise DegenerateError(_too_few_msg(uv.shape[1], res.pairs, min_tracks).replace(
            "(translations of a few percent of the scene distance)", "(turns of at most 30-45 deg between views)"))
    group_info = tuple(GroupInfo(label=str(labels[g]), views=tuple(int(v) for v in views), n_tracks=0)
                       for g, views in enumerate(groups))
    info = TrackInfo(method="features (general motion)", time_s=times, pairs=res.pairs,
                     n_observations=res.counts, n_static_dropped=res.n_static_dropped, groups=group_info,
                     n_shared_points=int((np.isfinite(uv[..., 0]).sum(0) >= 2).sum()))
    return Tracks(uv=uv, ids=np.arange(uv.shape[1]), colors=_colors(rgb, uv), view_names=names, info=info)


def _group_info(label, views, uv, derot) -> GroupInfo:
    """The :class:`GroupInfo` of one group, with its views' estimated rotations (degrees)."""
    est = derot is not None and derot.estimated
    return GroupInfo(label=str(label), views=tuple(int(v) for v in views), n_tracks=0 if uv is None else int(uv.shape[1]),
                     rotations_deg=tuple(tuple(float(c) for c in np.degrees(w)) for w in derot.omega) if est else (),
                     sigma_px=derot.sigma_px if est else float("nan"))


def _prefixed(report, label, n_groups):
    """Progress of one session: stages prefixed with the session's label when there are several."""
    if n_groups == 1:
        return report
    return lambda stage, done, total: report(f"{stage} ({label})", done, total)


def _merge_times(times, add):
    for k, v in add.items():
        times[k] = times.get(k, 0.0) + v


def _pair_infos(res, views) -> list[PairInfo]:
    out = []
    for (i, j), g in res.geometry.items():
        e = res.epipoles.get((i, j))
        out.append(PairInfo(views=(int(views[i]), int(views[j])), n_matches=int(res.n_matches[(i, j)]),
                            n_verified=g.n_inliers if g.e is not None else 0, source=g.source,
                            epipole=None if e is None else tuple(float(c) for c in e)))
    return out


def _too_few_msg(n_pts, pairs, min_tracks=8):
    per_pair = ", ".join(f"{p.views[0]}-{p.views[1]}: {p.n_verified}" for p in pairs)
    return (f"tracking found only {n_pts} usable tracks (need >= {min_tracks}); verified matches per view pair: "
            f"{per_pair or 'none'}. Use images of a well-textured scene (not blank walls), keep a large overlap "
            "between views (translations of a few percent of the scene distance), avoid motion blur, or pass "
            "target='squares' for a board of black squares")


def _n_long(uv: np.ndarray) -> int:
    """Number of tracks seen in at least 3 views."""
    return int((np.isfinite(uv[..., 0]).sum(axis=0) >= 3).sum())


def _check_T(T, n):
    """``T`` as ``(n_views, 3)`` float, or None; :class:`InputError` if malformed."""
    if T is None:
        return None
    T = np.asarray(T, float)
    if T.ndim != 2 or T.shape[1] != 3 or (n is not None and len(T) != n) or not np.all(np.isfinite(T)):
        raise InputError(f"track: T must be finite (n_views, 3) = ({n}, 3) robot translations, got shape {T.shape}")
    return T


def _groups(rotations, sessions, n, tolerance_deg=SESSION_TOLERANCE_DEG):
    """The views of each orientation group and its label, or ``(None, None)`` for one
    session of every view."""
    if rotations is None and sessions is None:
        return None, None
    from ..handeye.sessions import group_sessions

    if rotations is not None:
        R = np.asarray(rotations, float)
        if R.ndim != 3 or R.shape[1:] != (3, 3) or (n is not None and len(R) != n) or not np.all(np.isfinite(R)):
            raise InputError(f"track: rotations must be finite (n_views, 3, 3) = ({n}, 3, 3) flange rotations, "
                             f"got shape {R.shape}")
    else:
        R = np.repeat(np.eye(3)[None], len(sessions), axis=0)
    if sessions is not None and n is not None and len(sessions) != n:
        raise InputError(f"track: sessions has {len(sessions)} labels for {n} views; give one label per view")
    grouping = group_sessions(R, tolerance_deg, session=sessions)
    groups = [np.flatnonzero(grouping.session_of_view == s).tolist() for s in range(grouping.n_sessions)]
    return groups, [str(x) for x in grouping.labels]


def _colors(rgb, uv):
    if any(c is None for c in rgb) or uv.shape[1] == 0:
        return None
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    p = uv[ref, np.arange(uv.shape[1])]
    h, w = rgb[0].shape[:2]
    x = np.clip(np.rint(p[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.rint(p[:, 1]).astype(int), 0, h - 1)
    return np.stack(rgb)[ref, y, x].astype(np.uint8)
