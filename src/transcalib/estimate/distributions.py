"""The chi-square and F distribution functions of the inlier rules and the model tests.

Thin names over :mod:`scipy.special` (``scipy.stats`` would add about a second to every
command's start-up for the same four functions). ``nu``, ``d1``, ``d2`` are degrees of
freedom, scalars or arrays broadcast against ``x`` / ``p``.
"""

from __future__ import annotations

import numpy as np
from scipy import special

__all__ = ["chi2_ppf", "chi2_cdf", "chi2_sf", "f_sf", "chi2_ppf_table"]


def chi2_ppf(p, nu):
    """Quantile ``x`` with ``P(chi2_nu < x) = p``."""
    return special.chdtri(nu, 1.0 - np.asarray(p, float))


def chi2_cdf(x, nu):
    """``P(chi2_nu < x)``."""
    return special.chdtr(nu, x)


def chi2_sf(x, nu):
    """``P(chi2_nu > x)``."""
    return special.chdtrc(nu, x)


def f_sf(x, d1, d2):
    """``P(F_{d1,d2} > x)``."""
    return special.fdtrc(d1, d2, x)


def chi2_ppf_table(p: float, nu: np.ndarray) -> np.ndarray:
    """``chi2_ppf(p, nu)`` for an integer array ``nu`` of few distinct small values (track
    degrees of freedom): computed once per value and looked up, O(n)."""
    nu = np.asarray(nu)
    if nu.size == 0:
        return np.zeros(nu.shape)
    table = chi2_ppf(p, np.arange(1, int(nu.max()) + 1))
    return table[nu - 1]
