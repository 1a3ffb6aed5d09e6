"""Normal equations with one 3x3 block per point: Schur elimination, solves, covariances.

The Gauss-Newton normal matrix of a bundle problem is ``[[U, W], [W^T, V]]`` with ``V``
block-diagonal (one 3x3 block ``V_j`` per point, arrays laid out with the points last:
``V (3, 3, n)``, ``W (p, 3, n)``). Eliminating the points ::

    S = U - sum_j W_j V_j^-1 W_j^T,    S dg = b_g - sum_j W_j V_j^-1 b_j,
    dX_j = V_j^-1 (b_j - W_j^T dg),

costs O(n) time and memory (batched 3x3 inverses, BLAS products; no loop over points).
Nothing here knows about cameras.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


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


def solve_spd(S: np.ndarray, rhs: np.ndarray):
    """Solve ``S x = rhs`` (Jacobi-scaled Cholesky); None if not positive definite, or
    so nearly singular that the solution overflows."""
    diag = np.diag(S)
    if not np.all(diag > 0):
        return None
    d = 1.0 / np.sqrt(diag)
    with np.errstate(over="ignore", invalid="ignore"):
        try:
            L = np.linalg.cholesky(S * d[:, None] * d[None, :])
        except np.linalg.LinAlgError:
            return None
        x = d * np.linalg.solve(L.T, np.linalg.solve(L, rhs * d))
    return x if np.all(np.isfinite(x)) else None


def psd_factor(M: np.ndarray) -> np.ndarray:
    """``L`` with ``L L^T = M`` for a symmetric positive semi-definite ``M`` (from its
    eigen-decomposition: exact for singular ``M`` too)."""
    w, V = np.linalg.eigh(M)
    return V * np.sqrt(np.maximum(w, 0.0))


class NormalEquations(NamedTuple):
    """``[[U, W], [W^T, V]] [dg; dX] = [b_g; b_X]`` (points last) and the cost at the
    linearisation point (``inf`` if it is not a valid state)."""

    U: np.ndarray  # (p, p)
    W: np.ndarray  # (p, 3, n)
    V: np.ndarray  # (3, 3, n)
    bg: np.ndarray  # (p,)
    bX: np.ndarray  # (3, n)
    cost: float

    def solve(self, mu: float):
        """The Levenberg-Marquardt step with damping ``mu`` relative to the diagonal:
        ``((dg, dX), predicted)`` with ``predicted`` the decrease of the cost that the
        damped quadratic model predicts, or None if the damped system is not positive
        definite."""
        U, W, V, bg, bX = self.U, self.W, self.V, self.bg, self.bX
        dU = np.maximum(np.diag(U), 1e-12 * max(np.diag(U).max(), 1e-300))
        dV = np.stack([V[0, 0], V[1, 1], V[2, 2]])  # (3, n)
        dV = np.maximum(dV, 1e-12 * dV.max(axis=0))
        Vd = V.copy()
        for a in range(3):
            Vd[a, a] += mu * dV[a]
        S, rhs, Vinv, det, _ = schur(U + np.diag(mu * dU), W, Vd, bg, bX)
        dg = solve_spd(S, rhs) if np.all(det > 0) else None
        if dg is None:
            return None
        dX = matvec3(Vinv, bX - np.tensordot(dg, W, axes=1))  # (3, n)
        predicted = 0.5 * (dg @ (mu * dU * dg + bg) + np.sum(dX * (mu * dV * dX + bX)))
        return (dg, dX), float(predicted)


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

    def solve(self, mu: float = 0.0):
        """The Gauss-Newton step ``((dg, dX), None)`` (no damping: ``mu`` must be 0; the
        points' blocks are already eliminated), or None if ``S`` or a point block is not
        positive definite."""
        if mu != 0.0:
            raise ValueError("a reduced system solves undamped steps only")
        dg = solve_spd(self.S, self.rhs) if np.all(self.det > 0) else None
        return None if dg is None else ((dg, self.point_step(dg)), None)

    def point_step(self, dg: np.ndarray) -> np.ndarray:
        """``dX (3, n)`` given the global step ``dg (p,)``."""
        return np.einsum("abn,bn->an", self.Vinv, self.bX) - np.tensordot(dg, self.Y, axes=1)

    def point_variances(self, Sinv: np.ndarray) -> np.ndarray:
        """Diagonal of each point's covariance ``(n, 3)`` (unit noise) given ``S^-1``:
        ``diag(V_j^-1) + |L^T Y_j|^2`` column-wise, with ``S^-1 = L L^T``."""
        n = self.Y.shape[2]
        L = psd_factor(Sinv)
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
