"""Benchmark of issue 22: a robot error common to each session's views (docs/uncertainty.md §7.2).

A real arm errs by its configuration, which a session's small translations hardly change,
so much of a view's error is its session's. Monte Carlo of ``bench_robot_error.py``'s
three sessions of 6 views (60 points, 0.5 px, the refinement from near the truth with the
robot error's scales estimated), the images those of poses with a per-view error and a
part common to each session (``with_robot_error(..., session_rot_deg=, session_pos=)``).
Each trial is fitted twice on the same data: with the sessions' error tested for and,
where found, in the model-based covariance (the default), and without
(``RefineOptions(session_error=False)``); the estimates are the same, the std differ.
Reported per case and parameter: reported / empirical std and the coverage of the
nominal 95 % interval, without -> with; the share of trials where the test (5 %) found
the sessions' error, and its median estimated scales.

Run ``python benchmarks/bench_session_error.py`` (``--trials N``, default 300; ``--jobs``).
Writes ``benchmarks/results/session_error.md``.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bench_robot_error import _scene, _start, _summary, trials_cli  # noqa: E402
from transcalib.estimate.refine import fit_refine  # noqa: E402
from transcalib.geometry.rotation import matrix_to_rotvec  # noqa: E402
from transcalib.handeye.simulate import with_robot_error  # noqa: E402
from transcalib.types import RefineOptions  # noqa: E402

OUT = Path(__file__).parent / "results" / "session_error.md"
#: (per view deg, mm, common to a session deg, mm): mostly common, half common, none.
CASES = ((0.02, 0.2, 0.1, 1.0), (0.1, 1.0, 0.05, 0.5), (0.1, 1.0, 0.0, 0.0))
KEYS = ("fx", "cx", "rx", "ry", "rz", "t_x", "t_y", "t_z")


def trial(args):
    """Both fits of one scene: ``{"with": row, "without": row}``, a row ``{param: (error,
    std)}`` plus the sessions' error found (None if a fit failed)."""
    case, seed = args
    rng = np.random.default_rng(seed)
    sc = _scene("3 sessions", rng)
    rep, _ = with_robot_error(sc, case[0], case[1], rng, session_rot_deg=case[2], session_pos=case[3])
    start, flange, R_true = _start(sc, rep, rng)
    out = {}
    for name, on in (("with", True), ("without", False)):
        try:
            cal = fit_refine(rep.uv, rep.T, start, RefineOptions(distortion="none", robot_error=True, session_error=on),
                             flange=flange)
        except Exception as exc:  # noqa: BLE001 - a failed trial is counted, not hidden
            return {"failed": f"{type(exc).__name__}: {exc}"}
        w = np.degrees(matrix_to_rotvec(cal.R @ R_true.T))
        t_std = np.sqrt(np.diag(cal.hand_eye.t_cov))
        row = {"fx": (cal.K[0, 0] - sc.K[0, 0], cal.std["fx"]), "cx": (cal.K[0, 2] - sc.K[0, 2], cal.std["cx"])}
        row.update({k: (w[a], cal.std[k]) for a, k in enumerate(("rx", "ry", "rz"))})
        row.update({k: (cal.hand_eye.t[a] - sc.t_X[a], t_std[a]) for a, k in enumerate(("t_x", "t_y", "t_z"))})
        se = cal.uncertainty.session_error
        row["session"] = None if se is None else (se.included, se.sigma_rot_deg, se.sigma_pos)
        out[name] = row
    return out


def run(trials: int, jobs: int, seed0: int = 23000, write=None) -> str:
    results = {}
    t0 = time.perf_counter()
    with ProcessPoolExecutor(jobs) as pool:
        for c, case in enumerate(CASES):
            results[case] = list(pool.map(trial, [(case, seed0 + 1000 * c + k) for k in range(trials)], chunksize=4))
            text = _table(results, trials, jobs, time.perf_counter() - t0)
            if write is not None:
                write(text)
    return text


def _table(results, trials, jobs, elapsed) -> str:
    lines = ["# Robot error common to each session: Monte Carlo (issue 22)\n",
             f"`python benchmarks/bench_session_error.py --trials {trials}` ({elapsed:.0f} s, {jobs} processes). "
             "Three sessions of 6 views, 60 points, 0.5 px; per view a flange rotation and position error and a part "
             "common to each session; the refinement with the scales estimated. Per parameter: reported / empirical "
             "std and coverage of the nominal 95 % interval, without the sessions' error -> with it (the default; "
             "the same estimates). found: share of trials where the test (5 %) found it; its median scales where "
             "found.\n",
             "| per view deg / mm | per session deg / mm | fails | " + " | ".join(KEYS) + " | found | rot deg | pos mm |",
             "|" + "---|" * (len(KEYS) + 6)]
    for case, rows in results.items():
        ok = [r for r in rows if "failed" not in r]
        s = {k: _summary([r[k] for r in ok], KEYS) for k in ("without", "with")}
        cells = [f"{s['without'][k][2]:.2f} / {100 * s['without'][k][3]:.0f} % → {s['with'][k][2]:.2f} / "
                 f"{100 * s['with'][k][3]:.0f} %" for k in KEYS]
        found = [r["with"]["session"] for r in ok if r["with"]["session"] is not None and r["with"]["session"][0]]
        med = np.median(found, axis=0) if found else (np.nan, np.nan, np.nan)
        lines.append(f"| {case[0]} / {case[1]} | {case[2]} / {case[3]} | {len(rows) - len(ok)} | " + " | ".join(cells)
                     + f" | {100 * len(found) / max(len(ok), 1):.0f} % | {med[1]:.3f} | {med[2]:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    trials_cli(run, OUT, __doc__, argv)


if __name__ == "__main__":
    main()
