"""Tests of the robot's pose error in the bundle adjuster (estimate/robot_error.py) and the
variance-component estimation of its scales (estimate/variance_components.py)."""

from __future__ import annotations

import numpy as np
import pytest

from transcalib import simulate
from transcalib.estimate.bundle import predict_view
from transcalib.estimate.layout import Layout, State, intrinsic_basis
from transcalib.estimate.robot_error import perturb_poses, sample_errors
from transcalib.geometry.camera import pad_dist
from transcalib.geometry.rotation import rotvec_to_matrix


# ---------------------------------------------------------------------------- model and Jacobians


def _state(scene, rng, sessions: bool, errors: bool):
    n_views = scene.n_views
    K = scene.K
    F = np.stack([rotvec_to_matrix(0.3 * rng.normal(size=3)) for _ in range(n_views)]) if sessions else None
    E = sample_errors(n_views, 0.5, 2.0, rng) if errors else np.zeros((n_views, 6))
    return State(np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]]), pad_dist(scene.dist),
                 scene.R.copy(), np.tile(np.eye(3), (n_views, 1, 1)), scene.T_true.copy(), scene.X.copy(), F,
                 np.array([3.0, -2.0, 5.0]) if sessions else np.zeros(3), E)


@pytest.mark.parametrize("sessions", [False, True])
@pytest.mark.parametrize("inverted", [False, True])
@pytest.mark.parametrize("robot", [("rot", "pos"), ("pos",), ("rot",)])
def test_robot_error_jacobians_match_finite_differences(sessions, inverted, robot):
    """The pose-error columns (and the points' and offset's) against central differences,
    at zero error and at a non-zero one (where the rotation's derivative is first-order
    exact: tolerance |delta| / 2 relative)."""
    scene = simulate.random_scene(25, 4, dist=(-0.1, 0.02), rng=11)
    rng = np.random.default_rng(12)
    E5, names = intrinsic_basis({}, False, False)
    lay = Layout(scene.n_views, E5, names, (0, 1), t_basis=np.eye(3) if sessions else None, robot=robot,
                 robot_inverted=inverted)
    pts = np.arange(scene.n_points)
    for errors in (False, True):
        state = _state(scene, rng, sessions, errors)
        tol = 1e-6 if not errors else 0.5 * np.abs(state.E[:, :3]).max() + 1e-6
        for view in (0, 2):
            _, _, Jg, JX = predict_view(state, lay, view, pts)
            cols = lay.view_columns(view)
            assert len(cols) == lay.n_common + 3 * len(robot)
            for local, k in enumerate(cols):
                h = 1e-6 * max(1.0, abs(state.intr[k]) if k < 4 else 1.0)
                dg = np.zeros(lay.size)
                dg[k] = h
                zero = np.zeros((3, len(pts)))
                plus = predict_view(state.moved(lay, dg, zero), lay, view, pts, False)[0]
                minus = predict_view(state.moved(lay, -dg, zero), lay, view, pts, False)[0]
                fd = (plus - minus) / (2 * h)
                limit = tol if lay.names()[k].startswith("robot") else 1e-6
                assert np.abs(Jg[local] - fd).max() / max(np.abs(fd).max(), 1e-3) < limit, lay.names()[k]
            for a in range(3):
                dX = np.zeros((3, len(pts)))
                dX[a] = 1e-4
                plus = predict_view(state.moved(lay, np.zeros(lay.size), dX), lay, view, pts, False)[0]
                minus = predict_view(state.moved(lay, np.zeros(lay.size), -dX), lay, view, pts, False)[0]
                fd = (plus - minus) / 2e-4
                assert np.abs(JX[a] - fd).max() / np.abs(fd).max() < 1e-6


@pytest.mark.parametrize("inverted", [False, True])
def test_pose_error_model_is_the_perturbed_robot_pose(inverted):
    """Independent oracle: the prediction with errors equals the prediction without errors
    of the poses perturbed by :func:`perturb_poses` (eye-in-hand: the flange poses;
    eye-to-hand: the robot poses before the model's inversion)."""
    scene = simulate.random_scene(20, 5, rng=3)
    rng = np.random.default_rng(4)
    n = scene.n_views
    R_rob = np.stack([rotvec_to_matrix(0.4 * rng.normal(size=3)) for _ in range(n)])
    T_rob = scene.T_true + rng.normal(0, 5.0, (n, 3))
    errors = sample_errors(n, 0.3, 1.5, rng)
    R_true, T_true = perturb_poses(R_rob, T_rob, errors)

    def model_pose(R, T):  # the model's (F, T): eye-in-hand F = R^T; eye-to-hand inverted
        if inverted:
            return R.copy(), -np.einsum("vba,vb->va", R, T)
        return np.transpose(R, (0, 2, 1)).copy(), T.copy()

    E5, names = intrinsic_basis({}, False, False)
    lay = Layout(n, E5, names, (), t_basis=np.eye(3), robot=("rot", "pos"), robot_inverted=inverted)
    lay0 = Layout(n, E5, names, (), t_basis=np.eye(3))
    K = scene.K
    intr = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], 0.0])
    t = np.array([5.0, -3.0, 8.0])
    F, T = model_pose(R_rob, T_rob)
    Ft, Tt = model_pose(R_true, T_true)
    with_err = State(intr, np.zeros(5), scene.R, np.tile(np.eye(3), (n, 1, 1)), T, scene.X, F, t, errors)
    truth = State(intr, np.zeros(5), scene.R, np.tile(np.eye(3), (n, 1, 1)), Tt, scene.X, Ft, t)
    pts = np.arange(scene.n_points)
    for i in range(n):
        a = predict_view(with_err, lay, i, pts, False)[0]
        b = predict_view(truth, lay0, i, pts, False)[0]
        assert np.abs(a - b).max() < 1e-8
