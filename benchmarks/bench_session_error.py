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
Writes ``benchmarks/results/session_error.md``. ``--noise corners``: the pixel noise grows
towards the image corners (``1 + 3 (r / r_c)^2``, the same RMS), as on a lens sharper at
its centre; ``--noise track``: half of its variance is an offset per track shared by its
observations after the first (a tracker's template error). Where the sandwich is larger
than the model's std, ``auto`` reports it (docs/uncertainty.md §7), with the sessions'
share added (``session_error_corners.md``, ``session_error_track.md``; ``--cases`` picks
some of the cases by number, 1-3).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from bench_robot_error import _scene, _start, _summary  # noqa: E402
from transcalib.estimate.refine import fit_refine  # noqa: E402
from transcalib.geometry.rotation import matrix_to_rotvec  # noqa: E402
from transcalib.handeye.simulate import with_robot_error  # noqa: E402
from transcalib.types import RefineOptions  # noqa: E402

OUT = Path(__file__).parent / "results" / "session_error.md"
#: (per view deg, mm, common to a session deg, mm): mostly common, half common, none.
CASES = ((0.02, 0.2, 0.1, 1.0), (0.1, 1.0, 0.05, 0.5), (0.1, 1.0, 0.0, 0.0))
KEYS = ("fx", "cx", "rx", "ry", "rz", "t_x", "t_y", "t_z")


#: Pixel noise: the scene's white 0.5 px; that scaled up towards the image corners; or
#: half of its variance shared by a track's observations after its first (a tracker's
#: template error, docs/uncertainty.md §6.4), the same RMS.
NOISE = ("white", "corners", "track")


def trial(args):
    """Both fits of one scene: ``{"with": row, "without": row}``, a row ``{param: (error,
    std)}`` plus the sessions' error found and which std was reported for t_x (None if a
    fit failed)."""
    case, seed, noise = args
    rng = np.random.default_rng(seed)
    sc = _scene("3 sessions", rng)
    rep, _ = with_robot_error(sc, case[0], case[1], rng, session_rot_deg=case[2], session_pos=case[3])
    if noise == "corners":
        rep = _corner_noise(rep)
    elif noise == "track":
        rep = _track_noise(rep, rng)
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
        row["sandwich"] = cal.uncertainty.reported["t_x"] == "robust"
        out[name] = row
    return out


def _track_noise(scene, rng):
    """``scene`` with half its pixel noise's variance replaced by an offset per track,
    shared by its observations after the first (alike in each: a template's error)."""
    white = scene.uv - scene.uv_true
    seen = np.isfinite(white[..., 0])
    later = seen & (np.cumsum(seen, axis=0) > 1)
    rms = np.sqrt(np.mean(white[seen] ** 2))
    shared = np.where(later[..., None], rng.normal(0.0, rms, (1,) + white.shape[1:]), 0.0)
    return replace(scene, uv=scene.uv_true + (white + shared) / np.sqrt(2))


def _corner_noise(scene):
    """``scene`` with its pixel noise scaled by ``1 + 3 (r / r_c)^2`` (``r`` the distance of
    the exact pixel from the image centre, ``r_c`` a corner's), to the same RMS."""
    centre = np.asarray(scene.image_size, float) / 2
    gain = 1 + 3 * np.sum((scene.uv_true - centre) ** 2, axis=-1) / np.sum(centre**2)
    seen = np.isfinite(scene.uv[..., 0])
    gain /= np.sqrt(np.mean(gain[seen] ** 2))
    return replace(scene, uv=scene.uv_true + (scene.uv - scene.uv_true) * gain[..., None])


def run(trials: int, jobs: int, seed0: int = 23000, write=None, noise: str = "white", cases=CASES) -> str:
    results = {}
    t0 = time.perf_counter()
    with ProcessPoolExecutor(jobs) as pool:
        for case in cases:
            c = CASES.index(case)
            jobs_of_case = [(case, seed0 + 1000 * c + k, noise) for k in range(trials)]
            results[case] = list(pool.map(trial, jobs_of_case, chunksize=4))
            text = _table(results, trials, jobs, time.perf_counter() - t0, noise)
            if write is not None:
                write(text)
    return text


def _table(results, trials, jobs, elapsed, noise: str = "white") -> str:
    noise_text = {"white": "0.5 px", "corners": "0.5 px RMS growing towards the corners (x (1 + 3 (r / r_c)^2))",
                  "track": "0.5 px RMS, half its variance an offset per track shared by its observations after the "
                           "first"}[noise]
    lines = ["# Robot error common to each session: Monte Carlo (issue 22)\n",
             f"`python benchmarks/bench_session_error.py --trials {trials}"
             + ("" if noise == "white" else f" --noise {noise}")
             + ("" if len(results) == len(CASES) else
                " --cases " + ",".join(str(CASES.index(c) + 1) for c in results))
             + f"` ({elapsed:.0f} s, {jobs} processes). "
             f"Three sessions of 6 views, 60 points, {noise_text}; per view a flange rotation and position error "
             "and a part common to each session; the refinement with the scales estimated. Per parameter: "
             "reported / empirical std and coverage of the nominal 95 % interval, without the sessions' error -> "
             "with it (the default; the same estimates). found: share of trials where the test (5 %) found it; its "
             "median scales where found. sandwich: share of the trials (with) whose t_x std is the sandwich's.\n",
             "| per view deg / mm | per session deg / mm | fails | " + " | ".join(KEYS)
             + " | found | rot deg | pos mm | sandwich |",
             "|" + "---|" * (len(KEYS) + 7)]
    for case, rows in results.items():
        ok = [r for r in rows if "failed" not in r]
        s = {k: _summary([r[k] for r in ok], KEYS) for k in ("without", "with")}
        cells = [f"{s['without'][k][2]:.2f} / {100 * s['without'][k][3]:.0f} % → {s['with'][k][2]:.2f} / "
                 f"{100 * s['with'][k][3]:.0f} %" for k in KEYS]
        found = [r["with"]["session"] for r in ok if r["with"]["session"] is not None and r["with"]["session"][0]]
        med = np.median(found, axis=0) if found else (np.nan, np.nan, np.nan)
        lines.append(f"| {case[0]} / {case[1]} | {case[2]} / {case[3]} | {len(rows) - len(ok)} | " + " | ".join(cells)
                     + f" | {100 * len(found) / max(len(ok), 1):.0f} % | {med[1]:.3f} | {med[2]:.2f} | "
                     f"{100 * np.mean([r['with']['sandwich'] for r in ok]):.0f} % |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=300)
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--noise", choices=NOISE, default="white")
    p.add_argument("--cases", default="1,2,3", help="the cases by number (1-3, the rows of the table)")
    a = p.parse_args(argv)
    numbers = [k.strip() for k in a.cases.split(",")]
    if not all(k.isdigit() and 1 <= int(k) <= len(CASES) for k in numbers):
        p.error(f"--cases: give numbers 1-{len(CASES)} separated by commas, got {a.cases!r}")
    cases = [CASES[int(k) - 1] for k in numbers]
    out = OUT if a.noise == "white" else OUT.with_name(f"{OUT.stem}_{a.noise}.md")
    sys.stdout.write(run(a.trials, a.jobs, noise=a.noise, cases=cases, write=out.write_text))


if __name__ == "__main__":
    main()
