"""Benchmark: a view whose image contradicts its recorded pose, left out (``pose_left_out``).

Each trial is a simulated robot (``session_scene``: a table-top scene ~0.5 m away, 60
points, 0.5 px pixel noise) whose poses err per view by ``sigma_rot`` / ``sigma_pos``
(``with_robot_error``), and one view's recorded position given a typo of ``typo`` mm
along a random axis (none: the false alarms on correct poses). Two layouts: one
orientation with 12 views of 3-D moves, and three sessions of 6 views 25 deg apart plus 2
single views (hand-eye). The whole pipeline runs (``transcalib.calibrate``, the robot
error estimated from the data), by default (views left out) and, when it left a view out,
again with ``keep_pose_outliers=True`` (the code before the change).

Reported per case: how often the typo'd view was left out, how often another view was
(a false alarm), and for fx the RMS of error / reported std (z) and the RMS error, left out
and kept.

Run ``python benchmarks/bench_pose_outliers.py`` (``--trials N`` per case with a typo,
twice as many without; ``--jobs``). Writes ``benchmarks/results/pose_outliers.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import transcalib as tc  # noqa: E402
from transcalib.handeye.simulate import session_scene, with_robot_error  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from _common import md_table  # noqa: E402

OUT = Path(__file__).parent / "results" / "pose_outliers.md"
LAYOUTS = {"one session": dict(n_sessions=1, views_per_session=12),
           "3 sessions + 2 singles": dict(n_sessions=3, views_per_session=6, single_views=2)}
ROBOT = ((0.0, 0.0), (0.02, 0.2), (0.1, 1.0), (0.2, 2.0))
TYPOS_MM = (0.0, 3.0, 10.0, 30.0)


def trial(case: tuple) -> dict:
    """One trial of ``(layout, sigma_rot, sigma_pos, typo_mm, seed)``."""
    layout, s_rot, s_pos, typo, seed = case
    rng = np.random.default_rng(seed)
    sc = session_scene(rng, n_points=60, noise_px=0.5, **LAYOUTS[layout])
    rep, _ = with_robot_error(sc, s_rot, s_pos, rng)
    T = rep.T.copy()
    view = int(rng.integers(len(T)))
    T[view, rng.integers(3)] += typo * rng.choice((-1.0, 1.0))
    out = {"view": view if typo else None}
    for name, keep in (("left", False), ("kept", True)):
        try:
            cal = tc.calibrate(rep.uv, tc.Poses.of(T, rep.R), keep_pose_outliers=keep, rng=seed)
        except tc.TranscalibError as exc:  # a refused trial is counted, not hidden
            out[name] = {"failed": f"{type(exc).__name__}: {exc}"}
            continue
        out[name] = {"fx": (cal.K[0, 0] - sc.K[0, 0], cal.std["fx"]),
                     "left_out": [v["view"] for v in cal.info["views_left_out"] if v["why"] == "pose"]}
        if not out[name]["left_out"]:  # nothing left out: keeping changes nothing
            out["kept"] = out[name]
            break
    return out


def _cell(rows: list, name: str) -> tuple:
    """``(RMS z, RMS error)`` of fx over the trials that ran."""
    fx = np.array([r[name]["fx"] for r in rows if "fx" in r[name]])
    return float(np.sqrt(np.mean((fx[:, 0] / fx[:, 1]) ** 2))), float(np.sqrt(np.mean(fx[:, 0] ** 2)))


def table(results: dict, elapsed: float) -> str:
    header = ["layout", "σ_rot °", "σ_pos mm", "typo mm", "N", "typo'd view left out", "another left out",
              "fx RMS z left out", "fx RMS z kept", "fx RMS err left out px", "fx RMS err kept px", "refused"]
    rows = []
    for (layout, sr, sp, typo), res in results.items():
        ok = [r for r in res if "fx" in r["left"] and "fx" in r["kept"]]
        right = np.mean([r["view"] in r["left"]["left_out"] for r in ok]) if typo else np.nan
        other = np.mean([any(v != r["view"] for v in r["left"]["left_out"]) for r in ok])
        (zl, el), (zk, ek) = _cell(ok, "left"), _cell(ok, "kept")
        rows.append([layout, sr, sp, typo, len(ok), "-" if not typo else f"{100 * right:.0f} %",
                     f"{100 * other:.1f} %", zl, zk, el, ek, len(res) - len(ok)])
    return ("# A view whose image contradicts its recorded pose, left out\n\n"
            "`python benchmarks/bench_pose_outliers.py` (" + __doc__.split("\n\n")[1].replace("\n", " ") + ")\n\n"
            + md_table(header, rows) + f"\n\nfx RMS z: RMS of (error / reported std); 1 is honest. "
            f"{elapsed / 60:.0f} min on {os.cpu_count()} cores.\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=50, help="trials per case with a typo (twice as many without)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count())
    args = ap.parse_args(argv)
    cases = [(layout, sr, sp, typo) for layout in LAYOUTS for sr, sp in ROBOT for typo in TYPOS_MM]
    todo = [(*c, 31000 + 1000 * i + k) for i, c in enumerate(cases) for k in range(args.trials * (1 + (c[3] == 0)))]
    t0, results = time.perf_counter(), {c: [] for c in cases}
    with ProcessPoolExecutor(args.jobs) as pool:
        for n, (case, res) in enumerate(zip(todo, pool.map(trial, todo, chunksize=4)), 1):
            results[case[:4]].append(res)
            if n % 100 == 0 or n == len(todo):
                print(f"{n}/{len(todo)} trials, {time.perf_counter() - t0:.0f} s", flush=True)
    text = table(results, time.perf_counter() - t0)
    OUT.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
