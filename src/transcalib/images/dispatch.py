"""``track``: the one entry of the image front-end, choosing between feature tracking
(:mod:`.features`) and the target mode (:mod:`.target`) for images taken at pure
translations. A module of its own so that :mod:`.sessions` can call it without importing
the package that re-exports both (no import cycle).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import DegenerateError, InputError
from .features import RotatedViewsError, track_features
from .frames import Tracks
from .target import track_squares

__all__ = ["track"]


def track(
    images,
    *,
    method: str = "auto",
    T=None,
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
    """Track points across images taken at pure camera translations.

    Parameters
    ----------
    images : sequence of path or array, or array (n_views, h, w[, 3])
        The views, in order (the order of the robot poses). Arrays: grey or RGB.
    T : (n_views, 3) float, optional
        The robot translations, if known. Every epipole is then ``e_ij ~ A (T_j - T_i)``
        for one ``A = K R``: pairs whose epipole disagrees with the others' (a repetitive
        texture can make a wrong epipole win, consistently for all pairs of one view)
        get the predicted one (``info["pairs_set_by_translations"]``). Recommended.
    method : {"auto", "sift", "corners"}
        Features: ``"sift"`` descriptors only, ``"corners"`` Shi-Tomasi corners matched
        through the epipoles (epipoles still come from SIFT), ``"auto"`` both - and when
        fewer than ``AUTO_MIN_LONG_TRACKS`` tracks reach 3 views (a scene that is only a
        board of dark squares), the target mode if it tracks more.
    target : None or "squares"
        ``"squares"``: the paper's target mode instead of feature tracking - corners of
        dark squares on a light board (:func:`transcalib.target.track_squares`).
    max_features, max_corners : int
        Caps on SIFT keypoints and corners per image.
    corner_quality : float
        ``qualityLevel`` of ``cv2.goodFeaturesToTrack``.
    ratio : float
        Lowe's ratio-test threshold.
    threshold_px : float
        Epipolar distance for accepting a match before refinement.
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
        Keep at most this many tracks (the best spread over the reference image).
    progress : None, True or callable
        Called with a :class:`~transcalib.types.ProgressEvent` per step of each stage
        (``done`` of ``total``); ``True`` prints to stderr. Off by default.
    rng : seed or Generator
        For RANSAC.

    Returns
    -------
    Tracks

    Raises
    ------
    InputError
        Fewer than 2 images, unreadable files, images of different sizes, bad options.
    DegenerateError
        Too few tracks survive: the message says what to change.
    """
    if target is not None:
        if target != "squares":
            raise InputError(f"track: target must be None or 'squares', got {target!r}")
        return track_squares(images, progress=progress)
    if method not in ("auto", "sift", "corners"):
        raise InputError(f"track: method must be 'auto', 'sift' or 'corners', got {method!r}")
    if min_views < 2:
        raise InputError(f"track: min_views must be >= 2, got {min_views}")
    options = dict(method=method, max_features=max_features, max_corners=max_corners,
                   corner_quality=corner_quality, ratio=ratio, threshold_px=threshold_px, refine=refine,
                   window_radius=window_radius, min_ncc=min_ncc, final_threshold_px=final_threshold_px,
                   smooth_px=smooth_px, min_views=min_views, min_tracks=min_tracks, max_tracks=max_tracks,
                   progress=progress, rng=rng, T=_check_T(T, images))
    if method != "auto":
        return track_features(images, **options)
    # auto: features; a scene that is only a board of dark squares (too little texture)
    # falls back to the target mode when that tracks more points through 3+ views
    try:
        tracks, failure = track_features(images, **options), None
    except RotatedViewsError:
        raise  # the target mode would track the corners, but the views are not pure translations
    except DegenerateError as exc:
        tracks, failure = None, exc
    n_features = 0 if tracks is None else _n_long(tracks.uv)
    if n_features < AUTO_MIN_LONG_TRACKS:
        try:
            squares = track_squares(images, progress=progress)
        except DegenerateError:
            squares = None
        if squares is not None and _n_long(squares.uv) > n_features:
            return replace(squares, info={**squares.info, "method": "squares (auto: too few feature tracks)"})
    if failure is not None:
        raise failure
    return tracks


#: With fewer feature tracks seen in 3+ views, ``track(method="auto")`` tries the target mode.
AUTO_MIN_LONG_TRACKS = 30


def _n_long(uv: np.ndarray) -> int:
    """Number of tracks seen in at least 3 views."""
    return int((np.isfinite(uv[..., 0]).sum(axis=0) >= 3).sum())

def _check_T(T, images):
    """``T`` as ``(n_views, 3)`` float, or None; :class:`InputError` if malformed."""
    if T is None:
        return None
    T = np.asarray(T, float)
    n = len(images)
    if T.shape != (n, 3) or not np.all(np.isfinite(T)):
        raise InputError(f"track: T must be finite (n_views, 3) = ({n}, 3) robot translations, got shape {T.shape}")
    return T
