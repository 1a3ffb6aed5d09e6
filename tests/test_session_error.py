"""The robot error common to a session's views: measured, and its share in the covariance (issue 22)."""

from dataclasses import replace

import numpy as np

from transcalib.estimate.layout import FlangeModel
from transcalib.estimate.refine import fit_refine
from transcalib.estimate.session_error import session_groups
from transcalib.geometry.rotation import matrix_to_rotvec, rotvec_to_matrix
from transcalib.handeye.simulate import session_scene, with_robot_error
from transcalib.io.calibration_file import load_calibration, save_calibration
from transcalib.types import Calibration, Camera, RefineOptions

TRIALS = 8


def _fit(seed: int, per_view, common, **options):
    """Three sessions of 6 views (60 points, 0.5 px), the robot's errors ``per_view`` and
    ``common`` to each session ``(deg, mm)``, refined from near the truth: ``(cal, scene)``."""
    rng = np.random.default_rng(seed)
    sc = session_scene(rng, n_sessions=3, views_per_session=6, n_points=60, noise_px=0.5)
    rep, _ = with_robot_error(sc, *per_view, rng, session_rot_deg=common[0], session_pos=common[1])
    flange = FlangeModel(np.transpose(sc.R, (0, 2, 1)), sc.t_X + rng.normal(0, 2.0, 3), np.eye(3))
    K = sc.K * [[1 + 0.01 * rng.normal(), 1, 1], [1, 1 + 0.01 * rng.normal(), 1], [1, 1, 1]]
    start = Calibration(camera=Camera(K, rotvec_to_matrix(np.radians(0.2) * rng.normal(size=3)) @ sc.R_X.T),
                        X=sc.X, residuals_px=np.zeros_like(sc.uv), rms_px=0.0, T=sc.T)
    opts = RefineOptions(distortion="none", robot_error=True, **options)
    return fit_refine(rep.uv, rep.T, start, opts, flange=flange), sc


def test_session_groups_join_views_within_the_tolerance():
    F = rotvec_to_matrix(np.radians([[0, 0, 0], [0.3, 0, 0], [25, 0, 0], [25, 0.4, 0], [0, 40, 0], [0, 0, 0.2]]))
    groups = session_groups(F, 1.0)
    assert [g.tolist() for g in groups] == [[0, 1, 5], [2, 3]]  # the single view at 40 deg is no session


def test_a_common_session_error_widens_the_hand_eye_std_to_its_scatter():
    """With each session's error mostly common (0.1 deg / 1 mm per session, 0.02 deg / 0.2
    mm per view) the per-view model's std of the hand-eye offset covers a third to a half
    of its scatter (300 trials, benchmarks/bench_session_error.py: pooled RMS z about 3);
    the sessions' error, found by the test, widens it to the scatter or beyond (std ratio
    1.34-1.47 there). The pooled RMS z of t_x, t_y, t_z over the trials; one trial also
    without the component: the same estimate, a std at least 1.5 times smaller. R_X too,
    also in the trials (4 of 8) whose fit left the per-view rotation error out (0.02 deg
    is below what the data show): its session part is measured all the same (pooled RMS
    z 0.70; 2.15 when it was measured only with the per-view component in the fit)."""
    z, z_rot, rot_left_out = [], [], 0
    for seed in range(TRIALS):
        cal, sc = _fit(seed, (0.02, 0.2), (0.1, 1.0))
        se = cal.uncertainty.session_error
        assert se.included and se.n_sessions == 3
        z += list((cal.hand_eye.t - sc.t_X) / np.sqrt(np.diag(cal.hand_eye.t_cov)))
        z_rot += list(np.degrees(matrix_to_rotvec(cal.R @ sc.R_X)) / [cal.std[k] for k in ("rx", "ry", "rz")])
        rot_left_out += cal.robot_error.source[0] != "estimated"
    assert float(np.sqrt(np.mean(np.square(z)))) < 1.6
    assert float(np.sqrt(np.mean(np.square(z_rot)))) < 1.6 and rot_left_out >= 2
    without, _ = _fit(0, (0.02, 0.2), (0.1, 1.0), session_error=False)
    with_, _ = _fit(0, (0.02, 0.2), (0.1, 1.0))
    assert without.uncertainty.session_error is None
    np.testing.assert_allclose(without.hand_eye.t, with_.hand_eye.t, atol=1e-9)
    assert np.all(np.diag(with_.hand_eye.t_cov) > 1.5**2 * np.diag(without.hand_eye.t_cov))  # seed 0: 1.9-2.7 x


def test_the_sandwich_reported_keeps_the_sessions_share():
    """The sandwich clusters by point and does not see an error shared by a session's
    views: reported (``uncertainty="robust"``, what ``auto`` chooses where the tracker's
    noise is not white), it replaces the pixel noise's share only, the sessions' share
    stays. Pooled RMS z of the hand-eye offset over 6 trials of the mostly-common case:
    0.94, as with the model-based std (5.96 when the sandwich dropped the sessions' share)."""
    z = []
    for seed in range(6):
        cal, sc = _fit(seed, (0.02, 0.2), (0.1, 1.0), uncertainty="robust")
        assert cal.uncertainty.session_error.included and set(cal.uncertainty.reported.values()) == {"robust"}
        z += list((cal.hand_eye.t - sc.t_X) / np.sqrt(np.diag(cal.hand_eye.t_cov)))
    assert float(np.sqrt(np.mean(np.square(z)))) < 1.6


def test_per_view_errors_alone_are_not_taken_for_a_sessions():
    found = [_fit(100 + seed, (0.1, 1.0), (0.0, 0.0))[0].uncertainty.session_error.included for seed in range(TRIALS)]
    assert sum(found) <= 1  # the test's level is 5 %


def test_session_error_is_written_and_read_back(tmp_path):
    cal, _ = _fit(0, (0.02, 0.2), (0.1, 1.0))
    save_calibration(cal, tmp_path / "calibration.json")
    back = load_calibration(tmp_path / "calibration.json")
    assert back.uncertainty.session_error == cal.uncertainty.session_error
    assert replace(back.uncertainty.session_error, included=False) != cal.uncertainty.session_error
