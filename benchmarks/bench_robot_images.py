"""From rendered images to the hand-eye pose, through the command line, as a user runs it
(issues 20 and 25).

Renders of :func:`transcalib.synth.robot.robot_scene` at 640 x 480 with the realistic
camera effects (mild barrel distortion, vignetting, exposure changes, noise, a specular
highlight, JPEG 90) and no robot error, in two layouts:

- **session + single views** (issue 20): one 3-D pure-translation session of 6 views plus
  6 single views turned 15-45 deg from it, the scene 0.5-1 m away;
- **general motion** (issue 25): 12 views, each at its own orientation (15-45 deg from a
  common one), no session;

eye-in-hand (a work cell seen by the flange camera) and eye-to-hand (a fixed camera
watching a textured object on the flange before a static textured wall). Each scene is
written as JPEG images + ``poses.csv`` (quaternions) into a temporary folder and
calibrated by ``transcalib calibrate --images ... --poses ... --setup ... --json``; the
errors of fx, of the camera's rotation (``R_flange_camera`` / ``R_base_camera``) and of its
position against the truth are read from ``hand_eye.json``.
Targets: issue 20 fx within 0.1 %, R within 0.05 deg, t within 1 mm; issue 25 fx within
0.2 %, R within 0.1 deg, t within 2 mm.

Run ``python benchmarks/bench_robot_images.py`` (``--seeds N``: scenes per layout and
setup, default 3; seeds other than the shipped examples'; ``--layout sessions|general``:
one layout only). Writes
``benchmarks/results/robot_images.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from transcalib.geometry.rotation import rotation_angle_deg
from transcalib.io import write_poses_csv
from transcalib.synth.robot import robot_scene

HERE = Path(__file__).resolve().parent
LAYOUTS = {  # name: (robot_scene options, targets fx %, R deg, t mm)
    "session + 6 single views": (dict(session_views=6, single_views=6), (0.1, 0.05, 1.0)),
    "12 views, general motion": (dict(session_views=0, single_views=12), (0.2, 0.1, 2.0)),
}
JPEG_QUALITY = 90
FIRST_SEED = 100  # the shipped examples use 2026 and 2027


def write_scene(folder: Path, setup: str, seed: int, options: dict):
    """Render one scene into ``folder``: ``view*.jpg``, ``poses.csv``; returns its truth."""
    r = robot_scene(setup, rng=seed, **options)
    names = [f"view{i:02d}.jpg" for i in range(r.n_views)]
    for name, img in zip(names, r.images):
        cv2.imwrite(str(folder / name), img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    write_poses_csv(folder / "poses.csv", r.T, R=r.R, images=names)
    return r


def calibrate_cli(folder: Path, setup: str) -> tuple[dict, dict | None, float]:
    """``transcalib calibrate`` on the folder: the JSON summary, ``hand_eye.json`` (None on
    failure) and the wall time."""
    images = sorted(str(p) for p in folder.glob("view*.jpg"))
    out = folder / "out"
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "transcalib", "calibrate", "--images", *images, "--poses",
                        str(folder / "poses.csv"), "--setup", setup, "--unit", "mm", "--out", str(out), "--formats",
                        "json", "--json", "--quiet"], capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    try:
        summary = json.loads(r.stdout)
    except json.JSONDecodeError:
        summary = {"exit_code": r.returncode, "message": r.stderr.strip().splitlines()[-1:]}
    he = json.loads((out / "hand_eye.json").read_text()) if (out / "hand_eye.json").is_file() else None
    return summary, he, seconds


def errors(r, summary: dict, he: dict | None) -> tuple[float, float, float]:
    """fx error (%), rotation error (deg), position error (mm, largest component); NaN
    where the run failed."""
    if he is None or "K" not in summary:
        return float("nan"), float("nan"), float("nan")
    frame = "flange" if r.setup == "eye-in-hand" else "base"
    fx = 100.0 * (np.array(summary["K"])[0, 0] / r.K[0, 0] - 1.0)
    R = np.array(he[f"R_{frame}_camera"])
    t = np.array(he[f"t_{frame}_camera"])
    return fx, float(rotation_angle_deg(R.T @ r.R_X)), float(np.abs(t - r.t_X).max())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="scenes per layout and setup (default 3)")
    parser.add_argument("--layout", choices=["sessions", "general", "all"], default="all",
                        help="run only the session + single views layout, or only general motion (default all)")
    args = parser.parse_args(argv)
    layouts = {k: v for k, v in LAYOUTS.items()
               if args.layout == "all" or (args.layout == "general") == k.endswith("general motion")}
    rows = ["| layout | setup | seed | exit | fx err % | R err deg | t err mm | warnings | wall s | within targets |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for name, (options, targets) in layouts.items():
        for setup in ("eye-in-hand", "eye-to-hand"):
            for seed in range(FIRST_SEED, FIRST_SEED + args.seeds):
                with tempfile.TemporaryDirectory() as tmp:
                    folder = Path(tmp)
                    r = write_scene(folder, setup, seed, options)
                    summary, he, seconds = calibrate_cli(folder, setup)
                errs = errors(r, summary, he)
                ok = all(abs(e) <= t for e, t in zip(errs, targets))
                codes = ", ".join(d["code"] for d in summary.get("diagnostics", [])) or "-"
                rows.append(f"| {name} | {setup} | {seed} | {summary.get('exit_code')} | {errs[0]:+.3f} | "
                            f"{errs[1]:.3f} | {errs[2]:.2f} | {codes} | {seconds:.1f} | {'yes' if ok else 'NO'} |")
                print(rows[-1], flush=True)
    text = "\n".join(["# From rendered images to the hand-eye pose (benchmarks/bench_robot_images.py)", "",
                      f"`python benchmarks/bench_robot_images.py --seeds {args.seeds} --layout {args.layout}`; 640 x 480, realistic camera "
                      "effects, JPEG 90, no robot error. Targets: session + single views fx 0.1 %, R 0.05 deg, "
                      "t 1 mm; general motion fx 0.2 %, R 0.1 deg, t 2 mm.", "", *rows, ""])
    print(text)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "robot_images.md").write_text(text)


if __name__ == "__main__":
    main(sys.argv[1:])
