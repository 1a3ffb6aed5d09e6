"""A generic LO-RANSAC: sample, solve, score hooks; the loop owns ranking, noise, stopping.

The loop knows nothing about cameras (as PoseLib's ``ransac<Solver>`` or scikit-image's
``ransac(data, model_class)``). The caller describes its problem by a
:class:`RansacProblem`: which data may be sampled and which rank hypotheses, the degrees
of freedom ``nu_j`` of each datum's error, and four hooks:

- ``sample(rng, size)``: up to ``size`` minimal samples, ``(B, s)`` data indices;
- ``solve(samples)``: hypotheses ``(H, ...)`` and a validity mask ``(H,)`` (batched; a
  sample may give none, one or several hypotheses);
- ``errors(hypotheses)``: per-datum squared errors ``(H, n)`` (e.g. a track's sum of
  squared reprojection errors, px^2; inf: impossible, NaN: not scorable);
- ``refit(inliers)``: hypotheses ``(H, ...)`` and validity fitted to an inlier mask ``(n,)``
  (least squares; the local optimisation).

The loop, for batches of samples (16, doubling up to 256):

**Ranking.** With the noise unknown, least median of normalised errors
``median_j(e_j^2 / chi2_{nu_j}(0.5))`` over the scorable data (no threshold; right up to
half the data bad). With a known ``sigma``, the MSAC cost
``sum_j min(e_j^2, sigma^2 chi2_{nu_j}(1 - alpha))``.

**New best.** Its noise ``sigma`` (:func:`.noise.truncated_sigma` from
:func:`.noise.median_sigma`, unless known) and inliers (:func:`.noise.chi2_inliers`,
false-rejection rate ``alpha``); then **local optimisation**: ``refit`` on the inliers and
rescore, while the ranking improves (at most ``max_lo_steps``).

**Stopping.** After ``trials_needed = log(1 - confidence) / log(1 - p)`` samples, ``p``
the probability that a sample of ``s`` distinct data drawn from the ``m`` samplable ones
holds only inliers, ``p = prod_{i<s} (w m - i) / (m - i)`` (``~ w^s``; ``w`` the best
hypothesis' inlier ratio among the samplable data), or after ``max_trials`` samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..types import report
from .noise import chi2_inliers, chi2_quantiles, median_sigma, truncated_sigma

__all__ = ["RansacResult", "lo_ransac", "least_singular_vector"]

#: Samples of the first batch; each further batch doubles, up to :data:`MAX_BATCH`.
FIRST_BATCH = 16
#: Largest batch of samples solved and scored at once.
MAX_BATCH = 256
#: Local-optimisation refits of one new best hypothesis, at most.
MAX_LO_STEPS = 5


class RansacProblem(Protocol):
    """What :func:`lo_ransac` needs to know of a problem with ``n`` data (module docstring).

    Attributes
    ----------
    sample_size : int
        Data in a minimal sample, ``s``.
    dof : (n,) int
        Degrees of freedom of each datum's error: ``e_j^2 / sigma^2 ~ chi2(nu_j)`` for an
        inlier (>= 1).
    scorable : (n,) bool
        Data whose errors rank hypotheses (their errors are never NaN).
    samplable : (n,) bool
        Data the sampler draws from; the stopping rule counts inliers among them.
    """

    sample_size: int
    dof: np.ndarray
    scorable: np.ndarray
    samplable: np.ndarray

    def sample(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Up to ``size`` minimal samples ``(B, s)`` of data indices (fewer if valid samples are rare)."""

    def solve(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hypotheses ``(H, ...)`` from samples ``(B, s)``, and their validity ``(H,)``."""

    def errors(self, hypotheses: np.ndarray) -> np.ndarray:
        """Squared errors ``(H, n)`` of every datum under each hypothesis."""

    def refit(self, inliers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Hypotheses ``(H, ...)`` fitted to the data ``inliers (n,)``, and their validity ``(H,)``."""


@dataclass(frozen=True, eq=False)
class RansacResult:
    """Result of :func:`lo_ransac`.

    Attributes
    ----------
    hypothesis : ndarray or None
        The best hypothesis (one entry of the hooks' hypothesis arrays); None when no
        valid hypothesis was found (or fewer than ``s`` samplable data).
    score : float
        Its ranking value (median of normalised errors, or MSAC cost).
    errors : (n,) float
        Its per-datum errors (None without a hypothesis).
    sigma : float
        The noise of its inlier rule: estimated, or the known one.
    inliers : (n,) bool
        Data passing the chi-square rule with ``sigma``.
    trials : int
        Minimal samples drawn.
    trials_needed : float
        The adaptive number of samples at the end (inf before any hypothesis).
    lo_steps : int
        Local-optimisation refits in all.
    """

    hypothesis: np.ndarray | None
    score: float
    errors: np.ndarray | None
    sigma: float
    inliers: np.ndarray
    trials: int
    trials_needed: float
    lo_steps: int

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def least_singular_vector(A: np.ndarray) -> np.ndarray:
    """``(B, c)``: per batch the unit ``x`` minimising ``|A x|`` (``A (B, r, c)``), the
    right singular vector of the smallest singular value: a DLT's solution. Tall systems
    (a refit on every inlier) take the thin SVD: the full one forms ``U`` of ``r x r``
    (0.24 s against 0.002 s for 1000 points)."""
    return np.linalg.svd(A, full_matrices=A.shape[-2] < A.shape[-1])[2][:, -1]


def trials_needed(n_inliers: int, n_samplable: int, sample_size: int, confidence: float) -> float:
    """Samples after which an all-inlier one was drawn with probability ``confidence``::

        log(1 - confidence) / log(1 - p),   p = prod_{i<s} (n_inliers - i) / (n_samplable - i)

    (``p ~ w^s``, ``w = n_inliers / n_samplable``); inf below ``s`` inliers, 1 when all are.
    """
    s = int(sample_size)
    if n_samplable < s or n_inliers < s:
        return math.inf
    p = min(1.0, math.prod((n_inliers - i) / (n_samplable - i) for i in range(s)))
    if p >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log1p(-p)


class _Best:
    """The best hypothesis so far, its ranking, errors, noise and inliers."""

    def __init__(self, problem: RansacProblem, alpha: float, sigma: float | None):
        self.problem, self.alpha, self.known = problem, alpha, sigma
        self.dof = np.asarray(problem.dof, dtype=np.intp)
        self.ok = np.asarray(problem.scorable, bool)
        dof_ok = self.dof[self.ok]
        self.median_chi2 = chi2_quantiles(0.5, dof_ok)
        self.cap = None if sigma is None else sigma * sigma * chi2_quantiles(1.0 - alpha, dof_ok)
        self.hypothesis, self.score, self.errors = None, math.inf, None
        self.sigma = math.nan if sigma is None else float(sigma)
        self.inliers = np.zeros(len(self.dof), bool)
        self.lo_steps = 0

    def rank(self, errors: np.ndarray) -> np.ndarray:
        """Ranking ``(H,)`` of hypotheses from their errors ``(H, n)``: lower is better."""
        e = errors[:, self.ok]
        if self.cap is None:  # least median of normalised squares
            return np.median(e / self.median_chi2, axis=1)
        return np.sum(np.minimum(np.nan_to_num(e, nan=0.0), self.cap), axis=1)  # MSAC

    def consider(self, hypotheses: np.ndarray, valid: np.ndarray) -> bool:
        """Score the valid hypotheses; keep the best if it beats the best so far."""
        hypotheses = hypotheses[np.asarray(valid, bool)]
        if not len(hypotheses):
            return False
        errors = self.problem.errors(hypotheses)
        score = self.rank(errors)
        h = int(np.argmin(score))
        if not score[h] < self.score:
            return False
        self.hypothesis, self.score, self.errors = hypotheses[h], float(score[h]), errors[h]
        if self.known is None:
            self.sigma = truncated_sigma(errors[h], self.dof, median_sigma(errors[h], self.dof), self.alpha)
        self.inliers = chi2_inliers(errors[h], self.dof, self.sigma, self.alpha)
        return True

    def local_optimisation(self, max_steps: int) -> None:
        """Refit on the inliers of the best hypothesis while that improves its ranking."""
        for _ in range(max_steps):
            if self.inliers.sum() < self.problem.sample_size:
                return
            hypotheses, valid = self.problem.refit(self.inliers)
            self.lo_steps += 1
            if not self.consider(hypotheses, valid):
                return


def lo_ransac(problem: RansacProblem, *, confidence: float = 0.999, max_trials: int = 1000,
              false_rejection: float = 0.01, sigma: float | None = None, rng=None,
              progress=None, stage: str = "ransac", first_batch: int = FIRST_BATCH,
              max_batch: int = MAX_BATCH, max_lo_steps: int = MAX_LO_STEPS) -> RansacResult:
    """LO-RANSAC on a problem given by hooks (module docstring).

    Parameters
    ----------
    problem : RansacProblem
        Data description and the ``sample``, ``solve``, ``errors``, ``refit`` hooks.
    confidence : float
        In (0, 1): probability that an all-inlier sample was drawn when the loop stops.
    max_trials : int
        At most this many samples.
    false_rejection : float
        ``alpha``: probability that the inlier rule rejects a good datum.
    sigma : float, optional
        Known noise per coordinate (units of ``sqrt(errors)``): MSAC ranking and a fixed
        rule. None: least-median ranking and ``sigma`` estimated for each new best.
    rng : seed or numpy Generator
        Randomness of the sampling (passed to ``problem.sample``).
    progress : callable, optional
        Called after every batch with a :class:`~transcalib.types.ProgressEvent` of
        ``stage``: ``done`` the trials so far, ``info`` ``trials_needed`` and
        ``best_inliers``.
    stage : str
        The name of the stage in progress reports.
    first_batch, max_batch : int
        Samples in the first batch, and the most in one (batches double).
    max_lo_steps : int
        Local-optimisation refits per new best hypothesis, at most.

    Returns
    -------
    RansacResult
        ``hypothesis`` None when no valid hypothesis was found: the caller says why.
    """
    rng = np.random.default_rng(rng)
    best = _Best(problem, false_rejection, sigma)
    samplable = np.asarray(problem.samplable, bool)
    m, s = int(samplable.sum()), int(problem.sample_size)
    trials, needed, batch = 0, math.inf, int(first_batch)
    while m >= s and trials < min(needed, max_trials):
        left = max(1, math.ceil(needed - trials)) if math.isfinite(needed) else batch
        size = int(min(batch, max_trials - trials, left))
        samples = problem.sample(rng, size)
        trials += size
        if len(samples):
            hypotheses, valid = problem.solve(samples)
            if np.any(valid) and best.consider(hypotheses, valid):
                best.local_optimisation(max_lo_steps)
                needed = trials_needed(int(best.inliers[samplable].sum()), m, s, confidence)
        batch = min(2 * batch, int(max_batch))
        report(progress, stage, done=trials, trials_needed=needed, best_inliers=int(best.inliers.sum()))
    return RansacResult(hypothesis=best.hypothesis, score=best.score, errors=best.errors, sigma=best.sigma,
                        inliers=best.inliers, trials=trials, trials_needed=needed, lo_steps=best.lo_steps)
