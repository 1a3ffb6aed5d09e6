"""Inlier rules and noise estimators (transcalib.estimate.noise), each against its
equation by Monte Carlo with a stated statistical tolerance."""

import math

import numpy as np
import pytest

from transcalib.estimate.distributions import chi2_ppf
from transcalib.estimate.noise import (OBS_QUANTILE, SIGMA_FLOOR_PX, chi2_inliers, inlier_rule, mad_sigma,
                                       median_sigma, observation_quantile, sigma_from_threshold, track_dof,
                                       truncated_sigma, truncation_factor)


def track_errors(n, sigma, rng, k_max=8):
    """Track errors of inliers seen in 2..k_max views: ``sigma^2 chi2(2 k - 3)``."""
    k = rng.integers(2, k_max + 1, n)
    return sigma**2 * rng.chisquare(track_dof(k)), k


def test_track_dof():
    np.testing.assert_array_equal(track_dof([1, 2, 3, 4, 10]), [1, 1, 3, 5, 17])


def test_rule_rejects_alpha_of_the_inliers():
    """1e5 inlier tracks of mixed lengths: rejected fraction alpha = 0.01 (std 3e-4)."""
    rng = np.random.default_rng(0)
    sse, k = track_errors(100_000, 0.7, rng)
    rejected = 1 - inlier_rule(sse, k, 0.7, 0.01).mean()
    assert abs(rejected - 0.01) < 4 * math.sqrt(0.01 * 0.99 / 1e5)
    np.testing.assert_array_equal(inlier_rule(sse, k, 0.7, 0.01), chi2_inliers(sse, track_dof(k), 0.7, 0.01))
    assert not chi2_inliers(np.array([np.nan, np.inf]), np.array([3, 3]), 1.0, 0.01).any()


@pytest.mark.parametrize("outliers", [0.0, 0.3])
def test_median_then_truncated_sigma(outliers):
    """2e4 tracks, a fraction of them gross (errors 100-10^4 x sigma^2, or inf): the
    truncated estimator is within 2 % (std ~0.5 %); the median guess within 30 % (it is
    biased up by the outliers, which is why it only starts the iteration)."""
    rng = np.random.default_rng(1)
    sse, k = track_errors(20_000, 0.5, rng)
    bad = rng.random(sse.size) < outliers
    sse[bad] = 0.25 * 10 ** rng.uniform(2, 4, bad.sum())
    sse[bad & (rng.random(sse.size) < 0.1)] = np.inf
    s0 = median_sigma(sse, track_dof(k))
    assert abs(s0 / 0.5 - 1) < 0.3
    s = truncated_sigma(sse, track_dof(k), s0, 0.01)
    assert abs(s / 0.5 - 1) < 0.02


def test_sigma_floor_and_degenerate_inputs():
    zero = np.zeros(10)
    assert median_sigma(zero, np.ones(10, int)) == SIGMA_FLOOR_PX
    assert median_sigma(zero, 1, floor=0.0) == 0.0
    assert math.isnan(median_sigma(np.full(3, np.nan), 1))
    assert truncated_sigma(zero, np.ones(10, int), 1.0, 0.01) == SIGMA_FLOOR_PX
    assert truncated_sigma(np.array([1.0]), np.array([1]), 0.3, 0.01) == 0.3  # fewer than 2 inliers


def test_truncation_factor_is_the_shrinkage_of_the_inliers_variance():
    """The inliers' sum of squares per degree of freedom (sigma = 1) over 2e5 inlier
    tracks (relative std ~0.12 %)."""
    rng = np.random.default_rng(2)
    sse, k = track_errors(200_000, 1.0, rng)
    inl = inlier_rule(sse, k, 1.0, 0.01)
    mc = sse[inl].sum() / track_dof(k)[inl].sum()
    c = truncation_factor(k, 0.01)
    assert 0.97 < c < 0.99 and abs(mc / c - 1) < 0.005


def test_threshold_and_observation_quantile():
    """One observation's residual norm stays below ``threshold`` with probability 1 - alpha."""
    assert observation_quantile(0.01) == pytest.approx(math.sqrt(chi2_ppf(0.99, 2)), rel=1e-12)
    assert OBS_QUANTILE == pytest.approx(math.sqrt(chi2_ppf(0.999, 2)), rel=1e-12) and 3.71 < OBS_QUANTILE < 3.72
    sigma = sigma_from_threshold(3.0, 0.01)
    assert sigma == pytest.approx(3.0 / math.sqrt(-2 * math.log(0.01)))
    r = np.random.default_rng(3).normal(0, sigma, (200_000, 2))
    assert abs(np.mean(np.hypot(r[:, 0], r[:, 1]) > 3.0) - 0.01) < 4 * math.sqrt(0.01 * 0.99 / 2e5)


def test_mad_sigma():
    """Gaussian residual coordinates with 1 % gross ones: within 4 % (std ~0.6 %; the gross
    ones bias it up by ~1 %); the dof correction ``sqrt(N / (N - p))`` and NaN entries as
    the equation says."""
    rng = np.random.default_rng(4)
    r = rng.normal(0, 0.8, (4, 5000, 2))
    r[:, :50] = rng.uniform(-50, 50, (4, 50, 2))
    r[0, 100:200] = np.nan
    assert abs(mad_sigma(r, 0) / 0.8 - 1) < 0.04
    finite = np.abs(r[np.isfinite(r)])
    expected = 1.4826 * np.median(finite) * math.sqrt(finite.size / (finite.size - 1000))
    assert mad_sigma(r, 1000) == pytest.approx(expected)
    assert mad_sigma(np.zeros(6), 2) == SIGMA_FLOOR_PX
