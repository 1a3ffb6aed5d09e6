"""Images -> calibration through the command, against COLMAP's front-end, side by side.

    python benchmarks/bench_tracker_speed.py [--quick] [--repeat N] [--main SRC]

Two rendered sets (``render_scene("mixed")``, 1 grey level of noise): 6 views of
1024 x 768 saved as JPEG (quality 90) and 4 views of 800 x 600 saved as PNG, each with a
``poses.csv`` of the exact translations. For each set, in one run, alternating, the
median of ``--repeat`` wall times (warm disk cache, the files read once before):

- ``transcalib calibrate --images ... --poses poses.csv --formats json`` as a user runs
  it (a subprocess: interpreter start, imports, tracking, calibration, writing; Python's
  bytecode cache on, warmed by one untimed run);
- with ``--main SRC``, the same command with ``PYTHONPATH=SRC`` (another checkout);
- COLMAP's SIFT extraction plus exhaustive matching (pycolmap, CPU, 2 threads), alone.

Wall times depend on what else the machine runs; CPU times (user + system, every
thread) much less, so both are given. Also the tracker's own stage times (``Tracks.info.time_s``, in process) and fx against
the truth. Writes ``benchmarks/results/tracker_speed.md`` (``--quick``: a scratch folder,
one repetition).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import md_table, results_dir  # noqa: E402

SETS = {"6 x 1024x768 JPEG": dict(n=6, size=(1024, 768), ext="jpg", rng=11),
        "4 x 800x600 PNG": dict(n=4, size=(800, 600), ext="png", rng=12)}


def write_set(folder: Path, n, size, ext, rng):
    """Render a set into ``folder``: images, poses.csv; returns (image paths, K)."""
    import cv2

    from transcalib import render
    from transcalib.io import write_poses_csv

    r = render.render_scene("mixed", n_views=n, image_size=size, distance=1000.0, baseline=0.12, noise_std=1.0,
                            supersample=1, rng=rng)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, im in enumerate(r.images):
        p = folder / f"view{i}.{ext}"
        cv2.imwrite(str(p), im, [cv2.IMWRITE_JPEG_QUALITY, 90] if ext == "jpg" else [])
        paths.append(p)
    write_poses_csv(folder / "poses.csv", r.T, images=[p.name for p in paths])
    return paths, r.K


def run_cli(paths, folder: Path, src: str):
    """Wall and CPU time (s, the child's user + system) of the command, and its summary.

    As a user's Python runs it: with its bytecode cache (``PYTHONDONTWRITEBYTECODE``,
    set on some build machines, is dropped; without the cache every run compiles the
    package's modules again, ~0.1 s of CPU), warmed by one untimed run (:func:`main`);
    the thread settings are the user's (a BLAS thread count such as ``OMP_NUM_THREADS``
    in the environment is kept by the command, which otherwise runs BLAS on one thread)."""
    env = dict(os.environ, PYTHONPATH=src)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    out = folder / f"out_{abs(hash(src)) % 1000}"
    t0, c0 = time.perf_counter(), _children_cpu()
    r = subprocess.run([sys.executable, "-m", "transcalib.cli", "calibrate", "--images", *map(str, paths), "--poses",
                        str(folder / "poses.csv"), "--out", str(out), "--formats", "json", "--json", "--quiet"], capture_output=True, text=True, env=env)
    dt, cpu = time.perf_counter() - t0, _children_cpu() - c0
    if r.returncode not in (0, 1):
        raise RuntimeError(r.stderr[-2000:])
    return dt, cpu, json.loads(r.stdout)


def _children_cpu() -> float:
    import resource

    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def run_colmap(paths, folder: Path):
    """Wall and CPU time (s, this process's threads) of COLMAP's extraction + exhaustive
    matching on the images."""
    import pycolmap

    db = folder / "colmap.db"
    if db.exists():
        db.unlink()
    img_dir = paths[0].parent
    t0, c0 = time.perf_counter(), time.process_time()
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = 2
    pycolmap.extract_features(db, img_dir, image_names=[p.name for p in paths],
                              camera_mode=pycolmap.CameraMode.SINGLE, extraction_options=ext,
                              device=pycolmap.Device.cpu)
    mopt = pycolmap.FeatureMatchingOptions()
    mopt.num_threads = 2
    pycolmap.match_exhaustive(db, matching_options=mopt, device=pycolmap.Device.cpu)
    return time.perf_counter() - t0, time.process_time() - c0


def stages(paths):
    """The tracker's stage times in this process (s)."""
    from transcalib.images import track
    from transcalib.io import read_poses

    poses = read_poses(paths[0].parent / "poses.csv")
    tr = track([str(p) for p in paths], T=poses.T)
    return tr.info.time_s, tr.n_points, float(np.mean(np.isfinite(tr.uv[..., 0]).sum(0)))


def load_text() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return "uptime not available"


def main(argv=()) -> str:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeat", type=int, default=None)
    ap.add_argument("--main", default=None, help="src folder of another checkout to time beside this one")
    args = ap.parse_args(list(argv))
    repeat = args.repeat or (1 if args.quick else 3)
    here = str(Path(__file__).resolve().parents[1] / "src")
    rows, notes = [], [f"load before: {load_text()}"]
    with tempfile.TemporaryDirectory() as tmp:
        for name, spec in SETS.items():
            folder = Path(tmp) / name.split()[2]
            paths, K = write_set(folder, **spec)
            for p in paths:
                p.read_bytes()  # warm the disk cache
            for src in [here] + ([args.main] if args.main else []):
                run_cli(paths, folder, src)  # untimed: writes the bytecode cache
            times = {"ours": [], "main": [], "colmap": []}
            cpus = {"ours": [], "main": [], "colmap": []}
            fx = {}
            runs = {"ours": lambda: run_cli(paths, folder, here), "colmap": lambda: run_colmap(paths, folder)}
            if args.main:
                runs["main"] = lambda: run_cli(paths, folder, args.main)
            order = list(runs)
            for k in range(repeat):  # the order turns each round: no command always follows COLMAP's two threads
                for who in order[k % len(order):] + order[:k % len(order)]:
                    dt, cpu, *summ = runs[who]()
                    times[who].append(dt)
                    cpus[who].append(cpu)
                    if summ:
                        fx[who] = summ[0]["K"][0][0]
            st, n_pts, mean_len = stages(paths)
            med = {k: float(np.median(v)) if v else float("nan") for k, v in times.items()}
            mc = {k: float(np.median(v)) if v else float("nan") for k, v in cpus.items()}
            rows.append([name, med["ours"], med["main"], med["colmap"], med["ours"] / med["colmap"], mc["ours"],
                         mc["main"], mc["colmap"], mc["ours"] / mc["colmap"],
                         100 * (fx["ours"] / K[0, 0] - 1), n_pts, mean_len,
                         ", ".join(f"{k} {v:.2f}" for k, v in st.items())])
            print(rows[-1], file=sys.stderr, flush=True)
    notes.append(f"load after: {load_text()}")
    text = ("# Images -> calibration: the command against COLMAP's front-end\n\n"
            f"`python benchmarks/bench_tracker_speed.py{' --quick' if args.quick else ''}"
            f"{' --main ' + args.main if args.main else ''}` (median of {repeat}, wall s; "
            "pycolmap SIFT extraction + exhaustive matching, CPU, 2 threads; 2-core machine shared with other "
            "jobs: " + "; ".join(notes) + ")\n\n"
            + md_table(["images", "transcalib calibrate --images (wall s)", "main's command (wall s)",
                        "COLMAP extract + match (wall s)", "ours / COLMAP (wall)", "ours (CPU s)", "main (CPU s)",
                        "COLMAP (CPU s)", "ours / COLMAP (CPU)", "fx error %", "tracks",
                        "mean views per track", "tracker stages (s, in process)"], rows))
    print(text)
    (results_dir(args.quick) / "tracker_speed.md").write_text(text + "\n")
    return text


if __name__ == "__main__":
    main(sys.argv[1:])
