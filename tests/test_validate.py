"""``transcalib validate`` / ``transcalib.validate_views`` (issue 23 item 1): new views at
other flange orientations predicted by a saved calibration, compared with the
covariance's prediction; a wrong calibration flagged (exit 4 with --strict)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import transcalib as tc
from transcalib import io as tio
from transcalib.cli.main import main
from transcalib.handeye.simulate import session_scene


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """A calibration of 3 sessions (4 views each) and 3 held-out single views."""
    out = tmp_path_factory.mktemp("validate")
    sc = session_scene(4, n_sessions=3, views_per_session=4, n_points=80, noise_px=0.5, single_views=3)
    n = sc.uv.shape[0]
    ids = [f"v{i}" for i in range(n)]
    for name, sel in (("cal", np.arange(n - 3)), ("new", np.arange(n - 3, n))):
        tio.write_tracks_csv(out / f"{name}_tracks.csv", sc.uv[sel], np.arange(sc.uv.shape[1]), [ids[i] for i in sel])
        tio.write_poses_csv(out / f"{name}_poses.csv", sc.T[sel], [ids[i] for i in sel], R=sc.R[sel])
    assert main(["calibrate", "--tracks", str(out / "cal_tracks.csv"), "--poses", str(out / "cal_poses.csv"),
                 "--out", str(out / "cal"), "--formats", "json", "--quiet"]) == 0
    return out, sc


def _validate(capsys, out, folder="cal", *extra):
    capsys.readouterr()
    code = main(["validate", "--calibration", str(out / folder), "--tracks", str(out / "new_tracks.csv"),
                 "--poses", str(out / "new_poses.csv"), "--json", "--strict", *extra])
    text = capsys.readouterr()
    return code, json.loads(text.out), text.err


def test_right_calibration_predicts_at_the_noise_level(made, capsys):
    out, _ = made
    code, res, _ = _validate(capsys, out)
    assert code == 0 and not res["flagged"]
    assert {"rms_px", "median_px", "max_px", "n_points", "per_view", "fitted"} <= set(res)
    assert [v["view"] for v in res["per_view"]] == ["v12", "v13", "v14"]  # 12 views calibrated
    assert {"view", "rms_px", "median_px", "n_points"} <= set(res["per_view"][0])
    assert 0.8 < res["rms_px"] / res["predicted_rms_px"] < 1.25, res
    assert res["rms_px"] < 1.2 and 0.4 < res["noise_px"] < 0.65  # noise 0.5 px per coordinate


def test_fx_two_percent_off_is_flagged(made, capsys):
    out, _ = made
    (out / "bad").mkdir(exist_ok=True)
    doc = json.loads((out / "cal" / "calibration.json").read_text())
    doc["K"][0][0] *= 1.02
    (out / "bad" / "calibration.json").write_text(json.dumps(doc))
    (out / "bad" / "arrays.npz").write_bytes((out / "cal" / "arrays.npz").read_bytes())
    code, res, _ = _validate(capsys, out, "bad")
    assert code == 4 and res["flagged"] and res["diagnostics"][0]["code"] == "prediction_error"
    assert res["median_px"] > 1.3 * res["predicted_median_px"]


def test_offset_left_undetermined_is_fitted_on_new_views(made):
    """One orientation leaves t_X undetermined: the new views at other orientations fit it."""
    _, sc = made
    first = np.flatnonzero(np.all(np.isclose(sc.R, sc.R[0]), axis=(1, 2)))  # session 0
    cal = tc.calibrate(sc.uv[first], tc.Poses.of(sc.T[first], sc.R[first]), rng=0)
    new = np.setdiff1d(np.arange(len(sc.T)), first)
    res = tc.validate_views(cal, sc.uv[new], tc.Poses.of(sc.T[new], sc.R[new]))
    t = np.array([f["value"] for f in res.fitted])
    assert [f["name"] for f in res.fitted] == ["t_x", "t_y", "t_z"]
    assert np.linalg.norm(t - sc.truth["t_flange_camera"]) < 10.0, (t, sc.truth["t_flange_camera"])
    assert not res.flagged


def test_bad_inputs_named(made, capsys, tmp_path):
    out, sc = made
    tio.write_tracks_csv(tmp_path / "t.csv", sc.uv[-3:], np.arange(sc.uv.shape[1]) + 10_000, ["v12", "v13", "v14"])
    capsys.readouterr()
    code = main(["validate", "--calibration", str(out / "cal"), "--tracks", str(tmp_path / "t.csv"),
                 "--poses", str(out / "new_poses.csv")])
    err = capsys.readouterr().err
    assert code == 2 and "--tracks" in err and "none of the" in err and "Traceback" not in err
    tio.write_poses_csv(tmp_path / "p.csv", sc.T[-3:], ["v12", "v13", "v14"])  # no orientations
    code = main(["validate", "--calibration", str(out / "cal"), "--tracks", str(out / "new_tracks.csv"),
                 "--poses", str(tmp_path / "p.csv")])
    assert code == 2 and "orientations" in capsys.readouterr().err
    code = main(["validate", "--calibration", str(tmp_path / "nothing"), "--tracks", str(out / "new_tracks.csv"),
                 "--poses", str(out / "new_poses.csv")])
    assert code == 2 and "--calibration" in capsys.readouterr().err
