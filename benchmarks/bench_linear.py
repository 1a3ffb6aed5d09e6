"""Speed and peak memory of the linear estimator: the O(n) path vs the dense SVD.

    python benchmarks/bench_linear.py [--quick]

n points x 4 views, 0.5 px noise (random scene), with the default depth weighting (two
TLS solves) and with ``weighting="none"`` (one); then n points x 8 views with 20 % of the
observations missing (every point in 2 or more views: all visibility patterns and
reference views at once). Time: the best of a few runs (3 from 10^5 points, 5 below),
wall clock and, of the same run, CPU time (``time.process_time``: the machine is shared,
so wall-clock times vary). BLAS runs on one thread outside the dense reference too (as in
the ``transcalib`` command), so that no idle BLAS thread spins into the CPU times. Peak:
tracemalloc's peak of numpy and Python allocations during the call, in a separate run; it
includes the result itself (``result``: ``X``, ``depth``, ``used``, ``static``: 8 n
(3 + n_views) + 2 n bytes).
"""

from __future__ import annotations

import sys
import time
import tracemalloc

import numpy as np
from threadpoolctl import threadpool_limits

from transcalib import simulate
from transcalib.estimate.linear import estimate_linear


def measure(uv, T, repeats: int, **options) -> tuple[float, float, float, object]:
    """Best wall time, the CPU time of that run, peak MiB and the estimate."""
    best, cpu = np.inf, np.inf
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        est = estimate_linear(uv, T, **options)
        wall = time.perf_counter() - t0
        if wall < best:
            best, cpu = wall, time.process_time() - c0
    tracemalloc.start()
    estimate_linear(uv, T, **options)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return best, cpu, peak / 2**20, est


def main(argv: list[str]) -> None:
    quick = "--quick" in argv
    sizes = [10**2, 10**3, 10**4, 10**5] if quick else [10**2, 10**3, 10**4, 10**5, 10**6]
    table(sizes, 4, 0.0, dense_max=300 if quick else 1000)
    print("\n8 views, 20 % of the observations missing:")
    table(sizes[:-1], 8, 0.2, dense_max=300)


def table(sizes: list[int], n_views: int, missing: float, dense_max: int) -> None:
    print(f"{'n points':>10} {'depth [s]':>10} {'cpu [s]':>8} {'[MiB]':>7} {'none [s]':>9} {'cpu [s]':>8} "
          f"{'[MiB]':>7} {'result':>7} {'dense [s]':>10} {'[MiB]':>7} {'|K_fast-K_dense|/fx':>20} {'fx err':>9}")
    for n in sizes:
        with threadpool_limits(limits=1, user_api="blas"):
            scene = simulate.random_scene(n, n_views, noise_px=0.5, missing=missing, rng=1)
            repeats = 5 if n < 10**5 else 3
            t_fast, c_fast, m_fast, est = measure(scene.uv, scene.T, repeats)
            t_none, c_none, m_none, _ = measure(scene.uv, scene.T, repeats, weighting="none")
        result = (est.X.nbytes + est.depth.nbytes + est.used.nbytes + est.static.nbytes) / 2**20
        row = (f"{n:>10} {t_fast:>10.4f} {c_fast:>8.4f} {m_fast:>7.1f} {t_none:>9.4f} {c_none:>8.4f} {m_none:>7.1f} "
               f"{result:>7.1f}")
        if n <= dense_max:
            t_dense, _, m_dense, dense = measure(scene.uv, scene.T, 1, method="dense")
            time.sleep(0.5)  # BLAS's threads spin a while after the SVD: not into the next CPU times
            agree = np.max(np.abs(est.K - dense.K)) / dense.K[0, 0]
            row += f" {t_dense:>10.3f} {m_dense:>7.1f} {agree:>20.1e}"
        else:
            row += f" {'-':>10} {'-':>7} {'-':>20}"
        row += f" {est.K[0, 0] / scene.K[0, 0] - 1:>+9.1e}"
        print(row, flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
