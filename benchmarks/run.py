"""Run every benchmark (``benchmarks/bench_*.py``) and print its tables.

    python benchmarks/run.py             # all, full size   (make bench)
    python benchmarks/run.py --quick     # all, small and fast
    python benchmarks/run.py linear      # only bench_linear.py
    python benchmarks/run.py handeye     # only bench_handeye.py (sessions, issue 11)
"""

from __future__ import annotations

import importlib.util
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    quick = "--quick" in argv
    names = [a for a in argv if not a.startswith("-")]
    files = sorted(HERE.glob("bench_*.py"))
    if names:
        files = [f for f in files if f.stem.removeprefix("bench_") in names]
    for f in files:
        spec = importlib.util.spec_from_file_location(f.stem, f)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        print(f"\n=== {f.stem} ===", flush=True)
        t0 = time.perf_counter()
        module.main(["--quick"] if quick else [])
        print(f"({f.stem}: {time.perf_counter() - t0:.1f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
