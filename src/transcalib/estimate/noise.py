"""Inlier rules and pixel-noise (sigma) estimators: every one of the project, written once.

The pixel noise of real data is unknown (0.5-3 px: hand-clicked points, webcams, JPEG), so
every inlier rule is a quantile of the noise the data show, never a fixed pixel constant.

**Errors.** A datum's error ``e_j^2`` is a sum of squared residuals that, for an inlier
with Gaussian noise ``sigma`` per coordinate, follows ``e_j^2 / sigma^2 ~ chi2(nu_j)``:

- a track seen in ``k`` views, triangulated (``e_j^2 = sum_i |r_ij|^2``, px^2):
  ``nu_j = 2 k - 3`` (:func:`track_dof`);
- one observation's residual ``|r_ij|^2``: ``nu = 2``;
- one residual coordinate (a line fit's distance): ``nu = 1``.

**Rule** (:func:`chi2_inliers`; for tracks :func:`inlier_rule`)::

    inlier  <=>  e_j^2 < sigma^2 chi2_{nu_j}(1 - alpha)

so a good datum is rejected with probability ``alpha`` (the false-rejection rate) whatever
its ``nu``. ``sigma`` comes from the data: the least-median guess :func:`median_sigma`,
then the truncated estimator :func:`truncated_sigma`; after a robust fit of many
residuals, :func:`mad_sigma`. A user threshold on one observation's residual norm implies
a sigma (:func:`sigma_from_threshold`; a threshold on one signed distance, such as a
point's distance from its epipolar line, :func:`sigma_from_distance_threshold`). Robust losses and per-observation thresholds take
their scales from sigma (:data:`LOSS_SCALE`, :data:`OBS_QUANTILE`). No sigma is below
:data:`SIGMA_FLOOR_PX`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from .distributions import chi2_cdf, chi2_ppf, chi2_ppf_table

__all__ = ["SIGMA_FLOOR_PX", "LOSS_SCALE", "OBS_QUANTILE", "track_dof", "chi2_quantiles",
           "chi2_inliers", "inlier_rule", "noise_spread", "spread_quantiles", "median_sigma", "truncated_sigma",
           "truncation_factor", "observation_quantile", "sigma_from_threshold", "sigma_from_distance_threshold", "mad_sigma"]

#: Smallest pixel noise any rule assumes: exact (simulated) data have rounding errors of
#: ~1e-10 px, which are not Gaussian; no real tracker is below a thousandth of a pixel.
SIGMA_FLOOR_PX = 1e-6
#: Scale ``c`` of a robust loss per unit of pixel noise, ``c = LOSS_SCALE[loss] sigma``:
#: Huber 1.345 and Cauchy 2.385 have 95 % efficiency under Gaussian noise.
LOSS_SCALE = {"huber": 1.345, "cauchy": 2.385, "linear": 1.0}
#: False-rejection rate of the per-observation rule of a robust refinement.
OBS_FALSE_REJECTION = 1e-3


def observation_quantile(alpha: float) -> float:
    """Residual norm, in sigmas, below which one observation (2 coordinates) stays with
    probability ``1 - alpha``: ``sqrt(chi2_2(1 - alpha)) = sqrt(-2 ln alpha)`` (the
    chi-square with 2 degrees of freedom is an exponential)."""
    return math.sqrt(-2.0 * math.log(alpha))


#: Per-observation threshold of a robust refinement in sigmas:
#: ``sqrt(chi2_2(1 - OBS_FALSE_REJECTION)) = 3.72``.
OBS_QUANTILE = observation_quantile(OBS_FALSE_REJECTION)


def track_dof(k: np.ndarray) -> np.ndarray:
    """Residual degrees of freedom ``nu = 2 k - 3`` of tracks seen in ``k`` views (a
    triangulated point has 3 unknowns; at least 1)."""
    return np.maximum(2 * np.asarray(k, dtype=np.intp) - 3, 1)


def chi2_quantiles(p: float, dof: np.ndarray) -> np.ndarray:
    """``chi2_{nu_j}(p)`` for integer degrees of freedom ``dof (n,)`` (>= 1), O(n): one
    quantile per distinct value."""
    return chi2_ppf_table(p, np.asarray(dof, dtype=np.intp))


def chi2_inliers(errors: np.ndarray, dof: np.ndarray, sigma: float, alpha: float) -> np.ndarray:
    """The chi-square rule: ``errors_j < sigma^2 chi2_{nu_j}(1 - alpha)``.

    Parameters
    ----------
    errors : (..., n) float
        Squared errors ``e_j^2``; NaN (unscorable) and inf (impossible, e.g. behind the
        camera) are outliers.
    dof : (n,) int
        Degrees of freedom ``nu_j`` of each datum's error.
    sigma : float
        Noise per coordinate, in the units of ``sqrt(errors)``.
    alpha : float
        False-rejection rate.

    Returns
    -------
    (..., n) bool
    """
    q = chi2_quantiles(1.0 - alpha, dof)
    with np.errstate(invalid="ignore"):
        return np.isfinite(errors) & (errors < sigma * sigma * q)


def inlier_rule(sse: np.ndarray, k: np.ndarray, sigma: float, alpha: float, tau: float = 0.0) -> np.ndarray:
    """Inlier tracks of the ``k (n,)`` views that see them::

        sse_j < sigma^2 Q_{nu_j}(1 - alpha; tau),   nu_j = 2 k_j - 3    (:func:`spread_quantiles`)

    ``sigma^2`` the tracks' mean noise variance per coordinate and ``tau`` the spread of
    their log noise variance (:func:`noise_spread`); with ``tau = 0`` (one noise for every
    track) the chi-square rule :func:`chi2_inliers`. Real tracks differ in noise (texture,
    contrast, blur): a rule with one sigma rejects the noisier good tracks, and as a track
    near the threshold stays when the fit's error happens to explain part of its own,
    that selection follows the fit's error and enlarges it (docs/robust-and-diagnostics.md
    §2, "Tracks whose noise differs")."""
    nu = track_dof(k)
    q = spread_quantiles(1.0 - alpha, nu, tau)
    with np.errstate(invalid="ignore"):
        return np.isfinite(sse) & (sse < sigma * sigma * q)


#: Probabilists' Gauss-Hermite nodes and normalised weights: expectations over a track's
#: log noise variance ``tau Z``, ``Z ~ N(0, 1)``.
_GH_Z, _GH_W = np.polynomial.hermite_e.hermegauss(32)
_GH_W = _GH_W / _GH_W.sum()
#: Largest spread of the tracks' log noise variance the rule takes in (a factor of
#: ``exp(1 / 2) = 1.65`` in a track's sigma per std): an unweighted fit of tracks whose
#: noise spreads by ``tau`` keeps ``exp(-tau^2)`` of a weighted fit's information (37 %
#: here); wider, the noisiest tracks are better left out than averaged in.
SPREAD_MAX = 1.0
#: Fewest tracks (of at least 4 views, in groups of one length of at least
#: :data:`SPREAD_MIN_GROUP`) from which :func:`noise_spread` measures a spread (else 0).
SPREAD_MIN_DATA = 30
SPREAD_MIN_GROUP = 10
#: How many of its std (under one noise) the halves' rank correlation must exceed for a
#: spread to be measured (a one-sided test at 2.3 %): data of one noise keep the
#: chi-square rule.
SPREAD_SIGNIFICANCE = 2.0


def _centred_by_group(x: np.ndarray, group: np.ndarray) -> np.ndarray:
    """``x`` less the median of its group."""
    out = np.empty_like(x)
    for g in np.unique(group):
        m = group == g
        out[m] = x[m] - np.median(x[m])
    return out


def noise_spread(sse_a: np.ndarray, sse_b: np.ndarray, k: np.ndarray) -> float:
    """The spread ``tau`` of the tracks' log noise variance, ``log sigma_j^2 ~ N(m, tau^2)``,
    from the squared residuals of each track's two halves of views (alternate views of
    those that see it: ``sse_a``, ``sse_b`` (n,) px^2, ``k`` (n,) its views).

    A track's own noise is in both halves, a chi-square's chance and an error of one
    observation or one view (an outlier, a wrong pose) in one: so ``tau^2`` is the
    covariance of ``a = log sse_a``, ``b = log sse_b`` across tracks (each centred by its
    track length's median), measured by their rank correlation ``rho_S`` (Pearson's
    ``r = 2 sin(pi rho_S / 6)``) with the halves' chi-square variances ``v = psi_1(nu / 2)``,
    ``nu ~ (2 k - 3) k_half / k``::

        tau^2 = r sqrt((tau^2 + v_a) (tau^2 + v_b))

    0 when ``rho_S`` is within :data:`SPREAD_SIGNIFICANCE` of its std ``1 / sqrt(n - 1)``
    of zero or with fewer than :data:`SPREAD_MIN_DATA` tracks; at most :data:`SPREAD_MAX`.
    """
    sse_a, sse_b, k = np.asarray(sse_a, float), np.asarray(sse_b, float), np.asarray(k, np.intp)
    ok = np.isfinite(sse_a) & np.isfinite(sse_b) & (sse_a > 0) & (sse_b > 0) & (k >= 4)
    lengths, count = np.unique(k[ok], return_counts=True)
    ok &= np.isin(k, lengths[count >= SPREAD_MIN_GROUP])
    n = int(ok.sum())
    if n < SPREAD_MIN_DATA:
        return 0.0
    a, b = (_centred_by_group(np.log(x[ok]), k[ok]) for x in (sse_a, sse_b))
    ra, rb = (np.argsort(np.argsort(x)) for x in (a, b))
    rho = float(np.corrcoef(ra, rb)[0, 1])
    if not rho > SPREAD_SIGNIFICANCE / math.sqrt(n - 1):
        return 0.0
    r = min(2.0 * math.sin(math.pi * rho / 6.0), 0.999)
    half = (k[ok] + 1) // 2, k[ok] // 2
    v_a, v_b = (float(np.mean(special.polygamma(1, (2 * k[ok] - 3) * h / k[ok] / 2))) for h in half)
    r2 = r * r
    t = (r2 * (v_a + v_b) + math.sqrt((r2 * (v_a + v_b)) ** 2 + 4 * (1 - r2) * r2 * v_a * v_b)) / (2 * (1 - r2))
    return min(math.sqrt(t), SPREAD_MAX)


def _bisect(f, lo, hi, tol: float, steps: int = 60):
    """Root of the increasing ``f`` between ``lo`` and ``hi`` (arrays: elementwise)."""
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        below = f(mid) < 0
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        if np.all(hi - lo < tol):
            break
    return 0.5 * (lo + hi)


def spread_quantiles(p: float, dof: np.ndarray, tau: float) -> np.ndarray:
    """``Q_nu(p; tau)`` per datum ``(n,)``: the ``p``-quantile of ``exp(tau Z - tau^2 / 2)
    chi2(nu)`` (``Z ~ N(0, 1)``: a datum's noise variance relative to the mean one,
    log-normal with spread ``tau``); ``chi2_nu(p)`` at ``tau = 0``. One quantile per
    distinct ``nu`` (bisection in ``log x``, Gauss-Hermite over ``Z``), O(n)."""
    dof = np.asarray(dof, np.intp)
    if tau <= 0 or dof.size == 0:
        return chi2_quantiles(p, dof)
    nu = np.arange(1, int(dof.max()) + 1)
    shift = (-tau * _GH_Z + 0.5 * tau * tau)[None]

    def excess(logx):  # P(W < x) - p, per nu
        return np.sum(_GH_W * chi2_cdf(np.exp(logx[:, None] + shift), nu[:, None]), axis=1) - p

    start = np.log(chi2_ppf(p, nu))
    logx = _bisect(excess, start - 2.0 * tau - 1.0, start + 5.0 * tau + 1.0, 1e-6)
    return np.exp(logx)[dof - 1]


def median_sigma(errors: np.ndarray, dof: np.ndarray, floor: float = SIGMA_FLOOR_PX) -> float:
    """A robust first guess of sigma (right with up to half the data bad)::

        sigma = sqrt(median_j(e_j^2 / chi2_{nu_j}(0.5)))

    over the finite errors (``dof`` (n,) or a scalar). NaN when no error is finite; at
    least ``floor`` otherwise.
    """
    errors = np.asarray(errors, float)
    finite = np.isfinite(errors)
    if not finite.any():
        return float("nan")
    s = errors[finite] / chi2_quantiles(0.5, np.broadcast_to(dof, errors.shape)[finite])
    return max(float(np.sqrt(np.median(s))), floor)


def _truncated_means(dof: np.ndarray, alpha: float) -> np.ndarray:
    """``E[X | X < q] = nu F_{nu+2}(q) / F_nu(q)`` for ``X ~ chi2(nu)``, ``q = chi2_nu(1 - alpha)``,
    one value per datum."""
    values = np.arange(1, int(dof.max()) + 1) if dof.size else np.ones(1, np.intp)
    qv = chi2_ppf(1.0 - alpha, values)
    return (values * chi2_cdf(qv, values + 2) / chi2_cdf(qv, values))[dof - 1]


def truncated_sigma(errors: np.ndarray, dof: np.ndarray, sigma0: float, alpha: float, iterations: int = 50,
                    floor: float = SIGMA_FLOOR_PX) -> float:
    """Noise per coordinate from errors containing outliers: the fixed point of the mean of
    the inliers' errors corrected for the truncation at the rule's threshold::

        sigma^2 = sum_in e_j^2 / sum_in nu_j F_{nu_j+2}(q_j) / F_{nu_j}(q_j),
        q_j = chi2_{nu_j}(1 - alpha),   in = {j : e_j^2 < sigma^2 q_j}

    (``E[X | X < q] = nu F_{nu+2}(q) / F_nu(q)`` for ``X ~ chi2(nu)``).

    Parameters
    ----------
    errors : (n,) float
        Squared errors (NaN, inf: outliers).
    dof : (n,) int
        Their degrees of freedom (>= 1).
    sigma0 : float
        Start; an over-estimate is fine (e.g. :func:`median_sigma`).
    alpha : float
        False-rejection rate of the rule.
    iterations : int
        At most this many fixed-point steps (stops at a relative change of 1e-6).
    floor : float
        Smallest sigma returned.

    Returns
    -------
    float
        ``sigma0`` (floored) when fewer than 2 inliers remain.
    """
    dof = np.asarray(dof, dtype=np.intp)
    q = chi2_quantiles(1.0 - alpha, dof)
    factor = _truncated_means(dof, alpha)
    sigma = max(float(sigma0), floor)
    finite = np.isfinite(errors)
    for _ in range(iterations):
        inl = finite & (np.where(finite, errors, np.inf) < sigma * sigma * q)
        if inl.sum() < 2:
            return sigma
        new = max(float(np.sqrt(np.sum(errors[inl]) / np.sum(factor[inl]))), floor)
        if abs(new - sigma) <= 1e-6 * sigma:
            return new
        sigma = new
    return sigma


def truncation_factor(k: np.ndarray, alpha: float) -> float:
    """The inliers' expected sum of squares per degree of freedom, in units of ``sigma^2``,
    over tracks seen in ``k`` views::

        c = E[sum_in e_j^2] / (sigma^2 E[sum_in nu_j])
          = sum_j nu_j F_{nu_j+2}(q_j) / sum_j nu_j F_{nu_j}(q_j),   q_j = chi2_{nu_j}(1 - alpha)

    the factor by which selecting inliers with the chi-square rule shrinks the residual sum
    of squares (about 0.98 at ``alpha = 0.01``). Dividing a variance estimated on the
    inliers by it undoes the bias."""
    nu = track_dof(k)
    values = np.arange(1, int(nu.max()) + 1)
    qv = chi2_ppf(1.0 - alpha, values)
    count = np.bincount(nu, minlength=values.size + 1)[1:]
    return float(np.sum(count * values * chi2_cdf(qv, values + 2)) / np.sum(count * values * chi2_cdf(qv, values)))


def sigma_from_threshold(threshold_px: float, alpha: float) -> float:
    """The noise a user threshold implies: one observation's residual norm stays below
    ``threshold_px`` with probability ``1 - alpha``::

        sigma = threshold_px / sqrt(chi2_2(1 - alpha))      (:func:`observation_quantile`)
    """
    return float(threshold_px / observation_quantile(alpha))


def sigma_from_distance_threshold(threshold_px: float, alpha: float) -> float:
    """The noise a threshold on one residual coordinate implies (a signed distance, e.g. of
    a point from its epipolar line, ``nu = 1``): ``|r| < threshold_px`` with probability
    ``1 - alpha``::

        sigma = threshold_px / sqrt(chi2_1(1 - alpha))      (= threshold_px / z_{1 - alpha/2})
    """
    return float(threshold_px / math.sqrt(float(chi2_ppf(1.0 - alpha, 1))))


def mad_sigma(residuals: np.ndarray, n_params: int, floor: float = SIGMA_FLOOR_PX) -> float:
    """Noise per coordinate from the median absolute residual coordinate (outliers barely
    move a median), scaled to the residual degrees of freedom::

        sigma = 1.4826 median_c |r_c| sqrt(N / (N - p))

    ``1.4826 = 1 / Phi^-1(0.75)`` makes the MAD of a Gaussian its sigma.

    Parameters
    ----------
    residuals : array_like, any shape
        Residual coordinates (px); NaN entries (unseen) are left out.
    n_params : int
        Parameters ``p`` fitted to them (a dof of at least 1 is kept).
    floor : float
        Smallest sigma returned.
    """
    r = np.abs(residuals[np.isfinite(residuals)])
    dof = max(r.size - int(n_params), 1)
    return max(float(1.4826 * np.median(r) * np.sqrt(r.size / dof)), floor)
