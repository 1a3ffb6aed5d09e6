"""The ``transcalib`` command end to end, as a user runs it (a real subprocess)."""

import json
import subprocess
import sys

import numpy as np
import pytest

from transcalib import simulate
from transcalib import io as tio


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "transcalib.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    r = run("simulate", "--preset", "random", "--points", 60, "--views", 5, "--noise-px", 0.2,
            "--missing", 0.1, "--seed", 3, "--out", out)
    assert r.returncode == 0, r.stderr
    return out


def test_simulate_writes_three_files(simulated):
    assert sorted(p.name for p in simulated.iterdir()) == ["poses.csv", "tracks.csv", "truth.json"]
    truth = json.loads((simulated / "truth.json").read_text())
    assert np.array(truth["K"]).shape == (3, 3) and truth["units"] == "mm"


def test_calibrate_outputs(simulated, tmp_path):
    out = tmp_path / "result"
    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv",
            "--out", out, "--unit", "mm", "--truth", simulated / "truth.json")
    assert r.returncode == 0, r.stderr
    assert "fx =" in r.stdout and "±" in r.stdout and "truth" in r.stdout
    cal = json.loads((out / "calibration.json").read_text())
    for key in ("K", "R", "dist", "rms_px", "n_points", "n_views", "units", "diagnostics", "points",
                "std", "cov", "param_names", "dist_model", "inliers"):
        assert key in cal, key
    truth = json.loads((simulated / "truth.json").read_text())
    K, K_true = np.array(cal["K"]), np.array(truth["K"])
    assert np.abs(K - K_true).max() / K_true[0, 0] < 0.01
    assert cal["n_views"] == 5 and cal["units"] == "mm"
    # points in input order: ids 0..n-1 as written by simulate
    view_ids, point_ids, _, _ = tio.read_tracks(simulated / "tracks.csv")
    assert cal["point_ids"] == point_ids
    X = np.array([[np.nan if v is None else v for v in p] for p in cal["points"]])
    X_true = np.array(truth["points"])[[int(p) for p in point_ids]]
    ok = np.isfinite(X[:, 0])
    assert ok.sum() >= 0.9 * len(X)
    assert np.median(np.linalg.norm(X[ok] - X_true[ok], axis=1)) < 0.01 * np.linalg.norm(X_true, axis=1).mean()
    lines = (out / "points.csv").read_text().splitlines()
    assert lines[0].startswith("point,x,y,z") and len(lines) == len(point_ids) + 1


def test_no_refine_gives_linear(simulated, tmp_path):
    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv",
            "--out", tmp_path, "--no-refine", "--no-robust", "--quiet")
    assert r.returncode == 0, r.stderr
    cal = json.loads((tmp_path / "calibration.json").read_text())
    assert cal["info"]["stages"] == ["linear"] and cal["dist"] == []


@pytest.mark.parametrize(
    "tracks, poses, match",
    [
        ("view,point,u,v\n", "view,x,y,z\n0,0,0,0\n", "no data rows"),
        ("view,point,u,v\n0,a,1,2\n", "view,x,y\n0,0,0\n", "lacks column"),
        ("view,point,u,v\n0,a,1,2\n9,a,1,2\n", "view,x,y,z\n0,0,0,0\n", "not in the poses file"),
        ("view,point,u,v\n0,a,1,oops\n", "view,x,y,z\n0,0,0,0\n", "not a finite number"),
        ("view,point,u,v\n0,a,1,2\n1,a,3,2\n", "view,x,y,z\n0,0,0,0\n1,1,0,0\n", "at least 4 views"),
    ],
)
def test_errors_are_clear_and_leave_no_output(tmp_path, tracks, poses, match):
    (tmp_path / "t.csv").write_text(tracks)
    (tmp_path / "p.csv").write_text(poses)
    out = tmp_path / "out"
    r = run("calibrate", "--tracks", tmp_path / "t.csv", "--poses", tmp_path / "p.csv", "--out", out)
    assert r.returncode == 2
    assert match in r.stderr and "Traceback" not in r.stderr
    assert not out.exists() or not any(out.iterdir())


def test_degenerate_translations_message(tmp_path):
    scene = simulate.random_scene(30, 4, rng=2)
    T = scene.T.copy()
    T[3] = T[1] + 0.5 * (T[2] - T[1])  # coplanar with the others
    from transcalib.geometry.camera import project
    tio.write_tracks_csv(tmp_path / "t.csv", project(scene.K, scene.R, scene.X, T))
    tio.write_poses_csv(tmp_path / "p.csv", T)
    r = run("calibrate", "--tracks", tmp_path / "t.csv", "--poses", tmp_path / "p.csv", "--out", tmp_path / "o")
    assert r.returncode == 2 and "coplanar" in r.stderr and "principal-point" in r.stderr and "Traceback" not in r.stderr


def test_inputs_untouched(simulated, tmp_path):
    before = {p.name: p.read_bytes() for p in simulated.iterdir()}
    run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv", "--out", tmp_path,
        "--quiet")
    assert before == {p.name: p.read_bytes() for p in simulated.iterdir()}


def test_pose_orientations_checked(tmp_path):
    """poses.csv with qx,qy,qz,qw: a view whose orientation differs is reported, with its angle."""
    scene = simulate.paper_scene(noise_px=0.2, rng=1)
    tio.write_tracks_csv(tmp_path / "t.csv", scene.uv)
    lines = ["view,x,y,z,qx,qy,qz,qw"]
    for i, t in enumerate(scene.T):
        q = "0.0026,0,0,0.99999662" if i == 2 else "0,0,0,1"  # view 2: turned 0.3 deg
        lines.append(",".join([str(i), *(repr(float(x)) for x in t), q]))
    (tmp_path / "p.csv").write_text("\n".join(lines) + "\n")
    r = run("calibrate", "--tracks", tmp_path / "t.csv", "--poses", tmp_path / "p.csv", "--out", tmp_path / "o",
            "--quiet")
    assert r.returncode == 0, r.stderr
    cal = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert "pose_orientation" in cal["diagnostic_codes"]
    assert any("view 2: 0.298 deg" in d for d in cal["diagnostics"])
