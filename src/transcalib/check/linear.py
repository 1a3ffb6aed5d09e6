"""Check of the linear system: a nearly two-dimensional null space of ``C b = 0``."""

from __future__ import annotations

import numpy as np

from ..errors import Diagnostic
from ..types import LinearEstimate

NULL_SPACE_RATIO = 0.05

def check_null_space(linear: LinearEstimate, *, ratio: float = NULL_SPACE_RATIO) -> list:
    """Warn when the linear system ``C b = 0`` has a nearly two-dimensional null space.

    Parameters
    ----------
    linear : LinearEstimate
        Its ``singular_values`` ``[sigma_1, sigma_2, ...]`` (ascending): ``sigma_1`` the
        residual of the TLS solution, ``sigma_2`` that of the best solution with a
        different ``A``.
    ratio : float
        Warn when ``sigma_1 / sigma_2 > ratio``: a second, different ``A`` explains the
        data almost as well (on healthy data with 0.5-1 px noise the ratio is ~0.002).

    Returns
    -------
    list of Diagnostic
        ``null_space_2d``.
    """
    sv = np.asarray(linear.singular_values, dtype=float)
    if sv.size < 2 or not np.all(np.isfinite(sv[:2])) or sv[1] <= 0:
        return []
    r = sv[0] / sv[1]
    if r <= ratio:
        return []
    return [Diagnostic(
        "null_space_2d",
        f"the linear system has a nearly two-dimensional null space (sigma_1 / sigma_2 = {r:.3g} > {ratio}): "
        "a different camera explains the data almost as well, so K and R are not determined. Causes: "
        "translations nearly coplanar or too short, too few points, points nearly at one depth seen "
        "under tiny parallax, or mismatched tracks. Add robot motions along a third independent direction, "
        "track more points spread in depth, or use the robust estimator.")]
