"""Each view predicted by the calibration of the others (issue 23 item 2): the
leave-one-view-out error beside the covariance's prediction, in the result, the
summary, calibration.json and the report."""

from __future__ import annotations

import numpy as np
import pytest

import transcalib as tc
from transcalib.check.prediction import leave_one_view_out


@pytest.fixture(scope="module")
def scene():
    return tc.simulate.random_scene(120, 7, noise_px=0.5, missing=0.1, rng=11)


def test_prediction_error_matches_the_covariance(scene):
    loo = tc.calibrate(scene.uv, scene.T, rng=0).info["leave_one_view_out"]
    assert 0.85 < loo["ratio"] < 1.15, loo
    assert len(loo["per_view"]) == 7 and loo["skipped"] == []
    # the noise alone gives sqrt(2) sigma: the prediction is larger, not smaller
    assert loo["predicted_rms_px"] > np.sqrt(2) * 0.5


def test_a_wrong_pose_is_predicted_badly(scene):
    """A pose error of 2 % of the moves: the views are predicted about twice as badly as
    the covariance says (the biased fit predicts other views badly too: naming the view
    is the pose test's job, tests/test_poses_check.py)."""
    T = scene.T.copy()
    T[3, 0] += 0.02 * np.ptp(T[:, 0])
    loo = tc.calibrate(scene.uv, T, rng=0, check_rotation=False).info["leave_one_view_out"]
    per = {p["view"]: p for p in loo["per_view"]}
    assert loo["ratio"] > 1.5 and per[3]["rms_px"] > 2 * per[3]["predicted_rms_px"]


def test_leave_one_out_on_hand_eye_views():
    from transcalib.handeye.simulate import session_scene

    sc = session_scene(1, n_sessions=3, views_per_session=4, n_points=50, noise_px=0.5, single_views=1)
    loo = tc.calibrate(sc.uv, tc.Poses.of(sc.T, sc.R), rng=0).info["leave_one_view_out"]
    assert 0.8 < loo["ratio"] < 1.2, loo


def test_fewer_than_five_views_have_none():
    sc = tc.simulate.random_scene(40, 4, noise_px=0.5, rng=1)
    assert "leave_one_view_out" not in tc.calibrate(sc.uv, sc.T, rng=0).info


def test_saved_and_summarised(scene, tmp_path):
    from transcalib.cli.summary import summary_json, summary_text

    cal = tc.calibrate(scene.uv, scene.T, rng=0)
    tc.save(cal, tmp_path)
    assert tc.load(tmp_path).info["leave_one_view_out"] == cal.info["leave_one_view_out"]
    assert "Views predicted from the others: RMS" in summary_text(cal, "mm")
    assert summary_json(cal, "mm")["leave_one_view_out"]["n_points"] > 0
    direct = leave_one_view_out(np.where(cal.inliers[None, :, None], scene.uv, np.nan)
                                if cal.inliers is not None else scene.uv, scene.T, cal)
    assert direct["rms_px"] == pytest.approx(cal.info["leave_one_view_out"]["rms_px"])
