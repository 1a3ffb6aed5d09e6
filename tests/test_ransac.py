"""The generic LO-RANSAC (transcalib.estimate.ransac) alone, on a toy problem: a 2-D line
among outliers. An independent check of the loop, not the calibration again."""

import math

import numpy as np
import pytest

from transcalib.estimate.distributions import chi2_ppf
from transcalib.estimate.noise import SIGMA_FLOOR_PX
from transcalib.estimate.ransac import least_singular_vector, lo_ransac, trials_needed


class LineProblem:
    """Points ``xy (n, 2)``; hypotheses: lines ``(a, b, c)`` with ``a^2 + b^2 = 1``; errors:
    squared distances (one degree of freedom each); refit: total least squares."""

    sample_size = 2

    def __init__(self, xy, valid=True):
        self.xy = np.asarray(xy, float)
        n = len(self.xy)
        self.dof = np.ones(n, int)
        self.scorable = np.ones(n, bool)
        self.samplable = np.ones(n, bool)
        self.always_valid = valid
        self.refits = 0

    def sample(self, rng, size):
        n = len(self.xy)
        i = rng.integers(n, size=size)
        j = rng.integers(n - 1, size=size)
        return np.column_stack([i, j + (j >= i)])

    def solve(self, samples):
        h = np.column_stack([self.xy, np.ones(len(self.xy))])
        lines = np.cross(h[samples[:, 0]], h[samples[:, 1]])
        norm = np.hypot(lines[:, 0], lines[:, 1])
        valid = (norm > 0) & self.always_valid
        return lines / np.where(norm > 0, norm, 1.0)[:, None], valid

    def errors(self, lines):
        return (lines[:, :2] @ self.xy.T + lines[:, 2:]) ** 2

    def refit(self, inliers):
        self.refits += 1
        p = self.xy[inliers]
        c = p.mean(axis=0)
        normal = np.linalg.svd(p - c)[2][-1]
        return np.append(normal, -normal @ c)[None], np.array([True])


def line_data(n, inlier_ratio, noise, rng):
    """Points on ``y = 0.3 x + 1`` (x in [-10, 10]) with Gaussian perpendicular noise, the
    rest uniform in the box [-10, 10]^2. Returns (xy, inlier mask, true line)."""
    rng = np.random.default_rng(rng)
    line = np.array([0.3, -1.0, 1.0]) / np.hypot(0.3, 1.0)
    good = np.zeros(n, bool)
    good[: int(round(inlier_ratio * n))] = True
    rng.shuffle(good)
    x = rng.uniform(-10, 10, n)
    xy = np.column_stack([x, 0.3 * x + 1.0]) + rng.normal(0, noise, n)[:, None] * line[:2]
    xy[~good] = rng.uniform(-10, 10, (int((~good).sum()), 2))
    return xy, good, line


def same_line(a, b):
    return min(np.abs(a - b).max(), np.abs(a + b).max())


def found_at(calls, n_inliers):
    """Trials after the batch in which the best hypothesis reached ``n_inliers``."""
    return next(c.done for c in calls if c.info["best_inliers"] >= n_inliers)


def test_exact_on_noise_free_inliers():
    xy, good, line = line_data(300, 0.5, 0.0, rng=1)
    r = lo_ransac(LineProblem(xy), rng=0)
    assert same_line(r.hypothesis, line) < 1e-12
    np.testing.assert_array_equal(r.inliers, good)
    assert r.sigma == SIGMA_FLOOR_PX and np.all(r.errors[good] < 1e-24)


@pytest.mark.parametrize("seed", range(3))
def test_recovers_the_line_and_the_noise_among_outliers(seed):
    """1000 points, 40 % outliers, noise 0.05: the std of the estimated sigma is ~3 % (600
    inliers), of the line's angle ~0.05 / (20 sqrt(600 / 12)) rad: tolerances 4-5 std."""
    xy, good, line = line_data(1000, 0.6, 0.05, rng=seed)
    problem = LineProblem(xy)
    r = lo_ransac(problem, rng=seed)
    assert r.n_inliers == int(r.inliers.sum()) and r.lo_steps >= 1 and problem.refits == r.lo_steps
    recall = np.sum(r.inliers & good) / good.sum()
    precision = np.sum(r.inliers & good) / r.inliers.sum()
    assert recall >= 0.97 and precision >= 0.98
    assert abs(r.sigma / 0.05 - 1) < 0.15
    assert abs(r.hypothesis[0] * line[1] - r.hypothesis[1] * line[0]) < 5 * 0.05 / (20 * np.sqrt(50))


def test_stops_at_the_predicted_trial_count():
    """30 % inliers (beyond least median: the noise is given), noise-free: once the line
    is found the loop stops after exactly ``ceil(log(1 - c) / log(1 - p))`` samples,
    ``p = n_in (n_in - 1) / (n (n - 1))``."""
    n, n_in, confidence = 200, 60, 0.99
    xy, good, _ = line_data(n, n_in / n, 0.0, rng=4)
    needed = math.log(1 - confidence) / math.log(1 - n_in * (n_in - 1) / (n * (n - 1)))
    assert 40 < needed < 60
    for seed in range(10):
        calls = []
        r = lo_ransac(LineProblem(xy), confidence=confidence, sigma=1e-6, rng=seed, progress=calls.append)
        np.testing.assert_array_equal(r.inliers, good)
        assert r.trials_needed == pytest.approx(needed, rel=1e-12)
        assert r.trials == max(math.ceil(needed), found_at(calls, n_in))
        assert [c.done for c in calls] == sorted(c.done for c in calls)


def test_confidence_sets_the_number_of_trials():
    xy, _, _ = line_data(200, 0.6, 0.0, rng=6)
    n_in = 120
    p = n_in * (n_in - 1) / (200 * 199)
    for confidence in (0.9, 0.999, 0.99999):
        r = lo_ransac(LineProblem(xy), confidence=confidence, rng=0)
        assert r.n_inliers == n_in
        assert r.trials_needed == pytest.approx(math.log(1 - confidence) / math.log(1 - p), rel=1e-12)


@pytest.mark.parametrize("max_trials", [1, 7, 40])
def test_honours_max_trials(max_trials):
    xy, _, _ = line_data(400, 0.05, 0.01, rng=7)  # 5 % inliers: thousands of trials needed
    calls = []
    r = lo_ransac(LineProblem(xy), max_trials=max_trials, sigma=0.01, rng=0, progress=calls.append)
    assert r.trials == max_trials == calls[-1].done and r.trials_needed > 10 * max_trials


def test_batches_double_up_to_the_largest():
    xy, _, _ = line_data(400, 0.05, 0.01, rng=7)
    calls = []
    lo_ransac(LineProblem(xy), max_trials=1000, sigma=0.01, rng=0, progress=calls.append, first_batch=4,
              max_batch=32)
    sizes = np.diff([0] + [c.done for c in calls])
    assert list(sizes[:5]) == [4, 8, 16, 32, 32] and sizes.max() == 32


def test_known_sigma_ranks_by_msac_and_fixes_the_rule():
    xy, good, line = line_data(500, 0.5, 0.02, rng=8)
    r = lo_ransac(LineProblem(xy), sigma=0.05, false_rejection=0.05, rng=0)
    assert r.sigma == 0.05
    d2 = (xy @ r.hypothesis[:2] + r.hypothesis[2]) ** 2
    np.testing.assert_array_equal(r.inliers, d2 < 0.05**2 * chi2_ppf(0.95, 1))
    assert r.score == pytest.approx(np.sum(np.minimum(d2, 0.05**2 * chi2_ppf(0.95, 1))))
    assert np.sum(r.inliers & good) / good.sum() > 0.99


def test_no_valid_hypothesis_returns_none():
    xy, _, _ = line_data(50, 0.5, 0.0, rng=9)
    r = lo_ransac(LineProblem(xy, valid=False), max_trials=30, rng=0)
    assert r.hypothesis is None and r.errors is None and r.trials == 30 and r.n_inliers == 0


def test_too_few_samplable_data_draw_nothing():
    problem = LineProblem(np.zeros((3, 2)))
    problem.samplable = np.array([True, False, False])
    r = lo_ransac(problem, rng=0)
    assert r.hypothesis is None and r.trials == 0


def test_seeded_runs_are_reproducible():
    xy, _, _ = line_data(300, 0.4, 0.05, rng=10)
    a, b = lo_ransac(LineProblem(xy), rng=3), lo_ransac(LineProblem(xy), rng=3)
    np.testing.assert_array_equal(a.hypothesis, b.hypothesis)
    assert a.trials == b.trials


def test_trials_needed_formula():
    assert trials_needed(10, 10, 2, 0.99) == 1.0
    assert trials_needed(1, 10, 2, 0.99) == math.inf and trials_needed(5, 1, 2, 0.99) == math.inf
    # many data: p -> w^s
    w, s = 0.4, 3
    assert trials_needed(400_000, 1_000_000, s, 0.999) == pytest.approx(math.log(0.001) / math.log(1 - w**s),
                                                                        rel=1e-5)


@pytest.mark.parametrize("rows", [8, 12, 2000])
def test_least_singular_vector_minimises_the_residual(rows):
    """Tall (thin SVD) and wide (full SVD) systems: the unit vector of ``A``'s smallest
    singular value, against the eigenvector of ``A^T A``'s smallest eigenvalue."""
    A = np.random.default_rng(rows).normal(size=(3, rows, 9))
    x = least_singular_vector(A)
    w, v = np.linalg.eigh(np.einsum("brc,brd->bcd", A, A))
    oracle = v[:, :, 0]
    assert x.shape == (3, 9)
    np.testing.assert_allclose(np.abs(np.einsum("bc,bc->b", x, oracle)), 1.0, atol=1e-9)
