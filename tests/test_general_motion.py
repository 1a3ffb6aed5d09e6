"""General robot motion: every view at its own flange orientation, no pure-translation
session (transcalib.handeye.general, the start; then the one bundle adjuster). The CLI's
noise-free exactness for 8 views is in test_motions.py (LAYOUTS)."""

from dataclasses import replace

import numpy as np
import pytest

from transcalib import Poses, calibrate
from transcalib.errors import DegenerateError
from transcalib.geometry.rotation import rotation_angle_deg, rotvec_to_matrix
from transcalib.handeye.general import general_start
from transcalib.handeye.observability import sessions_crlb
from transcalib.handeye.simulate import DEFAULT_R_X, flange_rotations_looking, session_scene

EXACT = 1e-9


def _scene(n_views, setup="eye-in-hand", **kw):
    """Views 15-60 deg from straight down about random axes, 80 points at ~0.5 m."""
    return session_scene(1, n_sessions=0, single_views=n_views, single_tilt_deg=(15, 60), n_points=80, setup=setup,
                         **kw)


@pytest.mark.parametrize("setup", ["eye-in-hand", "eye-to-hand"])
def test_fifteen_views_exact(setup):
    sc = _scene(15, setup)
    cal = calibrate(sc.uv, Poses.of(sc.T, sc.R), setup=setup, distortion="none", rng=0)
    assert np.abs(cal.K - sc.K).max() < EXACT * sc.K[0, 0]
    assert rotation_angle_deg(cal.hand_eye.R.T @ sc.R_X) < EXACT
    assert cal.hand_eye.undetermined.shape == (3, 0) and np.abs(cal.hand_eye.t - sc.t_X).max() < EXACT * 500
    assert cal.diagnostics == ()


def test_start_lands_near_the_truth():
    """The start itself (no refinement), noise-free: the focal length from the pairs'
    rotations within 2 %, R_X within 2 deg, t_X within 30 mm (the principal point starts
    ~15 px off), independently of the bundle adjuster that then makes them exact."""
    sc = _scene(8)
    g = general_start(sc.uv, sc.T, sc.R, rng=0)
    assert abs(g.K[0, 0] / sc.K[0, 0] - 1) < 0.02
    assert rotation_angle_deg(g.R_X.T @ sc.R_X) < 2.0 and np.linalg.norm(g.t_X - sc.t_X) < 30.0


@pytest.mark.parametrize("relief_mm", [0.0, 5.0])
def test_a_flat_scene(relief_mm):
    """A flat table (or 5 mm of relief over 300 mm): the fundamental matrices are
    undetermined or weak, the pairs' homographies give the start; 0.5 px noise."""
    X = np.random.default_rng(0).uniform([-150, -150, 0], [150, 150, relief_mm], (80, 3))
    sc = session_scene(1, n_sessions=0, single_views=10, single_tilt_deg=(15, 60), X=X, n_points=80, noise_px=0.5)
    cal = calibrate(sc.uv, Poses.of(sc.T, sc.R), distortion="none", rng=0)
    assert abs(cal.K[0, 0] - sc.K[0, 0]) < 5 * cal.std["fx"]
    assert np.all(np.abs(cal.hand_eye.t - sc.t_X) < 5 * cal.hand_eye.t_std)


def test_turns_about_one_axis_are_refused():
    """A SCARA wrist: every turn about the base z axis cannot fix the camera's rotation
    about it from the turns; refused before any work, naming why."""
    look = flange_rotations_looking(np.array([[0.3, 0.0, -1.0]]), DEFAULT_R_X)[0]
    R = np.stack([rotvec_to_matrix(np.radians([0, 0, a])) @ look for a in (0, 20, 40, 60, 80, 100)])
    sc = session_scene(2, n_sessions=6, views_per_session=1, rotations=R, n_points=60)
    with pytest.raises(DegenerateError, match="about one axis"):
        calibrate(sc.uv, Poses.of(sc.T, sc.R), distortion="none")


def test_noise_at_the_bound():
    """Small Monte Carlo (500 trials: benchmarks/bench_handeye.py): 8 views, 0.5 px;
    24 trials put the sample std within ~15 % (1 sigma) of the true one; allow 45 %."""
    base = _scene(8)
    bound = sessions_crlb(replace(base, noise_px=0.5))
    rng = np.random.default_rng(0)
    est = []
    for trial in range(24):
        uv = np.where(np.isfinite(base.uv), base.uv_true + rng.normal(0, 0.5, base.uv.shape), np.nan)
        cal = calibrate(uv, Poses.of(base.T, base.R), distortion="none", rng=trial)
        est.append([cal.K[0, 0], cal.K[1, 2], *cal.hand_eye.t])
    ratio = np.std(est, axis=0, ddof=1) / np.array([bound[k] for k in ("fx", "cy", "t_x", "t_y", "t_z")])
    assert np.all((ratio > 0.55) & (ratio < 1.45)), ratio


def test_corrupted_tracks_do_not_derail_the_start():
    """20 % of the tracks with two observations moved by up to 80 px: the calibration
    still lands at the truth (within 6 of its reported std)."""
    base = _scene(8)
    rng = np.random.default_rng(1)
    for trial in range(4):
        uv = np.where(np.isfinite(base.uv), base.uv_true + rng.normal(0, 0.5, base.uv.shape), np.nan)
        for j in rng.choice(uv.shape[1], uv.shape[1] // 5, replace=False):
            views = rng.choice(np.flatnonzero(np.isfinite(uv[:, j, 0])), 2, replace=False)
            uv[views, j] += rng.uniform(20, 80, (2, 2)) * rng.choice([-1, 1], (2, 2))
        cal = calibrate(uv, Poses.of(base.T, base.R), distortion="none", rng=trial)
        assert abs(cal.K[0, 0] - base.K[0, 0]) < 6 * cal.std["fx"]
        assert np.all(np.abs(cal.hand_eye.t - base.t_X) < 6 * cal.hand_eye.t_std)
        assert (~cal.inliers).sum() >= 0.8 * (uv.shape[1] // 5)


def test_a_view_with_its_orientation_off_is_named_and_left_out():
    """One view's recorded orientation 5 deg off: every pair it belongs to disagrees with
    the flange; it is named with about its angle and left out, and the rest calibrates
    as if it were absent (without the check: fx 87 px off, t_X 1.7 m)."""
    sc = session_scene(1, n_sessions=0, single_views=10, single_tilt_deg=(15, 60), n_points=80, noise_px=0.5)
    R = sc.R.copy()
    R[4] = rotvec_to_matrix(np.radians([3.0, -4.0, 0.0])) @ R[4]
    cal = calibrate(sc.uv, Poses.of(sc.T, R), distortion="none", rng=0)
    off = [d for d in cal.diagnostics if d.code == "pose_orientation_off"]
    assert len(off) == 1 and "view 4:" in off[0]
    assert np.isnan(cal.residuals_px[4]).all()
    assert abs(cal.K[0, 0] - sc.K[0, 0]) < 5 * cal.std["fx"]
