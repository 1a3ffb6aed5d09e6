"""Predicted accuracy of candidate designs: the Fisher information of the one bundle adjuster.

A design ``T (n_views, 3)`` with the model's points ``X_j`` is a simulated scene
(:func:`~transcalib.planning.model.design_scene`); its reduced Fisher information is the
one the refinement's covariance and :func:`transcalib.crlb` use
(:func:`transcalib.estimate.covariance.scene_information`: the points eliminated by the
Schur complement), so that

    S = U - sum_j W_j V_j^-1 W_j^T,        cov(g) = sigma_px^2 S^-1,

with ``g = (fx, fy, cx, cy[, k], w[, T_1..T_{m-1}])`` (``w``: the rotation update; the
translations of views ``i >= 1`` with the prior ``I / sigma_T^2`` when the robot is
imprecise). The exchange search of :mod:`.optimise` needs each view's contribution per
point instead: :func:`view_jacobians` gives the observation Jacobians of any number of
candidate positions from the same model (:func:`transcalib.estimate.bundle.predict_view`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import DegenerateError
from ..estimate.bundle import predict_view
from ..estimate.covariance import bound_std, check_identifiable, scene_information
from ..estimate.layout import Layout, State
from ..geometry.camera import pad_dist
from ..types import RefineOptions
from .model import PlanOptions, design_scene

__all__ = ["predict", "view_jacobians"]


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


def _design(options: PlanOptions, X: np.ndarray, T: np.ndarray, points: bool):
    """``(std dict, visible (n_views,), point_std (n_points,) or None)`` of one design."""
    scene = design_scene(options, X, T)
    seen = np.isfinite(scene.uv[..., 0])
    red, lay, used = scene_information(scene, distortion=options.distortion)
    try:
        std = bound_std(red.S, lay, options.noise_px, red.U_diag)
    except DegenerateError:  # the design does not determine every parameter
        std = dict.fromkeys(lay.names(), np.inf)
    point_std = None
    if points:
        point_std = np.full(len(X), np.nan)
        if np.all(np.isfinite(list(std.values()))):
            evals, evecs = check_identifiable(red.S, lay.names(), scale=red.U_diag)
            keep = np.flatnonzero(used[seen.sum(axis=0) >= 2])  # the counted points among those seen twice
            var = red.point_variances((evecs / evals) @ evecs.T)[keep]
            point_std[used] = options.noise_px * np.sqrt(np.maximum(var.mean(axis=1), 0.0))
    return std, seen.mean(axis=1), point_std


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
        ``std[name][b] = noise_px * sqrt((S_b^-1)_kk)`` (degrees for the rotation): what
        :func:`transcalib.crlb` gives for the scene :func:`~transcalib.planning.model.design_scene`.
    """
    T = np.asarray(T, dtype=float)
    single = T.ndim == 2
    designs = [_design(options, X, t, points) for t in (T[None] if single else T)]
    std = {k: np.array([d[0][k] for d in designs]) for k in designs[0][0]}
    visible = np.array([d[1] for d in designs])
    point_std = np.array([d[2] for d in designs]) if points else None
    if single:
        return Prediction({k: float(v[0]) for k, v in std.items()}, visible[0], None if point_std is None
                          else point_std[0])
    return Prediction(std, visible, point_std)


def view_jacobians(options: PlanOptions, X: np.ndarray, P: np.ndarray):
    """Observation Jacobians of the camera at each position ``P (K, 3)``: ``J_g (K, n, 2,
    q)`` over the global parameters without the robot's translations (intrinsics
    ``fx, fy, cx, cy``, the distortion of ``options``, the rotation), ``J_X (K, n, 2, 3)``
    and which observations fall inside the image ``seen (K, n)`` (the margin applied)."""
    lay = Layout.from_options(RefineOptions(distortion=options.distortion), len(P))
    K = options.K
    state = State(np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], 0.0]), pad_dist(options.dist), options.R,
                  np.tile(np.eye(3), (len(P), 1, 1)), P, X)
    w, h = options.image_size
    m = options.margin_px
    Jg, JX, seen = [], [], []
    for i in range(len(P)):  # one view at a time, vectorised over the points
        z = (X - P[i]) @ options.R[2]
        front = z > 1e-9 * options.distance
        pred, _, jg, jx = predict_view(state, lay, i, slice(None), valid=front)
        u, v = pred
        seen.append(front & (u >= -0.5 + m) & (u <= w - 0.5 - m) & (v >= -0.5 + m) & (v <= h - 0.5 - m))
        Jg.append(jg.transpose(2, 1, 0))  # (q, 2, n) -> (n, 2, q)
        JX.append(jx.transpose(2, 1, 0))
    return np.array(Jg), np.array(JX), np.array(seen)
