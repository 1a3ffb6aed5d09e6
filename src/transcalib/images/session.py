"""One session (views of one camera orientation, pure translations) from features to tracks.

The stages, each timed in :class:`~.frames.TrackInfo` ``time_s``:

1. **match** - SIFT descriptors of every view pair (:func:`~.detect.match_pair`);
2. **verify** - with the robot translations, the views' small rotations (the robot's
   orientation error) estimated and removed (:mod:`.derotate`: every later stage works on
   derotated "model" pixels, the tracks stay image pixels); the epipole of every pair and
   their consistency (:mod:`.epipoles`; with the translations, one ``A`` for all), and
   the rotation test (:mod:`.rotation`);
3. **chain** - every corner followed through the session along its epipolar lines
   (:mod:`.propagate`);
4. **refine** - every observation aligned to its reference view (:mod:`.refine`);
5. **checks** - depth smoothness, epipoles from the refined tracks, multi-view depth
   (:mod:`.checks`);
6. **extend** - each track searched again where its depth says the views it lacks see
   it (re-detection along the epipolar lines), aligned and checked like the others;
7. static tracks dropped, duplicates merged (:mod:`.checks`).
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..handeye.sessions import SESSION_TOLERANCE_DEG
from .checks import check_added, check_session, drop_static, n_observations
from .derotate import Derotation, RotationOptions, estimate_rotations
from .detect import Features, match_pair, n_threads
from .epipoles import fit_translations, verify_pairs
from .propagate import PropagateOptions, Pyramids, predict_missing, propagate
from .refine import RefineOptions, SmoothedImages, refine_to_reference
from .rotation import RotationTest, _explained, check_pure_translation, general_inliers

__all__ = ["SessionOptions", "SessionResult", "track_session", "verify_session"]


@dataclass(frozen=True)
class SessionOptions:
    """Options of :func:`track_session` (the ``track`` options that concern one session).

    Attributes
    ----------
    ratio : float
        Lowe's ratio of the descriptor matches.
    threshold_px : float
        Epipolar distance of a match before refinement.
    final_threshold_px : float
        Epipolar distance after refinement.
    smooth_px : float
        Largest disagreement (image px) of an observation's depth with its neighbours'.
    refine : bool
        Align the observations (sub-pixel Lucas-Kanade).
    extend : bool
        Search tracks again in the views they lack.
    session_tolerance_deg : float
        A view turned more than this from the session's median orientation is refused.
    derotate : bool
        With the robot translations, estimate and remove the views' small rotations.
    propagate : PropagateOptions
    refinement : RefineOptions
    rotations : RotationOptions
    """

    ratio: float = 0.8
    threshold_px: float = 1.5
    final_threshold_px: float = 0.5
    smooth_px: float = 2.5
    refine: bool = True
    extend: bool = True
    propagate: PropagateOptions = field(default_factory=PropagateOptions)
    refinement: RefineOptions = field(default_factory=RefineOptions)
    session_tolerance_deg: float = SESSION_TOLERANCE_DEG
    derotate: bool = True
    rotations: RotationOptions = field(default_factory=RotationOptions)


@dataclass(frozen=True, eq=False)
class SessionResult:
    """Tracks of one session and how they were found.

    Attributes
    ----------
    uv : (n_views, n_tracks, 2) float
    geometry : dict ``(i, j) -> PairGeometry``
        The verified pairs (session view indices), in model pixels.
    n_matches : dict ``(i, j) -> int``
        Descriptor matches of each pair.
    epipoles : dict ``(i, j) -> (3,) float``
        Epipoles re-estimated from the refined tracks, in model pixels.
    inconsistent, repaired, set_by_translations : list of (i, j)
    counts : dict str -> int
        Observations after each stage.
    n_static_dropped : int
    time_s : dict str -> float
    rotation : RotationTest
        The rotation test of the session's pairs (:mod:`.rotation`).
    derotation : Derotation
        Image <-> model pixels (the identity when the rotations were not estimated).
    """

    uv: np.ndarray
    geometry: dict
    n_matches: dict
    epipoles: dict
    inconsistent: list
    repaired: list
    set_by_translations: list
    counts: dict
    n_static_dropped: int
    time_s: dict
    rotation: RotationTest | None = None
    derotation: Derotation | None = None


class _Timer:
    """``with timer("stage"):`` adds the stage's wall time to ``times[stage]``."""

    def __init__(self):
        self.times = {}

    def __call__(self, stage):
        self._stage = stage
        return self

    def __enter__(self):
        self._t0 = time.perf_counter()

    def __exit__(self, *exc):
        self.times[self._stage] = self.times.get(self._stage, 0.0) + time.perf_counter() - self._t0


def _matches(feats: list[Features], ratio: float, report):
    """Descriptor matches of every pair ``i < j``: ``{(i, j): (x_i (m, 2), x_j (m, 2))}``,
    on :func:`~.detect.n_threads` threads (the matrix products release the GIL)."""
    n = len(feats)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    xy = {}
    with ThreadPoolExecutor(n_threads()) as pool:
        found = pool.map(lambda p: match_pair(feats[p[0]].descriptors, feats[p[1]].descriptors, ratio), pairs)
        for k, ((i, j), m) in enumerate(zip(pairs, found)):
            xy[(i, j)] = (feats[i].keypoints[m[:, 0]], feats[j].keypoints[m[:, 1]])
            report("match", k + 1, len(pairs))
    return xy


def track_session(grey: list, feats: list[Features], opts: SessionOptions, rng, report, T=None,
                  names=None) -> SessionResult:
    """Tracks of one pure-translation session (module docstring).

    Parameters
    ----------
    grey : list of (h, w) float32
        The session's views.
    feats : list of Features
        Their features.
    opts : SessionOptions
    rng : Generator
    report : callable ``(stage, done, total)``
    T : (n_views, 3) float, optional
        The session's robot translations.
    names : sequence of str, optional
        View names for messages.
    """
    timer = _Timer()
    shape = grey[0].shape[:2]
    with timer("match"):
        xy = _matches(feats, opts.ratio, report)
    with timer("verify"):
        xy_m, derot, geo, inconsistent, repaired, replaced, rotation = verify_session(xy, grey, opts, rng, report, T,
                                                                                      names)
    sources = {p: (xy_m[p][0][g.inliers], xy_m[p][1][g.inliers]) for p, g in geo.items()}
    pyr = Pyramids(grey, opts.propagate.window_px, opts.propagate.levels)
    with timer("chain"):
        uv = propagate(pyr, [f.corners for f in feats], geo, sources, opts.propagate, shape, report, derot)
    counts = {"chained": n_observations(uv)}
    epi = {p: g.e for p, g in geo.items() if g.e is not None}
    smoothed = SmoothedImages(grey)
    with timer("refine"):
        if opts.refine and uv.shape[1]:
            uv = refine_to_reference(smoothed, uv, np.argmax(np.isfinite(uv[..., 0]), axis=0), geo, opts.refinement,
                                     report)
    counts["refined"] = n_observations(uv)
    thr = opts.final_threshold_px if opts.refine else opts.threshold_px
    with timer("checks"):
        checked, epi_final = check_session(derot.uv_to_model(uv), epi, thr, opts.smooth_px, rng, counts)
        uv = np.where(np.isfinite(checked), uv, np.nan)
    if opts.extend and opts.refine and uv.shape[1]:
        with timer("extend"):
            uv = _extend(smoothed, uv, epi_final, opts, thr, counts, derot)
    uv, n_static = drop_static(uv)
    counts["static"] = n_observations(uv)
    return SessionResult(uv=uv, geometry=geo, n_matches={p: len(v[0]) for p, v in xy.items()}, epipoles=epi_final,
                         inconsistent=inconsistent, repaired=repaired, set_by_translations=replaced, counts=counts,
                         n_static_dropped=n_static, time_s=timer.times, rotation=rotation, derotation=derot)


def verify_session(xy: dict, grey: list, opts: SessionOptions, rng, report=None, T=None, names=None):
    """Stage 2 (module docstring): the derotation, every pair's epipole, the rotation test.

    Returns ``(xy_m, derotation, geo, inconsistent, repaired, set_by_translations,
    rotation_test)``, ``xy_m`` the matches in model pixels; raises
    :class:`~.rotation.RotatedViewsError` where :func:`track_session` would.
    """
    n, shape = len(grey), grey[0].shape[:2]
    general = general_inliers(xy, opts.threshold_px)
    derot = _derotation(xy, general, T, opts, shape, rng, n)
    xy_m = derot.pairs_to_model(xy)  # every stage below on model pixels
    geo, inconsistent, repaired = verify_pairs(xy_m, n, opts.threshold_px, rng, report)
    rotation = check_pure_translation(xy_m, n, opts.threshold_px, rng, names, grey, general, derot,
                                      opts.session_tolerance_deg)
    if np.max(derot.angles_deg()) > opts.session_tolerance_deg:
        # rotations beyond the tolerance that the images do not show (the test passed): a fit
        # to wrong matches (repetitive texture: 2.5 deg made them consistent), not the
        # robot's small errors; tracked without them
        derot, xy_m = Derotation.identity(n), xy
        geo, inconsistent, repaired = verify_pairs(xy_m, n, opts.threshold_px, rng, report)
    replaced = []
    if T is not None:
        geo, replaced = fit_translations(geo, xy_m, T, opts.threshold_px, float(max(shape)), rng)
    return xy_m, derot, geo, inconsistent, repaired, replaced, rotation


def _derotation(xy, general, T, opts: SessionOptions, shape, rng, n: int) -> Derotation:
    """The session's :class:`~.derotate.Derotation`: estimated with the robot translations
    (``opts.derotate``), else (or when they do not span 3-D) the identity."""
    est = None
    if T is not None and opts.derotate:
        est = estimate_rotations(xy, general, T, opts.threshold_px, shape, rng, opts.rotations)
    if est is None or not _explains_more(xy, general, est, opts.threshold_px, rng):
        return Derotation.identity(n)
    return est


def _explains_more(xy: dict, general: dict, derot: Derotation, threshold_px: float, rng) -> bool:
    """Whether the derotated matches are explained by pure translations (each pair's
    general-``F`` inliers within ``threshold_px`` of its own epipole's lines) at least as
    often as the matches themselves: the rotations are used only when they explain the
    images better than none (on flat scenes with few views, repetitive textures, a wrong
    start of ``A``, the fit can find rotations that the matches do not support)."""
    n_image = n_model = 0
    for p, S in general.items():
        x, y = xy[p][0][S], xy[p][1][S]
        n_image += _explained(x, y, threshold_px, rng) * len(x)
        n_model += _explained(derot.to_model(p[0], x), derot.to_model(p[1], y), threshold_px, rng) * len(x)
    return bool(np.isfinite(derot.sigma_px) and abs(derot.lens.lam) < 0.5 and n_model >= n_image)


def _extend(smoothed, uv, epi, opts: SessionOptions, thr, counts, derot: Derotation):
    """Stage 6: each track searched where its depth predicts it in the views it lacks
    (predicted and checked in model pixels, aligned in the images)."""
    margin = opts.refinement.window_radius + 2
    uv_m = derot.uv_to_model(uv)
    guess_m = predict_missing(uv_m, epi, smoothed.shape(), margin)
    new = np.isfinite(guess_m[..., 0])
    if not new.any():
        counts["extended"] = counts["multiview"]
        return uv
    trial = np.where(new[..., None], derot.uv_to_image(guess_m), uv)
    ref = np.argmax(np.isfinite(uv[..., 0]), axis=0)
    refined = refine_to_reference(smoothed, trial, ref, epi, opts.refinement, None, only=new)
    refined = np.where(new[..., None], refined, uv)
    checked = check_added(np.where(new[..., None], derot.uv_to_model(refined), uv_m), new, guess_m, epi, thr,
                          opts.smooth_px)
    out = np.where(np.isfinite(checked), refined, np.nan)
    counts["extended"] = n_observations(out)
    return out
