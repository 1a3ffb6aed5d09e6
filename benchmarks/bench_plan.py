"""Benchmark of the planner ``transcalib.plan`` (issue 12).

(a) Monte Carlo: one scene model (camera, points, box), the planned design and the
    standard patterns in the same box with the same number of views. For each design,
    ``trials`` noisy observations (``transcalib.simulate.observe`` of the model's exact
    scene: pixel noise, points outside the image dropped) are calibrated with the full
    default pipeline ``transcalib.calibrate``. Targets: the empirical std of fx, fy, cx,
    cy within 15 % of the planner's prediction; the plan's empirical std of fx no worse
    (within 5 %) than the best standard pattern's; how much it beats each pattern and
    the naive choice (small moves along the three axes).
(b) Planning time for 4..12 views.

Run ``python benchmarks/bench_plan.py`` (``--quick``: 30 trials). Writes the tables to
``benchmarks/results/plan.md`` (full runs only).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import transcalib
from transcalib import simulate
from transcalib.planning.model import design_scene, scene_points

KEYS = ("fx", "fy", "cx", "cy")
SCENE = dict(image_size=(1280, 1024), focal_px=1000.0, distance=1000.0, depth_range=400.0, n_points=100,
             noise_px=0.5, view_direction="-z")
BOX = (-200.0, 200.0, -200.0, 200.0, 0.0, 300.0)
N_VIEWS = 8
DESIGNS = ("plan", "cube_corners", "tetrahedron", "paper", "naive")
OUT = Path(__file__).resolve().parent / "results" / "plan.md"


def _k4(K):
    return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])


def monte_carlo(result, trials: int, seed: int = 0):
    """Empirical std of fx, fy, cx, cy of each design over ``trials`` calibrations."""
    X = scene_points(result.options, result.box.mean(axis=1), 0)  # the plan's model points (rng=0)
    evaluations = {"plan": result.evaluation, **result.patterns}
    rows = {}
    for name in DESIGNS:
        ev = evaluations[name]
        base = design_scene(result.options, X, ev.T)
        truth = _k4(base.K)
        est, failed, t0 = [], 0, time.perf_counter()
        for k in range(trials):
            scene = simulate.observe(base, result.options.noise_px, rng=seed + k)
            try:
                cal = transcalib.calibrate(scene.uv, scene.T, rng=seed + k)
            except ValueError:  # InputError / DegenerateError: counted, not hidden
                failed += 1
                continue
            est.append(_k4(cal.K))
        est = np.array(est)
        rows[name] = dict(emp=est.std(axis=0, ddof=1), bias=est.mean(axis=0) - truth, n=len(est), failed=failed,
                          pred=np.array([ev.predicted_std[k] for k in KEYS]), time=time.perf_counter() - t0)
    return rows


def accuracy_table(rows: dict, trials: int) -> list[str]:
    out = [f"Monte Carlo: {trials} trials per design, default `transcalib.calibrate`, scene {SCENE}, "
           f"box {BOX}, {N_VIEWS} views.", "",
           "| design | trials ok | " + " | ".join(f"{k} pred | {k} emp | emp/pred" for k in KEYS)
           + " | within 15 % |",
           "|---|---|" + "---|---|---|" * len(KEYS) + "---|"]
    for name, r in rows.items():
        ratio = r["emp"] / r["pred"]
        cells = " | ".join(f"{p:.3f} | {e:.3f} | {q:.2f}" for p, e, q in zip(r["pred"], r["emp"], ratio))
        ok = "yes" if np.all(np.abs(ratio - 1) <= 0.15) else "**no**"
        out.append(f"| {name} | {r['n']}/{r['n'] + r['failed']} | {cells} | {ok} |")
    return out


def comparison_table(rows: dict) -> list[str]:
    plan_fx = rows["plan"]["emp"][0]
    best = min((n for n in rows if n not in ("plan", "naive")), key=lambda n: rows[n]["emp"][0])
    out = ["", "Empirical std of fx, planned design vs each pattern (ratio > 1: the plan is better):", "",
           "| design | emp std fx (px) | pattern / plan | predicted pattern / plan |", "|---|---|---|---|"]
    for name, r in rows.items():
        out.append(f"| {name} | {r['emp'][0]:.3f} | {r['emp'][0] / plan_fx:.2f} | "
                   f"{r['pred'][0] / rows['plan']['pred'][0]:.2f} |")
    verdict = "yes" if plan_fx <= 1.05 * rows[best]["emp"][0] else "**no**"
    out += ["", f"Best standard pattern: {best} (emp std fx {rows[best]['emp'][0]:.3f} px); plan "
                f"{plan_fx:.3f} px: no worse within 5 %: {verdict}."]
    return out


def timing_table(repeats: int) -> list[str]:
    out = ["", f"Planning time (`transcalib.plan`, same scene and box, best of {repeats}):", "",
           "| views | time (s) | predicted std fx (px) |", "|---|---|---|"]
    for m in range(4, 13):
        best, res = np.inf, None
        for _ in range(repeats):
            t0 = time.perf_counter()
            res = transcalib.plan(BOX, m, **SCENE)
            best = min(best, time.perf_counter() - t0)
        out.append(f"| {m} | {best:.2f} | {res.predicted_std['fx']:.3f} |")
    return out


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--trials", type=int, default=None)
    args = ap.parse_args(argv)
    trials = args.trials or (30 if args.quick else 200)
    t0 = time.perf_counter()
    result = transcalib.plan(BOX, N_VIEWS, **SCENE)
    lines = [f"Planned {N_VIEWS} views in {time.perf_counter() - t0:.2f} s: {result.criterion}.", ""]
    rows = monte_carlo(result, trials)
    lines += accuracy_table(rows, trials) + comparison_table(rows) + timing_table(1 if args.quick else 3)
    text = "\n".join(lines)
    print(text)
    if not args.quick and args.trials is None:
        OUT.parent.mkdir(parents=True, exist_ok=True)
        OUT.write_text("# Benchmark: `transcalib plan`\n\nCommand: `python benchmarks/bench_plan.py`\n\n"
                       + text + "\n", encoding="utf-8")
        print(f"\nWrote {OUT}")


if __name__ == "__main__":
    main(sys.argv[1:])
