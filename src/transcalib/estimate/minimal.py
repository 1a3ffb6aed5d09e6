"""The two-point minimal solver of the robust stage (paper §2.1).

Two points seen in four views determine ``A = K R`` (paper §2.1), so RANSAC draws pairs
of points, solves for ``A`` from them alone, triangulates *every* point with that ``A``
and the known translations, and scores the hypothesis by the reprojection errors.

Minimal solver
--------------
For point ``j`` seen in view ``i``, paper eq. 2 reads, with ``Y_j = A X_j``::

    lam_ij u_ij = Y_j - A T_i                        (u_ij = [u, v, 1], 3 equations)

Unknowns ``lam_ij`` (one per view), ``Y_j`` (3) and ``a = vec(A)`` (9, row-major, so
that ``A T_i = kron(I_3, T_i^T) a``). Eliminating ``lam_ij`` projects each block
onto the plane orthogonal to ``u_ij`` (``N_ij = I - u u^T / |u|^2``); eliminating
``Y_j`` leaves one quadratic form per point::

    m_j(a) = a^T M_j a,   M_j = sum_i kron(N_ij, T_i T_i^T) - W_j^T S_j^-1 W_j,
    S_j = sum_i N_ij,     W_j = sum_i kron(N_ij, T_i^T)          (S_j 3 x 3, W_j 3 x 9)

A point seen in ``k`` views constrains ``a`` by ``2k - 3`` equations, so a pair of
points seen in four views each (10 constraints, 8 degrees of freedom) determines ``A``
up to scale: ``a`` is the eigenvector of ``M_j1 + M_j2`` for the smallest eigenvalue
(exactly zero for noise-free data). Hypotheses are solved in batches (one batched 9 x 9
``eigh``), in Hartley-normalised coordinates (pixels: zero mean, mean distance
``sqrt(2)``; translations: unit mean norm). The same form summed over the inliers gives
the local-optimisation refit in O(n).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.triangulate import triangulate
from ..validate import as_uv_T
from .normalisation import hartley

__all__ = ["Problem", "normalise", "forms", "forms_sum", "null_vectors", "to_pixels", "solve_minimal"]


@dataclass(frozen=True)
class Problem:
    """Normalised data: ``x (n, V, 2)`` pixels (0 where unseen), ``seen (n, V)``,
    ``T (V, 3)`` translations, ``scale`` (normalised units per pixel), ``H``, ``t_scale``."""

    x: np.ndarray
    seen: np.ndarray
    T: np.ndarray
    scale: float
    H: np.ndarray
    t_scale: float


def normalise(uv: np.ndarray, T: np.ndarray) -> Problem:
    """Every observation Hartley-normalised (:func:`.normalisation.hartley`)."""
    norm = hartley(uv, T)
    seen = np.isfinite(uv[..., 0]).T  # (n, V)
    x = np.where(seen[..., None], uv.transpose(1, 0, 2) * norm.scale + norm.H[:2, 2], 0.0)
    return Problem(x=x, seen=seen, T=norm.T, scale=norm.scale, H=norm.H, t_scale=norm.t_scale)


def forms(pb: Problem, idx: np.ndarray) -> np.ndarray:
    """Quadratic forms ``M_j`` (len(idx), 9, 9) of the points ``idx`` (module docstring)."""
    x, seen, T = pb.x[idx], pb.seen[idx], pb.T
    u = np.concatenate([x, np.ones(x.shape[:2] + (1,))], axis=2)  # (n, V, 3)
    N = np.eye(3) - u[..., :, None] * u[..., None, :] / np.einsum("nva,nva->nv", u, u)[..., None, None]
    N *= seen[..., None, None]
    S = N.sum(axis=1)  # (n, 3, 3)
    W = np.einsum("nvab,vd->nabd", N, T).reshape(-1, 3, 9)
    TT = T[:, :, None] * T[:, None, :]
    M = np.einsum("nvab,vcd->nacbd", N, TT).reshape(-1, 9, 9)
    with np.errstate(all="ignore"):
        SW = np.linalg.solve(S, W)
    M -= np.einsum("nak,nal->nkl", W, SW)
    return M


def forms_sum(pb: Problem, idx: np.ndarray, chunk: int = 8192) -> np.ndarray:
    """``sum_j M_j`` over the points ``idx`` (9, 9), in chunks."""
    total = np.zeros((9, 9))
    for lo in range(0, len(idx), chunk):
        M = forms(pb, idx[lo: lo + chunk])
        total += np.nansum(M, axis=0)
    return total


def null_vectors(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvectors for the smallest eigenvalue of symmetric ``M`` (B, 9, 9) and a
    validity mask (False where the null space is not one-dimensional)."""
    M = 0.5 * (M + M.transpose(0, 2, 1))
    w, v = np.linalg.eigh(M)
    ok = np.isfinite(w).all(axis=1) & (w[:, 1] > 1e-10 * np.maximum(w[:, -1], 1e-300))
    return v[:, :, 0], ok


def to_pixels(pb: Problem, a: np.ndarray) -> np.ndarray:
    """Normalised ``a`` (..., 9) -> pixel ``A`` (..., 3, 3), ``||A[2]|| = 1`` (sign kept)."""
    A = np.linalg.solve(pb.H, a.reshape(-1, 3, 3)) / pb.t_scale
    return A / np.linalg.norm(A[:, 2], axis=1)[:, None, None]



def solve_minimal(uv, T, pairs) -> np.ndarray:
    """``A = K R`` from pairs of points (the two-point minimal solver, paper §2.1).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen.
    T : (n_views, 3) float
        Translations.
    pairs : (n_pairs, 2) int
        Point indices; the two points should be seen in >= 8 views counted per point
        (e.g. both in 4 views) whose translations span 3-D.

    Returns
    -------
    A : (n_pairs, 3, 3) float
        Pixel-unit ``A`` with ``||A[2]|| = 1`` and the sign that puts the pair in front of
        the camera; NaN for pairs that do not determine ``A``. Exact (to rounding) on
        noise-free data.
    """
    uv, T = as_uv_T(uv, T)
    pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
    pb = normalise(uv, T)
    M = forms(pb, pairs.ravel()).reshape(-1, 2, 9, 9).sum(axis=1)
    a, ok = null_vectors(M)
    A = to_pixels(pb, a)
    # sign: depths of the pair positive (triangulate with this A)
    for k in range(len(A)):  # one triangulation per pair: small, reference use only
        X = triangulate(A[k], uv[:, pairs[k]], T)
        z = np.einsum("a,vna->vn", A[k, 2], X[None] - T[:, None])
        if np.nanmedian(z) < 0:
            A[k] = -A[k]
    A[~ok] = np.nan
    return A


