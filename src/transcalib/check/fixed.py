"""Known parameters the data contradict (``fix_contradicted``): a wrong ``fix`` (CLI ``--fix``).

A parameter held at a wrong value biases every other one, and what is left shows up as
residuals that other checks would blame on a rotated camera or a bad pose. The score
test of the fixed parameters ``f`` (``k`` of them), linearised at the constrained
maximum-likelihood solution with the points eliminated and every free parameter
profiled out (:func:`transcalib.estimate.covariance.profile_step`)::

    d = g_f^T I_f^-1 g_f,    s^2 = (RSS - d) / (dof - k),    (d / k) / s^2 ~ F(k, dof - k)

``d`` is the drop of the residual sum of squares one Gauss-Newton step with ``f`` free
brings. When the joint test is significant at ``FIX_ALPHA``, each fixed parameter is
tested alone the same way, and those significant are named, with the value a refit with
that parameter free gives (:func:`transcalib.refine`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import DegenerateError, Diagnostic
from ..estimate.covariance import linearise, profile_step
from ..estimate.distributions import f_sf
from ..estimate.layout import Layout
from ..estimate.refine import refine
from ..types import Calibration
from .common import inlier_uv
from .rotation import _refinement

__all__ = ["fixed_score_test", "check_fixed", "FIX_ALPHA"]

#: False-alarm rate of the test on correct known values.
FIX_ALPHA = 1e-3


def fixed_score_test(uv, T, calibration: Calibration) -> dict | None:
    """Score test of the calibration's fixed parameters (module docstring).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        The observations fitted (outside ``calibration.inliers`` left out).
    T : (n_views, 3) float
        Flange positions as the calibration's model uses them.
    calibration : Calibration
        A refined calibration with ``options.refinement.fix``.

    Returns
    -------
    dict or None
        None without fixed parameters; else ``names`` (the fixed parameters tested),
        ``p_value`` (joint), ``each`` (name -> ``(p-value, linearised value)``).
    """
    opts = _refinement(calibration)
    if not opts.fix:
        return None
    lin = linearise(uv, T, calibration, opts, polish=0)
    free = Layout.from_options(replace(opts, fix={}, estimate_view_rotations=False), uv.shape[0],
                               lin.layout.t_basis)
    names = free.names()
    tested = [nm for nm in opts.fix if nm in names]
    if not tested:
        return None
    S, b, sse = lin.system(free)
    own = [names.index(nm) for nm in lin.layout.names() if nm in names]

    def test(subset):
        cols = np.array([names.index(nm) for nm in subset])
        w, _, r = profile_step(S, b, cols, np.setdiff1d(np.array(own), cols))
        d = lin.dof - len(cols)
        s2 = max((sse - r) / d, 1e-300)
        return float(f_sf(r / len(cols) / s2, len(cols), d)), w

    p, _ = test(tested)
    each = {}
    for nm in tested:
        p_nm, w = test([nm])
        each[nm] = (p_nm, float(opts.fix[nm] + w[0]))
    return {"names": tested, "p_value": p, "each": each}


def check_fixed(uv, T, calibration: Calibration, *, alpha: float = FIX_ALPHA) -> list:
    """``fix_contradicted`` naming each fixed parameter the data contradict, with the
    value they give it (module docstring); empty when the fixed values agree with the
    data or nothing is fixed."""
    res = fixed_score_test(uv, T, calibration)
    if res is None or not res["p_value"] < alpha:
        return []
    named = [nm for nm in res["names"] if res["each"][nm][0] < alpha] or list(res["names"])
    opts = _refinement(calibration)
    parts = []
    for nm in named:
        value = _refit_value(uv, T, calibration, opts, nm)
        value = res["each"][nm][1] if value is None else value
        parts.append(f"{nm} = {opts.fix[nm]:g} (the data give {nm} = {value:.4g}; p = {res['each'][nm][0]:.1e})")
    return [Diagnostic(
        "fix_contradicted",
        f"the known parameter(s) held fixed contradict the data: {'; '.join(parts)}. Fixing a parameter at a wrong "
        "value biases every other one and leaves residuals that look like a turned camera or a bad pose. Check the "
        "value (units: pixels; the principal point of a W x H image is near ((W-1)/2, (H-1)/2)), or leave it free "
        "(drop it from fix, CLI --fix).")]


def _refit_value(uv, T, calibration: Calibration, opts, name: str) -> float | None:
    """The value of ``name`` refitted with it free (the others still fixed), from the
    linear estimate (which fixes nothing: a start far from the wrong value's solution),
    or None."""
    others = {k: v for k, v in opts.fix.items() if k != name}
    uv = inlier_uv(uv, calibration)
    try:
        start = calibration.linear if calibration.linear is not None else calibration
        c = refine(uv, T, start, options=replace(opts, fix=others))
    except DegenerateError:
        return None
    values = dict(zip(("fx", "fy", "cx", "cy", "skew"), c.camera.intrinsics))
    values.update(zip(("k1", "k2", "p1", "p2", "k3"), c.camera.dist5))
    return float(values[name]) if name in values else None
