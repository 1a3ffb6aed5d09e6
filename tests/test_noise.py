"""Inlier rules and noise estimators (transcalib.estimate.noise), each against its
equation by Monte Carlo with a stated statistical tolerance."""

import math

import numpy as np
import pytest

from transcalib.estimate.distributions import chi2_ppf
from transcalib.estimate.noise import (OBS_QUANTILE, SIGMA_FLOOR_PX, chi2_inliers, inlier_rule, mad_sigma,
                                       median_sigma, noise_spread, observation_quantile, sigma_from_threshold,
                                       spread_quantiles, track_dof, truncated_sigma, truncation_factor)


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


def spread_halves(n, tau, rng, k_max=12, one_half_bad=0.0):
    """Two halves' squared errors of inlier tracks seen in 2..k_max views whose noise
    differs, ``sigma_j^2 chi2(nu_half)`` each with ``log sigma_j^2 ~ N(-tau^2 / 2, tau^2)``
    (mean 1), and the tracks' whole errors; a fraction ``one_half_bad`` with one half 10-1000
    times too large (an outlier in one view). Returns ``(sse, sse_a, sse_b, k)``."""
    k = rng.integers(2, k_max + 1, n)
    s2 = np.exp(tau * rng.normal(size=n) - 0.5 * tau * tau)
    nu = (2 * k - 3) * np.stack([(k + 1) // 2, k // 2]) / k
    a, b = s2 * rng.chisquare(np.maximum(nu, 0.5))
    bad = rng.random(n) < one_half_bad
    a[bad] *= rng.uniform(10.0, 1000.0, bad.sum())
    return a + b, a, b, k


@pytest.mark.parametrize("tau", [0.3, 0.6])
def test_noise_spread_is_measured(tau):
    """1500 tracks whose log noise variance spreads by ``tau``: measured within 20 % on
    average over 10 draws (its std ~0.04 per draw; 7-15 % high, as the rank correlation's
    conversion assumes normal log errors and a half's chi-square is skewed); with a third of the tracks off in one
    half (an outlier in one view) it is not inflated (those halves carry no shared noise:
    60-80 % of it is measured, the rule then nearer the chi-square rule)."""
    rng = np.random.default_rng(11)
    clean = [noise_spread(*spread_halves(1500, tau, rng)[1:]) for _ in range(10)]
    assert abs(np.mean(clean) - tau) < 0.2 * tau
    bad = [noise_spread(*spread_halves(1500, tau, rng, one_half_bad=0.3)[1:]) for _ in range(10)]
    assert 0.5 * tau < np.mean(bad) < tau


def test_one_noise_keeps_the_chi2_rule():
    """Tracks of one noise: a spread is measured in at most 3 of 50 draws of 1500 (the
    gate's false alarm rate is 2.3 %), and with none the rule is the chi-square rule."""
    rng = np.random.default_rng(12)
    found = sum(noise_spread(*spread_halves(1500, 0.0, rng)[1:]) > 0 for _ in range(50))
    assert found <= 3
    sse, k = track_errors(3000, 0.5, rng)
    np.testing.assert_array_equal(inlier_rule(sse, k, 0.5, 0.01, 0.0), chi2_inliers(sse, track_dof(k), 0.5, 0.01))
    assert noise_spread(np.ones(10), np.ones(10), np.full(10, 6)) == 0.0  # too few tracks to tell


def test_spread_quantiles_against_sampling():
    """``Q_nu(0.99; tau)`` against 4e6 draws of ``exp(tau Z - tau^2 / 2) chi2(nu)``: within
    1 % (the sampled quantile's own std is ~0.2 %); ``tau = 0`` is the chi-square quantile."""
    rng = np.random.default_rng(13)
    for nu, tau in ((1, 0.6), (5, 0.3), (17, 1.0)):
        w = np.exp(tau * rng.normal(size=4_000_000) - 0.5 * tau * tau) * rng.chisquare(nu, 4_000_000)
        q = spread_quantiles(0.99, np.array([nu]), tau)[0]
        assert abs(q / np.quantile(w, 0.99) - 1) < 0.01
    np.testing.assert_allclose(spread_quantiles(0.99, np.array([3, 1]), 0.0), chi2_ppf(0.99, np.array([3, 1])))


@pytest.mark.parametrize("tau", [0.3, 0.6])
def test_rule_rejects_alpha_whatever_the_spread(tau):
    """5e4 good tracks whose noise spreads by ``tau``: the rule with their mean sigma and
    the measured spread rejects alpha = 1 % of them (within 4 binomial std, plus the
    spread's own error), where one sigma's chi-square rule rejects 2-7 times as many."""
    rng = np.random.default_rng(14)
    sse, a, b, k = spread_halves(50_000, tau, rng)
    rejected = 1 - inlier_rule(sse, k, 1.0, 0.01, noise_spread(a, b, k)).mean()
    assert abs(rejected - 0.01) < 4 * math.sqrt(0.01 * 0.99 / 5e4) + 0.001
    assert 1 - chi2_inliers(sse, track_dof(k), 1.0, 0.01).mean() > 0.02


def test_spread_rule_still_rejects_outliers():
    """10 % of 5000 tracks a hundred times the noise variance in both halves (wrong
    matches): every one rejected at a spread of 0.6, and at most 1.5 % of the good tracks."""
    rng = np.random.default_rng(15)
    sse, a, b, k = spread_halves(5000, 0.6, rng)
    bad = rng.random(sse.size) < 0.1
    for x in (sse, a, b):
        x[bad] *= 100.0
    keep = inlier_rule(sse, k, 1.0, 0.01, noise_spread(a, b, k))
    assert (~keep[bad]).mean() > 0.95 and (~keep[~bad]).mean() < 0.015


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
