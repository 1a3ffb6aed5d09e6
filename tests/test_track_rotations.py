"""The session tracker with small per-view rotations (the robot's orientation error, issues 21, 22)."""

import re
from dataclasses import replace

import numpy as np
import pytest

from transcalib.geometry.rotation import rotvec_to_matrix
from transcalib.images import RotatedViewsError, track
from transcalib.images.derotate import (Derotation, Lens, RotationOptions, _jacobian, _pair_data, _unpack,
                                        estimate_rotations, residuals)
from transcalib.synth.robot import robot_scene

#: Rotation errors (deg, robot flange frame) of six session views; view 3 is turned 0.8 deg,
#: inside the 1 deg session tolerance.
DELTA_DEG = np.array([[0.2, -0.2, 0.2], [-0.2, 0.2, 0.2], [0.2, 0.2, -0.2], [0.48, -0.64, 0.0],
                      [0.2, -0.2, -0.2], [-0.2, 0.2, 0.2]])


def _exact_matches(n=6, n_points=400, rng=0, lam=0.0):
    """Noise-free matches of ``x_i ~ A Q_i^T (X - T_i)`` (radial term ``lam`` applied),
    rotations up to 0.3 deg per axis; returns ``xy, general, T, omega, lens``."""
    rng = np.random.default_rng(rng)
    K = np.array([[500.0, 0, 322], [0, 505, 236], [0, 0, 1]])
    A = K @ rotvec_to_matrix(np.array([2.9, 0.3, -0.2]))
    T = np.vstack([np.zeros(3), rng.uniform(-60, 60, (n - 1, 3))])
    omega = np.radians(rng.uniform(-0.3, 0.3, (n, 3)))
    X = np.linalg.solve(A, np.column_stack([rng.uniform(0, 640, n_points), rng.uniform(0, 480, n_points),
                                            np.ones(n_points)]).T).T * rng.uniform(700, 900, (n_points, 1))
    lens = Lens(centre=(319.5, 239.5), s=320.0, lam=lam)
    x = []
    for i in range(n):
        p = (X - T[i]) @ (A @ rotvec_to_matrix(omega[i]).T).T
        x.append(lens.distort(p[:, :2] / p[:, 2:]))
    xy = {(i, j): (x[i], x[j]) for i in range(n) for j in range(i + 1, n)}
    return xy, {p: np.ones(n_points, bool) for p in xy}, T, omega, lens


@pytest.mark.parametrize("lam", [0.0, 0.05])
def test_exact_rotations_recovered(lam):
    xy, general, T, omega, lens = _exact_matches(lam=lam)
    est = estimate_rotations(xy, general, T, 1.5, (480, 640), np.random.default_rng(0))
    d = (est.omega - est.omega.mean(0)) - (omega - omega.mean(0))
    assert np.degrees(np.abs(d)).max() < 1e-3
    assert est.lens.lam == pytest.approx(lam, abs=1e-5)
    assert est.sigma_px < 1e-3
    # derotated matches obey one pure-translation geometry: e_ij ~ A (T_j - T_i)
    x_m, y_m = est.to_model(0, xy[(0, 1)][0]), est.to_model(1, xy[(0, 1)][1])
    e = est.A @ (T[1] - T[0])
    d_line = np.cross(np.c_[x_m, np.ones(len(x_m))], np.c_[y_m, np.ones(len(y_m))]) @ e
    assert np.abs(d_line).max() / np.linalg.norm(e) < 1e-3
    # the maps are inverse to each other
    assert np.allclose(est.to_image(2, est.to_model(2, xy[(0, 2)][1])), xy[(0, 2)][1], atol=1e-9)


def test_jacobian_of_all_parameters_at_once_matches_each_alone():
    """The derotation fit's Jacobian, every parameter's step in one batched evaluation,
    against central differences of the one-set residuals, one parameter at a time."""
    xy, general, T, _, _ = _exact_matches(n=4, n_points=60, lam=0.05)
    d, _ = _pair_data(xy, general, T, (480, 640), RotationOptions(), np.random.default_rng(0))
    A = np.array([[500.0, 0, 322], [0, 505, 236], [0, 0, 1]]) @ rotvec_to_matrix(np.array([2.9, 0.3, -0.2]))
    rng = np.random.default_rng(1)  # near the fit's start, off its solution
    p = np.r_[(A / np.linalg.norm(A) + rng.normal(0, 1e-4, (3, 3))).ravel(), 0.03, np.radians(rng.uniform(-0.5, 0.5, 9))]
    mine = [np.flatnonzero((d.vi == v) | (d.vj == v)) for v in range(4)]
    J = _jacobian(p, 4, d, mine)
    h = 1e-6
    central = np.column_stack([(residuals(*_unpack(p + h * e, 4), d) - residuals(*_unpack(p - h * e, 4), d)) / (2 * h)
                               for e in np.eye(len(p))])
    # forward differences: each column within 1e-3 of its size (A's third row, the most
    # curved, ~1e-4)
    assert np.all(np.abs(J - central).max(0) < 1e-3 * np.abs(central).max(0))
    for v in range(1, 4):  # a view's rotation moves its own matches only
        others = np.setdiff1d(np.arange(len(d.x)), mine[v])
        assert np.all(J[others, 10 + 3 * (v - 1):13 + 3 * (v - 1)] == 0.0)
        assert np.all(central[others, 10 + 3 * (v - 1):13 + 3 * (v - 1)] == 0.0)


def test_identity_without_estimate():
    d = Derotation.identity(3)
    x = np.array([[1.0, 2.0]])
    assert not d.estimated and d.to_model(1, x) is x and np.all(d.angles_deg() == 0)


def _session(delta_deg, rng=5):
    err = np.hstack([np.radians(delta_deg), np.zeros((len(delta_deg), 3))])
    return robot_scene("eye-in-hand", session_views=len(delta_deg), single_views=0, image_size=(320, 240), rng=rng,
                       pose_error=err)


def test_session_with_rotation_errors_tracked_and_rotations_recovered():
    """Six views with 0.2 deg rotation errors per axis (one view 0.8 deg), no position error.

    Tolerance per view: the camera sits ``|t_X|`` = 124 mm from the flange, so a flange
    rotation ``|delta_i|`` also moves the camera by ``|delta_i| |t_X|``, which over a
    scene at ``D`` ~ 800 mm looks like a rotation of up to ``|delta_i| |t_X| / D``; plus
    0.02 deg of noise (a perfect robot's rotations come out within 0.01 deg).
    """
    r = _session(DELTA_DEG)
    tr = track(r.images, T=r.T)
    assert tr.n_points > 800
    truth = replace(r, R=r.meta["true_R"], T=r.meta["true_T"])
    X, ghost = truth.track_truth(tr.uv)
    err = np.linalg.norm(tr.uv - truth.project(X), axis=-1)
    judged = np.isfinite(err) & (~ghost)[None]
    assert np.mean(err[judged] < 0.5) > 0.99
    g = tr.info.groups[0]
    est, true = np.array(g.rotations_deg), DELTA_DEG @ r.R[0].T  # R_s delta_i, base frame
    d = np.linalg.norm((est - est.mean(0)) - (true - true.mean(0)), axis=1)
    tol = np.radians(np.linalg.norm(DELTA_DEG, axis=1)) * np.linalg.norm(r.t_X) / 800.0 * 180 / np.pi + 0.02
    assert np.all(d < tol), (d, tol)
    assert int(np.argmax(g.angles_deg)) == 3 and g.angles_deg[3] < 1.0
    assert tr.info.rotation_tests[0].angles_deg == pytest.approx(g.angles_deg)


def test_rotation_beyond_tolerance_refused():
    """A view turned 2 deg (beyond the 1 deg session tolerance) is refused, with its angle."""
    delta = np.zeros((6, 3))
    delta[2] = [0.0, 1.2, -1.6]
    r = _session(delta)
    with pytest.raises(RotatedViewsError, match=r"view\(s\) 2 \((1\.\d\d|2\.\d\d) deg\)") as err:
        track(r.images, T=r.T)
    angle = float(re.search(r"view\(s\) 2 \((\d\.\d\d) deg\)", str(err.value)).group(1))
    wider = float(re.search(r"--session-tolerance-deg (\d+(?:\.\d+)?)", str(err.value)).group(1))
    assert angle < wider <= angle + 0.75 and 2 * wider == round(2 * wider)  # the option that takes it in
    tr = track(r.images, T=r.T, session_tolerance_deg=wider)
    assert tr.n_points > 800
