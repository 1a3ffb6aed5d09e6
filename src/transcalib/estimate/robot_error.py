"""The robot's pose error: each view's true flange pose is the reported one times a small error.

A view's reported flange pose is ``(R_i, T_i)`` (flange -> robot base). Its true pose is ::

    R_i' = R_i exp([delta_i]x),     T_i' = T_i + eps_i,

with ``delta_i`` a rotation vector in the flange frame (radians) and ``eps_i`` a position
error in the base frame (robot units), independent per view with priors
``delta_i ~ N(0, sigma_rot^2 I)`` and ``eps_i ~ N(0, sigma_pos^2 I)``. In the bundle
adjuster's terms (:mod:`transcalib.estimate.bundle`, ``F_i = R_i^T``, the point in the
flange frame before the offset ``t``), eye-in-hand ::

    y_ij = exp(-[delta_i]x) F_i (X_j - T_i - eps_i)                     (1)

and eye-to-hand, where the model's poses are the inverted robot poses (``F_i = R_i``, ``T_i
= -R_i^T T_i^robot``; :mod:`transcalib.pipeline.motion`) and the flange carries the scene
points ``X_j`` ::

    y_ij = F_i exp([delta_i]x) X_j - F_i T_i + eps_i                     (2)

Without flange orientations (one orientation) ``F_i = I``: ``delta_i`` is then the
camera's rotation error about its own centre in the robot axes, and ``eps_i`` the camera
centre's position error (the flange rotation's lever arm to the camera is folded in).
The errors are nuisance parameters of the bundle adjustment (6 per view, global
parameters of the Schur step); their scales are estimated by variance components
(:mod:`transcalib.estimate.variance_components`).
"""

from __future__ import annotations

import numpy as np

from ..geometry.rotation import rotvec_to_matrix

__all__ = ["COMPONENTS", "flange_points", "jacobian", "sample_errors", "perturb_poses"]

#: The components of a view's pose error: flange rotation (rad; reported in degrees) and position (unit).
COMPONENTS = ("rot", "pos")


def flange_points(X: np.ndarray, T_i: np.ndarray, F: np.ndarray | None, e: np.ndarray, inverted: bool):
    """Points of one view in the flange frame (before the offset) under the pose error ``e``.

    Parameters
    ----------
    X : (3, n) float
        The points ``X_j`` (columns).
    T_i : (3,) float
        The view's reported position (model terms).
    F : (3, 3) float or None
        The view's rotation ``F_i`` (None: identity).
    e : (6,) float
        ``(delta_i, eps_i)``.
    inverted : bool
        Eye-to-hand, eq. (2); else eq. (1).

    Returns
    -------
    y : (3, n) float
        ``y_ij`` of eq. (1) or (2).
    M : (3, 3) float
        ``d y / d X_j``.
    """
    F = np.eye(3) if F is None else F
    if inverted:
        M = F @ rotvec_to_matrix(e[:3])
        return M @ X + (e[3:] - F @ T_i)[:, None], M
    M = rotvec_to_matrix(-e[:3]) @ F
    return M @ (X - (T_i + e[3:])[:, None]), M


def jacobian(y: np.ndarray, X: np.ndarray, P: np.ndarray, JX: np.ndarray, inverted: bool, robot: tuple,
             out: np.ndarray) -> None:
    """d pixel / d (the estimated components of ``delta_i``, ``eps_i``) into ``out (3 k, 2, n)``.

    ``P (3, 2, n)``: d pixel / d y (``P[d, k, n]``); ``JX (3, 2, n)``: d pixel / d X_j. The
    rotation's derivative is taken at the current error (exact at zero error, relative
    error ``|delta| / 2`` otherwise: far below a percent for robot errors). Eq. (1):
    ``dy/ddelta = [y]x``, ``dy/deps = -M``; eq. (2): ``dy/ddelta = -M [X]x``, ``dy/deps = I``.
    """
    row = 0
    for comp in robot:
        blk = out[row: row + 3]
        if comp == "rot":
            if inverted:  # a^T M (-[X]x) = (X x M^T a)^T
                _cross(X, JX, blk)
            else:  # a^T [y]x = (a x y)^T = -(y x a)^T
                _cross(y, P, blk)
                np.negative(blk, out=blk)
        else:
            blk[:] = P if inverted else -JX
        row += 3


def _cross(v: np.ndarray, A: np.ndarray, out: np.ndarray) -> None:
    """``out[:, k, n] = v[:, n] x A[:, k, n]`` for v (3, n), A (3, 2, n), out (3, 2, n)."""
    out[0] = v[1, None] * A[2] - v[2, None] * A[1]
    out[1] = v[2, None] * A[0] - v[0, None] * A[2]
    out[2] = v[0, None] * A[1] - v[1, None] * A[0]


def sample_errors(n_views: int, sigma_rot_deg: float, sigma_pos: float, rng=None) -> np.ndarray:
    """Pose errors ``(n_views, 6)``: ``delta`` (rad) with per-axis std ``sigma_rot_deg``
    degrees and ``eps`` with per-axis std ``sigma_pos`` (robot units), independent."""
    rng = np.random.default_rng(rng)
    return np.hstack([rng.normal(0.0, np.radians(sigma_rot_deg), (n_views, 3)),
                      rng.normal(0.0, sigma_pos, (n_views, 3))])


def perturb_poses(R: np.ndarray, T: np.ndarray, errors: np.ndarray):
    """The poses ``R_i exp([delta_i]x)``, ``T_i + eps_i`` of ``R (n, 3, 3)``, ``T (n, 3)``
    and ``errors (n, 6)``: the true poses of reported ones (or the reverse with ``-errors``
    to first order)."""
    return np.einsum("vab,vbc->vac", R, rotvec_to_matrix(errors[:, :3])), T + errors[:, 3:]
