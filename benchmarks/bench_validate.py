"""``transcalib validate`` on held-out rendered views at another flange orientation.

Rendered images (``render_scene("mixed")``, 640 x 480, the realistic degradations of
``synth.degrade.REALISTIC``: vignetting, exposure changes, shot and read noise, JPEG 85,
a specular highlight, a time-stamp overlay) in three sessions of a camera on a flange
(``t_X = (30, -20, 50)`` mm): A and C (6 views each, C turned 15 deg) are calibrated,
B (4 views, turned 12 deg about another axis) is held out. Every image is tracked in one
``track_sessions`` run (so the point ids agree), the tracks split by session, and the
command line run as a user would:

    transcalib calibrate --tracks AC.csv --poses AC.csv --out cal
    transcalib validate --calibration cal --tracks B.csv --poses B.csv --json --strict

once with the calibration as made and once with its fx 2 % off (calibration.json
edited). Printed: the prediction error of the held-out views, what the covariance
predicts, the offset component fitted on them, the exit status.

    python benchmarks/bench_validate.py [--quick] [--seed N]
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from transcalib import io as tio
from transcalib.images import track_sessions
from transcalib.synth import render
from transcalib.synth.degrade import REALISTIC

T_X = np.array([30.0, -20.0, 50.0])


def sessions(seed: int, size):
    """Images, flange rotations, flange positions and labels of sessions A, C, B."""
    r = render.render_scene("mixed", n_views=16, image_size=size, degrade=REALISTIC, rng=seed)
    turns = {"A": np.eye(3), "C": Rotation.from_rotvec(np.radians(15) * np.array([0.0, 1.0, 0.2]) / np.hypot(1, 0.2)),
             "B": Rotation.from_rotvec(np.radians(12) * np.array([1.0, 0.0, 0.3]) / np.hypot(1, 0.3))}
    views = {"A": slice(0, 6), "C": slice(6, 12), "B": slice(12, 16)}
    images, R_f, T_f, labels = [], [], [], []
    for k, (name, sl) in enumerate(views.items()):
        Q = np.eye(3) if name == "A" else turns[name].as_matrix()
        R_cam = Q @ r.R  # the camera turned in its own frame
        C = r.T[sl]
        images.append(render.render(r.surfaces, r.K, R_cam, C, r.image_size, degrade=REALISTIC, rng=seed + k))
        R_i = r.R.T @ Q.T @ r.R  # flange rotation: R_cam = R_X^T R_i^T with R_X = r.R^T
        R_f += [R_i] * len(C)
        T_f += list(C - R_i @ T_X)  # camera centre = T_i + R_i t_X
        labels += [name] * len(C)
    return r, np.concatenate(images), np.array(R_f), np.array(T_f), np.array(labels)


def run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "transcalib", *map(str, args)], capture_output=True, text=True)


def main(argv: list[str]) -> int:
    quick = "--quick" in argv
    seed = int(argv[argv.index("--seed") + 1]) if "--seed" in argv else 3
    size = (480, 360) if quick else (640, 480)
    r, images, R_f, T_f, labels = sessions(seed, size)
    tracks = track_sessions(images, list(labels), T=T_f)
    work = Path(tempfile.mkdtemp(prefix="bench-validate-"))
    ids = [str(v) for v in range(len(labels))]
    for name, sel in (("AC", labels != "B"), ("B", labels == "B")):
        tio.write_tracks_csv(work / f"{name}_tracks.csv", tracks.uv[sel], tracks.ids, [i for i, s in zip(ids, sel) if s])
        tio.write_poses_csv(work / f"{name}_poses.csv", T_f[sel], [i for i, s in zip(ids, sel) if s], R=R_f[sel])
    cal = run("calibrate", "--tracks", work / "AC_tracks.csv", "--poses", work / "AC_poses.csv", "--out",
              work / "cal", "--formats", "json", "--quiet", "--json")
    summary = json.loads(cal.stdout)
    print(f"calibrate: exit {cal.returncode}, fx {summary['K'][0][0]:.1f} (true {r.K[0, 0]:.1f}), rms "
          f"{summary['rms_px']:.3f} px, sigma {summary['sigma_px']:.3f} px, warnings "
          f"{[d['code'] for d in summary['diagnostics']]}")
    doc = json.loads((work / "cal" / "calibration.json").read_text())
    doc["K"][0][0] *= 1.02
    (work / "cal_fx").mkdir()
    (work / "cal_fx" / "calibration.json").write_text(json.dumps(doc))
    (work / "cal_fx" / "arrays.npz").write_bytes((work / "cal" / "arrays.npz").read_bytes())
    print("| calibration | exit | RMS px | median px | max px | predicted RMS | predicted median | new views' own "
          "noise px | fitted | points |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|---:|")
    for label, folder in (("as calibrated", "cal"), ("fx 2 % off", "cal_fx")):
        v = run("validate", "--calibration", work / folder, "--tracks", work / "B_tracks.csv", "--poses",
                work / "B_poses.csv", "--json", "--strict")
        out = json.loads(v.stdout)
        fitted = ", ".join(f"{f['name']} {f['value']:.1f}" for f in out["fitted"]) or "-"
        print(f"| {label} | {v.returncode} | {out['rms_px']:.3f} | {out['median_px']:.3f} | {out['max_px']:.3g} | "
              f"{out['predicted_rms_px']:.3f} | {out['predicted_median_px']:.3f} | {out['noise_px']:.3f} | {fitted} | "
              f"{out['n_points']} |")
    print(f"(files in {work}; t_X true {T_X.tolist()} mm)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
