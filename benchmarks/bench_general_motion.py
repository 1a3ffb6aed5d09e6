"""Benchmark of calibration from general robot motion (issue 25): every view at its own
flange orientation, no pure-translation session.

(a) Monte Carlo, eye-in-hand and eye-to-hand: 8 and 15 views, each tilted 15-60 deg from
    straight down about a random horizontal axis and rolled up to 30 deg
    (``session_scene(n_sessions=0, single_views=n, single_tilt_deg=(15, 60))``: a
    table-top scene ~0.5 m away, 60 points), fresh 0.5 px noise per trial, through
    ``transcalib.calibrate(uv, Poses.of(T, R), setup=...)``; the table of
    ``bench_handeye.monte_carlo`` (empirical std, CRLB, ratio, median reported std).
    Target: median std / CRLB within 5 %, every ratio within 15 %.
(b) The start's basin: the same 8-view scene with 20 % of the tracks corrupted (two
    observations of each moved by 20-80 px in a random direction); a trial converges when
    fx and every component of t_X land within 6 reported std of the truth. Target: >= 99 %.

Run ``python benchmarks/bench_general_motion.py`` (``--quick``: few trials). Writes
``benchmarks/results/general_motion.md``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_handeye import NOISE_PX, _verdict, monte_carlo  # noqa: E402

from transcalib import Poses, calibrate  # noqa: E402
from transcalib.errors import TranscalibError  # noqa: E402
from transcalib.handeye.simulate import session_scene  # noqa: E402

LAYOUTS = {
    "8 views, each at its own orientation": dict(n_sessions=0, single_views=8, single_tilt_deg=(15, 60)),
    "15 views, each at its own orientation": dict(n_sessions=0, single_views=15, single_tilt_deg=(15, 60)),
}
CORRUPT = 0.2
CONVERGED_STD = 6.0


def corrupted(base, rng):
    """Noisy observations with ``CORRUPT`` of the tracks moved by 20-80 px in two views."""
    uv = np.where(np.isfinite(base.uv), base.uv_true + rng.normal(0, NOISE_PX, base.uv.shape), np.nan)
    for j in rng.choice(uv.shape[1], int(CORRUPT * uv.shape[1]), replace=False):
        views = rng.choice(np.flatnonzero(np.isfinite(uv[:, j, 0])), 2, replace=False)
        uv[views, j] += rng.uniform(20, 80, (2, 2)) * rng.choice([-1, 1], (2, 2))
    return uv


def basin(trials: int, seed: int = 0) -> list[str]:
    """How often the start leads to the truth with corrupted tracks (b)."""
    base = session_scene(seed, n_points=60, **LAYOUTS["8 views, each at its own orientation"])
    rng = np.random.default_rng(seed + 7)
    converged, failed, seconds = 0, 0, []
    for trial in range(trials):
        uv = corrupted(base, rng)
        t0 = time.perf_counter()
        try:
            cal = calibrate(uv, Poses.of(base.T, base.R), distortion="none", rng=trial)
        except TranscalibError:
            failed += 1
            continue
        seconds.append(time.perf_counter() - t0)
        ok = abs(cal.K[0, 0] - base.K[0, 0]) < CONVERGED_STD * cal.std["fx"]
        converged += bool(ok and np.all(np.abs(cal.hand_eye.t - base.t_X) < CONVERGED_STD * cal.hand_eye.t_std))
    return [f"{trials} trials, {int(100 * CORRUPT)} % of the tracks corrupted: **{converged} converged "
            f"({100 * converged / trials:.1f} %)**, {failed} refused; median {np.median(seconds):.2f} s per "
            "calibration (calibrate(), in-process).", ""]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="few trials (smoke run)")
    parser.add_argument("--trials", type=int, default=None, help="Monte-Carlo trials (default 500; quick: 20)")
    args = parser.parse_args(argv)
    trials = args.trials or (20 if args.quick else 500)
    lines = ["# General robot motion: accuracy (benchmarks/bench_general_motion.py)", "",
             f"`python benchmarks/bench_general_motion.py{' --quick' if args.quick else ''}`; {NOISE_PX} px noise, "
             "60 points, ~0.5 m working distance, views tilted 15-60 deg.", "",
             "## (a) Monte-Carlo std vs the Cramér-Rao bound", ""]
    summary = ["| layout | setup | std / CRLB |", "|---|---|---|"]
    for name, kw in LAYOUTS.items():
        for setup in ("eye-in-hand", "eye-to-hand"):
            table, ratios = monte_carlo(name, kw, setup, trials)
            lines += table
            summary.append(f"| {name} | {setup} | {_verdict(ratios)} |")
            print(summary[-1], flush=True)
    lines += ["Summary:", ""] + summary + ["", "## (b) The start's basin with corrupted tracks", ""]
    lines += basin(trials)
    text = "\n".join(lines) + "\n"
    print(text)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "general_motion.md").write_text(text)


if __name__ == "__main__":
    main(sys.argv[1:])
