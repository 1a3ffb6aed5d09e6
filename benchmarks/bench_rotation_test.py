"""Benchmark of the rotation test (did the robot rotate between views?) at scale.

The test runs on the one bundle adjuster: per-view rotation parameters with analytic
Jacobians and the points eliminated by the Schur complement, so its memory grows with
views x points. Measures time and tracemalloc peak of ``check_view_rotations`` on a
refined calibration of a random scene, 40 views x 4000 points (0.5 px noise), and a
smaller case. Before the one-bundle-adjuster refactor (a second adjuster with dense
per-observation Jacobians) the 40 x 4000 case needed about 1 GiB and 6.9 s.

Run ``python benchmarks/bench_rotation_test.py`` (``--quick`` for a smoke run).
"""

from __future__ import annotations

import sys
import time
import tracemalloc

import numpy as np

from transcalib import calibrate, simulate
from transcalib.check import check_view_rotations


def _measure(n_points: int, n_views: int, seed: int = 0):
    scene = simulate.random_scene(n_points, n_views, noise_px=0.5, rng=seed)
    cal = calibrate(scene.uv, scene.T, check_rotation=False, rng=seed)
    uv = scene.uv if cal.inliers is None else np.where(cal.inliers[None, :, None], scene.uv, np.nan)
    tracemalloc.start()
    t0 = time.perf_counter()
    found = check_view_rotations(uv, scene.T, cal)
    elapsed = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return elapsed, peak / 2**20, len(found)


def main(argv: list[str]) -> int:
    quick = "--quick" in argv
    cases = [(400, 8)] if quick else [(400, 8), (4000, 40)]
    print("| views | points | time | peak memory (tracemalloc) | warnings |")
    print("|---:|---:|---:|---:|---:|")
    for n_points, n_views in cases:
        t, mib, n = _measure(n_points, n_views)
        print(f"| {n_views} | {n_points} | {t:.2f} s | {mib:.0f} MiB | {n} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
