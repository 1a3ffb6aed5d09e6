"""The one bundle adjuster: model, Jacobians, normal equations, Schur step, Levenberg-Marquardt.

Residual of observation ``(i, j)`` (paper eq. 2 with OpenCV distortion)::

    r_ij = uv_ij - pi(K, dist, Q_i R (F_i (X_j - T_i) - t))

with ``R`` the camera rotation, ``F_i`` a known per-view rotation (identity inside one
pure-translation session; ``R_i^T`` of the flange for several sessions, then ``R`` is
``R_X^T`` and ``t`` the camera's position in the flange ``t_X``), ``Q_i = exp([w_i]x)``
an optional model-violation rotation of view ``i`` (rotation test) and ``T_i`` the
translation, optionally a noisy measurement with prior ``|T_i - T_i^meas|^2 / sigma_T^2``.
``pi`` is :func:`transcalib.geometry.camera.project_camera_frame`, the project's only
projection.

The parameters are laid out by :class:`Layout`: free intrinsics (``fix``, square pixels),
free distortion coefficients, ``R`` (local update ``R <- exp([dw]x) R``), ``t`` (when
free), the rotations ``w_i`` and translations ``T_i`` of the views that have them, then
the points. The Jacobian has one 2x3 block per observation for its point, so the normal
matrix is ``[[U, W], [W^T, V]]`` with ``V`` block-diagonal; each step eliminates the points
with the Schur complement ::

    S = U - sum_j W_j V_j^-1 W_j^T,    S dg = b_g - sum_j W_j V_j^-1 b_j,
    dX_j = V_j^-1 (b_j - W_j^T dg),

O(n) time and memory (batched 3x3 inverses, BLAS products; no loop over points).
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from ..errors import DegenerateError
from ..geometry.camera import DIST_MODELS, DIST_NAMES, project_camera_frame
from ..geometry.rotation import rotvec_to_matrix
from ..types import INTRINSIC_NAMES
from . import translation_block

__all__ = ["Layout", "State", "Data", "build_data", "predict_view", "NormalEquations", "normal_equations", "schur",
           "solve_spd", "Reduced", "reduced_system", "BLOCK_POINTS", "one_blas_thread", "levenberg_marquardt",
           "gauss_newton", "cost", "view_residuals", "sum_sq", "all_residuals", "loss_weights", "intrinsic_basis"]

_MU0 = 1e-5  # initial LM damping, relative to the diagonal of the normal matrix
_MU_SHRINK = 0.1  # smallest factor of the damping after a step (Nielsen's rule; 1/3 in his paper)
_DENSE_FRACTION = 0.5  # views seeing at least this fraction of the points: see Data


# ----------------------------------------------------------------------------------------
# Parameter layout and state
# ----------------------------------------------------------------------------------------


def intrinsic_basis(fix, estimate_skew: bool, square_pixels: bool) -> tuple[np.ndarray, tuple]:
    """Free intrinsic parameters as a basis ``E (5, q)``: ``d(fx, fy, cx, cy, s) = E dp``.

    ``fix`` holds some of fx, fy, cx, cy, skew at known values; the skew is fixed unless
    ``estimate_skew``; with ``square_pixels`` one focal length ``f`` moves fx and fy
    together. Returns ``E`` and the names of the free parameters.
    """
    columns, names = [], []
    if square_pixels:
        if "fx" not in fix and "fy" not in fix:
            columns.append([1.0, 1.0, 0, 0, 0])
            names.append("f")
    else:
        for k in (0, 1):
            if INTRINSIC_NAMES[k] not in fix:
                columns.append(np.eye(5)[k])
                names.append(INTRINSIC_NAMES[k])
    for k in (2, 3):
        if INTRINSIC_NAMES[k] not in fix:
            columns.append(np.eye(5)[k])
            names.append(INTRINSIC_NAMES[k])
    if estimate_skew and "skew" not in fix:
        columns.append(np.eye(5)[4])
        names.append("skew")
    E = np.array(columns, dtype=float).T.reshape(5, len(columns))
    return E, tuple(names)


@dataclass
class Layout:
    """Where each global parameter sits in the vector ``g`` solved for by the Schur step.

    Parameters
    ----------
    n_views : int
    intr_basis : (5, q) float
        Free intrinsics (:func:`intrinsic_basis`).
    intr_names : tuple of str
    dist_free : tuple of int
        Free distortion coefficients, indices into OpenCV's five.
    rot_views : tuple of int
        Views with a rotation ``Q_i``.
    T_views : tuple of int
        Views whose translation is a parameter.
    t_basis : (3, k) float or None
        Free directions of the offset ``t`` (the hand-eye translation): ``dt = B dp``;
        None (or k = 0): ``t`` is fixed. Directions the data cannot determine (a rotation
        axis shared by every session) are left out, so ``t`` keeps its value there.
    """

    n_views: int
    intr_basis: np.ndarray
    intr_names: tuple
    dist_free: tuple = ()
    rot_views: tuple = ()
    T_views: tuple = ()
    t_basis: np.ndarray | None = None
    i_vrot: dict = field(init=False)
    i_T: dict = field(init=False)

    def __post_init__(self):
        self.n_intr = self.intr_basis.shape[1]
        self.i_dist = self.n_intr
        self.n_dist = len(self.dist_free)
        self.i_rot = self.i_dist + self.n_dist
        self.i_t = self.i_rot + 3
        self.n_t = 0 if self.t_basis is None else self.t_basis.shape[1]
        self.t_free = self.n_t > 0
        self.n_common = self.i_t + self.n_t
        start = self.n_common
        self.i_vrot, self.i_T = {}, {}
        for i in self.rot_views:
            self.i_vrot[int(i)] = start
            start += 3
        for i in self.T_views:
            self.i_T[int(i)] = start
            start += 3
        self.size = start

    @property
    def n_global_no_T(self) -> int:
        """Parameters other than the translations (these have priors)."""
        return self.size - 3 * len(self.i_T)

    def view_columns(self, i: int) -> np.ndarray:
        """Global indices of the columns of view ``i``'s local Jacobian (common first)."""
        cols = list(range(self.n_common))
        if i in self.i_vrot:
            cols += range(self.i_vrot[i], self.i_vrot[i] + 3)
        if i in self.i_T:
            cols += range(self.i_T[i], self.i_T[i] + 3)
        return np.array(cols)

    def names(self) -> tuple:
        names = list(self.intr_names) + [DIST_NAMES[k] for k in self.dist_free] + ["rx", "ry", "rz"]
        names += ["t_x", "t_y", "t_z"][: self.n_t] if self.n_t == 3 else [f"t_{k}" for k in range(self.n_t)]
        for i in self.i_vrot:
            names += [f"view{i}_rx", f"view{i}_ry", f"view{i}_rz"]
        for i in self.i_T:
            names += [f"T{i}_x", f"T{i}_y", f"T{i}_z"]
        return tuple(names)

    def rotation_mask(self) -> np.ndarray:
        """(size,) bool: parameters that are rotation angles (reported in degrees)."""
        m = np.zeros(self.size, bool)
        m[self.i_rot: self.i_rot + 3] = True
        for s in self.i_vrot.values():
            m[s: s + 3] = True
        return m


def dist_indices(model: str, fix=()) -> tuple:
    """Free coefficients of distortion ``model`` (indices into OpenCV's five), less ``fix``."""
    return tuple(DIST_NAMES.index(k) for k in DIST_MODELS[model] if k not in fix)


@dataclass
class State:
    """Current estimate. ``X`` holds only the used points; ``F`` None means identity."""

    intr: np.ndarray  # (5,) fx, fy, cx, cy, skew
    dist5: np.ndarray  # (5,) k1, k2, p1, p2, k3
    R: np.ndarray  # (3, 3)
    Q: np.ndarray  # (n_views, 3, 3) model-violation rotations, identity by default
    T: np.ndarray  # (n_views, 3)
    X: np.ndarray  # (n_used, 3)
    F: np.ndarray | None = None  # (n_views, 3, 3) known per-view rotations (sessions)
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) offset (hand-eye)

    def copy(self) -> "State":
        return State(self.intr.copy(), self.dist5.copy(), self.R.copy(), self.Q.copy(), self.T.copy(),
                     self.X.copy(), self.F, self.t.copy())


@dataclass
class Data:
    """Observations grouped by view: ``pts[i]`` indexes the used points seen in view i.

    Views seeing most points are also kept as full arrays over *all* used points with a
    mask (``full_uv``, ``full_seen``): contiguous arrays instead of a gather/scatter per
    accumulated quantity.
    """

    pts: list  # of (n_i,) int
    uv: list  # of (2, n_i) float
    T_meas: np.ndarray  # (n_views, 3)
    t_weight: np.ndarray  # (n_views,) sigma_px / sigma_T_i for free translations (else 0)
    n_points: int  # used points
    full_uv: list  # of (2, n) float (0 where unseen) or None
    full_seen: list  # of (n,) bool or None

    @property
    def n_obs(self) -> int:
        return int(sum(len(p) for p in self.pts))

    def points(self, lo: int, hi: int) -> "Data":
        """The observations of the used points ``lo <= j < hi`` (renumbered from 0)."""
        cuts = [np.searchsorted(p, (lo, hi)) for p in self.pts]
        return Data(pts=[p[a:b] - lo for p, (a, b) in zip(self.pts, cuts)],
                    uv=[u[:, a:b] for u, (a, b) in zip(self.uv, cuts)], T_meas=self.T_meas, t_weight=self.t_weight,
                    n_points=hi - lo, full_uv=[None if f is None else f[:, lo:hi] for f in self.full_uv],
                    full_seen=[None if f is None else f[lo:hi] for f in self.full_seen])

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """Every view's observations over all points: ``uv (2, n_views, n)`` (0 where
        unseen) and ``seen (n_views, n)`` bool."""
        uv, seen = np.zeros((2, len(self.pts), self.n_points)), np.zeros((len(self.pts), self.n_points), bool)
        for i, (pts, obs, full) in enumerate(zip(self.pts, self.uv, self.full_uv)):
            if full is not None:
                uv[:, i], seen[i] = full, self.full_seen[i]
            else:
                uv[:, i, pts], seen[i, pts] = obs, True
        return uv, seen

    def dense_weights(self, weights: list) -> np.ndarray:
        """Per-view weights over the observations ``(n_i,)`` as ``(n_views, n)`` (0 where unseen)."""
        out = np.zeros((len(self.pts), self.n_points))
        for i, (pts, w) in enumerate(zip(self.pts, weights)):
            out[i, pts] = w
        return out


def build_data(uv, seen, used_idx, T_meas, t_weight) -> Data:
    """Group the observations ``seen (V, n_all)`` of the points ``used_idx`` by view."""
    pts, obs, full_uv, full_seen = [], [], [], []
    n = len(used_idx)
    for i in range(uv.shape[0]):
        mask = seen[i, used_idx]
        sel = np.flatnonzero(mask)
        pts.append(sel)
        dense = _DENSE_FRACTION * n <= len(sel)
        if dense:  # one gather of the view; a second one only when some points are unseen
            full = np.where(mask, uv[i, used_idx].T, 0.0)  # (2, n)
            obs.append(full if len(sel) == n else full[:, sel])
        else:
            obs.append(np.ascontiguousarray(uv[i, used_idx[sel]].T))  # (2, n_i)
        partial = dense and len(sel) < n
        full_uv.append(full if partial else None)
        full_seen.append(mask if partial else None)
    return Data(pts=pts, uv=obs, T_meas=T_meas, t_weight=t_weight, n_points=n, full_uv=full_uv,
                full_seen=full_seen)


# ----------------------------------------------------------------------------------------
# Model and Jacobians of one view
# ----------------------------------------------------------------------------------------


def predict_view(state: State, lay: Layout, i: int, pts, jacobian: bool = True, valid=None):
    """Predicted pixels of the used points ``pts`` in view ``i`` and their Jacobians.

    Arrays are laid out with the points last. ``pts`` is an index array or
    ``slice(None)``; with ``valid`` (n,) bool the invalid points get depth 1 in the
    divisions (finite, meaningless values that enter with weight 0).

    Returns
    -------
    pred : (2, n) float
    z : (n,) float
        Camera depth (must be positive).
    Jg : (q, 2, n) float
        d pred / d (global parameters of this view), columns ``lay.view_columns(i)``.
    JX : (3, 2, n) float
        d pred / d X_j.
    """
    if not isinstance(pts, slice) and len(pts) == len(state.X):  # every point, in order: no gather
        pts = slice(None)
    d = (state.X[pts] - state.T[i]).T  # (3, n)
    y = d if state.F is None else state.F[i] @ d
    if lay.t_free or np.any(state.t):
        y = y - state.t[:, None]
    y2 = state.R @ y
    Q = state.Q[i]
    xc = Q @ y2 if lay.rot_views else y2
    p = project_camera_frame(state.intr, state.dist5, xc, jacobian=jacobian, valid=valid,
                             dist_jacobian=lay.dist_free)
    if not jacobian:
        return p.pred, xc[2], None, None
    n = y.shape[1]
    q = lay.n_common + 3 * (i in lay.i_vrot) + 3 * (i in lay.i_T)
    Jg = np.empty((q, 2, n))
    Jg[: lay.n_intr] = p.intrinsic_jacobian(lay.intr_basis)
    if lay.dist_free:
        Jg[lay.i_dist: lay.i_rot] = p.J_dist
    PQ = np.einsum("kcn,cd->kdn", p.P, Q) if lay.rot_views else p.P  # d pred / d y2
    # R <- exp([w]x) R: d y2 / dw = -[y2]x, and a^T (-[y2]x) = (y2 x a)^T
    _cross_rows(y2, PQ, Jg[lay.i_rot: lay.i_rot + 3])
    PQR = np.einsum("kcn,cd->dkn", PQ, state.R)  # d pred / d y  (3, 2, n)
    JX = PQR if state.F is None else np.einsum("dkn,de->ekn", PQR, state.F[i])
    if lay.t_free:  # d pred / dp = -PQR B
        Jg[lay.i_t: lay.i_t + lay.n_t] = -np.einsum("dkn,dp->pkn", PQR, lay.t_basis)
    col = lay.n_common
    if i in lay.i_vrot:  # Q_i <- exp([w_i]x) Q_i: d xc / dw_i = -[xc]x
        _cross_rows(xc, p.P, Jg[col: col + 3])
        col += 3
    if i in lay.i_T:
        Jg[col: col + 3] = -JX
    return p.pred, xc[2], Jg, JX


def _cross_rows(v: np.ndarray, A: np.ndarray, out: np.ndarray) -> None:
    """``out[:, k, n] = v[:, n] x A[k, :, n]`` for v (3, n), A (2, 3, n), out (3, 2, n)."""
    for k in range(2):
        a = A[k]
        out[0, k] = v[1] * a[2] - v[2] * a[1]
        out[1, k] = v[2] * a[0] - v[0] * a[2]
        out[2, k] = v[0] * a[1] - v[1] * a[0]


# ----------------------------------------------------------------------------------------
# Losses, cost, residuals
# ----------------------------------------------------------------------------------------


def loss_weights(e2: np.ndarray, loss: str, c: float):
    """``rho(e^2)`` and the IRLS weight ``w = d rho / d(e^2)`` (cost = sum rho / 2) of the
    residual norm ``e`` (px): linear ``e^2``; Huber ``e^2`` (e <= c) else ``2 c e - c^2``;
    Cauchy ``c^2 log(1 + e^2 / c^2)``."""
    if loss == "linear":
        return e2, np.ones_like(e2)
    c2 = c * c
    if loss == "huber":
        e = np.sqrt(e2)
        inside = e <= c
        return np.where(inside, e2, 2.0 * c * e - c2), np.where(inside, 1.0, c / np.maximum(e, 1e-300))
    return c2 * np.log1p(e2 / c2), 1.0 / (1.0 + e2 / c2)


def _view_residuals(state, lay, data, i):
    """Residuals ``(2, n_i)`` and depths ``(n_i,)`` of view ``i``, :data:`BLOCK_POINTS`
    points at a time (small temporaries: several times faster at 10^6 points)."""
    pts = data.pts[i]
    r, z = np.empty((2, len(pts))), np.empty(len(pts))
    for lo in range(0, len(pts), BLOCK_POINTS):
        b = slice(lo, lo + BLOCK_POINTS)
        pred, z[b], _, _ = predict_view(state, lay, i, pts[b], jacobian=False)
        np.subtract(data.uv[i][:, b], pred, out=r[:, b])
    return r, z


def view_residuals(state: State, lay: Layout, data: Data) -> list | None:
    """Residuals ``(2, n_i)`` of every view's observations, or None if a point is behind
    the camera (a depth <= 0) in some view."""
    if _all_views_at_once(state, lay, data):
        return _residuals_all_views(state, data)
    out = []
    for i in range(len(data.pts)):
        r, z = _view_residuals(state, lay, data, i)
        if not np.all(z > 0):
            return None
        out.append(r)
    return out


def _all_views_at_once(state: State, lay: Layout, data: Data) -> bool:
    """One pure-translation session whose views see most of the points: every view is
    handled in the same numpy calls (:mod:`transcalib.estimate.translation_block`), with
    temporaries of ``n_views x n_points`` (unseen included). From tens of points to a
    few thousand that is 1-4x faster than view by view, and as fast beyond."""
    return translation_block.applies(state, lay) and data.n_obs >= _DENSE_FRACTION * len(data.pts) * data.n_points


def _residuals_all_views(state: State, data: Data) -> list | None:
    """:func:`view_residuals` with every view projected at once, :data:`BLOCK_POINTS`
    points at a time."""
    out = [np.empty((2, len(p))) for p in data.pts]
    for lo in range(0, data.n_points, BLOCK_POINTS):
        hi = min(lo + BLOCK_POINTS, data.n_points)
        part = data.points(lo, hi)
        uv, seen = part.dense()
        r = translation_block.residuals(replace(state, X=state.X[lo:hi]), uv, seen)
        if r is None:
            return None
        for i, (pts, local) in enumerate(zip(data.pts, part.pts)):
            a = np.searchsorted(pts, lo)
            out[i][:, a: a + len(local)] = r[:, i, local]
    return out


def _rho_sum(r: np.ndarray, loss: str, c: float) -> float:
    """``sum rho(|r|^2)`` of residuals ``r (2, m)``."""
    e2 = r[0] ** 2 + r[1] ** 2
    return float(np.sum(e2 if loss == "linear" else loss_weights(e2, loss, c)[0]))


def _prior_cost(state: State, data: Data) -> float:
    """``sum_i t_w_i^2 |T_i - T_i^meas|^2`` (twice the translation priors' cost)."""
    dT = (state.T - data.T_meas) * data.t_weight[:, None]
    return float(np.sum(dT * dT))


def cost(state: State, lay: Layout, data: Data, loss: str, c: float, residuals: list | None = None) -> float:
    """``0.5 sum rho(|r_ij|^2) + 0.5 sum_i t_w_i^2 |T_i - T_i^meas|^2``; inf if a depth <= 0.
    ``residuals``: those of :func:`view_residuals` at ``state``, when already known."""
    residuals = view_residuals(state, lay, data) if residuals is None else residuals
    if residuals is None:
        return np.inf
    return 0.5 * (sum(_rho_sum(r, loss, c) for r in residuals) + _prior_cost(state, data))


def sum_sq(state, lay, data, loss="linear", thr=np.inf) -> float:
    """Sum of squared pixel residuals of ``data`` (with a robust loss: of the observations
    whose norm is at most ``thr``)."""
    total = 0.0
    for i, pts in enumerate(data.pts):
        if len(pts):
            r = _view_residuals(state, lay, data, i)[0]
            e2 = r[0] ** 2 + r[1] ** 2
            total += float(np.sum(e2 if loss == "linear" else e2[e2 <= thr * thr]))
    return total


def all_residuals(state, lay, uv, seen, used_idx, T) -> np.ndarray:
    """Residuals ``(n_views, n_used, 2)`` of the used points, NaN where unseen."""
    data = build_data(uv, seen, used_idx, T, np.zeros(len(T)))
    out = np.full((len(T), len(used_idx), 2), np.nan)
    for i, pts in enumerate(data.pts):
        if len(pts):
            out[i, pts] = _view_residuals(state, lay, data, i)[0].T
    return out


# ----------------------------------------------------------------------------------------
# Normal equations and the Schur step
# ----------------------------------------------------------------------------------------


def _view_system(state, lay, data, i, loss, c, obs_weight):
    """Residuals, weights and Jacobians of view ``i`` over its points (or all points with a
    mask): ``(r (2, m), w (m,) or None for ones, Jg, JX, pts, rho)`` with ``rho`` the sum
    of the loss over the view's observations (inf if one of them is behind the camera)."""
    n, seen = data.n_points, data.full_seen[i]
    if seen is None:
        pred, z, Jg, JX = predict_view(state, lay, i, data.pts[i], True)
        r = data.uv[i] - pred
        rho = _rho_sum(r, loss, c) if np.all(z > 0) else np.inf
        if obs_weight is not None:
            return r, obs_weight[i], Jg, JX, data.pts[i], rho
        w = None if loss == "linear" else loss_weights(r[0] ** 2 + r[1] ** 2, loss, c)[1]
        return r, w, Jg, JX, data.pts[i], rho
    pred, z, Jg, JX = predict_view(state, lay, i, slice(None), True, valid=seen)
    r = (data.full_uv[i] - pred) * seen
    rho = _rho_sum(r, loss, c) if np.all((z > 0) | ~seen) else np.inf  # rho(0) = 0 where unseen: no gather
    if obs_weight is None:
        w = loss_weights(r[0] ** 2 + r[1] ** 2, loss, c)[1] * seen
    else:
        w = np.zeros(n)
        w[data.pts[i]] = obs_weight[i]
    return r, w, Jg, JX, np.arange(n), rho


class NormalEquations(NamedTuple):
    """``[[U, W], [W^T, V]] [dg; dX] = [b_g; b_X]`` (points last) and the cost at the
    linearisation point (``0.5 sum rho``, inf if a point is behind the camera; without
    the translation priors unless they were included)."""

    U: np.ndarray  # (p, p)
    W: np.ndarray  # (p, 3, n)
    V: np.ndarray  # (3, 3, n)
    bg: np.ndarray  # (p,)
    bX: np.ndarray  # (3, n)
    cost: float


def normal_equations(state, lay, data, loss="linear", c=1.0, obs_weight=None, priors: bool = True) -> NormalEquations:
    """Assemble the Gauss-Newton normal equations (IRLS weights for a robust loss), with
    every view at once where that applies (:func:`_all_views_at_once`) and the problem
    is small, else view by view (:func:`reduced_system` assembles large problems block
    by block).

    ``obs_weight``: optional list of (n_i,) weights replacing the loss's IRLS weights
    (the covariance uses ones). ``priors``: include the translation priors (once per
    system: not in each block of points).
    """
    # every view at once while its temporaries stay small (Levenberg-Marquardt on a subset)
    at_once = data.n_points <= 2 * BLOCK_POINTS and _all_views_at_once(state, lay, data)
    with one_blas_thread():  # small products: BLAS's threads would only spin
        U, W, V, bg, bX, cost = (_all_views if at_once else _view_by_view)(state, lay, data, loss, c, obs_weight)
    if priors:
        _add_priors(U, bg, state, lay, data)
        cost += 0.5 * _prior_cost(state, data)
    return NormalEquations(U, W, V, bg, bX, cost)


def _all_views(state, lay, data, loss, c, obs_weight):
    """:func:`normal_equations` without priors, every view at once
    (:func:`transcalib.estimate.translation_block.normal_equations`; the same equations)."""
    uv, seen = data.dense()
    weight = None if obs_weight is None else data.dense_weights(obs_weight)
    return translation_block.normal_equations(state, lay, uv, seen, weight, loss, c, loss_weights)


def _view_by_view(state, lay, data, loss, c, obs_weight):
    """:func:`normal_equations` without priors, one view at a time (any layout)."""
    p, n = lay.size, data.n_points
    U, W, V = np.zeros((p, p)), np.zeros((p, 3, n)), np.zeros((3, 3, n))
    bg, bX = np.zeros(p), np.zeros((3, n))
    rho = 0.0
    for i in range(len(data.pts)):
        if len(data.pts[i]) == 0:
            continue
        r, w, Jg, JX, pts, rho_i = _view_system(state, lay, data, i, loss, c, obs_weight)
        rho += rho_i
        cols = lay.view_columns(i)
        q = len(cols)
        Jw, JXw = (Jg, JX) if w is None else (Jg * w, JX * w)
        U[np.ix_(cols, cols)] += Jw.reshape(q, -1) @ Jg.reshape(q, -1).T
        bg[cols] += Jw.reshape(q, -1) @ r.reshape(-1)
        # sums over the two rows of each observation, one row of a block at a time
        at = slice(None) if len(pts) == n else pts  # every used point seen: no scatter
        for a in range(3):
            for b in range(a, 3):
                V[a, b, at] += JXw[a, 0] * JX[b, 0] + JXw[a, 1] * JX[b, 1]
            bX[a, at] += JXw[a, 0] * r[0] + JXw[a, 1] * r[1]
        for la, ga in enumerate(cols):
            for d in range(3):
                W[ga, d, at] += Jw[la, 0] * JX[d, 0] + Jw[la, 1] * JX[d, 1]
    for a in range(3):
        for b in range(a):
            V[a, b] = V[b, a]
    return U, W, V, bg, bX, 0.5 * rho


def _add_priors(U, bg, state, lay, data) -> None:
    """Translation priors into ``U``, ``b_g``: residual ``t_w (T^meas - T)``, Jacobian ``t_w I``."""
    for i, s in lay.i_T.items():
        tw2 = data.t_weight[i] ** 2
        U[s: s + 3, s: s + 3] += tw2 * np.eye(3)
        bg[s: s + 3] += tw2 * (data.T_meas[i] - state.T[i])


def inv3_spd(V: np.ndarray):
    """Inverses of symmetric positive definite 3x3 blocks ``V (3, 3, n)``, vectorised.

    Jacobi-scaled adjugate: ``V^-1 = D (D V D)^-1 D`` with ``D = diag(V)^-1/2``. Returns
    the inverses ``(3, 3, n)`` and the determinants of the scaled blocks ``(n,)``.
    """
    d = 1.0 / np.sqrt(np.maximum(np.stack([V[0, 0], V[1, 1], V[2, 2]]), 1e-300))
    A = V * d[:, None] * d[None, :]
    a, b, c = A[0, 0], A[0, 1], A[0, 2]
    e, f, h = A[1, 1], A[1, 2], A[2, 2]
    c00, c01, c02 = e * h - f * f, c * f - b * h, b * f - c * e
    c11, c12, c22 = a * h - c * c, b * c - a * f, a * e - b * b
    det = a * c00 + b * c01 + c * c02
    idet = 1.0 / np.where(det > 0, det, 1.0)
    inv = np.array([[c00, c01, c02], [c01, c11, c12], [c02, c12, c22]]) * idet
    return inv * d[:, None] * d[None, :], det


def matvec3(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``M_j v_j`` for M (3, 3, n), v (3, n)."""
    return M[:, 0] * v[0] + M[:, 1] * v[1] + M[:, 2] * v[2]


def schur(U, W, V, bg, bX):
    """Reduced system ``S dg = rhs`` with the points eliminated, and ``V^-1``.

    ``S = U - sum_j W_j V_j^-1 W_j^T``, ``rhs = b_g - sum_j W_j V_j^-1 b_j``; returns
    ``S, rhs, V^-1, det`` (scaled determinants of the point blocks) and ``Y = W V^-1
    (p, 3, n)``.
    """
    Vinv, det = inv3_spd(V)
    p = U.shape[0]
    Y = np.einsum("pdn,den->pen", W, Vinv)  # W_j V_j^-1
    S = U - Y.reshape(p, -1) @ W.reshape(p, -1).T
    rhs = bg - Y.reshape(p, -1) @ bX.reshape(-1)
    return 0.5 * (S + S.T), rhs, Vinv, det, Y


#: Points per block of :func:`reduced_system` (its temporaries stay in the CPU cache).
BLOCK_POINTS = 8192
#: Threads of :func:`reduced_system`: the cores of the machine, at most 4.
THREADS = min(4, os.cpu_count() or 1)


@dataclass(frozen=True, eq=False)
class Reduced:
    """The normal equations with the points eliminated (:func:`reduced_system`).

    ``S dg = rhs`` for the global parameters; per point ``V_j^-1`` (3, 3, n), ``Y_j =
    W_j V_j^-1`` (p, 3, n), ``b_j`` (3, n) and the scaled determinants ``det`` (n,) of
    ``V_j``: the points' step is ``dX_j = V_j^-1 b_j - Y_j^T dg`` and, with ``Sinv =
    S^-1``, their covariance ``V_j^-1 + Y_j^T Sinv Y_j`` (module docstring). ``cost``:
    the cost at the linearisation point (:func:`cost`; inf if a point is behind the camera).
    ``U_diag (p,)``: the information of each global parameter with the points held fixed
    (the diagonal of ``U``), the scale for deciding whether ``S`` is singular: in an
    undetermined direction ``S`` is a difference of large sums, rounding noise at the
    scale of ``U``, not of itself.
    """

    S: np.ndarray
    rhs: np.ndarray
    Vinv: np.ndarray
    Y: np.ndarray
    bX: np.ndarray
    det: np.ndarray
    cost: float
    U_diag: np.ndarray

    def point_step(self, dg: np.ndarray) -> np.ndarray:
        """``dX (3, n)`` given the global step ``dg (p,)``."""
        return np.einsum("abn,bn->an", self.Vinv, self.bX) - np.tensordot(dg, self.Y, axes=1)

    def point_variances(self, Sinv: np.ndarray) -> np.ndarray:
        """Diagonal of each point's covariance ``(n, 3)`` (unit noise) given ``S^-1``:
        ``diag(V_j^-1) + |L^T Y_j|^2`` column-wise, with ``S^-1 = L L^T``."""
        p, n = self.Y.shape[0], self.Y.shape[2]
        L = _psd_factor(Sinv)
        out = np.empty((3, n))
        for a in range(3):
            LY = L.T @ self.Y[:, a]  # (p, n)
            out[a] = self.Vinv[a, a] + np.einsum("pn,pn->n", LY, LY)
        return out.T


def one_blas_thread():
    """A context in which BLAS runs on one thread (``threadpoolctl``): the products of
    the assembly are small, and BLAS's own threads would spin on the cores that numpy
    and :func:`reduced_system`'s threads use."""
    return _blas_threads().limit(limits=1, user_api="blas")


@functools.cache
def _blas_threads():
    """The BLAS libraries' thread pools (looked up once: 0.3 ms)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def _psd_factor(M: np.ndarray) -> np.ndarray:
    """``L`` with ``L L^T = M`` for a symmetric positive semi-definite ``M`` (from its
    eigen-decomposition: exact for singular ``M`` too)."""
    w, V = np.linalg.eigh(M)
    return V * np.sqrt(np.maximum(w, 0.0))


def reduced_system(state, lay, data, loss="linear", c=1.0, obs_weight=None, ok=None,
                   out: Reduced | None = None) -> Reduced:
    """The Schur-reduced normal equations of all points, assembled :data:`BLOCK_POINTS`
    points at a time (the Schur complement is a sum over points): the same system as
    :func:`normal_equations` then :func:`schur`, with small temporaries. The blocks run
    on :data:`THREADS` threads (numpy releases the GIL in its loops); their sums are
    added in block order, so the result does not depend on the threads.

    ``obs_weight``: per-view weights as in :func:`normal_equations`; ``ok (n,)`` bool:
    the points that count (the others are left out of ``S``; their ``V`` is the
    identity, their ``Y`` zero). ``out``: a system of the same problem whose per-point
    arrays are no longer needed and are overwritten (hundreds of megabytes at 10^6
    points, which a new allocation pays for again in page faults).
    """
    p, n = lay.size, data.n_points
    if out is not None and out.Y.shape == (p, 3, n):
        Vinv, Y, bX, det = out.Vinv, out.Y, out.bX, out.det
    else:
        Vinv, Y, bX, det = np.empty((3, 3, n)), np.empty((p, 3, n)), np.empty((3, n)), np.empty(n)

    def block_weights(lo: int, hi: int, part: Data):
        """Per-view weights of the block's observations (None: ones), ``ok`` applied."""
        weights = None
        if obs_weight is not None:
            weights = [w[slice(*np.searchsorted(pts, (lo, hi)))] for w, pts in zip(obs_weight, data.pts)]
        if ok is not None:
            keep = ok[lo:hi]
            weights = [keep[q] * (1.0 if weights is None else weights[i]) for i, q in enumerate(part.pts)]
        return weights

    assemble = _all_views if _all_views_at_once(state, lay, data) else _view_by_view

    def block(lo: int):
        """Fill the block's per-point arrays; return its shares of ``S``, ``rhs``, the
        cost and the diagonal of ``U``."""
        hi = min(lo + BLOCK_POINTS, n)
        part, at = data.points(lo, hi), slice(lo, hi)
        U, W, V, bg, bX[:, at], cost_b = assemble(replace(state, X=state.X[lo:hi]), lay, part, loss, c,
                                                  block_weights(lo, hi, part))
        if ok is not None:
            for a in range(3):
                V[a, a, ~ok[lo:hi]] = 1.0  # left out: W is zero there
        S_b, rhs_b, Vinv[:, :, at], det[at], Y[:, :, at] = schur(U, W, V, bg, bX[:, at])
        return S_b, rhs_b, cost_b, np.diag(U).copy()

    starts = range(0, n, BLOCK_POINTS)
    # the blocks' small products on one BLAS thread each: BLAS's own threads would spin
    # on the same cores as ours
    with one_blas_thread():
        if THREADS > 1 and len(starts) > 1:
            with ThreadPoolExecutor(THREADS) as pool:
                parts = list(pool.map(block, starts))
        else:
            parts = [block(lo) for lo in starts]
    S, rhs, total, U_diag = np.zeros((p, p)), np.zeros(p), 0.0, np.zeros(p)
    for S_b, rhs_b, cost_b, U_b in parts:
        S += S_b
        rhs += rhs_b
        total += cost_b
        U_diag += U_b
    priors = np.zeros((p, p))
    _add_priors(priors, rhs, state, lay, data)
    return Reduced(S + priors, rhs, Vinv, Y, bX, det, total + 0.5 * _prior_cost(state, data), U_diag + np.diag(priors))


def solve_spd(S: np.ndarray, rhs: np.ndarray):
    """Solve ``S x = rhs`` (Jacobi-scaled Cholesky); None if not positive definite."""
    d = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))
    try:
        L = np.linalg.cholesky(S * d[:, None] * d[None, :])
    except np.linalg.LinAlgError:
        return None
    return d * np.linalg.solve(L.T, np.linalg.solve(L, rhs * d))


def apply_step(state: State, lay: Layout, dg: np.ndarray, dX: np.ndarray) -> State:
    """The state moved by ``dg`` (global, layout order) and ``dX (3, n)``."""
    new = state.copy()
    new.intr += lay.intr_basis @ dg[: lay.n_intr]
    new.dist5[list(lay.dist_free)] += dg[lay.i_dist: lay.i_rot]
    new.R = rotvec_to_matrix(dg[lay.i_rot: lay.i_rot + 3]) @ state.R
    if lay.t_free:
        new.t += lay.t_basis @ dg[lay.i_t: lay.i_t + lay.n_t]
    for i, s in lay.i_vrot.items():
        new.Q[i] = rotvec_to_matrix(dg[s: s + 3]) @ state.Q[i]
    for i, s in lay.i_T.items():
        new.T[i] += dg[s: s + 3]
    new.X += dX.T
    return new


# ----------------------------------------------------------------------------------------
# Levenberg-Marquardt
# ----------------------------------------------------------------------------------------


def _damped_step(state, f, lay, data, system, mu, loss, c):
    """One damped Schur step from ``state`` (cost ``f``): ``(new_state, new_cost, gain)``,
    gain < 0 if rejected."""
    U, W, V, bg, bX, _ = system
    dU = np.maximum(np.diag(U), 1e-12 * max(np.diag(U).max(), 1e-300))
    dV = np.stack([V[0, 0], V[1, 1], V[2, 2]])  # (3, n)
    dV = np.maximum(dV, 1e-12 * dV.max(axis=0))
    Vd = V.copy()
    for a in range(3):
        Vd[a, a] += mu * dV[a]
    S, rhs, Vinv, det, _ = schur(U + np.diag(mu * dU), W, Vd, bg, bX)
    dg = solve_spd(S, rhs) if np.all(det > 0) else None
    if dg is None:
        return None, np.inf, -1.0
    dX = matvec3(Vinv, bX - np.tensordot(dg, W, axes=1))  # (3, n)
    new = apply_step(state, lay, dg, dX)
    new_cost = cost(new, lay, data, loss, c)
    # decrease predicted by the damped quadratic model
    predicted = 0.5 * (dg @ (mu * dU * dg + bg) + np.sum(dX * (mu * dV * dX + bX)))
    gain = (f - new_cost) / predicted if predicted > 0 else -1.0
    return new, new_cost, gain


def gauss_newton(state, lay, data, loss="linear", c=1.0, steps: int = 2, tol=1e-6, progress=None):
    """Undamped Gauss-Newton steps from a start near the solution (the fit of a subset of
    the points), each on the block-wise reduced system (:func:`reduced_system`: small
    temporaries at any number of points), which also gives the cost at its state: a
    step is checked by the next step's system, the last by the residuals at the
    solution. A step that does not lower the cost hands over to
    :func:`levenberg_marquardt`.

    Returns ``(state, cost, iterations, stop reason, system, residuals)`` with ``system``
    the :class:`Reduced` system of the last step (linearised one step before the
    returned state) and ``residuals`` those of :func:`view_residuals` at the returned
    state (both None after Levenberg-Marquardt).
    """
    red = reduced_system(state, lay, data, loss, c)
    f = red.cost
    if not np.isfinite(f):
        raise DegenerateError("the initial estimate puts some used points behind the camera; "
                              "start from a better initial estimate (e.g. the linear one)")
    system = residuals = None
    for it in range(steps):
        dg = solve_spd(red.S, red.rhs) if np.all(red.det > 0) else None
        new = None if dg is None else apply_step(state, lay, dg, red.point_step(dg))
        last = it == steps - 1
        if new is None:
            new_f = np.inf
        elif last:
            residuals = view_residuals(new, lay, data)
            new_f = cost(new, lay, data, loss, c, residuals)
        else:  # the arrays of this step's system are free once the step is taken
            new_red = reduced_system(new, lay, data, loss, c, out=red)
            new_f = new_red.cost
        if not new_f < f:
            state, f, more, reason = levenberg_marquardt(state, lay, data, loss, c, steps - it, tol, progress)
            return state, f, it + more, reason, None, None
        state, f = new, new_f
        if last:
            system = red
        else:
            red = new_red
        if progress is not None:
            progress({"iteration": it + 1, "cost": f, "damping": 0.0})
    return state, f, steps, f"{steps} Gauss-Newton step(s)", system, residuals


def levenberg_marquardt(state, lay, data, loss="linear", c=1.0, max_iterations=100, tol=1e-6, progress=None):
    """Minimise the (robust) cost; returns ``(state, cost, iterations, stop reason)``.

    Stops when a step decreases the cost by less than ``tol * sigma^2`` with
    ``sigma^2 = 2 cost / dof`` (the parameters moved by about ``sqrt(2 tol)`` standard
    deviations), when no step decreases it, or at zero residual.
    """
    f = cost(state, lay, data, loss, c)
    if not np.isfinite(f):
        raise DegenerateError("the initial estimate puts some used points behind the camera; "
                              "start from a better initial estimate (e.g. the linear one)")
    mu, nu = _MU0, 2.0
    reason = f"max_iterations ({max_iterations}) reached"
    floor = 1e-24 * max(data.n_obs, 1)  # residuals ~1e-12 px: exact data
    dof = max(2 * data.n_obs - lay.n_global_no_T - 3 * data.n_points, 1)
    it = 0
    while it < max_iterations:
        if f <= floor:
            reason = "converged: zero residual"
            break
        system = normal_equations(state, lay, data, loss, c)
        while True:
            new, new_f, gain = _damped_step(state, f, lay, data, system, mu, loss, c)
            if gain > 0:
                mu *= max(_MU_SHRINK, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
                break
            mu *= nu
            nu *= 2.0
            if mu > 1e16:
                return state, f, it, "converged: no step decreases the cost (minimum within numerical precision)"
        it += 1
        decrease = f - new_f
        state, f = new, new_f
        if progress is not None:
            progress({"iteration": it, "cost": f, "damping": mu})
        if decrease <= tol * 2.0 * f / dof:
            reason = f"converged: cost decrease below tol={tol:g} x sigma^2"
            break
    return state, f, it, reason
