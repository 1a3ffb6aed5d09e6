"""The robot error's variance components while fitting: the bookkeeping of
:class:`transcalib.estimate.refine`'s fitter.

What a previous fit of nearly the same tracks found (:class:`RobotStart`, a refit's warm
start), what a fit found (:class:`RobotFit`), the prior weights of the scales, their
updates (:func:`component_sigma`, Aitken's :func:`extrapolated`) and the early stop of
rounds that run away from the score tests' evidence (:func:`check_growth`). The tests
and the statistics are in :mod:`.variance_components`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import DegenerateError
from .layout import State
from .robot_error import COMPONENTS
from .variance_components import MISFIT_ALPHA, JointScore

__all__ = ["RobotStart", "RobotFit", "RunAway", "check_growth", "robot_weights", "extrapolated",
           "component_sigma", "robot_error_on", "DROP_FRACTION", "DROP_REDUNDANCY", "RUNAWAY_ALPHA"]


@dataclass(frozen=True)
class RobotStart:
    """The robot error a previous fit of nearly the same tracks (a refit's start, the
    robust loss's polish before) found: the scales it estimated (rad, unit), each view's
    errors ``E (V, 6)`` (None without scales), and the p-values of every component it
    tested (score test, scale check) with the score's scale estimates. A refit continues
    the variance-component rounds from there and does not test those components again."""

    sigma: dict
    E: np.ndarray | None
    p_values: dict
    consistency: dict
    scores: dict

    @classmethod
    def of(cls, initial, given: dict, n_views: int) -> "RobotStart | None":
        """From ``initial``'s :class:`RobotError` (None if it has none for these views)."""
        re = getattr(initial, "robot_error", None)
        if re is None or re.rot_deg.shape[0] != n_views:
            return None
        tested = [k for k, (c, src) in enumerate(zip(COMPONENTS, re.source))
                  if src in ("estimated", "not detected", "misfit") and c in given and given[c] is None]
        if not tested:
            return None
        scales = (np.radians(re.sigma_rot_deg), re.sigma_pos)
        scales_of_score = (np.radians(re.score_scales[0]), re.score_scales[1])
        sigma = {COMPONENTS[k]: float(scales[k]) for k in tested if re.source[k] == "estimated"}
        E = np.hstack([np.radians(re.rot_deg), re.pos])
        for k, c in enumerate(COMPONENTS):
            if c not in sigma:
                E[:, 3 * k: 3 * k + 3] = 0.0
        return cls(sigma, E if sigma else None, {COMPONENTS[k]: float(re.p_values[k]) for k in tested},
                   {COMPONENTS[k]: float(re.consistency_p[k]) for k in tested},
                   {COMPONENTS[k]: float(scales_of_score[k]) for k in tested if np.isfinite(scales_of_score[k])})


@dataclass(frozen=True)
class RobotFit:
    """Scales of the robot error components found (``sigma``: rad / unit), their
    redundancies, the score tests' p-values, what was given, the pixel noise, the
    p-values of the fitted scales against their scores (``consistency``; a component
    below ``MISFIT_ALPHA`` there was left out as a misfit) and the scores' scale estimates
    (``scores``, rad / unit)."""

    sigma: dict
    r: dict
    p_values: dict
    given: dict
    sigma_px: float | None
    consistency: dict = field(default_factory=dict)
    scores: dict = field(default_factory=dict)


#: A robot error component estimated while fitting is dropped again when its scale falls
#: below this fraction of its start while its redundancy falls below ``DROP_REDUNDANCY``.
DROP_FRACTION = 0.05
DROP_REDUNDANCY = 1.0


#: The variance-component rounds stop early once a growing scale's check against the
#: scores (:class:`.variance_components.JointScore`) falls below this: below the
#: ``MISFIT_ALPHA`` of the verdict, which they would then only fail by more. (Such rounds
#: crawl: the fit runs along a valley where per-view errors trade with the camera, up to
#: 100 Levenberg-Marquardt steps a round.)
RUNAWAY_ALPHA = MISFIT_ALPHA / 10


class RunAway(DegenerateError):
    """The variance-component rounds ran away from the scores' evidence: ``p`` the checks'
    p-values (component -> p)."""

    def __init__(self, p: dict):
        super().__init__(f"robot error scales far above the score tests' evidence (p = {p})")
        self.p = p


def check_growth(joint: JointScore | None, sig: dict, new: dict, sigma_px: float) -> None:
    """Raise :class:`RunAway` when a scale grew from ``sig`` to ``new`` and its check
    against ``joint`` (None: no check) is below ``RUNAWAY_ALPHA``."""
    if joint is None or not any(new[c] > sig[c] for c in new if c in joint.blocks):
        return
    p = joint.consistency({c: v**2 for c, v in new.items()}, sigma_px)
    if any(p.get(c, 1.0) < RUNAWAY_ALPHA and new[c] > sig[c] for c in new):
        raise RunAway(p)


def robot_weights(sigma_px: float, sig: dict) -> np.ndarray:
    """Prior weights ``sigma_px / sigma_k`` of (rot, pos), 0 for a component left out."""
    return np.array([sigma_px / sig[c] if c in sig else 0.0 for c in COMPONENTS])


def extrapolated(history: dict, new: dict, given: dict) -> dict:
    """Aitken's extrapolation of the estimated scales' slow (linear) convergence: from
    three successive values of ``log sigma`` moving the same way by a ratio ``q`` in
    (0, 0.95), the limit ``x2 + (x2 - x1) q / (1 - q)`` (at most a factor 3 away); then
    the history starts again. ``history`` (component -> log sigmas) is updated in place."""
    out = dict(new)
    for c, v in new.items():
        if given.get(c) is not None or v <= 0:
            continue
        h = history.setdefault(c, [])
        h.append(np.log(v))
        if len(h) == 3:
            d1, d2 = h[1] - h[0], h[2] - h[1]
            q = d2 / d1 if d1 != 0 else 0.0
            if 0 < q < 0.95:
                out[c] = float(np.exp(h[2] + np.clip(d2 * q / (1 - q), -np.log(3), np.log(3))))
            history[c] = []
    return out


def component_sigma(state: State, comp: str, r: float) -> float:
    """``sqrt(|e_k|^2 / r_k)`` of a component's estimated errors (0 without redundancy)."""
    e = state.E[:, :3] if comp == "rot" else state.E[:, 3:]
    return float(np.sqrt(np.sum(e * e) / r)) if r > 1e-9 else 0.0


def robot_error_on(opts) -> bool:
    """Whether ``opts`` model the robot pose error: ``robot_error`` True or None (the
    default: the score tests decide each component), never with ``sigma_T``."""
    return opts.sigma_T is None and opts.robot_error is not False
