"""The optimiser: translations inside the box that minimise the design criterion.

The information of a design is a sum over views, point by point (``U_j``, ``W_j``,
``V_j`` from the observation Jacobians of :func:`.fisher.view_jacobians`, before the
points are eliminated). Replacing one view by a
candidate position therefore costs only the candidate's own per-point contributions, and
all candidates of a step are scored in one vectorised call:

    S(c) = sum_j [n_j(c) >= 2] (U_j + U_cj - (W_j + W_cj)(V_j + V_cj)^-1 (W_j + W_cj)^T)

(``U_j, W_j, V_j``: the other views; ``n_j``: the number of views that see point j).
Search: the best standard pattern as the start, then a greedy exchange over a grid of
candidate positions (or over the user's allowed positions) until no exchange improves
the criterion, then (on a grid) a pattern search of each view with halving steps. Two
views are never closer than ``min_sep``.
Candidate positions from which a view would see fewer than ``min_visible`` of the points
are never used. The robot-noise terms are left out of the search (they couple the views);
every reported figure includes them (:func:`.fisher.predict`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..estimate.covariance import UNDETERMINED_POINT_DET
from ..estimate.schur import inv3_spd
from .fisher import view_jacobians
from .model import CRITERIA, PlanOptions

__all__ = ["optimise"]

_OFFSETS = np.array([o for o in np.ndindex(3, 3, 3) if o != (1, 1, 1)], float) - 1.0  # (26, 3)


class Pool(NamedTuple):
    """Per-point information contributions of ``K`` positions: ``U (K, n, q, q)``,
    ``W (K, n, q, 3)``, ``V (K, n, 3, 3)``, ``seen (K, n)`` and the positions ``P (K, 3)``."""

    P: np.ndarray
    U: np.ndarray
    W: np.ndarray
    V: np.ndarray
    seen: np.ndarray

    @classmethod
    def of(cls, options: PlanOptions, X: np.ndarray, P) -> "Pool":
        P = np.atleast_2d(np.asarray(P, dtype=float))
        Jg, JX, seen = view_jacobians(options, X, P)
        wf = seen.astype(float)[..., None, None]
        U = np.einsum("knaq,knar->knqr", Jg * wf, Jg)
        W = np.einsum("knaq,knaj->knqj", Jg * wf, JX)
        V = np.einsum("knai,knaj->knij", JX * wf, JX)
        return cls(P, U, W, V, seen)

    def take(self, idx) -> "Pool":
        return Pool(*(a[idx] for a in self))


def _criterion_index(options: PlanOptions) -> np.ndarray:
    names = ("fx", "fy", "cx", "cy")
    return np.array([names.index(k) for k in CRITERIA[options.criterion]])


def _score(rest: tuple, cand: Pool, crit_idx: np.ndarray) -> np.ndarray:
    """Criterion (RMS predicted std over the criterion's parameters, unit pixel noise) of
    the designs "the other views ``rest`` + one candidate", for each candidate: ``(K,)``."""
    U0, W0, V0, n0 = rest
    U = U0 + cand.U
    W = W0 + cand.W
    V = V0 + cand.V
    used = (n0 + cand.seen) >= 2
    Vinv, det = inv3_spd(np.moveaxis(V, (-2, -1), (0, 1)))  # blocks last, as the bundle adjuster's
    Vinv = np.moveaxis(Vinv, (0, 1), (-2, -1))
    ok = (det > UNDETERMINED_POINT_DET) & used
    okf = ok.astype(float)[..., None, None]
    S = np.einsum("knqr->kqr", U * okf) - np.einsum("knqi,knij,knrj->kqr", W * okf, Vinv, W, optimize=True)
    out = np.full(len(S), np.inf)
    ds = 1.0 / np.sqrt(np.maximum(np.einsum("kii->ki", S), 1e-300))
    Ss = S * ds[:, :, None] * ds[:, None, :]
    good = np.linalg.cond(Ss) < 1e13
    if good.any():
        inv = np.linalg.inv(Ss[good]) * ds[good][:, :, None] * ds[good][:, None, :]
        var = np.einsum("kii->ki", inv)[:, crit_idx]
        out[good] = np.sqrt(np.maximum(var.mean(axis=1), 0.0))
    return out


def _rest(design: Pool, i: int) -> tuple:
    keep = np.arange(len(design.P)) != i
    return (design.U[keep].sum(0), design.W[keep].sum(0), design.V[keep].sum(0), design.seen[keep].sum(0))


def _improve_slot(design: Pool, i: int, cand: Pool, crit_idx, current: float, min_sep: float):
    """Best replacement of view ``i`` among ``cand`` at least ``min_sep`` from the other views;
    returns (design, value, changed)."""
    others = np.delete(design.P, i, axis=0)
    far = np.min(np.linalg.norm(cand.P[:, None] - others[None], axis=2), axis=1) >= min_sep
    cand = cand.take(np.flatnonzero(far))
    if len(cand.P) == 0:
        return design, current, False
    s = _score(_rest(design, i), cand, crit_idx)
    k = int(np.argmin(s))
    if s[k] < current * (1.0 - 1e-9):
        parts = [np.concatenate([a[:i], b[k: k + 1], a[i + 1:]]) for a, b in zip(design, cand)]
        return Pool(*parts), float(s[k]), True
    return design, current, False


def _feasible(pool: Pool, options: PlanOptions) -> Pool:
    return pool.take(np.flatnonzero(pool.seen.mean(axis=1) >= options.min_visible - 1e-12))


def optimise(options: PlanOptions, X: np.ndarray, start, box: np.ndarray, candidates, *, polish: bool,
             step: float, min_sep: float, max_passes: int = 20):
    """Greedy exchange over ``candidates`` from ``start``, then a pattern search.

    Parameters
    ----------
    options : PlanOptions
    X : (n_points, 3) float
    start : (n_views, 3) float
        Initial design.
    box : (3, 2) float
        ``[min, max]`` per axis (the pattern search stays inside).
    candidates : (K, 3) float
        Allowed positions of the exchange.
    polish : bool
        Continue with a pattern search off the candidates (only for a box).
    step : float
        Initial step of the pattern search (robot units; halved 4 times).
    min_sep : float
        Smallest distance between two views (robot units): a repeated position adds no
        geometry, and the linear start of the calibration breaks down on exact repeats.

    Returns
    -------
    T : (n_views, 3) float
    value : float
        Criterion at unit pixel noise.
    """
    crit = _criterion_index(options)
    design = Pool.of(options, X, start)
    pool = _feasible(Pool.of(options, X, candidates), options)
    value = float(_score(_rest(design, 0), design.take([0]), crit)[0])
    for _ in range(max_passes):
        changed = False
        for i in range(len(design.P)):
            design, value, ch = _improve_slot(design, i, pool, crit, value, min_sep)
            changed |= ch
        if not changed:
            break
    if polish:
        lo, hi = box[:, 0], box[:, 1]
        for h in step * 0.5 ** np.arange(5):
            for _ in range(max_passes):
                changed = False
                for i in range(len(design.P)):
                    moves = np.unique(np.clip(design.P[i] + h * _OFFSETS, lo, hi), axis=0)
                    cand = _feasible(Pool.of(options, X, moves), options)
                    design, value, ch = _improve_slot(design, i, cand, crit, value, min_sep)
                    changed |= ch
                if not changed:
                    break
    return design.P.copy(), value
