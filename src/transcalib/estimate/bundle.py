"""The one bundle adjuster's model: residuals, Jacobians and normal equations of every motion.

Residual of observation ``(i, j)`` (paper eq. 2 with OpenCV distortion)::

    r_ij = uv_ij - pi(K, dist, Q_i R (F_i (X_j - T_i) - t))

with ``R`` the camera rotation, ``F_i`` a known per-view rotation (identity inside one
pure-translation session; ``R_i^T`` of the flange for several sessions, then ``R`` is
``R_X^T`` and ``t`` the camera's position in the flange ``t_X``), ``Q_i = exp([w_i]x)``
an optional model-violation rotation of view ``i`` (rotation test) and ``T_i`` the
translation, optionally a noisy measurement with prior ``|T_i - T_i^meas|^2 / sigma_T^2``.
``pi`` is :func:`transcalib.geometry.camera.project_camera_frame`, the project's only
projection. The parameters are laid out by :class:`~transcalib.estimate.layout.Layout`.

The Jacobian has one 2x3 block per observation for its point, so the normal matrix is
``[[U, W], [W^T, V]]`` with ``V`` block-diagonal, and the points are eliminated by the
Schur complement (:mod:`transcalib.estimate.schur`): O(n) time and memory.
:class:`BundleProblem` offers the model to the generic solvers
(:mod:`transcalib.estimate.solvers`).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from ..geometry.camera import project_camera_frame
from . import observations, robot_error, translation_block
from .layout import Layout, State
from .observations import Data, build_data
from .schur import NormalEquations, Reduced, one_blas_thread, schur

#: Points per block of :func:`reduced_system` (its temporaries stay in the CPU cache).
BLOCK_POINTS = 8192
#: Threads of :func:`reduced_system`: the cores of the machine, at most 4.
THREADS = min(4, os.cpu_count() or 1)


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
    if lay.i_robot or (state.E is not None and np.any(state.E[i])):  # the view's pose error (robot_error)
        Xp = state.X[pts].T
        e = np.zeros(6) if state.E is None else state.E[i]
        y, M = robot_error.flange_points(Xp, state.T[i], None if state.F is None else state.F[i], e,
                                         lay.robot_inverted)
    else:
        d = (state.X[pts] - state.T[i]).T  # (3, n)
        y = d if state.F is None else state.F[i] @ d
        M = state.F[i] if state.F is not None else None
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
    q = lay.n_common + 3 * (i in lay.i_vrot) + 3 * (i in lay.i_T) + lay.n_robot * (i in lay.i_robot)
    Jg = np.empty((q, 2, n))
    Jg[: lay.n_intr] = p.intrinsic_jacobian(lay.intr_basis)
    if lay.dist_free:
        Jg[lay.i_dist: lay.i_rot] = p.J_dist
    PQ = np.einsum("kcn,cd->kdn", p.P, Q) if lay.rot_views else p.P  # d pred / d y2
    # R <- exp([w]x) R: d y2 / dw = -[y2]x, and a^T (-[y2]x) = (y2 x a)^T
    _cross_rows(y2, PQ, Jg[lay.i_rot: lay.i_rot + 3])
    PQR = np.einsum("kcn,cd->dkn", PQ, state.R)  # d pred / d y  (3, 2, n)
    JX = PQR if M is None else np.einsum("dkn,de->ekn", PQR, M)
    if lay.t_free:  # d pred / dp = -PQR B
        Jg[lay.i_t: lay.i_t + lay.n_t] = -np.einsum("dkn,dp->pkn", PQR, lay.t_basis)
    col = lay.n_common
    if i in lay.i_vrot:  # Q_i <- exp([w_i]x) Q_i: d xc / dw_i = -[xc]x
        _cross_rows(xc, p.P, Jg[col: col + 3])
        col += 3
    if i in lay.i_T:
        Jg[col: col + 3] = -JX
        col += 3
    if i in lay.i_robot:
        robot_error.jacobian(y + state.t[:, None], Xp, PQR, JX, lay.robot_inverted, lay.robot,
                             Jg[col: col + lay.n_robot])
    return p.pred, xc[2], Jg, JX


def _cross_rows(v: np.ndarray, A: np.ndarray, out: np.ndarray) -> None:
    """``out[:, k, n] = v[:, n] x A[k, :, n]`` for v (3, n), A (2, 3, n), out (3, 2, n)."""
    for k in range(2):
        a = A[k]
        out[0, k] = v[1] * a[2] - v[2] * a[1]
        out[1, k] = v[2] * a[0] - v[0] * a[2]
        out[2, k] = v[0] * a[1] - v[1] * a[0]


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
    return translation_block.applies(state, lay) and data.n_obs >= observations.DENSE_FRACTION * len(data.pts) * data.n_points


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
    """``sum_i t_w_i^2 |T_i - T_i^meas|^2 + sum_i (w_rot^2 |delta_i|^2 + w_pos^2 |eps_i|^2)``
    (twice the priors' cost: translations, robot pose errors)."""
    dT = (state.T - data.T_meas) * data.t_weight[:, None]
    total = float(np.sum(dT * dT))
    if state.E is not None:
        w = np.repeat(data.robot_weight, 3)
        total += float(np.sum((state.E * w) ** 2))
    return total


def cost(state: State, lay: Layout, data: Data, loss: str, c: float) -> float:
    """``0.5 sum rho(|r_ij|^2) + 0.5 sum_i t_w_i^2 |T_i - T_i^meas|^2``; inf if a depth <= 0."""
    return _cost(view_residuals(state, lay, data), state, data, loss, c)


def _cost(residuals: list | None, state: State, data: Data, loss: str, c: float) -> float:
    """:func:`cost` from the residuals of :func:`view_residuals` at ``state``."""
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
        block = np.einsum("lkn,dkn->ldn", Jw, JX)  # (q, 3, m): d pred / d cols against d pred / d X
        row = lay.n_common
        W[:row, :, at] += block[:row]
        for starts, size in ((lay.i_vrot, 3), (lay.i_T, 3), (lay.i_robot, lay.n_robot)):  # the view's own columns
            if i in starts:  # (view_columns' order) meet each point once: no sum
                W[starts[i]: starts[i] + size, :, at] = block[row: row + size]
                row += size
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
    for k, comp in enumerate(lay.robot):  # residual w (0 - e), Jacobian w I
        w2 = data.robot_weight[robot_error.COMPONENTS.index(comp)] ** 2
        cols = lay.robot_columns(comp)
        at = slice(0, 3) if comp == "rot" else slice(3, 6)
        U[cols.ravel(), cols.ravel()] += w2
        if state.E is not None:
            bg[cols.ravel()] -= w2 * state.E[:, at].ravel()


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


class BundleProblem:
    """The cost of the observations ``data`` over the parameters of ``lay`` (loss ``loss``
    of scale ``c``, pixels) as the generic solvers take it
    (:class:`transcalib.estimate.solvers.Problem`). A step is ``(dg, dX)``: the global
    parameters in ``lay``'s order and the points ``(3, n)``. The residuals of the last
    state whose cost was asked for are kept (:meth:`residuals`): a converged solve
    reports them without projecting every point again."""

    invalid_start = ("the initial estimate puts some used points behind the camera; "
                     "start from a better initial estimate (e.g. the linear one)")

    def __init__(self, lay: Layout, data: Data, loss: str = "linear", c: float = 1.0):
        self.lay, self.data, self.loss, self.c = lay, data, loss, c
        self.dof = lay.residual_dof(data.n_obs, data.n_points)
        self.zero_cost = 1e-24 * max(data.n_obs, 1)  # residuals ~1e-12 px: exact data
        self._kept = (None, None)

    def residuals(self, state: State) -> list | None:
        """:func:`view_residuals` at ``state`` (None if a point is behind the camera)."""
        if self._kept[0] is not state:
            self._kept = (state, view_residuals(state, self.lay, self.data))
        return self._kept[1]

    def cost(self, state: State) -> float:
        return _cost(self.residuals(state), state, self.data, self.loss, self.c)

    def linearise(self, state: State, damped: bool = True, reuse: Reduced | None = None):
        """The normal equations at ``state`` (:func:`normal_equations`) for damped steps,
        else the reduced system assembled block by block (:func:`reduced_system`, whose
        per-point arrays may overwrite those of ``reuse``)."""
        if damped:
            return normal_equations(state, self.lay, self.data, self.loss, self.c)
        return reduced_system(state, self.lay, self.data, self.loss, self.c, out=reuse)

    def apply(self, state: State, step) -> State:
        dg, dX = step
        return state.moved(self.lay, dg, dX)


def reduced_rows(state: State, lay: Layout, data: Data, Y: np.ndarray, lo: int, hi: int, ok=None) -> list:
    """The Schur-reduced Jacobian rows and residuals of the points ``lo <= j < hi``, view
    by view: the per-point pieces of :func:`reduced_system` that a cluster-robust
    (sandwich) covariance needs (:func:`transcalib.estimate.covariance.sandwich`).

    With ``P_j = I - J_Xj V_j^-1 J_Xj^T`` the projection that eliminates point j, its
    observations' reduced rows are ``P_j J_cj``; for observation ``(i, j)``, with
    ``J_cij (p, 2)`` and ``J_Xij (3, 2)`` the derivatives of its prediction ::

        R_ij = J_cij - Y_j J_Xij        (p x 2,  Y_j = W_j V_j^-1)

    so that ``S_j = sum_i R_ij R_ij^T`` is point j's share of ``S`` and ``g_j = sum_i
    R_ij r_ij`` its reduced score (``J_cj^T r_j - Y_j J_Xj^T r_j``). Unit weights (the
    covariance's), no priors.

    Parameters
    ----------
    Y : (p, 3, n) float
        ``W V^-1`` of the reduced system (:attr:`transcalib.estimate.schur.Reduced.Y`).
    ok : (n,) bool, optional
        Points that count; the others get zero rows.

    Returns
    -------
    list of (R (p, 2, m) float, r (2, m) float px, pts (m,) int)
        Per view with observations in the block: rows (d pred / d global parameters,
        reduced), residuals ``uv - pred`` and the points' indices within the block.
    """
    part = data.points(lo, hi)
    sub = replace(state, X=state.X[lo:hi])
    keep = None if ok is None else ok[lo:hi]
    out = []
    for i in range(len(part.pts)):
        if len(part.pts[i]) == 0:
            continue
        r, w, Jg, JX, pts, _ = _view_system(sub, lay, part, i, "linear", 1.0, None)
        mask = np.ones(len(pts)) if w is None else np.asarray(w, float)
        if keep is not None:
            mask = mask * keep[pts]
        R = np.zeros((lay.size, 2, len(pts)))
        R[lay.view_columns(i)] = Jg
        R -= np.einsum("pdm,dkm->pkm", Y[:, :, lo + pts], JX)
        out.append((R * mask, r * mask, pts))
    return out
