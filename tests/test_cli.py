"""The ``transcalib`` command end to end, as a user runs it (a real subprocess), and its
checks: every bad option, input or output path fails first, in one line, exit 2."""

import json
import re
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from transcalib import io as tio
from transcalib import simulate

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "transcalib.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def assert_clean_error(r, *words, code=2):
    """Exit ``code``, one error line on stderr (after any progress lines) naming ``words``,
    no traceback."""
    assert r.returncode == code, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    errors = [line for line in lines if "error" in line.lower()]
    assert errors == lines[-1:] and lines[-1].startswith("transcalib: error:"), r.stderr
    assert "Traceback" not in r.stderr
    for w in words:
        assert w in lines[-1], (w, lines[-1])


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim")
    r = run("simulate", "--preset", "random", "--points", 60, "--views", 5, "--noise-px", 0.2,
            "--missing", 0.1, "--seed", 3, "--out", out)
    assert r.returncode == 0, r.stderr
    return out


@pytest.fixture(scope="module")
def calibrated(simulated, tmp_path_factory):
    out = tmp_path_factory.mktemp("cal") / "result"
    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv",
            "--out", out, "--unit", "mm", "--truth", simulated / "truth.json")
    assert r.returncode == 0, r.stderr
    return out, r


def test_simulate_writes_three_files(simulated):
    assert sorted(p.name for p in simulated.iterdir()) == ["manifest.json", "poses.csv", "tracks.csv", "truth.json"]
    truth = json.loads((simulated / "truth.json").read_text())
    assert np.array(truth["K"]).shape == (3, 3) and truth["units"] == "mm"
    for p in simulated.iterdir():
        assert b"\r" not in p.read_bytes(), p  # LF line endings


def test_calibrate_outputs(simulated, calibrated):
    from transcalib.io.calibration_file import load_saved

    out, r = calibrated
    assert "fx =" in r.stdout and "±" in r.stdout and "truth" in r.stdout
    names = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()}
    assert {"calibration.json", "arrays.npz", "points.csv", "camera.yaml", "camera_info.yaml", "points.ply",
            "colmap/cameras.txt", "colmap/images.txt", "colmap/points3D.txt", "report.html",
            "figures/residuals.png"} <= names
    saved = load_saved(out)
    cal = saved.calibration
    truth = json.loads((simulated / "truth.json").read_text())
    K_true = np.array(truth["K"])
    assert np.abs(cal.K - K_true).max() / K_true[0, 0] < 0.01
    assert cal.n_views == 5 and cal.options.unit == "mm" and cal.image_size == tuple(truth["image_size"])
    assert saved.inputs["image_size_from"] == "--truth"
    table = tio.read_track_table(simulated / "tracks.csv")
    np.testing.assert_array_equal(saved.point_ids, table.point_ids)  # points in input order
    assert saved.point_ids.dtype == np.int64  # simulated ids are integers
    X_true = np.array(truth["points"])[[int(p) for p in saved.point_ids]]
    ok = np.isfinite(cal.X[:, 0])
    assert ok.sum() >= 0.9 * len(cal.X)
    assert np.median(np.linalg.norm(cal.X[ok] - X_true[ok], axis=1)) < 0.01 * np.linalg.norm(X_true, axis=1).mean()
    lines = (out / "points.csv").read_text().splitlines()
    assert lines[0].startswith("point,x,y,z") and len(lines) == len(saved.point_ids) + 1
    for p in ("calibration.json", "points.csv", "camera.yaml", "report.html"):
        assert b"\r\n" not in (out / p).read_bytes(), p
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["schema_version"] == 2 and "arrays.npz" == doc["arrays"]["file"]


def test_point_errors_against_the_truth(calibrated):
    """Simulated ids (integers, read as int64) index the true points: the summary has
    the point errors; text or out-of-range ids give none."""
    from transcalib.cli.summary import point_errors

    from transcalib.io.calibration_file import load_saved

    out, r = calibrated
    assert "Point error vs truth: median" in r.stdout
    saved = load_saved(out)
    truth = {"points": saved.calibration.X[::-1]}  # point k is true point n - 1 - k
    n = saved.calibration.n_points
    err = point_errors(saved.calibration, truth, np.arange(n)[::-1])
    assert np.nanmax(err) == 0 and np.isfinite(err).sum() > 0.9 * n
    assert point_errors(saved.calibration, truth, np.arange(n)[::-1].astype(str)).shape == (n,)
    assert point_errors(saved.calibration, truth, np.arange(n) + 1) is None   # id n is not a true point
    assert point_errors(saved.calibration, truth, [f"p{k}" for k in range(n)]) is None


def test_no_single_view_point_counted_as_outlier(tmp_path):
    """Points seen in one view only are not outliers: the inlier count is over tracked points."""
    scene = simulate.random_scene(40, 5, noise_px=0.1, rng=5)
    uv = scene.uv.copy()
    uv[1:, 30:] = np.nan  # 10 points seen in view 0 only
    tio.write_tracks_csv(tmp_path / "t.csv", uv)
    tio.write_poses_csv(tmp_path / "p.csv", scene.T)
    r = run("calibrate", "--tracks", tmp_path / "t.csv", "--poses", tmp_path / "p.csv", "--out", tmp_path / "o",
            "--quiet", "--formats", "json", "--json")
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    tracked = int((np.isfinite(uv[..., 0]).sum(axis=0) >= 2).sum())
    assert tracked >= 28 and summary["n_points_tracked"] == tracked and summary["n_inliers"] == tracked


def test_no_refine_gives_linear(simulated, tmp_path):
    from transcalib.io.calibration_file import load_calibration

    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv",
            "--out", tmp_path, "--no-refine", "--no-robust", "--quiet", "--formats", "json,csv")
    assert r.returncode == 0, r.stderr
    cal = load_calibration(tmp_path)
    assert cal.stats.stages == ("linear",) and cal.dist.size == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["arrays.npz", "calibration.json", "manifest.json",
                                                          "points.csv"]


def test_json_summary_and_show(calibrated, tmp_path):
    out, _ = calibrated
    r = run("show", out, "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)  # stdout is JSON only
    assert d["status"] == "ok" and d["exit_code"] == 0 and d["n_views"] == 5
    assert np.array(d["K"]).shape == (3, 3) and "fx" in d["std"] and d["schema_version"] == 2
    r = run("show", out)
    assert r.returncode == 0 and "fx =" in r.stdout and "schema 2" in r.stdout
    r = run("show", tmp_path)
    assert_clean_error(r, "does not exist")


def test_calibrate_json(simulated, tmp_path):
    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv",
            "--out", tmp_path, "--json", "--formats", "json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["status"] in ("ok", "warnings") and d["exit_code"] == 0
    assert {"K", "R_cam_world", "rms_px", "std", "diagnostics", "outputs", "timings_s", "run_timings_s"} <= set(d)
    assert str(tmp_path / "calibration.json") in d["outputs"]


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
    assert_clean_error(r, match)
    assert not out.exists() or not any(out.iterdir())


def test_degenerate_translations_exit_3(tmp_path):
    scene = simulate.random_scene(30, 4, rng=2)
    T = scene.T.copy()
    T[3] = T[1] + 0.5 * (T[2] - T[1])  # coplanar with the others
    from transcalib.geometry.camera import project
    tio.write_tracks_csv(tmp_path / "t.csv", project(scene.K, scene.R, scene.X, T))
    tio.write_poses_csv(tmp_path / "p.csv", T)
    r = run("calibrate", "--tracks", tmp_path / "t.csv", "--poses", tmp_path / "p.csv", "--out", tmp_path / "o")
    assert_clean_error(r, "coplanar", "--fix", code=3)
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_inputs_untouched(simulated, tmp_path):
    before = {p.name: p.read_bytes() for p in simulated.iterdir()}
    run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv", "--out", tmp_path,
        "--quiet", "--formats", "json")
    assert before == {p.name: p.read_bytes() for p in simulated.iterdir()}


def _rotated_view_inputs(tmp_path):
    scene = simulate.paper_scene(noise_px=0.2, rng=1)
    tio.write_tracks_csv(tmp_path / "t.csv", scene.uv)
    lines = ["view,x,y,z,qx,qy,qz,qw"]
    for i, t in enumerate(scene.T):
        q = "0.0026,0,0,0.99999662" if i == 2 else "0,0,0,1"  # view 2: turned 0.3 deg
        lines.append(",".join([str(i), *(repr(float(x)) for x in t), q]))
    (tmp_path / "p.csv").write_text("\n".join(lines) + "\n")
    return tmp_path / "t.csv", tmp_path / "p.csv"


def test_pose_orientations_checked_and_strict_exit_4(tmp_path):
    """poses.csv with qx,qy,qz,qw: view 2's recorded orientation is 0.3 deg off (inside the
    session tolerance) while its image is a pure translation of the others: the rotation
    test names it with the angle; with --strict the run exits 4 (outputs still written)."""
    from transcalib.io.calibration_file import load_calibration

    t, p = _rotated_view_inputs(tmp_path)
    r = run("calibrate", "--tracks", t, "--poses", p, "--out", tmp_path / "o", "--quiet", "--formats", "json")
    assert r.returncode == 0, r.stderr
    cal = load_calibration(tmp_path / "o")
    assert [d.code for d in cal.diagnostics] == ["view_rotation"]
    assert re.search(r"view 2: about 0\.3\d deg", str(cal.diagnostics[0]))
    r = run("calibrate", "--tracks", t, "--poses", p, "--out", tmp_path / "s", "--quiet", "--formats", "json",
            "--strict", "--json")
    assert r.returncode == 4 and json.loads(r.stdout)["exit_code"] == 4
    assert (tmp_path / "s" / "calibration.json").is_file()


def _calibrate_with_ids(folder, scene, poses_ids: str, tracks_ids: str, R=None, *extra):
    """Run ``calibrate`` on ``scene`` with view ids formatted by ``poses_ids`` /
    ``tracks_ids`` (e.g. ``"{:02d}"``); the saved calibration."""
    from transcalib.io.calibration_file import load_saved

    folder.mkdir()
    n = scene.n_views
    tio.write_tracks_csv(folder / "t.csv", scene.uv, view_ids=[tracks_ids.format(i) for i in range(n)])
    tio.write_poses_csv(folder / "p.csv", scene.T, [poses_ids.format(i) for i in range(n)], R=R)
    r = run("calibrate", "--tracks", folder / "t.csv", "--poses", folder / "p.csv", "--out", folder / "o",
            "--quiet", "--formats", "json", *extra)
    assert r.returncode == 0, r.stderr
    assert (folder / "o" / "hand_eye.json").exists() == (R is not None)  # one orientation: R_X, not t_X
    return load_saved(folder / "o")


def test_zero_padded_view_ids_with_one_orientation(tmp_path):
    """View ids compare as integers through the command: poses "00", "01", ... with tracks
    "0", "1", ... (or "000", ...) give the calibration of plain ids, with or without a
    (constant) orientation in the poses (JSON poses too)."""
    scene = simulate.random_scene(40, 5, noise_px=0.2, rng=4)
    R = np.tile(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), (5, 1, 1))
    ref = _calibrate_with_ids(tmp_path / "ref", scene, "{}", "{}")
    assert np.abs(ref.calibration.K - scene.K).max() < 0.01 * scene.K[0, 0]
    for k, (poses_ids, tracks_ids, rot) in enumerate([("{:02d}", "{}", None), ("{:02d}", "{:03d}", R),
                                                       ("{}", "{:02d}", R)]):
        saved = _calibrate_with_ids(tmp_path / str(k), scene, poses_ids, tracks_ids, rot)
        np.testing.assert_array_equal(saved.calibration.K, ref.calibration.K)
        assert saved.inputs["view_ids"] == ["0", "1", "2", "3", "4"]
        assert saved.calibration.diagnostics == ref.calibration.diagnostics
    from transcalib.io.calibration_file import load_saved

    js = [{"view": f"{i:02d}", "x": t[0], "y": t[1], "z": t[2], "rx": 0, "ry": 0, "rz": 0.5}
          for i, t in enumerate(tio.read_poses(tmp_path / "ref" / "p.csv").T.tolist())]
    (tmp_path / "p.json").write_text(json.dumps(js))
    r = run("calibrate", "--tracks", tmp_path / "ref" / "t.csv", "--poses", tmp_path / "p.json", "--out",
            tmp_path / "j", "--quiet", "--formats", "json")
    assert r.returncode == 0, r.stderr
    np.testing.assert_array_equal(load_saved(tmp_path / "j").calibration.K, ref.calibration.K)


@pytest.mark.parametrize("poses, extra, words", [
    ("view,x,y,z,qx,qy,qz\n0,0,0,0,0,0,0\n", [], ["line 1", "qx,qy,qz", "without qw", "--rotation-format"]),
    ("view,x,y,z,qx,qy,qz,qw,a,b,c\n0,0,0,0,0,0,0,1,0,0,0\n", [], ["two orientations", "--rotation-format"]),
    ("view,x,y,z\n0,0,0,0\n", ["--rotation-format", "kuka"], ["lacks column(s) a, b, c", "--rotation-format"]),
    ("view,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,1,0,0,0,0,0,1.1\n", [], ["line 3", "norm 1.1"]),
    ("view,x,y,z\n01,0,0,0\n1,1,0,0\n", [], ["line 3", "column 'view'", "appears more than once"]),
])
def test_pose_file_errors_are_one_line(tmp_path, simulated, poses, extra, words):
    """Errors of the pose reader through the command: exit 2, one line naming the file,
    the line and the column and what to do (the option, not the Python keyword)."""
    (tmp_path / "p.csv").write_text(poses)
    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", tmp_path / "p.csv", "--out",
            tmp_path / "o", *extra)
    assert_clean_error(r, "p.csv", *words)
    assert "rotation_format" not in r.stderr
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


# --------------------------------------------------------------------------------------
# checked before any work
# --------------------------------------------------------------------------------------


def _image_args():
    images = sorted((EXAMPLES / "images").glob("view*.png"))
    return ["calibrate", "--images", *images, "--poses", EXAMPLES / "images" / "poses.csv"]


def _bad_outs(tmp_path):
    f = tmp_path / "a_file"
    f.write_text("x")
    return {"existing file": (f, "is an existing file"), "under a file": (f / "sub", "is a file")}


@pytest.mark.parametrize("case", ["existing file", "under a file"])
def test_bad_out_fails_before_tracking(tmp_path, case, capsys):
    """A bad --out on an image run fails in one line, exit 2, in well under a second
    (measured in-process: the check comes before reading or tracking any image)."""
    from transcalib.cli.main import main

    out, words = _bad_outs(tmp_path)[case]
    main(["simulate", "--out", str(tmp_path / "warm")])  # imports done: time the check only
    capsys.readouterr()
    t0 = time.perf_counter()
    code = main([*map(str, _image_args()), "--out", str(out)])
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err
    assert code == 2 and "--out" in err and words in err and len(err.strip().splitlines()) == 1
    assert elapsed < 1.0, elapsed
    assert_clean_error(run(*_image_args(), "--out", out), "--out", words)


@pytest.mark.skipif(os.geteuid() == 0 and shutil.which("chattr") is None, reason="needs chattr as root")
def test_unwritable_out(tmp_path):
    """A read-only (non-root) or immutable (root, chattr +i) folder is refused up front."""
    locked = tmp_path / "locked"
    locked.mkdir()
    if os.geteuid() == 0:
        if subprocess.run(["chattr", "+i", str(locked)], capture_output=True).returncode != 0:
            pytest.skip("file system without the immutable attribute")
    else:
        locked.chmod(0o555)
    try:
        r = run("simulate", "--out", locked / "sim")
        assert_clean_error(r, "--out", "not writable")
        r = run(*_image_args(), "--out", locked)
        assert_clean_error(r, "--out", "not writable")
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(locked)])
        locked.chmod(0o755)


def test_missing_truth_fails_first(simulated, tmp_path):
    out = tmp_path / "o"
    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv", "--out", out,
            "--truth", tmp_path / "nope.json")
    assert_clean_error(r, "--truth", "does not exist")
    assert not out.exists()
    K = [[800.0, 0.0, 400.0], [0.0, 800.0, 300.0], [0.0, 0.0, 1.0]]
    for text in ("{not json", "[1, 2]", '{"R": []}', json.dumps({"K": K, "points": [[1.0, 2.0]]}),
                 json.dumps({"K": K, "points": [[1.0, 2.0, "x"]]}), b"\xff\xfe"):
        bad = tmp_path / "bad.json"
        (bad.write_bytes if isinstance(text, bytes) else bad.write_text)(text)
        r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv", "--out", out,
                "--truth", bad)
        assert_clean_error(r, "--truth", "not a truth.json")
        assert not out.exists()


def test_track_output_onto_folder(tmp_path):
    images = sorted((EXAMPLES / "images").glob("view*.png"))
    r = run("track", *images, "-o", tmp_path)
    assert_clean_error(r, "-o/--output", "is a folder")
    r = run("track", *images, "-o", tmp_path / "tracks.txt")
    assert_clean_error(r, "-o/--output", "extension")


@pytest.mark.parametrize("args, words", [
    (["--preset", "random", "--views", "3"], ["--views", "at least 4"]),
    (["--preset", "random", "--points", "-5"], ["--points", "positive integer"]),
    (["--points", "100000"], ["--points", "--preset random"]),
    (["--planar"], ["--planar", "--preset random"]),
    (["--noise-px", "-1"], ["--noise-px", ">= 0"]),
    (["--robot-noise", "nan"], ["--robot-noise", "finite"]),
    (["--preset", "random", "--missing", "1.5"], ["--missing", "[0, 1)"]),
    (["--preset", "random", "--points", "ten"], ["--points", "number"]),
])
def test_simulate_bad_options(tmp_path, args, words):
    r = run("simulate", "--out", tmp_path / "o", *args)
    assert_clean_error(r, *words)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, words", [
    (["--no-refine", "--robot-sigma", "0.1"], ["--no-refine", "--robot-sigma"]),
    (["--no-refine", "--distortion", "radial2"], ["--no-refine", "distortion"]),
    (["--no-robust", "--threshold-px", "3"], ["--no-robust"]),
    (["--one-noise", "--no-robust"], ["--one-noise", "--no-robust"]),
    (["--one-noise", "--threshold-px", "2"], ["--one-noise", "--threshold-px"]),
    (["--robot-sigma", "-1"], ["--robot-sigma", ">= 0"]),
    (["--no-robot-error", "--robot-sigma-deg", "0.1"], ["--no-robot-error", "--robot-sigma"]),
    (["--threshold-px", "0"], ["--threshold-px", "positive"]),
    (["--image-size", "640"], ["--image-size", "WIDTHxHEIGHT"]),
    (["--formats", "json,matlab"], ["--formats", "matlab"]),
    (["--target", "squares"], ["--target", "--images"]),
    (["--fix", "cx"], ["--fix", "NAME=VALUE"]),
    (["--fix", "focal=3"], ["--fix", "unknown parameter"]),
    (["--fix", "principal-point=centre", "--image-size", "0x0"], ["--image-size"]),
    (["--subset-points", "50"], ["--subset-points", "100"]),
    (["--subset-points", "many"], ["--subset-points"]),
])
def test_calibrate_bad_options_name_the_option(simulated, tmp_path, args, words):
    out = tmp_path / "o"
    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv", "--out", out,
            *args)
    assert_clean_error(r, *words)
    assert "sigma_T" not in r.stderr and "threshold_px" not in r.stderr
    assert not out.exists()


def test_fix_and_square_pixels(simulated, tmp_path):
    """--fix principal-point=centre (image size from --truth) and --square-pixels reach the fit."""
    from transcalib.io.calibration_file import load_calibration

    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", simulated / "poses.csv", "--out", tmp_path,
            "--truth", simulated / "truth.json", "--fix", "principal-point=centre", "--square-pixels", "--quiet",
            "--formats", "json")
    assert r.returncode == 0, r.stderr
    cal = load_calibration(tmp_path)
    w, h = cal.image_size
    assert cal.K[0, 2] == (w - 1) / 2 and cal.K[1, 2] == (h - 1) / 2 and cal.K[0, 0] == cal.K[1, 1]
    assert dict(cal.options.refinement.fix) == {"cx": (w - 1) / 2, "cy": (h - 1) / 2}


def test_missing_inputs_name_the_option(simulated, tmp_path):
    r = run("calibrate", "--tracks", tmp_path / "no.csv", "--poses", simulated / "poses.csv", "--out", tmp_path / "o")
    assert_clean_error(r, "--tracks", "does not exist")
    r = run("calibrate", "--tracks", simulated / "tracks.csv", "--poses", tmp_path / "no.csv", "--out", tmp_path / "o")
    assert_clean_error(r, "--poses", "does not exist")
    r = run("calibrate", "--images", tmp_path / "no.png", "--poses", simulated / "poses.csv", "--out", tmp_path / "o")
    assert_clean_error(r, "--images", "does not exist")


# --------------------------------------------------------------------------------------
# undistort
# --------------------------------------------------------------------------------------


def test_undistort_matches_opencv(tmp_path):
    import cv2

    from test_io import full_calibration
    from transcalib.io.calibration_file import save_calibration

    cal = full_calibration()  # radial2, 640 x 480
    save_calibration(cal, tmp_path / "cal")
    img = np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    img = cv2.GaussianBlur(img, (9, 9), 3)
    cv2.imwrite(str(tmp_path / "a.png"), img)
    r = run("undistort", tmp_path / "a.png", "--calibration", tmp_path / "cal", "--out", tmp_path / "u")
    assert r.returncode == 0, r.stderr
    got = cv2.imread(str(tmp_path / "u" / "a.png"))
    np.testing.assert_array_equal(got, cv2.undistort(img, cal.K, cal.dist_opencv))
    assert not np.array_equal(got, img)
    r = run("undistort", tmp_path / "a.png", "--calibration", tmp_path / "cal", "--out", tmp_path)
    assert_clean_error(r, "--out", "holds the input", "would delete it")
    cv2.imwrite(str(tmp_path / "small.png"), img[:100])
    r = run("undistort", tmp_path / "small.png", "--calibration", tmp_path / "cal", "--out", tmp_path / "u")
    assert_clean_error(r, "640x480")


def test_subcommands_registered_from_one_list():
    import importlib

    cli_main = importlib.import_module("transcalib.cli.main")
    assert cli_main.COMMANDS == ("calibrate", "extract", "simulate", "track", "show", "undistort", "plan", "validate",
                                 "dense")
    r = run("--help")
    assert all(c in r.stdout for c in cli_main.COMMANDS)


def test_json_on_failure_and_binary_tracks(tmp_path):
    """--json also reports a failure on stdout; simulate --tracks-format npz feeds calibrate."""
    r = run("simulate", "--preset", "random", "--points", 40, "--views", 5, "--tracks-format", "npz",
            "--out", tmp_path / "s", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["outputs"][0].endswith("tracks.npz")
    r = run("calibrate", "--tracks", tmp_path / "s" / "tracks.npz", "--poses", tmp_path / "s" / "poses.csv",
            "--out", tmp_path / "o", "--formats", "json", "--json", "--quiet")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["n_points"] == 40
    (tmp_path / "bad.csv").write_text("view,x,y,z\n0,0,0,0\n")
    r = run("calibrate", "--tracks", tmp_path / "s" / "tracks.npz", "--poses", tmp_path / "bad.csv",
            "--out", tmp_path / "o2", "--json")
    d = json.loads(r.stdout)
    assert r.returncode == 2 and d["status"] == "error" and d["exit_code"] == 2 and "not in the poses file" in d["error"]


def test_progress_bar_on_a_terminal_plain_lines_otherwise():
    import io

    from transcalib.cli.common import Progress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    tty, pipe = Terminal(), io.StringIO()
    for stream in (tty, pipe):
        p = Progress(stream=stream)
        for k in range(1, 9):
            p.step("matching", k, 8)
    assert "\r" in tty.getvalue() and "100%" in tty.getvalue()  # a tqdm bar
    assert pipe.getvalue().splitlines() == ["  matching: 2/8", "  matching: 4/8", "  matching: 6/8", "  matching: 8/8"]
    quiet = io.StringIO()
    Progress(quiet=True, stream=quiet).step("x", 1, 1)
    assert quiet.getvalue() == ""


def test_subset_points_reaches_the_fit(tmp_path):
    """--subset-points N: the iterative stages on N tracks, then every track (JSON summary
    and the saved options say so); 'all' turns it off."""
    from transcalib.io.calibration_file import load_calibration

    sim = tmp_path / "sim"
    assert run("simulate", "--preset", "random", "--points", 400, "--views", 5, "--noise-px", 0.3, "--seed", 2,
               "--out", sim).returncode == 0
    for arg, subset, stage in (("150", 150, "all tracks"), ("all", None, "refine")):
        out = tmp_path / f"o{arg}"
        r = run("calibrate", "--tracks", sim / "tracks.csv", "--poses", sim / "poses.csv", "--out", out,
                "--subset-points", arg, "--formats", "json", "--json", "--quiet")
        assert r.returncode == 0, r.stderr
        assert load_calibration(out).options.subset_points == subset
        assert json.loads(r.stdout)["stages"][-1].split(" (")[0] in (stage, "reclassify+refine")


def test_the_command_keeps_freed_memory_on_glibc():
    """The allocator settings are accepted by glibc (each mallopt call returns 1)."""
    import platform

    from transcalib.cli.main import keep_freed_memory

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("not glibc")
    assert keep_freed_memory() is True


_TUNED = """
import gc, json, os
from transcalib.cli.main import tune_process
tune_process()
import pyarrow as pa
from threadpoolctl import threadpool_info
print(json.dumps({"pool": pa.default_memory_pool().backend_name, "env": os.environ.get("OPENBLAS_NUM_THREADS"),
                  "blas": [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"],
                  "gc": gc.get_threshold()[0]}))
"""


@pytest.mark.parametrize("user_env", [{}, {"OPENBLAS_NUM_THREADS": "2", "ARROW_DEFAULT_MEMORY_POOL": "mimalloc"}])
def test_the_command_process_runs_blas_on_one_thread_and_arrow_on_glibc(user_env):
    """tune_process (the console script's, in a process of its own): numpy's BLAS on one
    thread, the same for processes it starts, Arrow's default pool the system one, the
    garbage collector's youngest generation at GC_THRESHOLD; a user's own settings are
    kept."""
    from transcalib.cli.main import GC_THRESHOLD

    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "ARROW_DEFAULT_MEMORY_POOL")}
    r = subprocess.run([sys.executable, "-c", _TUNED], env={**env, **user_env}, capture_output=True, text=True,
                       check=True)
    got = json.loads(r.stdout)
    assert got["gc"] == GC_THRESHOLD
    if user_env:
        assert got["env"] == "2" and got["pool"] == "mimalloc" and set(got["blas"]) == {2}
    else:
        assert got["env"] == "1" and got["pool"] == "system" and set(got["blas"]) == {1}


# --------------------------------------------------------------------------- images at several orientations (issue 21)
def test_calibrate_images_with_quaternion_poses_links_sessions_and_single_views(tmp_path):
    """``calibrate --images --poses`` with flange orientations: two sessions 20 deg apart
    and a single view 12 deg off, the camera at a fixed offset in the flange; the images
    route groups them, tracks and links them (points seen in both sessions and in the
    single view) and calibrates K. Measured (400 x 300, seed 3): 1126 points in both sessions,
    989 of them also in the single view; fx, fy within 2e-5 (bars 500, 400, 0.2 %)."""
    import cv2
    from scipy.spatial.transform import Rotation

    from transcalib.synth import render

    r = render.render_scene("natural", n_views=4, image_size=(400, 300), supersample=1, rng=3)
    centre = r.T[0] + 1000.0 * r.R[2]
    cams, centres = [r.R] * 4, list(r.T)
    for deg, axis, n in ((20.0, [0.3, 1.0, 0.2], 4), (12.0, [1.0, 0.2, 0.3], 1)):
        Q = Rotation.from_rotvec(np.deg2rad(deg) * np.asarray(axis) / np.linalg.norm(axis)).as_matrix()
        moves = render.robot_translations(n, 120.0, np.random.default_rng(n)) if n > 1 else np.zeros((1, 3))
        cams += [r.R @ Q.T] * n
        centres += [centre + Q @ (r.T[0] - centre) + t for t in moves]
    R_X = Rotation.from_euler("xyz", [170.0, 5.0, 80.0], degrees=True).as_matrix()
    t_X = np.array([20.0, -30.0, 100.0])
    R_flange = np.array([Rc.T @ R_X.T for Rc in cams])  # camera -> base = R_i R_X
    T = np.array(centres) - R_flange @ t_X
    names = []
    for i, (Rc, C) in enumerate(zip(cams, centres)):
        img = render.render(r.surfaces, r.K, Rc, C[None], r.image_size, supersample=1, noise_std=1.0, rng=i)[0]
        names.append(f"v{i}.png")
        cv2.imwrite(str(tmp_path / names[-1]), img)
    tio.write_poses_csv(tmp_path / "poses.csv", T, images=names, R=R_flange)
    out = tmp_path / "out"
    res = run("calibrate", "--images", *[tmp_path / n for n in names], "--poses", tmp_path / "poses.csv",
              "--out", out, "--formats", "json", "--json")
    assert res.returncode in (0, 1), res.stderr
    summary = json.loads(res.stdout)
    K = np.array(summary["K"])
    assert abs(K[0, 0] / r.K[0, 0] - 1) < 0.002 and abs(K[1, 1] / r.K[1, 1] - 1) < 0.002, (K, r.K)
    uv, _ = tio.tracks_to_uv(out / "tracks.csv", tio.read_poses(tmp_path / "poses.csv"))
    seen = np.isfinite(uv[..., 0])
    both = seen[:4].any(0) & seen[4:8].any(0)
    assert both.sum() >= 500 and (both & seen[8]).sum() >= 400, (both.sum(), (both & seen[8]).sum())
