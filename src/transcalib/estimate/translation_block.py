"""The normal equations of one pure-translation session, every view at once.

Inside one session the camera only translates. In camera-aligned point coordinates
``y_j = R X_j`` an observation is ``x_c = y_j - c_i`` with the view centre ``c_i = R
T_i``, so the rotation update ``R <- exp([w]x) R`` only moves the centres,
``d x_c = [c_i]x w``, and its Jacobian is the point Jacobian times a per-view constant::

    J_y,ij = P_ij,     J_w,ij = P_ij [c_i]x,     P_ij = d pixel / d x_c.

The point blocks and their coupling to the rotation are then sums over views of
``Q_ij = P_ij^T P_ij`` with per-view coefficients (one small matrix product)::

    V'_j = sum_i Q_ij,     W'_w,j = sum_i [c_i]x^T Q_ij = -sum_k [e_k]x sum_i c_ik Q_ij,

the rotation's own columns of the Jacobian are never formed per point, and all views are
handled by the same few numpy calls. The blocks are then expressed for the robot-axes
points the bundle adjuster uses (``X_j = R^T y_j``: ``dX_j = R^T (dy_j + [y_j]x dw)``)::

    V_j = R^T V'_j R,    W_A,j = W'_A,j R,    W_w,j = (W'_w,j + [y_j]x V'_j) R,
    U_Aw = U'_Aw - sum_j W'_A,j [y_j]x,
    U_ww = U'_ww - sum_j (M_j + M_j^T) + sum_j [y_j]x^T V'_j [y_j]x,   M_j = W'_w,j [y_j]x,
    b_w = b'_w + sum_j y_j x b'_j,    b_X,j = R^T b'_j,

so that the result is the general assembly's
(:func:`transcalib.estimate.bundle.normal_equations`) to rounding (tests/test_refine.py).
"""

from __future__ import annotations

import numpy as np

from ..geometry.camera import project_camera_frame
from ..geometry.rotation import skew

__all__ = ["applies", "normal_equations", "residuals"]


def applies(state, lay) -> bool:
    """Whether :func:`normal_equations` can assemble ``lay``'s system at ``state``: one
    pure-translation session (no flange rotations, no offset, no per-view rotations,
    translations or robot pose errors among the parameters or in the state)."""
    return (state.F is None and not lay.rot_views and not lay.i_T and not lay.t_free
            and not np.any(state.t) and not lay.i_robot and (state.E is None or not np.any(state.E)))


def normal_equations(state, lay, uv: np.ndarray, seen: np.ndarray, weight, loss: str, c: float, loss_weights):
    """The Gauss-Newton normal equations of points seen in most views, all views at once.

    Parameters
    ----------
    state : transcalib.estimate.layout.State
        ``X`` holds the points ``(n, 3)``.
    lay : transcalib.estimate.layout.Layout
        Intrinsics, distortion and the rotation (:func:`applies`).
    uv : (2, n_views, n) float
        Observed pixels (any finite value where not seen).
    seen : (n_views, n) bool
    weight : (n_views, n) float or None
        Observation weights (0 where not seen); None: ones where seen.
    loss, c : str, float
        Loss and its scale; a robust loss multiplies ``weight`` by its IRLS weights.
    loss_weights : callable
        :func:`transcalib.estimate.bundle.loss_weights`.

    Returns
    -------
    U (p, p), W (p, 3, n), V (3, 3, n), b_g (p,), b_X (3, n), cost
        As :func:`transcalib.estimate.bundle.normal_equations` (without priors), with
        ``0.5 sum rho(|r|^2)`` over the seen observations (inf if one of them is behind
        the camera).
    """
    R = state.R
    y = R @ state.X.T  # (3, n) points in camera axes
    centres = R @ state.T.T  # (3, V) view centres c_i in camera axes
    xc = y[:, None, :] - centres[:, :, None]  # (3, V, n)
    unit = weight is None and loss == "linear" and seen.all()  # every weight 1: nothing to whiten
    weight = seen.astype(float) if weight is None else weight
    proj = project_camera_frame(state.intr, state.dist5, xc, jacobian=True, valid=seen,
                                dist_jacobian=lay.dist_free)
    r = np.where(seen, uv - proj.pred, 0.0)  # (2, V, n)
    e2 = r[0] * r[0] + r[1] * r[1]
    if loss == "linear":
        rho = float(np.sum(e2))
    else:
        rho_all, irls = loss_weights(e2, loss, c)
        rho = float(np.sum(rho_all, where=seen))
        weight = weight * irls
    cost = 0.5 * rho if not np.any(seen & (xc[2] <= 0)) else np.inf

    P = proj.P  # (2, 3, V, n)
    JA = _camera_columns(proj, lay)  # (m, 2, V, n): intrinsics, distortion
    if not unit:  # whitened rows: sums of products carry the weights once
        root = np.sqrt(weight)
        P *= root
        r *= root
        JA *= root
    m = JA.shape[0]

    # point blocks in camera axes: V' = sum_i Q_i, and sum_i c_ik Q_i for the rotation
    Q = np.einsum("kavn,kbvn->vabn", P, P)  # (V, 3, 3, n)
    coef = np.vstack([np.ones(centres.shape[1]), centres])  # (4, V)
    V_cam, M0, M1, M2 = np.tensordot(coef, Q, axes=1)  # each (3, 3, n)
    W_cam = np.empty((lay.n_common, 3, y.shape[1]))
    W_cam[:m] = np.einsum("mkvn,kdvn->mdn", JA, P)
    W_cam[m:] = -np.stack([M1[2] - M2[1], M2[0] - M0[2], M0[1] - M1[0]])  # -sum_k [e_k]x M_k
    b_cam = np.einsum("kdvn,kvn->dn", P, r)
    U, bg = _global_block(JA, P, r, Q, centres)
    return (*_robot_axes(U, bg, V_cam, W_cam, b_cam, y, R, m), cost)


def residuals(state, uv: np.ndarray, seen: np.ndarray) -> np.ndarray | None:
    """Residuals ``(2, n_views, n)`` of points seen in most views (0 where unseen), every
    view projected at once; None if a seen point is behind the camera."""
    y = state.R @ state.X.T
    xc = y[:, None, :] - (state.R @ state.T.T)[:, :, None]  # (3, V, n)
    if np.any(seen & (xc[2] <= 0)):
        return None
    return np.where(seen, uv - project_camera_frame(state.intr, state.dist5, xc, valid=seen).pred, 0.0)


def _global_block(JA, P, r, Q, centres):
    """``U'`` and ``b'_g`` of the global parameters (camera columns, then rotation) in
    camera axes, from per-view sums: the rotation's Jacobian ``P_ij [c_i]x`` is never formed."""
    m = JA.shape[0]
    F = np.einsum("mkvn,kdvn->vmd", JA, P)  # per view: sum_j JA^T P
    Qv = Q.sum(axis=-1)  # (V, 3, 3)
    bv = np.einsum("kdvn,kvn->vd", P, r)  # per view: sum_j P^T r
    C = np.array([skew(c) for c in centres.T])  # (V, 3, 3): [c_i]x
    U = np.empty((m + 3, m + 3))
    flat = JA.reshape(m, r.size)  # (m, 2 V n); m is 0 when every intrinsic is known
    U[:m, :m] = flat @ flat.T
    U[:m, m:] = np.einsum("vmd,vde->me", F, C)
    U[m:, m:] = np.einsum("vda,vde,veb->ab", C, Qv, C)  # sum_i [c_i]x^T Q_i [c_i]x
    bg = np.concatenate([flat @ r.reshape(-1), np.einsum("vda,vd->a", C, bv)])
    return U, bg


def _camera_columns(proj, lay) -> np.ndarray:
    """d pixel / d (free intrinsics, free distortion coefficients) ``(m, 2, V, n)``, in
    one new array."""
    q, k = lay.intr_basis.shape[1], len(lay.dist_free)
    cols = np.empty((q + k, 2) + proj.xd.shape)
    proj.intrinsic_jacobian(lay.intr_basis, out=cols[:q])
    if k:
        cols[q:] = proj.J_dist
    return cols


def _robot_axes(U, bg, V_cam, W_cam, b_cam, y, R, m):
    """The normal equations for robot-axes points (module docstring) from the camera-axes
    ones: ``(U, W, V, b_g, b_X)``."""
    n = y.shape[1]
    Yx = np.array([[np.zeros(n), -y[2], y[1]], [y[2], np.zeros(n), -y[0]], [-y[1], y[0], np.zeros(n)]])  # [y]x
    W_A, W_w = W_cam[:m], W_cam[m:]
    M = np.einsum("adn,den->ae", W_w, Yx)  # sum_j W'_w,j [y_j]x
    U[:m, m:] -= np.einsum("mdn,den->me", W_A, Yx)
    VY = np.einsum("den,ebn->dbn", V_cam, Yx)  # V' [y]x
    U[m:, m:] += np.einsum("dan,dbn->ab", Yx, VY) - M - M.T  # + sum_j [y]x^T V' [y]x
    U[m:, :m] = U[:m, m:].T
    bg[m:] += [y[1] @ b_cam[2] - y[2] @ b_cam[1], y[2] @ b_cam[0] - y[0] @ b_cam[2],
               y[0] @ b_cam[1] - y[1] @ b_cam[0]]  # sum_j y_j x b'_j
    W_cam[m:] = W_w + np.einsum("adn,den->aen", Yx, V_cam)  # W'_w + [y]x V'
    W = np.matmul(R.T, W_cam)  # W[p, b] = sum_d W_cam[p, d] R[d, b]
    V = np.matmul(R.T, (R.T @ V_cam.reshape(3, -1)).reshape(3, 3, n))  # V[a, b] = R^T V' R
    return 0.5 * (U + U.T), W, V, bg, R.T @ b_cam
