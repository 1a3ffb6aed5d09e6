"""Plots of docs/planning.md: predicted accuracy vs move size, views, depth range, noise.

Every figure is the planner's prediction (the CRLB, which the Monte Carlo of
``bench_plan.py`` confirms within 15 %) for the scene of the benchmark: 1280 x 1024 px,
F = 1000 px, D = 1000 mm, N = 100 points, camera looking along robot -z. Run
``python benchmarks/plot_plan.py``; writes ``docs/img/plan_*.png`` and prints the numbers.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import transcalib  # noqa: E402
from transcalib.planning import PlanOptions, evaluate_plan  # noqa: E402

IMG = Path(__file__).resolve().parents[1] / "docs" / "img"
BASE = dict(image_size=(1280, 1024), focal_px=1000.0, distance=1000.0, depth_range=400.0, n_points=100,
            noise_px=0.5)


def _box(half: float, depth: float | None = None):
    d = half if depth is None else depth
    return (-half, half, -half, half, -d / 2, d / 2)


def move_size():
    sizes = np.array([10, 20, 50, 100, 150, 200, 300, 400, 600])
    plan_fx, corner_fx, vis = [], [], []
    for s in sizes:
        box = _box(s / 2, s / 2)
        p = transcalib.plan(box, 8, **BASE)
        plan_fx.append(p.predicted_std["fx"])
        corner_fx.append(p.patterns["cube_corners"].predicted_std["fx"])
        vis.append(np.min(p.patterns["cube_corners"].visible))
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(sizes / 1000, plan_fx, "o-", label="planned (8 views)")
    ax.loglog(sizes / 1000, corner_fx, "s--", label="cube corners (8 views)")
    ax.loglog(sizes / 1000, plan_fx[3] * (sizes[3] / sizes), ":", color="grey", label="∝ 1 / move size")
    ax.set_xlabel("box side / working distance")
    ax.set_ylabel("predicted std of fx (px)")
    ax.set_title("Move size (box side × half that in depth), σ = 0.5 px")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(IMG / "plan_move_size.png", dpi=110)
    return sizes, plan_fx, corner_fx, vis


def views():
    ms = np.arange(4, 13)
    box = _box(200, 300)
    plan_fx = [transcalib.plan(box, m, **BASE).predicted_std["fx"] for m in ms]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(ms, plan_fx, "o-", label="planned")
    ax.plot(ms, plan_fx[0] * np.sqrt(4 / ms), ":", color="grey", label="∝ 1 / √views")
    ax.set_xlabel("number of views")
    ax.set_ylabel("predicted std of fx (px)")
    ax.set_title("Views (box 400 × 400 × 300 mm at D = 1000 mm)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(IMG / "plan_views.png", dpi=110)
    return ms, plan_fx


def depth_range():
    ranges = np.array([0, 100, 200, 400, 600, 800, 1200])
    box = _box(200, 300)
    out = {}
    for name, m in (("planned", "plan"), ("cube corners", "cube_corners")):
        out[name] = []
        for r in ranges:
            p = transcalib.plan(box, 8, **{**BASE, "depth_range": float(r)})
            ev = p.evaluation if m == "plan" else p.patterns[m]
            out[name].append((ev.predicted_std["fx"], ev.predicted_std["cx"]))
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, vals in out.items():
        v = np.array(vals)
        ax.plot(ranges / 1000, v[:, 0], "o-", label=f"fx, {name}")
        ax.plot(ranges / 1000, v[:, 1], "s--", label=f"cx, {name}")
    ax.set_xlabel("depth range / working distance")
    ax.set_ylabel("predicted std (px)")
    ax.set_title("Depth range of the scene (8 views)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(IMG / "plan_depth_range.png", dpi=110)
    return ranges, out


def noise():
    box = _box(200, 300)
    T = transcalib.plan(box, 8, **BASE).T
    sig = np.array([0.1, 0.2, 0.5, 1.0, 2.0, 3.0])
    robot = [0.0, 0.05, 0.2, 0.5]
    table = {}
    fig, ax = plt.subplots(figsize=(6, 4))
    for r in robot:
        fx = [evaluate_plan(T, PlanOptions(**{**BASE, "noise_px": float(s), "robot_noise": r}), box=box)
              .predicted_std["fx"] for s in sig]
        table[r] = fx
        ax.loglog(sig, fx, "o-", label=f"robot σ = {r} mm")
    ax.set_xlabel("pixel noise σ (px)")
    ax.set_ylabel("predicted std of fx (px)")
    ax.set_title("Pixel noise and robot precision (planned 8 views)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(IMG / "plan_noise.png", dpi=110)
    return sig, table


def points():
    box = _box(200, 300)
    ns = [10, 25, 50, 100, 200, 400]
    fx = [transcalib.plan(box, 8, **{**BASE, "n_points": n}).predicted_std["fx"] for n in ns]
    return ns, fx


def main() -> None:
    IMG.mkdir(parents=True, exist_ok=True)
    sizes, pf, cf, vis = move_size()
    print("move size: box side (mm), plan fx, cube-corner fx, cube-corner min visible")
    for row in zip(sizes, pf, cf, vis):
        print("  %5d  %8.3f  %8.3f  %4.0f%%" % (row[0], row[1], row[2], 100 * row[3]))
    ms, vf = views()
    print("views:", ", ".join(f"{m}: {v:.3f}" for m, v in zip(ms, vf)))
    ranges, dr = depth_range()
    for name, v in dr.items():
        print(f"depth range ({name}, fx/cx):", ", ".join(f"{r}: {a:.3f}/{b:.3f}" for r, (a, b) in zip(ranges, v)))
    sig, table = noise()
    for r, fx in table.items():
        print(f"noise, robot {r}:", ", ".join(f"{s}: {v:.3f}" for s, v in zip(sig, fx)))
    ns, fx = points()
    print("points:", ", ".join(f"{n}: {v:.3f}" for n, v in zip(ns, fx)))
    print(f"wrote {IMG}/plan_*.png")


if __name__ == "__main__":
    main()
