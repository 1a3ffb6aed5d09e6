"""The calibration's part of the depth uncertainty: its covariance carried to depth.

A matched pixel keeps its image positions when the calibration changes; what changes is
the depth triangulated from them. On a grid of reference pixels and inverse depths
``rho`` (17 x 13 x 5 nodes), the point ``r / rho`` is projected into every source view
with the calibration ``theta``; for each calibration parameter ``theta_k`` we
re-triangulate the same pixels with ``theta + delta_k e_k`` (a one-dimensional
Gauss-Newton on ``rho`` along the reference pixel's new ray, the sources' centres
``t_j' = exp([w]x) t_j`` turning with a rotation ``w``), so that
``g_k = d rho / d theta_k``. Then ``var(rho) = g^T Sigma g`` with ``Sigma`` the
calibration's covariance (intrinsics, distortion and rotation; the hand-eye offset and
robot translations are not carried, nor the small rotations between the views of a
session, which change the sources' positions but hardly the derivatives),
``sigma_z / z = sigma_rho / rho``, interpolated trilinearly to every pixel.
"""

from __future__ import annotations

import numpy as np

from ..geometry.camera import DIST_NAMES, INTRINSIC_PARAMS, Camera, pixels_to_rays, project_camera_frame
from ..geometry.rotation import rotvec_to_matrix

__all__ = ["calibration_depth_std"]

_ROTATION = ("rx", "ry", "rz")
GRID = (17, 13, 5)  # u, v, rho nodes


def _carried(names) -> list[int]:
    return [k for k, nm in enumerate(names) if nm in INTRINSIC_PARAMS or nm in DIST_NAMES or nm in _ROTATION]


def _perturbed(camera: Camera, name: str, delta: float):
    """``(intrinsics (5,), dist5 (5,), rotation (3, 3) left factor)`` with ``name`` moved by
    ``delta`` (rotations in degrees, as in the covariance)."""
    intr, dist5, turn = camera.intrinsics.copy(), camera.dist5.copy(), np.eye(3)
    if name in INTRINSIC_PARAMS:
        intr[list(INTRINSIC_PARAMS[name])] += delta
    elif name in DIST_NAMES:
        dist5[DIST_NAMES.index(name)] += delta
    else:
        w = np.zeros(3)
        w[_ROTATION.index(name)] = np.radians(delta)
        turn = rotvec_to_matrix(w)
    return intr, dist5, turn


def _triangulate(intr, dist5, turn, uv_ref, uv_src, t, rho0, iterations: int = 4) -> np.ndarray:
    """``rho`` along the ray of pixels ``uv_ref (G, 2)`` that best projects onto
    ``uv_src (J, 2, G)`` in sources at ``t (J, 3)`` (one-dimensional Gauss-Newton from
    ``rho0 (G,)``)."""
    K = np.array([[intr[0], intr[4], intr[2]], [0.0, intr[1], intr[3]], [0.0, 0.0, 1.0]])
    r = pixels_to_rays(K, uv_ref, dist5).T  # (3, G)
    tt = t @ turn.T  # (J, 3)
    rho = rho0.copy()
    for _ in range(iterations):
        h = 1e-6 * rho
        f0, f1 = (project_camera_frame(intr, dist5, r[:, None, :] - q[None, None, :] * tt.T[:, :, None]).pred
                  for q in (rho, rho + h))
        res, J = f0 - np.moveaxis(uv_src, 1, 0), (f1 - f0) / h  # (2, J, G)
        rho = rho - (J * res).sum(axis=(0, 1)) / (J * J).sum(axis=(0, 1))
    return rho


def calibration_depth_std(calibration, camera: Camera, t: np.ndarray, rho_range, shape, rho: np.ndarray):
    """``sigma_z / z`` at every known pixel from the calibration's covariance.

    Parameters
    ----------
    calibration : Calibration or Camera
        Needs ``cov`` and ``param_names``; without them, None is returned.
    camera : Camera
        The reference view's camera.
    t : (n_sources, 3) float
        Source centres in the reference's camera frame.
    rho_range : (2,) float
        Inverse depths searched.
    shape : (H, W)
    rho : (H, W) float32
        Inverse depth of every pixel (NaN: unknown).

    Returns
    -------
    (H, W) float32 or None
        Relative standard deviation (NaN where ``rho`` is).
    """
    cov, names = getattr(calibration, "cov", None), getattr(calibration, "param_names", ())
    keep = _carried(names) if cov is not None else []
    if not keep:
        return None
    h, w = shape
    gu, gv, gr = (np.linspace(0, w - 1, GRID[0]), np.linspace(0, h - 1, GRID[1]),
                  np.linspace(max(rho_range[0], 1e-12 * rho_range[1]), rho_range[1], GRID[2]))
    R_, V_, U_ = np.meshgrid(gr, gv, gu, indexing="ij")
    uv_ref, rho0 = np.column_stack([U_.ravel(), V_.ravel()]), R_.ravel()
    intr, dist5 = camera.intrinsics, camera.dist5
    r = camera.pixels_to_rays(uv_ref).T
    uv_src = project_camera_frame(intr, dist5, r[:, None, :] / rho0 - t.T[:, :, None]).pred  # (2, J, G)
    uv_src = np.moveaxis(uv_src, 0, 1)
    sd = np.sqrt(np.maximum(np.diag(cov)[keep], 0.0))
    G = np.zeros((len(keep), len(rho0)))
    for row, (k, s) in enumerate(zip(keep, sd)):  # a loop over the few calibration parameters
        delta = max(1e-3 * s, 1e-9)
        G[row] = (_triangulate(*_perturbed(camera, names[k], delta), uv_ref, uv_src, t, rho0) - rho0) / delta
    S = np.asarray(cov)[np.ix_(keep, keep)]
    rel = np.sqrt(np.maximum(np.einsum("kg,kl,lg->g", G, S, G), 0.0)) / rho0
    grid = rel.reshape(GRID[2], GRID[1], GRID[0])
    v, u = np.nonzero(np.isfinite(rho))
    coords = [(rho[v, u] - gr[0]) / (gr[-1] - gr[0]) * (GRID[2] - 1), v / max(h - 1, 1) * (GRID[1] - 1),
              u / max(w - 1, 1) * (GRID[0] - 1)]
    out = np.full(shape, np.nan, np.float32)
    out[v, u] = _trilinear(grid, coords)
    return out


def _trilinear(grid: np.ndarray, coords) -> np.ndarray:
    """Values of ``grid (n0, n1, n2)`` at fractional indices ``coords`` (three ``(n,)``
    arrays; clamped to the grid)."""
    idx, frac = [], []
    for c, n in zip(coords, grid.shape):
        c = np.clip(c, 0.0, n - 1.0)
        i = np.minimum(np.floor(c).astype(int), n - 2)
        idx.append(i)
        frac.append(c - i)
    out = np.zeros(len(coords[0]))
    for corner in range(8):  # the eight corners of each cell
        b = [(corner >> k) & 1 for k in range(3)]
        weight = np.prod([f if bit else 1.0 - f for f, bit in zip(frac, b)], axis=0)
        out += weight * grid[idx[0] + b[0], idx[1] + b[1], idx[2] + b[2]]
    return out
