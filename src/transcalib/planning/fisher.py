"""Predicted accuracy of many candidate designs at once: the reduced Fisher information.

For a design ``T (n_views, 3)`` and the model's points ``X_j``, every visible observation
``u_ij = pi(K, dist, R (X_j - T_i))`` contributes ``J_ij^T J_ij / sigma_px^2`` to the Fisher
information of the global parameters ``g = (fx, fy, cx, cy[, k], w[, T_1..T_{m-1}])`` (``w``:
the rotation update ``R <- exp([w]x) R``; the translations of views ``i >= 1`` with the
prior ``I / sigma_T^2`` when the robot is imprecise) and of the points. The points are
eliminated by the Schur complement, exactly as :func:`transcalib.crlb` does:

    S = U - sum_j W_j V_j^-1 W_j^T,        cov(g) = sigma_px^2 S^-1,

with ``U = sum J_g^T J_g``, ``W_j = sum_i J_g^T J_X``, ``V_j = sum_i J_X^T J_X``. Here every
array carries a leading batch axis of designs, so that an optimiser scores all candidate
exchanges of a step in one vectorised call (no loop over designs, views or points).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..geometry.camera import DIST_NAMES, dist_size, pad_dist, project_camera_frame
from .model import PlanOptions

__all__ = ["Prediction", "predict", "parameter_names"]

_RAD2DEG = 180.0 / np.pi


class Prediction(NamedTuple):
    """Predicted standard deviations of a batch of ``B`` designs.

    ``std`` maps parameter names (as :func:`transcalib.crlb`) to ``(B,)`` arrays (px,
    degrees for ``rx, ry, rz``; ``inf`` for a design that does not determine them);
    ``visible (B, n_views)`` is the fraction of points each view sees; ``point_std (B,
    n_points)`` the RMS over x, y, z of each point's predicted std (robot units; NaN for
    points seen in fewer than 2 views), when asked for.
    """

    std: dict
    visible: np.ndarray
    point_std: np.ndarray | None


def parameter_names(options: PlanOptions, n_views: int) -> tuple:
    """Names of the global parameters in the order of ``S``."""
    names = ["fx", "fy", "cx", "cy"] + list(DIST_NAMES[: dist_size(options.distortion)]) + ["rx", "ry", "rz"]
    if options.robot_noise > 0:
        names += [f"T{i}_{a}" for i in range(1, n_views) for a in "xyz"]
    return tuple(names)


def _jacobians(options: PlanOptions, X: np.ndarray, T: np.ndarray):
    """Observation Jacobians ``J_g (B, m, n, 2, q)``, ``J_X (B, m, n, 2, 3)`` and the mask of seen ones."""
    R = options.R
    K = options.K
    xc = (X[None, None, :, :] - T[:, :, None, :]) @ R.T  # (B, m, n, 3)
    z = xc[..., 2]
    front = z > 1e-9 * options.distance
    intr = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], 0.0])
    pr = project_camera_frame(intr, pad_dist(options.dist), np.moveaxis(xc, -1, 0), jacobian=True, valid=front)
    w, h = options.image_size
    m = options.margin_px
    u, v = pr.pred[0], pr.pred[1]
    seen = front & (u >= -0.5 + m) & (u <= w - 0.5 - m) & (v >= -0.5 + m) & (v <= h - 0.5 - m)
    P = np.moveaxis(pr.P, (0, 1), (-2, -1))  # (B, m, n, 2, 3)
    JX = P @ R
    # d xc / dw = -[xc]x  ->  J_rot = P (-[xc]x)
    x0, x1, x2 = xc[..., 0], xc[..., 1], xc[..., 2]
    zero = np.zeros_like(x0)
    negskew = np.stack([np.stack([zero, x2, -x1], -1), np.stack([-x2, zero, x0], -1),
                        np.stack([x1, -x0, zero], -1)], -2)
    Jrot = P @ negskew
    nd = dist_size(options.distortion)
    Jin = np.moveaxis(pr.J_intr[:4], 0, -1)  # (2, B, m, n, 4) -> moved below
    Jin = np.moveaxis(Jin, 0, -2)
    parts = [Jin]
    if nd:
        parts.append(np.moveaxis(np.moveaxis(pr.J_dist[:nd], 0, -1), 0, -2))
    parts.append(Jrot)
    return np.concatenate(parts, axis=-1), JX, seen


def _reduced(options: PlanOptions, Jg, JX, w):
    """Reduced information ``S (B, p, p)`` (unit pixel noise), ``V^-1`` and ``W`` of the used points."""
    B, m, n = w.shape
    q = Jg.shape[-1]
    wf = w.astype(float)[..., None, None]
    Jgw, JXw = Jg * wf, JX * wf
    U = np.einsum("bmnaq,bmnar->bqr", Jgw, Jg, optimize=True)
    Vm = np.einsum("bmnai,bmnaj->bmnij", JXw, JX, optimize=True)
    Wm = np.einsum("bmnaq,bmnaj->bmnqj", Jgw, JX, optimize=True)
    V = Vm.sum(axis=1)
    W = Wm.sum(axis=1)
    if options.robot_noise > 0:  # translations of views 1.. : J_T = -J_X
        rho2 = (options.noise_px / options.robot_noise) ** 2
        nt = 3 * (m - 1)
        Ufull = np.zeros((B, q + nt, q + nt))
        Ufull[:, :q, :q] = U
        UcT = -Wm[:, 1:].sum(axis=2)  # (B, m-1, q, 3)
        Ufull[:, :q, q:] = np.moveaxis(UcT, 1, 2).reshape(B, q, nt)
        Ufull[:, q:, :q] = np.swapaxes(Ufull[:, :q, q:], 1, 2)
        UTT = Vm[:, 1:].sum(axis=2) + rho2 * np.eye(3)  # (B, m-1, 3, 3)
        idx = np.arange(m - 1)
        blocks = np.zeros((B, m - 1, 3, m - 1, 3))
        blocks[:, idx, :, idx, :] = np.moveaxis(UTT, 1, 0)
        Ufull[:, q:, q:] = blocks.reshape(B, nt, nt)
        WT = -np.moveaxis(Vm[:, 1:], 1, 2).reshape(B, n, nt, 3)  # rows of T_i: -V_ij
        U, W = Ufull, np.concatenate([W, WT], axis=2)
    Vinv, ok = inv3_spd(V)
    Y = W @ Vinv  # (B, n, p, 3)
    S = U - np.einsum("bnpi,bnqi->bpq", Y, W, optimize=True)
    return 0.5 * (S + np.swapaxes(S, 1, 2)), Vinv, Y, ok


def predict(options: PlanOptions, X: np.ndarray, T, *, points: bool = False) -> Prediction:
    """Predicted standard deviations (the CRLB) of each design of a batch.

    Parameters
    ----------
    options : PlanOptions
    X : (n_points, 3) float
        Scene points (robot frame), e.g. :func:`~transcalib.planning.model.scene_points`.
    T : (B, n_views, 3) or (n_views, 3) float
        Designs: camera translations (robot frame).
    points : bool
        Also predict each point's standard deviation.

    Returns
    -------
    Prediction
        ``std[name][b] = noise_px * sqrt((S_b^-1)_kk)`` (degrees for the rotation), equal to
        :func:`transcalib.crlb` of the scene :func:`~transcalib.planning.model.design_scene`.
    """
    T = np.asarray(T, dtype=float)
    single = T.ndim == 2
    T = T[None] if single else T
    Jg, JX, seen = _jacobians(options, X, T)
    used = seen.sum(axis=1) >= 2  # (B, n): a point needs 2 views
    for _ in range(2):  # again without points whose rays turn out (nearly) parallel
        S, Vinv, Y, ok = _reduced(options, Jg, JX, seen & used[:, None, :])
        if np.all(ok | ~used):
            break
        used &= ok
    names = parameter_names(options, T.shape[1])
    Sinv, good = _inverse_spd(S)
    var = np.where(good[:, None], np.einsum("bii->bi", Sinv), np.inf)
    scale = np.array([_RAD2DEG if nm in ("rx", "ry", "rz") else 1.0 for nm in names])
    sd = options.noise_px * np.sqrt(var) * scale
    std = {nm: (sd[0, k] if single else sd[:, k]) for k, nm in enumerate(names)}
    vis = seen.mean(axis=2)
    pstd = None
    if points:
        # cov(X_j) = V_j^-1 + Y_j^T S^-1 Y_j
        vX = np.einsum("bnii->bni", Vinv) + np.einsum("bnpi,bpq,bnqi->bni", Y, Sinv, Y, optimize=True)
        pstd = options.noise_px * np.sqrt(np.maximum(vX.mean(axis=2), 0.0))
        pstd = np.where(used & good[:, None], pstd, np.nan)
        pstd = pstd[0] if single else pstd
    return Prediction(std, vis[0] if single else vis, pstd)


def _inverse_spd(S: np.ndarray):
    """Inverses of a batch of symmetric matrices ``S (B, p, p)`` (Jacobi-scaled) and which are
    positive definite (Cholesky succeeds): the others do not determine every parameter."""
    d = 1.0 / np.sqrt(np.maximum(np.einsum("bii->bi", S), 1e-300))
    Ss = S * d[:, :, None] * d[:, None, :]
    good = np.ones(len(S), bool)
    try:
        np.linalg.cholesky(Ss)
    except np.linalg.LinAlgError:  # find the failing designs (batched Cholesky stops at the first)
        for b in range(len(S)):
            try:
                np.linalg.cholesky(Ss[b])
            except np.linalg.LinAlgError:
                good[b] = False
    # positive definite but numerically singular (the bound of refine's covariance)
    good &= np.linalg.cond(Ss) < 1e13 if len(S) else good
    Ss[~good] = np.eye(S.shape[1])
    return np.linalg.inv(Ss) * d[:, :, None] * d[:, None, :], good


def inv3_spd(V: np.ndarray):
    """Inverses of symmetric 3x3 blocks ``V (..., 3, 3)`` by the Jacobi-scaled adjugate, and
    which are well determined (scaled determinant > 1e-12, the rule of :func:`transcalib.crlb`);
    the others get a zero inverse."""
    d = 1.0 / np.sqrt(np.maximum(np.stack([V[..., 0, 0], V[..., 1, 1], V[..., 2, 2]], -1), 1e-300))
    A = V * d[..., :, None] * d[..., None, :]
    a, b, c = A[..., 0, 0], A[..., 0, 1], A[..., 0, 2]
    e, f, h = A[..., 1, 1], A[..., 1, 2], A[..., 2, 2]
    c00, c01, c02 = e * h - f * f, c * f - b * h, b * f - c * e
    c11, c12, c22 = a * h - c * c, b * c - a * f, a * e - b * b
    det = a * c00 + b * c01 + c * c02
    ok = det > 1e-12
    idet = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    inv = np.stack([np.stack([c00, c01, c02], -1), np.stack([c01, c11, c12], -1),
                    np.stack([c02, c12, c22], -1)], -2) * idet[..., None, None]
    return inv * d[..., :, None] * d[..., None, :], ok
