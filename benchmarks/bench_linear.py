"""Speed and peak memory of the linear estimator: O(n) path vs the dense SVD.

    python benchmarks/bench_linear.py [--quick]

n points x 4 views, 0.5 px noise (random scene); then n points x 8 views with 20 % of the
observations missing (every point in 2 or more views: all visibility patterns and
reference views at once). Time: best of a few runs (one for the largest sizes). Peak
memory: tracemalloc's peak of numpy and Python allocations during the call, in a
separate run.
"""

from __future__ import annotations

import sys
import time
import tracemalloc

import numpy as np

from transcalib import simulate
from transcalib.estimate.linear import estimate_linear


def measure(uv, T, method: str, repeats: int) -> tuple[float, float, np.ndarray]:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        est = estimate_linear(uv, T, method=method)
        best = min(best, time.perf_counter() - t0)
    tracemalloc.start()
    estimate_linear(uv, T, method=method)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return best, peak / 2**20, est.K


def main(argv: list[str]) -> None:
    quick = "--quick" in argv
    sizes = [10**2, 10**3, 10**4, 10**5] if quick else [10**2, 10**3, 10**4, 10**5, 10**6]
    table(sizes, 4, 0.0, dense_max=300 if quick else 1000)
    print("\n8 views, 20 % of the observations missing:")
    table(sizes[:-1], 8, 0.2, dense_max=300)


def table(sizes: list[int], n_views: int, missing: float, dense_max: int) -> None:
    print(f"{'n points':>10} {'fast [s]':>10} {'fast [MiB]':>11} {'dense [s]':>10} {'dense [MiB]':>12} "
          f"{'|K_fast-K_dense|/fx':>20} {'fx err':>9}")
    for n in sizes:
        scene = simulate.random_scene(n, n_views, noise_px=0.5, missing=missing, rng=1)
        repeats = 5 if n <= 10**4 else 2 if n <= 10**5 else 1
        t_fast, m_fast, K_fast = measure(scene.uv, scene.T, "fast", repeats)
        row = f"{n:>10} {t_fast:>10.4f} {m_fast:>11.1f}"
        if n <= dense_max:
            t_dense, m_dense, K_dense = measure(scene.uv, scene.T, "dense", 1)
            agree = np.max(np.abs(K_fast - K_dense)) / K_dense[0, 0]
            row += f" {t_dense:>10.3f} {m_dense:>12.1f} {agree:>20.1e}"
        else:
            row += f" {'-':>10} {'-':>12} {'-':>20}"
        row += f" {K_fast[0, 0] / scene.K[0, 0] - 1:>+9.1e}"
        print(row, flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
