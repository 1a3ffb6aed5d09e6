"""Levenberg-Marquardt and Gauss-Newton, generic over the problem (they know nothing of cameras).

A problem offers (:class:`Problem`): ``cost(state)`` (``0.5 sum rho``, ``inf`` for an
invalid state), ``linearise(state, damped=True, reuse=None)`` (normal equations at
``state`` that carry their ``cost`` and can ``solve(mu)`` for a step and the decrease
the damped model predicts), ``apply(state, step)``, the residual degrees of freedom
``dof`` and ``zero_cost`` (a cost at rounding level: exact data). This is the shape of
PoseLib's ``lm_impl<Problem>``; here the problem solves its own damped system, because
its normal matrix is only ever formed with the points eliminated.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..errors import DegenerateError
from ..types import report

#: Initial damping, relative to the diagonal of the normal matrix.
MU0 = 1e-5
#: Smallest factor of the damping after a good step (Nielsen's rule; 1/3 in his paper).
MU_SHRINK = 0.1
#: Damping beyond which no step lowers the cost: the minimum within numerical precision.
MU_MAX = 1e16


class Linearisation(Protocol):
    cost: float

    def solve(self, mu: float) -> tuple[Any, float | None] | None: ...


class Problem(Protocol):
    dof: int
    zero_cost: float
    invalid_start: str

    def cost(self, state) -> float: ...

    def linearise(self, state, damped: bool = True, reuse=None) -> Linearisation: ...

    def apply(self, state, step): ...


@dataclass(frozen=True, eq=False)
class Solution:
    """Where a solver stopped: ``state``, its ``cost``, the accepted ``iterations``, the
    stop ``reason`` (starts with ``"converged"`` when it converged) and, after Gauss-Newton
    steps, ``linearisation``: the system of the last step (linearised one step before
    ``state``), None otherwise."""

    state: Any
    cost: float
    iterations: int
    reason: str
    linearisation: Any = None

    @property
    def converged(self) -> bool:
        return self.reason.startswith("converged")


def _start_cost(problem: Problem, f: float) -> float:
    if not np.isfinite(f):
        raise DegenerateError(problem.invalid_start)
    return f


def levenberg_marquardt(problem: Problem, state, max_iterations: int = 100, tol: float = 1e-6, progress=None,
                        stage: str = "refine") -> Solution:
    """Minimise the problem's cost from ``state``.

    Stops when a step decreases the cost by less than ``tol * sigma^2`` with ``sigma^2 =
    2 cost / dof`` (the parameters moved by about ``sqrt(2 tol)`` standard deviations), when
    no step decreases it (damping beyond :data:`MU_MAX`), at zero residual, or after
    ``max_iterations`` accepted steps. ``progress`` gets a :class:`ProgressEvent` per step.
    """
    f = _start_cost(problem, problem.cost(state))
    mu, nu = MU0, 2.0
    dof = max(problem.dof, 1)
    it = 0
    reason = f"max_iterations ({max_iterations}) reached"
    while it < max_iterations:
        if f <= problem.zero_cost:
            reason = "converged: zero residual"
            break
        lin = problem.linearise(state)
        while True:
            solved = lin.solve(mu)
            new, new_f, gain = None, np.inf, -1.0
            if solved is not None:
                step, predicted = solved
                new = problem.apply(state, step)
                new_f = problem.cost(new)
                gain = (f - new_f) / predicted if predicted > 0 else -1.0
            if gain > 0:
                mu *= max(MU_SHRINK, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
                break
            mu *= nu
            nu *= 2.0
            if mu > MU_MAX:
                return Solution(state, f, it, "converged: no step decreases the cost (minimum within numerical "
                                "precision)")
        it += 1
        decrease, state, f = f - new_f, new, new_f
        report(progress, f"{stage}: iteration", done=it, cost=f, damping=mu)
        if decrease <= tol * 2.0 * f / dof:
            reason = f"converged: cost decrease below tol={tol:g} x sigma^2"
            break
    return Solution(state, f, it, reason)


def gauss_newton(problem: Problem, state, steps: int = 2, tol: float = 1e-6, progress=None,
                 stage: str = "refine") -> Solution:
    """Undamped Gauss-Newton steps from a start near the solution (the fit of a subset of
    the data). Each step's system gives the cost at its state, so a step is checked by
    the next step's linearisation (``reuse``: the previous system's memory), the last by
    the cost at the solution. A step that does not lower the cost hands over to
    :func:`levenberg_marquardt` (then ``Solution.linearisation`` is None).
    """
    lin = problem.linearise(state, damped=False)
    f = _start_cost(problem, lin.cost)
    for it in range(steps):
        solved = lin.solve(0.0)
        new = None if solved is None else problem.apply(state, solved[0])
        last = it == steps - 1
        new_lin = None
        if new is None:
            new_f = np.inf
        elif last:
            new_f = problem.cost(new)
        else:  # the arrays of this step's system are free once the step is taken
            new_lin = problem.linearise(new, damped=False, reuse=lin)
            new_f = new_lin.cost
        if not new_f < f:
            more = levenberg_marquardt(problem, state, steps - it, tol, progress, stage)
            return Solution(more.state, more.cost, it + more.iterations, more.reason)
        state, f = new, new_f
        report(progress, f"{stage}: iteration", done=it + 1, cost=f, damping=0.0)
        if not last:
            lin = new_lin
    return Solution(state, f, steps, f"{steps} Gauss-Newton step(s)", lin)
