"""Robust estimation: the two-point minimal solver (:mod:`.minimal`) inside an LO-RANSAC
loop, hypotheses scored by :mod:`.scoring`, with no noise knob to turn.

The pixel noise is unknown, so hypotheses are first ranked by the **median** of their
normalised track errors ``e_j^2 / median(chi2(2 k_j - 3))`` (least median of squares:
no threshold needed, correct up to 50 % of bad tracks). For each new best hypothesis
the noise ``sigma`` is estimated from its track errors (:func:`.scoring.truncated_sigma`),
its inliers follow from the chi-square rule with false-rejection rate ``alpha``
(:func:`.scoring.inlier_rule`), and local optimisation refits ``A`` on them while the
median drops. The number of trials adapts: ``log(1 - confidence) / log(1 - p)`` with
``p`` the probability of drawing two inliers at the best inlier ratio so far. A user
threshold (``RansacOptions.threshold_px``) replaces the estimated ``sigma`` by
``threshold_px / sqrt(chi2_2(1 - alpha))`` and ranks hypotheses by the MSAC cost
``sum_j min(e_j^2, sigma^2 q_j)`` instead.

Problems with more than ``SCORE_POINTS`` points draw and score hypotheses on a random
subset of that many points; every track is then classified. The final model is the
linear TLS (depth-weighted, :func:`.linear.fit_linear`) on the inliers, with ``sigma`` and the inliers re-estimated from it until
they settle.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from ..errors import DegenerateError, MirroredError
from ..types import LinearEstimate, RansacOptions
from ..validate import SPAN_RTOL, as_uv_T, check_translations_span
from ..geometry.rotation import rq_decompose
from ..geometry.triangulate import triangulate
from .distributions import chi2_ppf
from .linear import fit_linear
from .minimal import forms, forms_sum, normalise, null_vectors, solve_minimal, to_pixels
from .scoring import Scorer, inlier_rule, median_sigma, point_errors, sigma_from_threshold, truncated_sigma

__all__ = ["RobustEstimate", "estimate_robust", "fit_robust", "solve_minimal", "point_errors"]

#: Points on which hypotheses are scored (a random subset of larger problems).
SCORE_POINTS = 4096
#: Fewest inliers (sampled pair included) that count as a consensus.
MIN_CONSENSUS = 4
#: The inliers have settled when at most this fraction of them change between refits (none
#: for fewer than 1000 tracks; in large problems borderline tracks trading places do not
#: count).
SETTLED_FRACTION = 0.001


@dataclass(frozen=True, eq=False)
class RobustEstimate:
    """Result of :func:`estimate_robust`.

    Attributes
    ----------
    linear : LinearEstimate
        The linear estimate (:func:`.linear.fit_linear`) refitted on the inliers (``linear.used == inliers``;
        ``linear.X`` is NaN for outliers).
    inliers : (n_points,) bool
        Tracks whose error passes the chi-square rule under the final ``linear.A``.
    sse_px2 : (n_points,) float
        Track errors: sum of squared reprojection errors (pixels^2) over the views that
        see the track, triangulated from all its views with the final ``A``; ``inf``
        behind the camera, NaN if seen in fewer than 2 views.
    residuals_px : (n_views, n_points, 2) float
        Observed minus predicted pixels for every observation under the final ``A``
        (outliers included); NaN where unseen.
    sigma_px : float
        Pixel noise per coordinate estimated from the inliers (also when a threshold
        was given: compare the two).
    rule_sigma_px : float
        The sigma of the inlier rule: ``sigma_px``, or the one ``threshold_px`` implies.
    trials : int
        Minimal-sample hypotheses drawn.
    inlier_ratio : float
        ``inliers.sum() / n_points``.
    options : RansacOptions
    info : dict
        ``trials_needed``, ``lo_steps``, ``refits``, ``time_s``, ``n_candidates``
        (points eligible for sampling), ``n_scored`` (points hypotheses were scored on).
    """

    linear: LinearEstimate
    inliers: np.ndarray
    sse_px2: np.ndarray
    residuals_px: np.ndarray
    sigma_px: float
    rule_sigma_px: float
    trials: int
    inlier_ratio: float
    options: RansacOptions
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
        good[k] = s[0] > 0 and s[2] > SPAN_RTOL * s[0]
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
    """Calibrate linearly despite gross outliers: two-point LO-RANSAC, then a TLS refit.

    Parameters
    ----------
    uv : array_like (n_views, n_points, 2)
        Pixels (OpenCV convention), NaN where a point is not seen.
    T : array_like (n_views, 3)
        Robot translations spanning 3-D (``n_views >= 4``).
    options : RansacOptions, optional
        False-rejection rate, confidence, maximum trials, and an optional fixed threshold.
    rng : seed or numpy Generator
        Randomness of the sampling.
    progress : callable, optional
        Called after every batch of hypotheses with a dict
        ``{trials, trials_needed, best_inliers}``.

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
    search = _Search(uv, T, opts, rng)
    search.run(progress)
    lin, sse, res, sigma, rule_sigma, refits = _final_refit(uv, T, search, opts)
    return RobustEstimate(
        linear=lin, inliers=lin.used.copy(), sse_px2=sse, residuals_px=res, sigma_px=sigma, rule_sigma_px=rule_sigma,
        trials=int(search.trials), inlier_ratio=float(lin.used.sum() / uv.shape[1]), options=opts,
        info={"trials_needed": float(search.needed), "lo_steps": search.lo_steps, "refits": refits,
              "n_candidates": int(len(search.pool)), "n_scored": int(len(search.subset)),
              "time_s": time.perf_counter() - t0})


class _Search:
    """The LO-RANSAC loop on a scored subset of the points: the best hypothesis so far
    (``a``, its track errors ``sse``, ranking ``score``, noise ``sigma``, inliers
    ``n_in``), trials and LO steps."""

    def __init__(self, uv, T, opts: RansacOptions, rng):
        self.T, self.opts, self.rng = T, opts, rng
        n_points = uv.shape[1]
        pb_all = normalise(uv, T)
        # hypotheses are drawn and scored on a random subset of at most SCORE_POINTS points;
        # the final classification and refit use every point
        scorable = np.flatnonzero(pb_all.seen.sum(axis=1) >= 2)
        self.subset = (np.sort(rng.choice(scorable, SCORE_POINTS, replace=False)) if len(scorable) > SCORE_POINTS
                       else np.arange(n_points))
        self.pb = replace(pb_all, x=pb_all.x[self.subset], seen=pb_all.seen[self.subset])
        self.scorer = Scorer(self.pb)
        self.k = self.pb.seen.sum(axis=1)
        self.pool = np.flatnonzero((self.k >= 3) & self.scorer.ok)
        if len(self.pool) < 2:
            raise DegenerateError(
                f"robust estimation needs points seen in at least 3 views (pairs together in 8, e.g. two points "
                f"in 4 views); only {len(self.pool)} such point(s) among {n_points}. Track the points through "
                "more views.")
        ok = self.scorer.ok
        self.median_chi2 = np.where(ok, chi2_ppf(0.5, np.maximum(2 * self.k - 3, 1)), 1.0)
        self.fixed_sigma = (None if opts.threshold_px is None
                            else sigma_from_threshold(opts.threshold_px, opts.false_rejection))
        self.score, self.a, self.sse, self.sigma, self.n_in = np.inf, None, None, np.nan, 0
        self.trials = self.lo_steps = 0
        self.needed = math.inf

    def _rank(self, sse: np.ndarray) -> np.ndarray:
        """Score of hypotheses (H,) from their track errors (H, n): lower is better."""
        ok = self.scorer.ok
        if self.fixed_sigma is None:  # least median of normalised squares
            return np.median(sse[:, ok] / self.median_chi2[ok], axis=1)
        q = self.fixed_sigma**2 * chi2_ppf(1.0 - self.opts.false_rejection, np.maximum(2 * self.k - 3, 1))
        return np.sum(np.minimum(np.nan_to_num(sse[:, ok], nan=0.0), q[ok]), axis=1)  # MSAC

    def consider(self, a: np.ndarray) -> bool:
        """Score hypotheses ``a (H, 9)``; keep the best; True if it improved."""
        sse = self.scorer.sse(a.reshape(-1, 3, 3))
        score = self._rank(sse)
        h = int(np.argmin(score))
        if not score[h] < self.score:
            return False
        self.score, self.a, self.sse = float(score[h]), a[h], sse[h]
        self.sigma = self.fixed_sigma or truncated_sigma(sse[h], self.k, median_sigma(sse[h], self.k),
                                                         self.opts.false_rejection)
        self.n_in = int(self.inliers().sum())
        return True

    def inliers(self) -> np.ndarray:
        return inlier_rule(self.sse, self.k, self.sigma, self.opts.false_rejection)

    def local_optimisation(self) -> None:
        """Refit on the inliers of the best hypothesis while that improves its score."""
        for _ in range(5):
            inl = np.flatnonzero(self.inliers())
            if len(inl) < 2:
                return
            a, ok = null_vectors(forms_sum(self.pb, inl)[None])
            self.lo_steps += 1
            if not ok[0] or not self.consider(a):
                return

    def run(self, progress) -> None:
        """Draw batches of pairs until the adaptive number of trials is reached."""
        batch, opts = 16, self.opts
        while self.trials < min(self.needed, opts.max_trials):
            left = max(1, math.ceil(self.needed - self.trials)) if math.isfinite(self.needed) else batch
            B = int(min(batch, opts.max_trials - self.trials, left))
            pairs = _draw_pairs(self.rng, self.pool, self.k, self.pb.seen, self.T, B)
            self.trials += B
            if len(pairs):
                a, ok = null_vectors(forms(self.pb, pairs.ravel()).reshape(-1, 2, 9, 9).sum(axis=1))
                if ok.any() and self.consider(a[ok]):
                    self.local_optimisation()
                    n_in_pool = int(self.inliers()[self.pool].sum())
                    self.needed = _trials_needed(n_in_pool, len(self.pool), opts.confidence)
            batch = min(2 * batch, 256)
            if progress is not None:
                progress({"trials": self.trials, "trials_needed": self.needed, "best_inliers": self.n_in})
        if self.a is None or self.n_in < MIN_CONSENSUS:
            raise DegenerateError(
                f"no consensus: after {self.trials} hypotheses the best one agrees with only {self.n_in} track(s) "
                f"(at least {MIN_CONSENSUS} needed). The tracks are mostly wrong, or the motion was not a pure "
                "translation (the robot rotated).")


def _final_refit(uv, T, search: _Search, opts: RansacOptions):
    """The linear TLS on the inliers, with sigma and the inliers (all tracks) re-estimated
    until they settle: ``(linear, sse, residuals, sigma, rule_sigma, refits)``. Where the
    TLS on the inliers explains them worse than the best hypothesis (a few bad tracks left
    among them can even mirror it), the hypothesis is kept."""
    k = np.isfinite(uv[..., 0]).sum(axis=0)
    A_best = to_pixels(search.pb, search.a)[0]
    sse = search.sse if len(search.subset) == uv.shape[1] else point_errors(A_best, uv, T)[0]
    sigma = search.sigma if search.fixed_sigma is None else truncated_sigma(
        sse, k, median_sigma(sse, k), opts.false_rejection)
    rule_sigma = search.fixed_sigma or sigma
    inliers = inlier_rule(sse, k, rule_sigma, opts.false_rejection)
    refits = 0
    for _ in range(5):
        masked = np.where(inliers[None, :, None], uv, np.nan)
        lin, sse, res = _best_linear(masked, uv, T, A_best if refits == 0 else None, inliers)
        refits += 1
        sigma = truncated_sigma(sse, k, sigma, opts.false_rejection)
        rule_sigma = search.fixed_sigma or sigma
        new = inlier_rule(sse, k, rule_sigma, opts.false_rejection)
        # settled; in large problems a few borderline tracks trading places do not count
        if np.sum(new != inliers) <= SETTLED_FRACTION * inliers.sum() or new.sum() < MIN_CONSENSUS:
            break
        inliers = new
    return lin, sse, res, sigma, rule_sigma, refits


def _best_linear(masked, uv, T, A_hyp, inliers):
    """The TLS on the inliers ``masked``, or the hypothesis ``A_hyp`` triangulated, whichever
    explains the inliers better: ``(linear, sse of every track, residuals)``. Without a
    hypothesis the TLS is taken unless it is mirrored."""
    try:
        lin = fit_linear(masked, T)
    except MirroredError:
        if A_hyp is None:
            raise
        lin = None
    except DegenerateError as exc:
        raise DegenerateError(f"the {int(inliers.sum())} inliers found do not determine the camera: {exc}") from exc
    if lin is not None:
        sse, res = point_errors(lin.A, uv, T)
        if A_hyp is None:
            return lin, sse, res
    hyp_sse, hyp_res = point_errors(A_hyp, uv, T)
    if lin is not None and np.nansum(np.where(inliers, sse, 0.0)) <= np.nansum(np.where(inliers, hyp_sse, 0.0)):
        return lin, sse, res
    return _from_hypothesis(A_hyp, masked, T), hyp_sse, hyp_res


def _from_hypothesis(A: np.ndarray, masked: np.ndarray, T: np.ndarray) -> LinearEstimate:
    """A :class:`LinearEstimate` from a hypothesis ``A`` (its sign putting most points in
    front): K and R by RQ (raises :class:`MirroredError` if ``det A < 0``), the points
    triangulated."""
    A = A / np.linalg.norm(A[2])
    X = triangulate(A, masked, T)
    z = np.einsum("a,vna->vn", A[2], X[None] - T[:, None])
    if np.nanmedian(z[np.isfinite(masked[..., 0])]) < 0:
        A, z = -A, -z
    K, R = rq_decompose(A)
    used = np.isfinite(masked[..., 0]).sum(axis=0) >= 2
    depth = np.where(np.isfinite(masked[..., 0]), z, np.nan)
    return LinearEstimate(K=K, R=R, A=K @ R, X=X, depth=depth, singular_values=np.full(3, np.nan),
                          n_used_points=int(used.sum()), used=used, method="hypothesis")
