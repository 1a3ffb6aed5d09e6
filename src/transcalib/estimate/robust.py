"""Robust estimation: the two-point minimal solver (:mod:`.minimal`) inside an MSAC /
LO-RANSAC loop, hypotheses scored by :mod:`.scoring`.

Loop: adaptive number of trials ``log(1 - confidence) / log(1 - p)`` (``p`` the
probability of drawing two inliers at the best inlier ratio so far); each new best
hypothesis is refined by local optimisation (refit on its inliers, rescore, repeat while
the cost drops). Problems with more than ``SCORE_POINTS`` points draw and score the
hypotheses on a random subset of that many points (the ranking of hypotheses needs no
more); every point is then classified with the best hypothesis. The final model is
:func:`transcalib.estimate_linear` on the inliers, with the inliers reclassified from it
(weighted triangulation, all points) until they settle.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ..errors import DegenerateError, MirroredError
from ..types import LinearEstimate, RansacOptions
from ..validate import as_uv_T, check_translations_span
from .linear import fit_linear
from .minimal import forms, forms_sum, normalise, null_vectors, solve_minimal, to_pixels
from .scoring import Scorer, msac_cost, point_errors

__all__ = ["RobustEstimate", "estimate_robust", "fit_robust", "solve_minimal", "point_errors"]

#: Points on which hypotheses are scored (a random subset of larger problems).
SCORE_POINTS = 4096
#: Fewest inliers (sampled pair included) that count as a consensus.
MIN_CONSENSUS = 4
#: Relative singular value below which a set of translations counts as not spanning 3-D.
_SPAN_TOL = 1e-6


@dataclass(frozen=True, eq=False)
class RobustEstimate:
    """Result of :func:`estimate_robust`.

    Attributes
    ----------
    linear : LinearEstimate
        The paper's linear estimate refitted on the inliers (``linear.used == inliers``;
        ``linear.X`` is NaN for outliers).
    inliers : (n_points,) bool
        Points whose reprojection error is below ``threshold_px`` in **every** view that
        sees them, under the final ``linear.A``.
    error_px : (n_points,) float
        Per-point score: the largest reprojection error (pixels) over the views that see
        the point, each point triangulated from all its views with the final ``A``;
        ``inf`` if it falls behind the camera, NaN if it is seen in fewer than 2 views.
    residuals_px : (n_views, n_points, 2) float
        Observed minus predicted pixels for every observation under the final ``A``
        (outliers included); NaN where unseen.
    trials : int
        Minimal-sample hypotheses drawn.
    inlier_ratio : float
        ``inliers.sum() / n_points``.
    threshold_px : float
        The inlier threshold used.
    cost : float
        MSAC cost ``sum_j min(error_px_j^2, threshold_px^2)`` of the final model (px^2).
    info : dict
        ``trials_needed``, ``lo_steps``, ``refits``, ``time_s``, ``n_candidates``
        (points eligible for sampling), ``n_scored`` (points hypotheses were scored on).
    """

    linear: LinearEstimate
    inliers: np.ndarray
    error_px: np.ndarray
    residuals_px: np.ndarray
    trials: int
    inlier_ratio: float
    threshold_px: float
    cost: float
    info: dict

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


# ----------------------------------------------------------------------------------------
# Sampling
# ----------------------------------------------------------------------------------------


def _spans(T: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """For boolean view masks (m, V): do the translations of those views span 3-D?"""
    uniq, inv = np.unique(masks, axis=0, return_inverse=True)
    good = np.zeros(len(uniq), bool)
    for k, m in enumerate(uniq):  # one per distinct visibility pattern (few)
        if m.sum() < 4:
            continue
        t = T[m] - T[m][0]
        s = np.linalg.svd(t, compute_uv=False)
        good[k] = s[0] > 0 and s[2] > _SPAN_TOL * s[0]
    return good[np.ravel(inv)]


def _draw_pairs(rng, pool: np.ndarray, k_views: np.ndarray, seen: np.ndarray, T: np.ndarray, B: int):
    """``B`` random valid pairs of pool points (rejection sampling), as indices (B', 2).

    Valid: the two points are seen in ``k1 + k2 >= 8`` views in all (``2 k - 3``
    constraints each; a 4 + 3 split leaves a two-dimensional solution space) and the
    views seeing either of them have translations spanning 3-D."""
    m = len(pool)
    out = []
    got = 0
    for _ in range(20):
        i = rng.integers(m, size=2 * B)
        j = rng.integers(m - 1, size=2 * B)
        j += j >= i
        a, b = pool[i], pool[j]
        valid = k_views[a] + k_views[b] >= 8
        if valid.any():
            valid[valid] = _spans(T, seen[a[valid]] | seen[b[valid]])
        pairs = np.column_stack([a, b])[valid]
        out.append(pairs)
        got += len(pairs)
        if got >= B:
            break
    pairs = np.concatenate(out)[:B] if out else np.zeros((0, 2), int)
    return pairs


def _trials_needed(n_in: int, m: int, confidence: float) -> float:
    """``log(1 - confidence) / log(1 - p)``, ``p = n_in (n_in - 1) / (m (m - 1))``."""
    if m < 2 or n_in < 2:
        return math.inf
    p = min(1.0, n_in * (n_in - 1) / (m * (m - 1)))
    if p >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log1p(-p)


# ----------------------------------------------------------------------------------------
# The loop
# ----------------------------------------------------------------------------------------


def estimate_robust(uv, T, *, options: RansacOptions | None = None, rng=None, progress=None) -> RobustEstimate:
    """Calibrate linearly despite gross outliers: two-point LO-MSAC, then a TLS refit.

    Parameters
    ----------
    uv : array_like (n_views, n_points, 2)
        Pixels (OpenCV convention), NaN where a point is not seen.
    T : array_like (n_views, 3)
        Robot translations spanning 3-D (``n_views >= 4``).
    options : RansacOptions, optional
        Threshold (on a point's **largest** reprojection error over its views, the point
        triangulated from all its views with the hypothesised ``A``), confidence and the
        maximum number of trials.
    rng : seed or numpy Generator
        Randomness of the sampling.
    progress : callable, optional
        Called after every batch of hypotheses with a dict
        ``{trials, trials_needed, best_inliers, best_cost}``.

    Returns
    -------
    RobustEstimate

    Raises
    ------
    InputError
        Malformed input.
    DegenerateError
        No two points can be sampled (each needs 3+ views, together 8+ views whose
        translations span 3-D), or no consensus of at least ``MIN_CONSENSUS`` points.
    MirroredError
        The inliers imply a mirrored camera (left-handed robot frame, swapped axes).
    """
    uv, T = as_uv_T(uv, T)
    return fit_robust(uv, T, options or RansacOptions(), rng=rng, progress=progress)


def fit_robust(uv: np.ndarray, T: np.ndarray, opts: RansacOptions, *, rng=None, progress=None) -> RobustEstimate:
    """:func:`estimate_robust` on validated arrays and options (the pipeline's entry)."""
    t0 = time.perf_counter()
    check_translations_span(T)
    rng = np.random.default_rng(rng)
    search = _Search(uv, T, opts.threshold_px, rng)
    search.run(opts, progress)
    lin, err, res, refits = _final_refit(uv, T, search, opts.threshold_px)
    return RobustEstimate(
        linear=lin, inliers=lin.used.copy(), error_px=err, residuals_px=res, trials=int(search.trials),
        inlier_ratio=float(lin.used.sum() / uv.shape[1]), threshold_px=float(opts.threshold_px),
        cost=float(msac_cost(err[None], opts.threshold_px)[0]),
        info={"trials_needed": float(search.needed), "lo_steps": search.lo_steps, "refits": refits,
              "n_candidates": int(len(search.pool)), "n_scored": int(len(search.subset)),
              "time_s": time.perf_counter() - t0})


class _Search:
    """The LO-MSAC loop on a scored subset of the points: the best hypothesis so far
    (``a``, its per-point errors ``err``, ``cost``, ``n_in``), trials and LO steps."""

    def __init__(self, uv, T, thr: float, rng):
        self.uv, self.T, self.thr, self.rng = uv, T, float(thr), rng
        n_points = uv.shape[1]
        self.pb_all = normalise(uv, T)
        # hypotheses are drawn and scored on a random subset of at most SCORE_POINTS points;
        # the final classification and refit use every point
        scorable = np.flatnonzero(self.pb_all.seen.sum(axis=1) >= 2)
        self.subset = (np.sort(rng.choice(scorable, SCORE_POINTS, replace=False)) if len(scorable) > SCORE_POINTS
                       else np.arange(n_points))
        self.pb = replace(self.pb_all, x=self.pb_all.x[self.subset], seen=self.pb_all.seen[self.subset])
        self.scorer = Scorer(self.pb)
        self.k_views = self.pb.seen.sum(axis=1)
        self.pool = np.flatnonzero((self.k_views >= 3) & self.scorer.ok)
        if len(self.pool) < 2:
            raise DegenerateError(
                f"robust estimation needs points seen in at least 3 views (pairs together in 8, e.g. two points "
                f"in 4 views); only {len(self.pool)} such point(s) among {n_points}. Track the points through "
                "more views.")
        self.cost, self.a, self.err, self.n_in = np.inf, None, None, 0
        self.trials = self.lo_steps = 0
        self.needed = math.inf

    def consider(self, a: np.ndarray) -> bool:
        """Score hypotheses ``a (H, 9)``; keep the best; True if it improved."""
        err = self.scorer.errors(a.reshape(-1, 3, 3))
        cost = msac_cost(err, self.thr)
        k = int(np.argmin(cost))
        if cost[k] >= self.cost:
            return False
        self.cost, self.a, self.err, self.n_in = float(cost[k]), a[k], err[k], int(np.sum(err[k] < self.thr))
        return True

    def local_optimisation(self) -> None:
        """Refit on the inliers of the best hypothesis while that lowers the cost."""
        for _ in range(5):
            inl = np.flatnonzero(self.err < self.thr)
            if len(inl) < 2:
                return
            a, ok = null_vectors(forms_sum(self.pb, inl)[None])
            self.lo_steps += 1
            if not ok[0] or not self.consider(a):
                return

    def run(self, opts: RansacOptions, progress) -> None:
        """Draw batches of pairs until the adaptive number of trials is reached."""
        batch = 16
        while self.trials < min(self.needed, opts.max_trials):
            left = max(1, math.ceil(self.needed - self.trials)) if math.isfinite(self.needed) else batch
            B = int(min(batch, opts.max_trials - self.trials, left))
            pairs = _draw_pairs(self.rng, self.pool, self.k_views, self.pb.seen, self.T, B)
            self.trials += B
            if len(pairs):
                a, ok = null_vectors(forms(self.pb, pairs.ravel()).reshape(-1, 2, 9, 9).sum(axis=1))
                if ok.any() and self.consider(a[ok]):
                    self.local_optimisation()
                    n_in_pool = int(np.sum(self.err[self.pool] < self.thr))
                    self.needed = _trials_needed(n_in_pool, len(self.pool), opts.confidence)
            batch = min(2 * batch, 256)
            if progress is not None:
                progress({"trials": self.trials, "trials_needed": self.needed, "best_inliers": self.n_in,
                          "best_cost": self.cost})
        if self.a is None or self.n_in < MIN_CONSENSUS:
            raise DegenerateError(
                f"no consensus: after {self.trials} hypotheses the best one agrees with only {self.n_in} point(s) "
                f"within {self.thr:g} px (at least {MIN_CONSENSUS} needed). The tracks are mostly wrong, the "
                "threshold is too small for the pixel noise (try 3-4x the noise), or the motion was not a pure "
                "translation.")


def _final_refit(uv, T, search: _Search, thr: float):
    """The paper's TLS on the inliers, reclassified (all points) until the inliers settle:
    ``(linear, error_px, residuals_px, refits)``."""
    if len(search.subset) == uv.shape[1]:
        inliers = search.err < thr
    else:
        inliers = point_errors(to_pixels(search.pb, search.a)[0], uv, T)[0] < thr
    refits = 0
    for _ in range(4):
        masked = np.where(inliers[None, :, None], uv, np.nan)
        try:
            lin = fit_linear(masked, T)
        except MirroredError:
            raise
        except DegenerateError as exc:
            raise DegenerateError(f"the {int(inliers.sum())} inliers found do not determine the camera: {exc}") \
                from exc
        refits += 1
        err, res = point_errors(lin.A, uv, T)
        new = err < thr
        if np.array_equal(new, inliers) or new.sum() < MIN_CONSENSUS:
            break
        inliers = new
    return lin, err, res, refits
