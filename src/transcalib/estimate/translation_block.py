"""The reduced normal equations of one pure-translation session, every view at once.

Inside one session the camera only translates. In camera-aligned point coordinates
``y_j = R X_j`` an observation is ``x_c = y_j - c_i`` with the view centre ``c_i = R
T_i``, so the rotation update ``R <- exp([w]x) R`` only moves the centres,
``d x_c = [c_i]x w``, and its Jacobian is the point Jacobian times a per-view constant::

    J_y,ij = P_ij,     J_w,ij = P_ij [c_i]x,     P_ij = d pixel / d x_c.

The point blocks and their coupling to the rotation are then sums over views of
``Q_ij = P_ij^T P_ij`` with per-view coefficients (one small matrix product)::

    V'_j = sum_i Q_ij,     W'_w,j = sum_i [c_i]x^T Q_ij = -sum_k [e_k]x sum_i c_ik Q_ij,

the rotation's own columns of the Jacobian are never formed per point, and all views are
handled by the same few numpy calls. The Schur complement ``S`` and its right-hand side
do not depend on how the points are parametrised; the per-point blocks are returned in
robot coordinates (``V_j = R^T V'_j R``, ``W_j = W'_j R`` plus ``[y_j]x V'_j R`` in the
rotation rows), so that the result equals the general assembly of
:func:`transcalib.estimate.bundle.reduced_system` to rounding (tests/test_refine.py).
"""

from __future__ import annotations

import numpy as np

from ..geometry.camera import project_camera_frame

__all__ = ["applies", "translation_block"]


def applies(state, lay) -> bool:
    """Whether :func:`translation_block` can assemble ``lay``'s system at ``state``: one
    pure-translation session (no flange rotations, no offset, no per-view rotations or
    translations among the parameters)."""
    return (state.F is None and not lay.rot_views and not lay.i_T and not lay.t_free
            and not np.any(state.t))


def translation_block(state, lay, uv: np.ndarray, seen: np.ndarray, weight, loss: str, c: float, loss_weights):
    """Reduced normal equations of a block of points seen in every view (with weights).

    Parameters
    ----------
    state : bundle.State
        ``X`` holds the block's points ``(n, 3)``.
    lay : bundle.Layout
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
    S (p, p), rhs (p,), Vinv (3, 3, n), det (n,), Y (p, 3, n), bX (3, n), cost, U_diag (p,)
        As :func:`transcalib.estimate.bundle.schur` returns them for robot coordinates;
        ``0.5 sum rho(|r|^2)`` over the seen observations (inf if one of them is behind
        the camera); the diagonal of ``U`` in camera axes (:class:`bundle.Reduced`).
    """
    R = state.R
    y = R @ state.X.T  # (3, n) points in camera axes
    centres = R @ state.T.T  # (3, V) view centres c_i in camera axes
    xc = y[:, None, :] - centres[:, :, None]  # (3, V, n)
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

    root = np.sqrt(weight)  # whitened rows: sums of products carry the weights once
    P = proj.P * root  # (2, 3, V, n)
    r *= root
    JA = _camera_columns(proj, lay) * root  # (m, 2, V, n): intrinsics, distortion
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
    return (*_schur_robot_axes(U, bg, V_cam, W_cam, b_cam, y, R, m), cost, np.diag(U).copy())


def _global_block(JA, P, r, Q, centres):
    """``U`` and ``b_g`` of the global parameters (camera columns, then rotation) from
    per-view sums: the rotation's Jacobian ``P_ij [c_i]x`` is never formed."""
    m, n_views = JA.shape[0], centres.shape[1]
    F = np.einsum("mkvn,kdvn->vmd", JA, P)  # per view: sum_j JA^T P
    Qv = Q.sum(axis=-1)  # (V, 3, 3)
    bv = np.einsum("kdvn,kvn->vd", P, r)  # per view: sum_j P^T r
    C = np.array([_cross(c) for c in centres.T])  # (V, 3, 3): [c_i]x
    U = np.empty((m + 3, m + 3))
    flat = JA.reshape(m, r.size)  # (m, 2 V n); m is 0 when every intrinsic is known
    U[:m, :m] = flat @ flat.T
    U[:m, m:] = np.einsum("vmd,vde->me", F, C)
    U[m:, :m] = U[:m, m:].T
    U[m:, m:] = np.einsum("vda,vde,veb->ab", C, Qv, C)  # sum_i [c_i]x^T Q_i [c_i]x
    bg = np.concatenate([flat @ r.reshape(-1), np.einsum("vda,vd->a", C, bv)])
    return U, bg


def _cross(c) -> np.ndarray:
    """``[c]x`` (3, 3) of one 3-vector."""
    return np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])


def _camera_columns(proj, lay) -> np.ndarray:
    """d pixel / d (free intrinsics, free distortion coefficients) ``(m, 2, V, n)``."""
    cols = proj.intrinsic_jacobian(lay.intr_basis)
    if lay.dist_free:
        cols = np.concatenate([cols, proj.J_dist])
    return cols


def _schur_robot_axes(U, bg, V_cam, W_cam, b_cam, y, R, m):
    """The Schur complement of the camera-axes blocks, with the per-point arrays in robot
    axes: ``V = R^T V' R``, ``b = R^T b'``, ``W = W' R`` (plus ``[y]x V' R`` in the
    rotation rows, absorbed into ``Y``). Returns ``S, rhs, Vinv, det, Y, bX``."""
    from .bundle import inv3_spd

    n = y.shape[1]
    V = np.matmul(R.T, (R.T @ V_cam.reshape(3, -1)).reshape(3, 3, n))  # V[a, b] = R^T V' R
    Vinv, det = inv3_spd(V)
    W = np.matmul(R.T, W_cam)  # W[p, b] = sum_d W'[p, d] R[d, b]
    Y = np.einsum("pdn,den->pen", W, Vinv)  # = W' V'^-1 R: camera-axes Y, in robot axes
    bX = R.T @ b_cam
    p = U.shape[0]
    S = U - Y.reshape(p, -1) @ W.reshape(p, -1).T
    rhs = bg - Y.reshape(p, -1) @ bX.reshape(-1)
    # robot-axes points move with the rotation at fixed camera-axes points: dX = R^T [y]x dw
    for a in range(3):  # row a of [y]x R: y_{a+1} R[a+2] - y_{a+2} R[a+1]
        a1, a2 = (a + 1) % 3, (a + 2) % 3
        Y[m + a] += R[a2][:, None] * y[a1] - R[a1][:, None] * y[a2]
    return 0.5 * (S + S.T), rhs, Vinv, det, Y, bX
