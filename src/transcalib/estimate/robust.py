"""Robust estimation: the two-point minimal solver (:mod:`.minimal`) inside the generic
LO-RANSAC loop (:func:`.ransac.lo_ransac`), hypotheses scored by :mod:`.scoring`, with no
noise knob to turn.

The data are the tracks; a track seen in ``k`` views has an error ``e_j^2`` (px^2) with
``2 k - 3`` degrees of freedom (:func:`.noise.track_dof`). The pixel noise is unknown, so
the loop ranks hypotheses by the **median** of the normalised track errors (least median
of squares), estimates ``sigma`` for each new best (:func:`.noise.truncated_sigma`), takes
its inliers by the chi-square rule with false-rejection rate ``alpha``
(:func:`.noise.inlier_rule`) and refits ``A`` on them (local optimisation) while the median
drops; the number of trials adapts to the inlier ratio. A user threshold
(``RansacOptions.threshold_px``) fixes ``sigma = threshold_px / sqrt(chi2_2(1 - alpha))``
(:func:`.noise.sigma_from_threshold`) and the loop ranks by the MSAC cost instead.

Problems with more than ``SCORE_POINTS`` points draw and score hypotheses on a random
subset of that many points; every track is then classified. The final model is the
linear TLS (depth-weighted, :func:`.linear.fit_linear`) on the inliers, with ``sigma`` and
the inliers re-estimated from it until they settle.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..errors import DegenerateError, MirroredError
from ..types import LinearEstimate, RansacOptions, RansacStats
from ..validate import SPAN_RTOL, as_uv_T, check_translations_span
from ..geometry.rotation import rq_decompose
from ..geometry.triangulate import triangulate
from .linear import fit_linear
from .minimal import forms, forms_sum, normalise, null_vectors, to_pixels
from .noise import inlier_rule, median_sigma, sigma_from_threshold, track_dof, truncated_sigma
from .ransac import RansacResult, lo_ransac
from .scoring import Scorer, point_errors

__all__ = ["RobustEstimate", "estimate_robust", "fit_robust"]

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
    trials_needed : float
        The adaptive number of trials when the loop stopped
        (:func:`.ransac.trials_needed`).
    lo_steps : int
        Local-optimisation refits in the loop.
    refits : int
        Linear refits on the inliers after the loop.
    n_candidates : int
        Points eligible for sampling (seen in 3+ views, triangulable).
    n_scored : int
        Points hypotheses were scored on (at most ``SCORE_POINTS``).
    time_s : float
        Wall-clock time of the whole estimate (s).
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
    trials_needed: float
    lo_steps: int
    refits: int
    n_candidates: int
    n_scored: int
    time_s: float

    @property
    def stats(self) -> RansacStats:
        """The record a calibration keeps of this stage (:attr:`Calibration.stats.ransac`)."""
        return RansacStats(trials=self.trials, trials_needed=self.trials_needed, n_inliers=self.n_inliers,
                           sigma_px=self.sigma_px, rule_sigma_px=self.rule_sigma_px, time_s=self.time_s)

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


# ----------------------------------------------------------------------------------------
# The two-point problem
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


class _PairProblem:
    """The calibration as a :class:`.ransac.RansacProblem`: the tracks of a scored subset
    (``subset``, Hartley-normalised ``pb``), pairs of points seen in 3+ views as samples,
    ``a = vec(A)`` (normalised units) as hypotheses, track errors (px^2) as errors."""

    sample_size = 2

    def __init__(self, uv: np.ndarray, T: np.ndarray, rng: np.random.Generator):
        n_points = uv.shape[1]
        pb_all = normalise(uv, T)
        # hypotheses are drawn and scored on a random subset of at most SCORE_POINTS points;
        # the final classification and refit use every point
        scorable = np.flatnonzero(pb_all.seen.sum(axis=1) >= 2)
        self.subset = (np.sort(rng.choice(scorable, SCORE_POINTS, replace=False)) if len(scorable) > SCORE_POINTS
                       else np.arange(n_points))
        self.pb = replace(pb_all, x=pb_all.x[self.subset], seen=pb_all.seen[self.subset])
        self.scorer = Scorer(self.pb)
        self.T = T
        self.k = self.pb.seen.sum(axis=1)
        self.dof = track_dof(self.k)
        self.scorable = self.scorer.ok
        self.samplable = (self.k >= 3) & self.scorer.ok
        self.pool = np.flatnonzero(self.samplable)
        if len(self.pool) < 2:
            raise DegenerateError(
                f"robust estimation needs points seen in at least 3 views (pairs together in 8, e.g. two points "
                f"in 4 views); only {len(self.pool)} such point(s) among {n_points}. Track the points through "
                "more views.")

    def sample(self, rng, size: int) -> np.ndarray:
        return _draw_pairs(rng, self.pool, self.k, self.pb.seen, self.T, size)

    def solve(self, pairs: np.ndarray):
        return null_vectors(forms(self.pb, pairs.ravel()).reshape(-1, 2, 9, 9).sum(axis=1))

    def errors(self, a: np.ndarray) -> np.ndarray:
        return self.scorer.sse(a.reshape(-1, 3, 3))

    def refit(self, inliers: np.ndarray):
        return null_vectors(forms_sum(self.pb, np.flatnonzero(inliers))[None])


# ----------------------------------------------------------------------------------------
# The estimate
# ----------------------------------------------------------------------------------------


def estimate_robust(uv, T, *, options: RansacOptions | None = None, rng=0, progress=None) -> RobustEstimate:
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
        Randomness of the sampling; the default seed repeats the result for the same input.
    progress : callable, optional
        Called after every batch of hypotheses with a
        :class:`~transcalib.types.ProgressEvent` (stage ``"robust"``, ``done`` the
        hypotheses drawn so far; ``info`` ``trials_needed``, ``best_inliers``).

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
    problem = _PairProblem(uv, T, rng)
    fixed = None if opts.threshold_px is None else sigma_from_threshold(opts.threshold_px, opts.false_rejection)
    best = lo_ransac(problem, confidence=opts.confidence, max_trials=opts.max_trials,
                     false_rejection=opts.false_rejection, sigma=fixed, rng=rng, progress=progress, stage="robust")
    if best.hypothesis is None or best.n_inliers < MIN_CONSENSUS:
        raise DegenerateError(
            f"no consensus: after {best.trials} hypotheses the best one agrees with only {best.n_inliers} track(s) "
            f"(at least {MIN_CONSENSUS} needed). The tracks are mostly wrong, or the motion was not a pure "
            "translation (the robot rotated).")
    lin, sse, res, sigma, rule_sigma, refits = _final_refit(uv, T, problem, best, fixed, opts)
    return RobustEstimate(
        linear=lin, inliers=lin.used.copy(), sse_px2=sse, residuals_px=res, sigma_px=sigma, rule_sigma_px=rule_sigma,
        trials=int(best.trials), inlier_ratio=float(lin.used.sum() / uv.shape[1]), options=opts,
        trials_needed=float(best.trials_needed), lo_steps=int(best.lo_steps), refits=refits,
        n_candidates=int(len(problem.pool)), n_scored=int(len(problem.subset)), time_s=time.perf_counter() - t0)


def _final_refit(uv, T, problem: _PairProblem, best: RansacResult, fixed: float | None, opts: RansacOptions):
    """The linear TLS on the inliers, with sigma and the inliers (all tracks) re-estimated
    until they settle: ``(linear, sse, residuals, sigma, rule_sigma, refits)``. Where the
    TLS on the inliers explains them worse than the best hypothesis (a few bad tracks left
    among them can even mirror it), the hypothesis is kept. ``fixed``: the rule's sigma a
    user threshold implies."""
    k = np.isfinite(uv[..., 0]).sum(axis=0)
    dof = track_dof(k)
    A_best = to_pixels(problem.pb, best.hypothesis)[0]
    sse = best.errors if len(problem.subset) == uv.shape[1] else point_errors(A_best, uv, T)[0]
    sigma = best.sigma if fixed is None else truncated_sigma(sse, dof, median_sigma(sse, dof), opts.false_rejection)
    rule_sigma = fixed or sigma
    inliers = inlier_rule(sse, k, rule_sigma, opts.false_rejection)
    refits = 0
    for _ in range(5):
        masked = np.where(inliers[None, :, None], uv, np.nan)
        lin, sse, res = _best_linear(masked, uv, T, A_best if refits == 0 else None, inliers)
        refits += 1
        sigma = truncated_sigma(sse, dof, sigma, opts.false_rejection)
        rule_sigma = fixed or sigma
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
