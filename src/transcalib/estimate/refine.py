"""Maximum-likelihood refinement (sparse bundle adjustment), covariance and the CRLB.

The refinement minimises the reprojection error of every observation

    r_ij = uv_ij - pi(K, dist, Q_i R (X_j - T_i))                      (paper eq. 2 + distortion)

over the intrinsics ``(fx, fy, cx, cy[, skew])``, the lens distortion (OpenCV
convention, :func:`transcalib.camera.distort`), the rotation ``R`` (3 parameters, local
update ``R <- exp([w]x) R``), every scene point ``X_j`` and optionally

* the translations ``T_i`` as noisy measurements with standard deviation ``sigma_T``
  (cost term ``|T_i - T_i^meas|^2 / sigma_T^2``, errors in images *and* robot);
* a small rotation ``Q_i = exp([w_i]x)`` per view ``i >= 1`` (view 0 is the reference),
  which models a robot that did not purely translate (DESIGN.md §4, diagnostics).

Levenberg-Marquardt on the normal equations. The Jacobian has one 2x3 block per
observation for its point, so the normal matrix is ``[[U, W], [W^T, V]]`` with ``V``
block-diagonal (one 3x3 block ``V_j`` per point). Each iteration eliminates the points
with the Schur complement

    S = U - sum_j W_j V_j^-1 W_j^T,    S dg = b_g - sum_j W_j V_j^-1 b_j,
    dX_j = V_j^-1 (b_j - W_j^T dg),

which costs O(n) time and memory (batched 3x3 inverses, BLAS products; no loop over
points). The covariance of the global parameters is ``sigma^2 S^-1`` at the solution and
that of each point ``sigma^2 (V_j^-1 + V_j^-1 W_j^T S^-1 W_j V_j^-1)``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..geometry.camera import DIST_MODELS, K_from_params, dist_size
from ..types import Calibration, DegenerateError, InputError, LinearEstimate

__all__ = ["refine", "crlb", "LOSSES"]

#: Robust losses of the refinement, ``rho(e^2)`` of the residual norm ``e = |r_ij|`` (px).
LOSSES = ("linear", "huber", "cauchy")

_DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")
_RAD2DEG = 180.0 / np.pi
_MU0 = 1e-3  # initial LM damping, relative to the diagonal of the normal matrix
_DENSE_FRACTION = 0.5  # views seeing at least this fraction of the points: see _Data


# ----------------------------------------------------------------------------------------
# Problem layout and state
# ----------------------------------------------------------------------------------------


@dataclass
class _Layout:
    """Where each global parameter sits in the vector ``g`` solved for by the Schur step."""

    n_views: int
    n_dist: int
    estimate_skew: bool
    view_rotations: object  # True (views 1..), False, or a sequence of rotated views
    t_free: np.ndarray  # (n_views,) bool: translation i is a parameter

    def __post_init__(self):
        self.n_intr = 5 if self.estimate_skew else 4
        self.i_dist = self.n_intr
        self.i_rot = self.i_dist + self.n_dist
        self.n_common = self.i_rot + 3
        start = self.n_common
        self.view_rotations = _rotated_views(self.view_rotations, self.n_views)
        self.i_vrot = {}
        for i in self.view_rotations:
            self.i_vrot[i] = start
            start += 3
        self.i_T = {}
        for i in np.flatnonzero(self.t_free):
            self.i_T[int(i)] = start
            start += 3
        self.size = start

    def view_columns(self, i: int) -> np.ndarray:
        """Global indices of the columns of view ``i``'s local Jacobian (common first)."""
        cols = list(range(self.n_common))
        if i in self.i_vrot:
            cols += range(self.i_vrot[i], self.i_vrot[i] + 3)
        if i in self.i_T:
            cols += range(self.i_T[i], self.i_T[i] + 3)
        return np.array(cols)

    def names(self) -> tuple:
        names = ["fx", "fy", "cx", "cy"] + (["skew"] if self.estimate_skew else [])
        names += list(_DIST_NAMES[: self.n_dist]) if self.n_dist != 2 else ["k1", "k2"]
        names += ["rx", "ry", "rz"]
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


def _rotated_views(spec, n_views: int) -> tuple:
    """Views with a rotation parameter: ``True`` -> 1..n_views-1, ``False`` -> none, or
    the given view indices (at least one view must stay unrotated, as the reference)."""
    if spec is True:
        return tuple(range(1, n_views))
    if spec is False or spec is None:
        return ()
    try:
        views = sorted({int(v) for v in spec})
    except (TypeError, ValueError):
        raise InputError(f"estimate_view_rotations must be a bool or a sequence of view indices, got {spec!r}") \
            from None
    if any(v < 0 or v >= n_views for v in views) or len(views) >= n_views:
        raise InputError(f"estimate_view_rotations={spec!r}: view indices must be in 0..{n_views - 1} and at "
                         "least one view must stay unrotated (the reference)")
    return tuple(views)


@dataclass
class _State:
    """Current estimate. ``X`` holds only the used points."""

    intr: np.ndarray  # (5,) fx, fy, cx, cy, skew
    dist5: np.ndarray  # (5,) k1, k2, p1, p2, k3 (zeros beyond the model)
    R: np.ndarray  # (3, 3)
    Q: np.ndarray  # (n_views, 3, 3) per-view rotations, Q[0] = I
    T: np.ndarray  # (n_views, 3)
    X: np.ndarray  # (n_used, 3)

    def copy(self) -> "_State":
        return _State(self.intr.copy(), self.dist5.copy(), self.R.copy(), self.Q.copy(), self.T.copy(), self.X.copy())


@dataclass
class _Data:
    """Observations grouped by view: ``pts[i]`` indexes the used points seen in view i."""

    pts: list  # of (n_i,) int
    uv: list  # of (2, n_i) float
    T_meas: np.ndarray  # (n_views, 3)
    t_weight: np.ndarray  # (n_views,) sigma_px / sigma_T_i for free translations (else 0)
    n_points: int  # used points
    # Views seeing most points are linearised for *all* used points with weight 0 on the
    # unseen ones: contiguous arrays instead of a gather/scatter per accumulated quantity.
    full_uv: list  # of (2, n) float (0 where unseen) or None
    full_seen: list  # of (n,) bool or None

    @property
    def n_obs(self) -> int:
        return int(sum(len(p) for p in self.pts))


def _rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """``exp([w]x)`` for a rotation vector ``w`` (3,) in radians (Rodrigues)."""
    theta = float(np.linalg.norm(w))
    Wx = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if theta < 1e-8:
        return np.eye(3) + Wx + 0.5 * Wx @ Wx
    return np.eye(3) + np.sin(theta) / theta * Wx + (1.0 - np.cos(theta)) / theta**2 * Wx @ Wx


def _matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_rotvec_to_matrix` (angles below pi)."""
    c = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(c)
    v = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    if theta < 1e-8:
        return v
    return v * theta / np.sin(theta)


# ----------------------------------------------------------------------------------------
# Model and Jacobians of one view
# ----------------------------------------------------------------------------------------


def _predict_view(state: _State, lay: _Layout, i: int, pts, jacobian: bool = True, valid=None):
    """Predicted pixels of the used points ``pts`` in view ``i`` and their Jacobians.

    Arrays are laid out with the points last, so that every operation below is a
    vector operation over points. ``pts`` is an index array or ``slice(None)`` (all);
    with ``valid`` (n,) bool, the invalid points get depth 1 in the divisions (their
    values are finite and meaningless: they enter with weight 0).

    Returns
    -------
    pred : (2, n) float
        ``pi(K, dist, Q_i R (X_j - T_i))``.
    z : (n,) float
        Camera depth (must be positive).
    Jg : (q, 2, n) float
        d pred / d (global parameters of this view), columns ``lay.view_columns(i)``.
    JX : (3, 2, n) float
        d pred / d X_j.
    """
    R, Q = state.R, state.Q[i]
    y = R @ (state.X[pts] - state.T[i]).T  # (3, n): R (X_j - T_i)
    xc = Q @ y  # camera frame
    z = xc[2]
    iz = 1.0 / (z if valid is None else np.where(valid, z, 1.0))
    x, yy = xc[0] * iz, xc[1] * iz
    k1, k2, p1, p2, k3 = state.dist5
    distorted = bool(np.any(state.dist5))
    if distorted:
        r2 = x * x + yy * yy
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * yy + p2 * (r2 + 2.0 * x * x)
        yd = yy * radial + p1 * (r2 + 2.0 * yy * yy) + 2.0 * p2 * x * yy
    else:  # pinhole: fewer temporaries on the hot path
        xd, yd = x, yy
    fx, fy, cx, cy, s = state.intr
    pred = np.stack([fx * xd + s * yd + cx, fy * yd + cy])
    if not jacobian:
        return pred, z, None, None

    n = y.shape[1]
    # d(xd, yd)/d(x, y)
    if distorted:
        dR = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        a11 = radial + 2.0 * x * x * dR + 2.0 * p1 * yy + 6.0 * p2 * x
        a12 = 2.0 * x * yy * dR + 2.0 * p1 * x + 2.0 * p2 * yy
        a22 = radial + 2.0 * yy * yy * dR + 6.0 * p1 * yy + 2.0 * p2 * x
    else:
        a11, a12, a22 = 1.0, 0.0, 1.0
        r2 = x * x + yy * yy  # for the distortion columns (all-zero start)
    # M = [[fx, s], [0, fy]] d(xd, yd)/d(x, y);  P = d pred / d xc = M [[1, 0, -x], [0, 1, -y]] / z
    m11, m12 = fx * a11 + s * a12, fx * a12 + s * a22
    m21, m22 = fy * a12, fy * a22
    P = np.empty((2, 3, n))
    P[0, 0], P[0, 1], P[0, 2] = m11 * iz, m12 * iz, -(m11 * x + m12 * yy) * iz
    P[1, 0], P[1, 1], P[1, 2] = m21 * iz, m22 * iz, -(m21 * x + m22 * yy) * iz

    q = lay.n_common + 3 * (i in lay.i_vrot) + 3 * (i in lay.i_T)
    Jg = np.zeros((q, 2, n))
    # intrinsics: u = fx xd + s yd + cx, v = fy yd + cy
    Jg[0, 0] = xd
    Jg[1, 1] = yd
    Jg[2, 0] = 1.0
    Jg[3, 1] = 1.0
    if lay.estimate_skew:
        Jg[4, 0] = yd
    # distortion: d(xd, yd)/dk, then through [[fx, s], [0, fy]]
    if lay.n_dist:
        r4 = r2 * r2
        grads = [(x * r2, yy * r2), (x * r4, yy * r4), (2.0 * x * yy, r2 + 2.0 * yy * yy),
                 (r2 + 2.0 * x * x, 2.0 * x * yy), (x * r4 * r2, yy * r4 * r2)]
        for c, (gx, gy) in enumerate(grads[: lay.n_dist]):
            Jg[lay.i_dist + c, 0] = fx * gx + s * gy
            Jg[lay.i_dist + c, 1] = fy * gy
    # rows of P Q (d pred / d y), then d pred / dX = P Q R
    PQ = np.einsum("kcn,cd->kdn", P, Q) if lay.view_rotations else P
    JX = np.einsum("kcn,cd->dkn", PQ, R)  # (3, 2, n)
    # rotation R <- exp([w]x) R: d y / dw = -[y]x, and a^T (-[y]x) = (y x a)^T
    _cross_rows(y, PQ, Jg[lay.i_rot: lay.i_rot + 3])
    col = lay.n_common
    if i in lay.i_vrot:  # Q_i <- exp([w_i]x) Q_i: d xc / dw_i = -[xc]x
        _cross_rows(xc, P, Jg[col: col + 3])
        col += 3
    if i in lay.i_T:
        Jg[col: col + 3] = -JX
    return pred, z, Jg, JX


def _cross_rows(v: np.ndarray, A: np.ndarray, out: np.ndarray) -> None:
    """``out[:, k, n] = v[:, n] x A[k, :, n]`` for v (3, n), A (2, 3, n), out (3, 2, n)."""
    for k in range(2):
        a = A[k]
        out[0, k] = v[1] * a[2] - v[2] * a[1]
        out[1, k] = v[2] * a[0] - v[0] * a[2]
        out[2, k] = v[0] * a[1] - v[1] * a[0]


# ----------------------------------------------------------------------------------------
# Losses, cost, normal equations
# ----------------------------------------------------------------------------------------


def _loss(e2: np.ndarray, loss: str, c: float):
    """``rho(e^2)`` and the IRLS weight ``w = d rho / d(e^2)`` (cost = sum rho / 2)."""
    if loss == "linear":
        return e2, np.ones_like(e2)
    c2 = c * c
    if loss == "huber":
        e = np.sqrt(e2)
        inside = e <= c
        rho = np.where(inside, e2, 2.0 * c * e - c2)
        w = np.where(inside, 1.0, c / np.maximum(e, 1e-300))
        return rho, w
    # cauchy
    return c2 * np.log1p(e2 / c2), 1.0 / (1.0 + e2 / c2)


def _residual_view(state, lay, data, i, jacobian=False):
    """Residuals ``r (2, n_i)`` of view i (observed - predicted), depths, Jacobians."""
    pred, z, Jg, JX = _predict_view(state, lay, i, data.pts[i], jacobian)
    return data.uv[i] - pred, z, Jg, JX


def _cost(state: _State, lay: _Layout, data: _Data, loss: str, c: float) -> float:
    """``0.5 sum rho(|r_ij|^2) + 0.5 sum_i t_w_i^2 |T_i - T_i^meas|^2``; inf if a depth <= 0."""
    total = 0.0
    for i, pts in enumerate(data.pts):
        if len(pts) == 0:
            continue
        r, z, _, _ = _residual_view(state, lay, data, i)
        if not np.all(z > 0):
            return np.inf
        total += np.sum(_loss(r[0] ** 2 + r[1] ** 2, loss, c)[0])
    dT = (state.T - data.T_meas) * data.t_weight[:, None]
    return 0.5 * (total + np.sum(dT * dT))


def _normal_equations(state, lay, data, loss, c, obs_weight=None):
    """Assemble the normal equations ``[[U, W], [W^T, V]] [dg; dX] = [b_g; b_X]``.

    Returns ``U (p, p)``, ``W (p, 3, n)``, ``V (3, 3, n)``, ``b_g (p,)``, ``b_X (3, n)``
    (points last). ``obs_weight``: optional list of (n_i,) weights replacing the loss's
    IRLS weights (used for the covariance).
    """
    p, n = lay.size, data.n_points
    U = np.zeros((p, p))
    W = np.zeros((p, 3, n))
    V = np.zeros((3, 3, n))
    bg = np.zeros(p)
    bX = np.zeros((3, n))
    for i, pts in enumerate(data.pts):
        if len(pts) == 0:
            continue
        seen = data.full_seen[i]
        if seen is None:  # gather the seen points (or all are seen)
            r, _, Jg, JX = _residual_view(state, lay, data, i, jacobian=True)
            w = _loss(r[0] ** 2 + r[1] ** 2, loss, c)[1] if obs_weight is None else obs_weight[i]
        else:  # all used points, weight 0 where unseen
            pred, _, Jg, JX = _predict_view(state, lay, i, slice(None), True, valid=seen)
            r = data.full_uv[i] - pred
            if obs_weight is None:
                w = _loss(r[0] ** 2 + r[1] ** 2, loss, c)[1] * seen
            else:
                w = np.zeros(n)
                w[pts] = obs_weight[i]
            r = r * seen
            pts = np.arange(n)
        cols = lay.view_columns(i)
        q = len(cols)
        Jw = Jg * w
        JXw = JX * w
        U[np.ix_(cols, cols)] += Jw.reshape(q, -1) @ Jg.reshape(q, -1).T
        bg[cols] += Jw.reshape(q, -1) @ r.reshape(-1)
        whole = len(pts) == n  # every used point seen: plain slices, no scatter
        for a in range(3):
            for b in range(a, 3):
                vab = JXw[a, 0] * JX[b, 0] + JXw[a, 1] * JX[b, 1]
                if whole:
                    V[a, b] += vab
                else:
                    V[a, b, pts] += vab
            bXa = JXw[a, 0] * r[0] + JXw[a, 1] * r[1]
            if whole:
                bX[a] += bXa
            else:
                bX[a, pts] += bXa
        for la, ga in enumerate(cols):
            wab = Jw[la, 0] * JX[:, 0] + Jw[la, 1] * JX[:, 1]  # (3, n_i)
            if whole:
                W[ga] += wab
            else:
                W[ga][:, pts] += wab
    for a in range(3):
        for b in range(a):
            V[a, b] = V[b, a]
    # translation priors: residual t_w (T^meas - T), Jacobian of the prediction t_w I
    for i, s in lay.i_T.items():
        tw2 = data.t_weight[i] ** 2
        U[s: s + 3, s: s + 3] += tw2 * np.eye(3)
        bg[s: s + 3] += tw2 * (data.T_meas[i] - state.T[i])
    return U, W, V, bg, bX


def _inv3_spd(V: np.ndarray):
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


def _matvec3(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``M_j v_j`` for M (3, 3, n), v (3, n)."""
    return M[:, 0] * v[0] + M[:, 1] * v[1] + M[:, 2] * v[2]


def _schur(U, W, V, bg, bX):
    """Reduced system ``S dg = rhs`` with the points eliminated, and ``V^-1``.

    ``S = U - sum_j W_j V_j^-1 W_j^T``, ``rhs = b_g - sum_j W_j V_j^-1 b_j``.
    """
    Vinv, det = _inv3_spd(V)
    p, n = U.shape[0], V.shape[2]
    # Y_j = W_j V_j^-1  (p, 3, n)
    Y = W[:, 0:1] * Vinv[0][None] + W[:, 1:2] * Vinv[1][None] + W[:, 2:3] * Vinv[2][None]
    S = U - Y.reshape(p, -1) @ W.reshape(p, -1).T
    rhs = bg - Y.reshape(p, -1) @ bX.reshape(-1)
    return 0.5 * (S + S.T), rhs, Vinv, det


def _solve_spd(S: np.ndarray, rhs: np.ndarray):
    """Solve ``S x = rhs`` (Jacobi-scaled Cholesky); None if not positive definite."""
    d = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))
    try:
        cf = scipy.linalg.cho_factor(S * d[:, None] * d[None, :])
    except np.linalg.LinAlgError:
        return None
    return d * scipy.linalg.cho_solve(cf, rhs * d)


def _apply_step(state: _State, lay: _Layout, dg: np.ndarray, dX: np.ndarray) -> _State:
    new = state.copy()
    new.intr[: lay.n_intr] += dg[: lay.n_intr]
    new.dist5[: lay.n_dist] += dg[lay.i_dist: lay.i_dist + lay.n_dist]
    new.R = _rotvec_to_matrix(dg[lay.i_rot: lay.i_rot + 3]) @ state.R
    for i, s in lay.i_vrot.items():
        new.Q[i] = _rotvec_to_matrix(dg[s: s + 3]) @ state.Q[i]
    for i, s in lay.i_T.items():
        new.T[i] += dg[s: s + 3]
    new.X += dX.T
    return new


def _levenberg_marquardt(state, lay, data, loss, c, max_iterations, tol, progress):
    """Minimise the (robust) cost; returns the final state, cost, iterations, stop reason."""
    cost = _cost(state, lay, data, loss, c)
    if not np.isfinite(cost):
        raise DegenerateError("the initial estimate puts some used points behind the camera; "
                              "start from a better initial estimate (e.g. the linear one)")
    mu, nu = None, 2.0
    reason = f"max_iterations ({max_iterations}) reached"
    floor = 1e-24 * max(data.n_obs, 1)  # residuals ~1e-12 px: exact data
    # stop when a step moves the parameters by ~sqrt(2 tol) standard deviations or less:
    # a step of k std decreases the cost by k^2 sigma^2 / 2, sigma^2 ~ 2 cost / dof
    dof = max(2 * data.n_obs - (lay.size - 3 * len(lay.i_T)) - 3 * data.n_points, 1)
    it = 0
    while it < max_iterations:
        if cost <= floor:
            reason = "converged: zero residual"
            break
        U, W, V, bg, bX = _normal_equations(state, lay, data, loss, c)
        dU = np.diag(U).copy()
        dV = np.stack([V[0, 0], V[1, 1], V[2, 2]])  # (3, n)
        dV_floor = np.maximum(dV, 1e-12 * dV.max(axis=0))
        if mu is None:
            mu = _MU0
        accepted = False
        while not accepted:
            eps = 1e-12 * max(dU.max(), 1e-300)
            Ud = U + np.diag(mu * np.maximum(dU, eps))
            Vd = V.copy()
            for a in range(3):
                Vd[a, a] += mu * dV_floor[a]
            S, rhs, Vinv, det = _schur(Ud, W, Vd, bg, bX)
            dg = _solve_spd(S, rhs) if np.all(det > 0) else None
            if dg is not None:
                dX = _matvec3(Vinv, bX - np.tensordot(dg, W, axes=1))  # (3, n)
                new = _apply_step(state, lay, dg, dX)
                new_cost = _cost(new, lay, data, loss, c)
                # decrease predicted by the damped quadratic model
                predicted = 0.5 * (dg @ (mu * np.maximum(dU, eps) * dg + bg)
                                   + np.sum(dX * (mu * dV_floor * dX + bX)))
                gain = (cost - new_cost) / predicted if predicted > 0 else -1.0
            else:
                gain = -1.0
            if gain > 0:
                accepted = True
                mu *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
                nu = 2.0
            else:
                mu *= nu
                nu *= 2.0
                if mu > 1e16:
                    break
        if not accepted:
            reason = "converged: no step decreases the cost (minimum within numerical precision)"
            break
        it += 1
        decrease = cost - new_cost
        state, cost = new, new_cost
        if progress is not None:
            progress({"iteration": it, "cost": cost, "damping": mu})
        if decrease <= tol * 2.0 * cost / dof:
            reason = f"converged: cost decrease below tol={tol:g} x sigma^2"
            break
    return state, cost, it, reason


# ----------------------------------------------------------------------------------------
# Public API
# ----------------------------------------------------------------------------------------


def _check_inputs(uv, T, initial, distortion, loss, loss_scale_px, sigma_px, sigma_T, max_iterations, tol):
    uv = np.asarray(uv, dtype=float)
    T = np.asarray(T, dtype=float)
    if uv.ndim != 3 or uv.shape[2] != 2:
        raise InputError(f"uv must have shape (n_views, n_points, 2), got {uv.shape}; "
                         "stack the pixel coordinates of every point in every view (NaN where unseen)")
    n_views, n_points = uv.shape[:2]
    if T.shape != (n_views, 3):
        raise InputError(f"T must have shape (n_views, 3) = ({n_views}, 3) to match uv, got {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InputError("T contains NaN or inf; every view needs a measured translation")
    if np.any(np.isinf(uv)):
        raise InputError("uv contains inf; mark unseen points with NaN")
    if not isinstance(initial, (LinearEstimate, Calibration)):
        raise InputError(f"initial must be a LinearEstimate or a Calibration, got {type(initial).__name__}; "
                         "run transcalib.estimate_linear(uv, T) first")
    X0 = np.asarray(initial.X, dtype=float)
    if X0.shape != (n_points, 3):
        raise InputError(f"initial.X has shape {X0.shape}, expected (n_points, 3) = ({n_points}, 3) to match uv")
    K0 = np.asarray(initial.K, dtype=float)
    if K0.shape != (3, 3) or not np.all(np.isfinite(K0)) or K0[0, 0] <= 0 or K0[1, 1] <= 0:
        raise InputError(f"initial.K must be a finite 3x3 matrix with fx, fy > 0, got {K0.tolist()}")
    R0 = np.asarray(initial.R, dtype=float)
    if R0.shape != (3, 3) or not np.all(np.isfinite(R0)) or not np.allclose(R0 @ R0.T, np.eye(3), atol=1e-6) \
            or np.linalg.det(R0) < 0:
        raise InputError("initial.R must be a 3x3 rotation matrix (orthonormal, det +1), got "
                         f"{np.array2string(R0, precision=4)}")
    if distortion not in DIST_MODELS:
        raise InputError(f"distortion must be one of {sorted(DIST_MODELS)}, got {distortion!r}")
    if loss not in LOSSES:
        raise InputError(f"loss must be one of {LOSSES}, got {loss!r}")
    if not (np.isfinite(loss_scale_px) and loss_scale_px > 0):
        raise InputError(f"loss_scale_px must be a positive number of pixels, got {loss_scale_px!r}")
    if sigma_px is not None and not (np.isfinite(sigma_px) and sigma_px > 0):
        raise InputError(f"sigma_px must be None (estimate it) or a positive number, got {sigma_px!r}")
    if sigma_T is not None:
        s = np.asarray(sigma_T, dtype=float)
        if s.shape not in ((), (n_views,)) or not np.all(np.isfinite(s)) or np.any(s < 0) or not np.any(s > 0):
            raise InputError(f"sigma_T must be a positive number or an (n_views,) = ({n_views},) array "
                             f"of standard deviations >= 0 (0: exact), got {sigma_T!r}")
    if int(max_iterations) != max_iterations or max_iterations < 0:
        raise InputError(f"max_iterations must be a non-negative integer, got {max_iterations!r}")
    if not (tol >= 0):
        raise InputError(f"tol must be >= 0, got {tol!r}")
    return uv, T, X0, K0


def _initial_dist(initial, n_dist: int) -> np.ndarray:
    d5 = np.zeros(5)
    dist = np.asarray(getattr(initial, "dist", ()), dtype=float).ravel()
    if dist.size == 2:
        d5[:2] = dist
    elif dist.size in (4, 5):
        d5[: dist.size] = dist
    keep = {0: [], 2: [0, 1], 5: [0, 1, 2, 3, 4]}[n_dist]
    out = np.zeros(5)
    out[keep] = d5[keep]
    return out


def _build_data(uv, seen, used_idx, T_meas, t_weight):
    """Group the observations of the used points by view."""
    pts, obs = [], []
    for i in range(uv.shape[0]):
        sel = np.flatnonzero(seen[i, used_idx])
        pts.append(sel)
        obs.append(np.ascontiguousarray(uv[i, used_idx[sel]].T))  # (2, n_i)
    n = len(used_idx)
    full_uv, full_seen = [], []
    for i, sel in enumerate(pts):
        if _DENSE_FRACTION * n <= len(sel) < n:
            f = np.zeros((2, n))
            f[:, sel] = obs[i]
            mask = np.zeros(n, bool)
            mask[sel] = True
            full_uv.append(f)
            full_seen.append(mask)
        else:
            full_uv.append(None)
            full_seen.append(None)
    return _Data(pts=pts, uv=obs, T_meas=T_meas, t_weight=t_weight, n_points=n, full_uv=full_uv,
                 full_seen=full_seen)


def _covariance(state, lay, data, obs_weight):
    """Unscaled covariances at the solution: ``S^-1 (p, p)``, ``diag`` of each point's ``(n, 3)``.

    Observations with ``obs_weight == 0`` are left out; so are the points left with fewer
    than 2 observations or whose 3x3 block is (numerically) singular (returned mask ``ok``
    False; their variances are NaN).
    """
    n_w = np.zeros(data.n_points, int)
    for i, pts in enumerate(data.pts):
        np.add.at(n_w, pts, obs_weight[i] > 0)
    ok = n_w >= 2
    for _ in range(2):  # a second pass only if some points turn out undetermined
        weights = [np.where(ok[pts], w, 0.0) for pts, w in zip(data.pts, obs_weight)]
        U, W, V, _, _ = _normal_equations(state, lay, data, "linear", 1.0, obs_weight=weights)
        for a in range(3):
            V[a, a, ~ok] = 1.0  # excluded points: W is zero there, they do not enter S
        S, _, Vinv, det = _schur(U, W, V, np.zeros(lay.size), np.zeros((3, data.n_points)))
        undetermined = ok & (det <= 1e-12)  # rays (nearly) parallel: X_j not determined
        if not undetermined.any():
            break
        ok &= ~undetermined
    d = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))
    evals, evecs = np.linalg.eigh(S * d[:, None] * d[None, :])
    if evals[0] <= 1e-13 * evals[-1]:
        names = lay.names()
        worst = [names[k] for k in np.argsort(-np.abs(evecs[:, 0]))[:3]]
        raise DegenerateError("the data do not determine all parameters (the reduced normal matrix is "
                              f"singular; the weakest combination involves {', '.join(worst)}). Use a simpler "
                              "distortion model, more points spread over the image, or more views.")
    Sinv = (evecs / evals) @ evecs.T * d[:, None] * d[None, :]
    # cov(X_j) = V_j^-1 + Z_j^T S^-1 Z_j with Z_j = W_j V_j^-1 (p, 3): diagonal only
    p, n = lay.size, data.n_points
    Z = W[:, 0:1] * Vinv[0][None] + W[:, 1:2] * Vinv[1][None] + W[:, 2:3] * Vinv[2][None]
    SZ = (Sinv @ Z.reshape(p, -1)).reshape(p, 3, n)
    var_X = np.stack([Vinv[0, 0], Vinv[1, 1], Vinv[2, 2]]) + np.sum(Z * SZ, axis=0)  # (3, n)
    var_X = var_X.T
    var_X[~ok] = np.nan
    return Sinv, var_X, ok


def refine(
    uv,
    T,
    initial,
    *,
    distortion: str = "none",
    estimate_skew: bool = False,
    sigma_T=None,
    loss: str = "linear",
    loss_scale_px: float = 1.0,
    inlier_threshold_px: float | None = None,
    sigma_px: float | None = None,
    max_iterations: int = 100,
    tol: float = 1e-6,
    estimate_view_rotations=False,
    progress=None,
) -> Calibration:
    """Maximum-likelihood refinement of a calibration (sparse bundle adjustment).

    Minimises ``0.5 sum_ij rho(|r_ij|^2) [+ 0.5 sum_i |T_i - T_i^meas|^2 sigma^2/sigma_T^2]``
    with ``r_ij = uv_ij - pi(K, dist, Q_i R (X_j - T_i))`` (paper eq. 2 with OpenCV
    distortion) by Levenberg-Marquardt, eliminating the points with the Schur complement
    (one iteration costs O(n_points)).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Observed pixels, NaN where a point is not seen.
    T : (n_views, 3) float
        Measured robot translations (world frame, user units).
    initial : LinearEstimate or Calibration
        Starting point: ``K``, ``R``, ``X`` (and ``dist`` of a Calibration). Points with
        non-finite ``X``, seen in fewer than 2 views, or behind the camera in some view
        are left out (NaN in the result; counted in ``info["n_points_excluded"]``).
    distortion : {"none", "radial2", "opencv5"}
        Lens distortion model, OpenCV order ``k1, k2, p1, p2, k3``
        (``Calibration.dist_opencv`` pads them to the five values OpenCV takes).
    estimate_skew : bool
        Estimate the skew ``K[0, 1]``; otherwise it is fixed at 0 (OpenCV's model).
    sigma_T : float or (n_views,) float, optional
        Standard deviation of the measured translations (user units, per coordinate).
        If given, the translations are parameters with this measurement prior (0 in the
        array: that view's translation is exact); otherwise they are fixed.
    loss : {"linear", "huber", "cauchy"}
        Loss of the residual norm ``e = |r_ij|``, with scale ``c = loss_scale_px``:
        linear ``e^2``; Huber ``e^2`` (e <= c), ``2 c e - c^2``; Cauchy
        ``c^2 log(1 + e^2/c^2)``. Robust losses are minimised by IRLS inside LM; then
        the observations with ``e <= inlier_threshold_px`` are refitted by least squares
        (points keeping >= 2 of them; repeated until the inlier set is stable, at most 3
        times), so that the estimate and its covariance are those of the inliers alone.
    loss_scale_px : float
        Scale ``c`` of the robust loss (pixels); about twice the pixel noise is a good value.
    inlier_threshold_px : float, optional
        An observation is an inlier when its residual norm is at most this; a point is an
        inlier (``Calibration.inliers``) when **all** its observations are (default
        ``3 * loss_scale_px``). Only used with a robust loss.
    sigma_px : float, optional
        Known pixel noise (per coordinate). By default estimated from the residuals as
        ``sqrt(sum |r|^2 / dof)``, ``dof = 2 n_obs - n_global - 3 n_points``.
    max_iterations : int
        Maximum number of accepted LM steps.
    tol : float
        Stop when an accepted step decreases the cost by less than ``tol * sigma^2`` with
        ``sigma^2 = 2 cost / dof``, i.e. when the parameters moved by less than about
        ``sqrt(2 tol)`` of their standard deviations (or the residuals are zero).
    estimate_view_rotations : bool or sequence of int
        Add a rotation ``Q_i = exp([w_i]x)`` per view ``i >= 1`` (``True``) or per listed
        view (camera rotation ``R_i = Q_i R``; the other views are the reference), to
        detect a robot that rotated. Freeing every view leaves K poorly determined with 4
        views; testing one view at a time (``[i]``) is far more sensitive. Reported in
        ``info["view_rotations_deg"]`` (n_views, 3) (rotation vectors in the camera frame,
        zero rows for unrotated views), ``info["view_rotations_std_deg"]`` (n_views, 3) and
        ``info["view_rotations_chi2"]`` (n_views,): ``w_i^T cov(w_i)^-1 w_i``, chi-square
        with 3 degrees of freedom when view i did not rotate (e.g. > 11.34: p < 0.01).
    progress : callable, optional
        Called after each accepted step with a dict ``{iteration, cost, damping}``.

    Returns
    -------
    Calibration
        ``K``, ``R``, ``X``, ``dist``, ``residuals_px``, ``rms_px``, ``T`` (refined when
        ``sigma_T`` is given), ``cov`` / ``std`` / ``param_names`` (rotations in
        **degrees**, translations in user units; ``cov`` in the same units),
        ``X_std`` (NaN for unused points and points with fewer than 2 inlier
        observations), ``inliers`` (robust loss only, else None), ``linear`` (when
        ``initial`` is a LinearEstimate), ``diagnostics`` empty, and ``info``:
        ``iterations`` (accepted LM steps, all stages), ``cost`` (final
        ``0.5 sum |r|^2 [+ prior]`` of the last least-squares stage), ``stop_reason``,
        ``converged``, ``sigma_px`` (used for ``cov``), ``sigma_px_estimated``, ``dof``,
        ``n_observations``, ``n_points_used`` / ``_excluded`` / ``_behind_camera`` /
        ``_undetermined``, ``distortion``, ``loss``, ``loss_scale_px``,
        ``inlier_threshold_px``, ``time_s``; with ``sigma_T``: ``sigma_T``, ``T_std``
        (n_views, 3); with view rotations: see ``estimate_view_rotations``.

    Raises
    ------
    InputError
        Malformed input.
    DegenerateError
        Fewer than 2 usable points, no residual degrees of freedom to estimate the noise,
        or parameters the data do not determine.
    """
    t_start = time.perf_counter()
    uv, T, X0, K0 = _check_inputs(uv, T, initial, distortion, loss, loss_scale_px, sigma_px, sigma_T,
                                  max_iterations, tol)
    n_views, n_points = uv.shape[:2]
    n_dist = dist_size(distortion)
    seen = np.all(np.isfinite(uv), axis=2)

    R0 = np.asarray(initial.R, dtype=float)
    intr = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], K0[0, 1] if estimate_skew else 0.0])
    dist5 = _initial_dist(initial, n_dist)
    # used points: finite X, >= 2 views, in front of the camera in every view that sees them
    usable = np.all(np.isfinite(X0), axis=1) & (seen.sum(axis=0) >= 2)
    z0 = np.einsum("b,vnb->vn", R0[2], X0[None] - T[:, None])
    in_front = np.all(~seen | (z0 > 0) | ~usable[None], axis=0)
    used = usable & in_front
    n_behind = int(np.sum(usable & ~in_front))
    used_idx = np.flatnonzero(used)
    if len(used_idx) < 2:
        raise DegenerateError(f"only {len(used_idx)} usable points (finite initial X, seen in >= 2 views, in "
                              "front of the camera); refinement needs at least 2. Track more points.")

    if sigma_T is None:
        t_sigma = np.zeros(n_views)
    else:
        t_sigma = np.broadcast_to(np.asarray(sigma_T, dtype=float), (n_views,)).copy()
    lay = _Layout(n_views, n_dist, bool(estimate_skew), estimate_view_rotations, t_sigma > 0)
    n_global_no_T = lay.size - 3 * len(lay.i_T)
    n_obs = int(seen[:, used_idx].sum())
    dof = 2 * n_obs - n_global_no_T - 3 * len(used_idx)
    if dof < 0 or (dof == 0 and sigma_px is None):
        raise DegenerateError(f"too few observations: {2 * n_obs} residuals for {n_global_no_T + 3 * len(used_idx)} "
                              f"unknowns ({len(used_idx)} points, {n_global_no_T} camera parameters). Track more "
                              "points, use more views, or a simpler distortion model.")
    c = float(loss_scale_px)
    thr = 3.0 * c if inlier_threshold_px is None else float(inlier_threshold_px)
    state = _State(intr, dist5, R0.copy(), np.tile(np.eye(3), (n_views, 1, 1)), T.copy(), X0[used_idx].copy())
    fit = _Fitter(uv, T, lay, t_sigma, sigma_px, n_global_no_T, c, thr, max_iterations, tol, progress)

    # 1. the (robust) fit on every observation of the used points
    state, cost, reason, data, sigma_T_mode = fit(state, used_idx, seen, loss)
    fit_idx, fit_mask, fit_state, fit_data = used_idx, seen, state, data
    inliers = None
    if loss != "linear":
        # 2. inlier observations: residual norm <= thr; inlier points: all their observations.
        #    Then a least-squares polish on the inlier observations (points keeping >= 2 of
        #    them), so that estimate and covariance are those of the inliers alone.
        previous = None
        for _ in range(3):
            obs_in = _inlier_observations(state, lay, uv, seen, used_idx, T, thr)
            if previous is not None and np.array_equal(obs_in, previous):
                break
            previous = obs_in
            keep = obs_in[:, used_idx].sum(axis=0) >= 2
            sub = _State(state.intr, state.dist5, state.R, state.Q, state.T, state.X[keep])
            sub, cost, reason, fit_data, sigma_T_mode = fit(sub, used_idx[keep], obs_in, "linear")
            state = state.copy()
            state.intr, state.dist5, state.R, state.Q, state.T = sub.intr, sub.dist5, sub.R, sub.Q, sub.T
            state.X[keep] = sub.X
            fit_idx, fit_mask, fit_state = used_idx[keep], obs_in, sub
        obs_in = _inlier_observations(state, lay, uv, seen, used_idx, T, thr)
        inliers = np.zeros(n_points, bool)
        inliers[used_idx] = np.all(obs_in[:, used_idx] | ~seen[:, used_idx], axis=0)

    # 3. covariance at the solution: sigma^2 S^-1 (the translation priors were weighted
    #    with the same sigma, so this holds in both modes)
    Sinv, var_X, ok = _covariance(fit_state, lay, fit_data, [np.ones(len(p)) for p in fit_data.pts])
    n_obs_fit = int(fit_mask[:, fit_idx].sum())
    dof_fit = 2 * n_obs_fit - n_global_no_T - 3 * len(fit_idx)
    if sigma_T_mode is not None:
        sigma = sigma_T_mode
    elif sigma_px is not None:
        sigma = float(sigma_px)
    else:
        if dof_fit <= 0:
            raise DegenerateError("no residual degrees of freedom left among the inliers to estimate the pixel "
                                  "noise; pass sigma_px or track more points")
        sigma = float(np.sqrt(_sum_sq(fit_state, lay, fit_data) / dof_fit))
    names = lay.names()
    scale = np.where(lay.rotation_mask(), _RAD2DEG, 1.0)  # rotations in degrees
    cov = sigma**2 * Sinv * scale[:, None] * scale[None, :]
    std = {nm: float(np.sqrt(cov[k, k])) for k, nm in enumerate(names)}
    X_std = np.full((n_points, 3), np.nan)
    X_std[fit_idx[ok]] = sigma * np.sqrt(var_X[ok])
    X = np.full((n_points, 3), np.nan)
    X[used_idx] = state.X
    residuals = np.full((n_views, n_points, 2), np.nan)
    residuals[:, used_idx] = _all_residuals(state, lay, uv, seen, used_idx, T)
    used_res = residuals[:, used_idx][seen[:, used_idx]]
    rms = float(np.sqrt(np.mean(np.sum(used_res**2, axis=1))))

    info = {
        "stage": "refine",
        "iterations": int(fit.iterations),
        "cost": float(cost),
        "stop_reason": reason,
        "converged": reason.startswith("converged"),
        "sigma_px": sigma,
        "sigma_px_estimated": sigma_px is None,
        "dof": int(dof_fit),
        "n_observations": n_obs,
        "n_points_used": int(len(used_idx)),
        "n_points_excluded": int(n_points - len(used_idx)),
        "n_points_behind_camera": n_behind,
        "n_points_undetermined": int(np.sum(~ok)),
        "distortion": distortion,
        "estimate_skew": bool(estimate_skew),
        "loss": loss,
        "loss_scale_px": c,
        "inlier_threshold_px": thr if loss != "linear" else None,
        "time_s": time.perf_counter() - t_start,
    }
    if lay.view_rotations:
        view_rot = np.zeros((n_views, 3))
        view_rot_std = np.zeros((n_views, 3))
        for i, s in lay.i_vrot.items():
            view_rot[i] = _matrix_to_rotvec(state.Q[i]) * _RAD2DEG
            view_rot_std[i] = np.sqrt(np.diag(cov)[s: s + 3])
        chi2 = np.zeros(n_views)
        for i, s in lay.i_vrot.items():  # Wald statistic w_i^T cov_i^-1 w_i, ~ chi^2(3) if no rotation
            chi2[i] = view_rot[i] @ np.linalg.solve(cov[s: s + 3, s: s + 3], view_rot[i])
        info["view_rotations_deg"] = view_rot
        info["view_rotations_std_deg"] = view_rot_std
        info["view_rotations_chi2"] = chi2
    if lay.i_T:
        info["sigma_T"] = t_sigma
        info["T_std"] = np.zeros((n_views, 3))
        for i, s in lay.i_T.items():
            info["T_std"][i] = np.sqrt(np.diag(cov)[s: s + 3])
    return Calibration(
        K=K_from_params(*state.intr),
        R=state.R,
        X=X,
        dist=state.dist5[:n_dist].copy(),
        dist_model=distortion,
        residuals_px=residuals,
        rms_px=rms,
        diagnostics=[],
        T=state.T.copy(),
        linear=initial if isinstance(initial, LinearEstimate) else getattr(initial, "linear", None),
        cov=cov,
        std=std,
        param_names=names,
        X_std=X_std,
        inliers=inliers,
        info=info,
    )


class _Fitter:
    """Runs LM on a subset of observations; handles the robot-noise (``sigma_T``) mode.

    With ``sigma_T`` and unknown pixel noise the prior weight ``sigma_px / sigma_T`` needs
    ``sigma_px``: it is estimated by a fit with fixed translations, then refined by the
    fixed point ``sigma^2 = sum |r|^2 / (dof - chi2_T)`` (the whitened cost then equals its
    expectation, the degrees of freedom).
    """

    def __init__(self, uv, T, lay, t_sigma, sigma_px, n_global_no_T, c, thr, max_iterations, tol, progress):
        self.uv, self.T, self.lay, self.t_sigma, self.sigma_px = uv, T, lay, t_sigma, sigma_px
        self.n_global_no_T, self.c, self.thr = n_global_no_T, c, thr
        self.max_iterations, self.tol, self.progress = max_iterations, tol, progress
        self.iterations = 0

    def _lm(self, state, lay, data, loss):
        state, cost, it, reason = _levenberg_marquardt(state, lay, data, loss, self.c, self.max_iterations,
                                                       self.tol, self.progress)
        self.iterations += it
        return state, cost, reason

    def _weights(self, sigma):
        free = self.t_sigma > 0
        return np.where(free, sigma / np.where(free, self.t_sigma, 1.0), 0.0)

    def __call__(self, state, idx, mask, loss):
        """Fit the points ``idx`` on the observations ``mask``; returns state, cost, reason,
        data and the pixel sigma used for the translation priors (None without them)."""
        lay, n_views = self.lay, len(self.T)
        if not lay.i_T:
            data = _build_data(self.uv, mask, idx, self.T, np.zeros(n_views))
            return (*self._lm(state, lay, data, loss), data, None)
        if self.sigma_px is not None:
            data = _build_data(self.uv, mask, idx, self.T, self._weights(self.sigma_px))
            return (*self._lm(state, lay, data, loss), data, float(self.sigma_px))
        dof = 2 * int(mask[:, idx].sum()) - self.n_global_no_T - 3 * len(idx)
        fixed = _Layout(n_views, lay.n_dist, lay.estimate_skew, lay.view_rotations, np.zeros(n_views, bool))
        data = _build_data(self.uv, mask, idx, self.T, np.zeros(n_views))
        state, _, _ = self._lm(state, fixed, data, loss)
        sigma = np.sqrt(_sum_sq(state, fixed, data, loss, self.thr) / max(dof, 1))
        for _ in range(5):
            data = _build_data(self.uv, mask, idx, self.T, self._weights(sigma))
            state, cost, reason = self._lm(state, lay, data, loss)
            free = self.t_sigma > 0
            chi2_T = float(np.sum(((state.T - self.T)[free] / self.t_sigma[free, None]) ** 2))
            new = float(np.sqrt(_sum_sq(state, lay, data, loss, self.thr) / max(dof - chi2_T, 0.5 * dof)))
            done = abs(new - sigma) <= 1e-3 * sigma
            sigma = new
            if done:
                break
        data = _build_data(self.uv, mask, idx, self.T, self._weights(sigma))
        return state, _cost(state, lay, data, loss, self.c), reason, data, sigma


def _inlier_observations(state, lay, uv, seen, used_idx, T, thr) -> np.ndarray:
    """(n_views, n_points) bool: observations of the used points with residual norm <= thr."""
    obs_in = np.zeros(seen.shape, bool)
    res = _all_residuals(state, lay, uv, seen, used_idx, T)
    obs_in[:, used_idx] = seen[:, used_idx] & (np.sum(res**2, axis=2) <= thr * thr)
    return obs_in


def _all_residuals(state, lay, uv, seen, used_idx, T) -> np.ndarray:
    """Residuals ``(n_views, n_used, 2)`` of the used points, NaN where unseen."""
    data = _build_data(uv, seen, used_idx, T, np.zeros(len(T)))
    out = np.full((len(T), len(used_idx), 2), np.nan)
    for i, pts in enumerate(data.pts):
        if len(pts):
            out[i, pts] = _residual_view(state, lay, data, i)[0].T
    return out


def _sum_sq(state, lay, data, loss="linear", thr=np.inf) -> float:
    """Sum of squared pixel residuals of ``data``, over the observations with norm <= ``thr``
    for a robust loss (all for the linear loss)."""
    total = 0.0
    for i, pts in enumerate(data.pts):
        if len(pts) == 0:
            continue
        r = _residual_view(state, lay, data, i)[0]
        e2 = r[0] ** 2 + r[1] ** 2
        total += float(np.sum(e2 if loss == "linear" else e2[e2 <= thr * thr]))
    return total


def crlb(scene, *, distortion: str | None = None, estimate_skew: bool = False,
         estimate_view_rotations=False) -> dict:
    """Cramér-Rao lower bound on the parameter standard deviations of a simulated scene.

    The Fisher information ``J^T J / noise_px^2`` (plus ``1 / robot_noise^2`` on the
    translations of views ``i >= 1`` when the scene has robot noise, as
    :func:`transcalib.simulate.observe` draws it) at the ground truth, for the
    observation pattern of ``scene.uv``; the points are eliminated with the Schur
    complement as in :func:`refine`.

    Parameters
    ----------
    scene : transcalib.simulate.Scene
        With ``noise_px > 0``.
    distortion : {"none", "radial2", "opencv5"}, optional
        Model whose parameters are bounded; default from the number of true coefficients.
    estimate_skew : bool
        Include the skew as a parameter.
    estimate_view_rotations : bool or sequence of int
        Include a rotation per view ``i >= 1`` or per listed view (as :func:`refine`), at zero: the bound on
        how well a robot rotation could be detected (``view{i}_rx`` ..., degrees).

    Returns
    -------
    dict of str to float
        Lower bound of the standard deviation of each parameter, named as in
        ``Calibration.std`` (rotations in degrees).
    """
    if not scene.noise_px > 0:
        raise InputError(f"the CRLB needs a scene with pixel noise > 0, got noise_px={scene.noise_px!r}")
    n_true = np.asarray(scene.dist).size
    if distortion is None:
        distortion = {0: "none", 2: "radial2"}.get(n_true, "opencv5")
    if distortion not in DIST_MODELS:
        raise InputError(f"distortion must be one of {sorted(DIST_MODELS)}, got {distortion!r}")
    n_views, n_points = scene.uv.shape[:2]
    seen = np.all(np.isfinite(scene.uv), axis=2)
    used_idx = np.flatnonzero(seen.sum(axis=0) >= 2)
    t_sigma = np.zeros(n_views)
    if scene.robot_noise > 0:
        t_sigma[1:] = scene.robot_noise
    lay = _Layout(n_views, dist_size(distortion), bool(estimate_skew), estimate_view_rotations, t_sigma > 0)
    K = scene.K
    state = _State(np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]]),
                   _initial_dist(scene, dist_size(distortion)), scene.R.copy(),
                   np.tile(np.eye(3), (n_views, 1, 1)), scene.T_true.copy(), scene.X[used_idx].copy())
    tw = np.where(t_sigma > 0, scene.noise_px / np.where(t_sigma > 0, t_sigma, 1.0), 0.0)
    data = _build_data(scene.uv_true, seen, used_idx, scene.T_true, tw)
    Sinv, _, _ = _covariance(state, lay, data, [np.ones(len(p)) for p in data.pts])
    scale = np.where(lay.rotation_mask(), _RAD2DEG, 1.0)
    sd = scene.noise_px * np.sqrt(np.diag(Sinv)) * scale
    return {nm: float(v) for nm, v in zip(lay.names(), sd)}
