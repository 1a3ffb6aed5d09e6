"""The session tracker on renders with robot pose errors (issues 21, 22).

    nice python benchmarks/bench_tracker_pose_error.py [--trials N] [--first-seed S] [--layouts ...]

Each trial renders :func:`transcalib.synth.robot.robot_scene` (eye-in-hand, 640 x 480, the
preset's camera effects and lens) once with a perfect robot and once per error level at
the **true** flange poses ``R_i exp([delta_i]x)``, ``T_i + eps_i`` (the same seed, the same
unit errors scaled: ``delta ~ N(0, sigma_rot)``, ``eps ~ N(0, sigma_pos)`` per axis),
and tracks each with the **reported** poses: ``track(images, T=r.T, rotations=r.R)``.
Layouts: ``one session`` (12 views of 3-D pure translation) and ``session + singles``
(a session of 6 views and 6 single views turned 15-45 deg).

Per case: refusals (``RotatedViewsError``), failures (``DegenerateError``: too few
tracks), crashes; tracks and mean track length in the session views relative to the
perfect robot's render of the same seed; the share of observations within 0.5 px of the
true projection (the render's truth at the true poses: the point seen at a track's first
observation, projected into every view; tracks at occlusion edges left out); the RMS error
(degrees per axis) of the session views' rotations the tracker estimated
(``info.groups[...].rotations_deg``) against the true ``R_s delta_i`` (both with their mean
removed: the tracker reports rotations from the session's median orientation). Writes
``benchmarks/results/tracker_pose_error.md`` after every trial.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from transcalib.errors import DegenerateError
from transcalib.estimate.robot_error import sample_errors
from transcalib.images import RotatedViewsError, track
from transcalib.synth.robot import robot_scene

OUT = Path(__file__).resolve().parent / "results" / "tracker_pose_error.md"
#: (sigma_rot deg, sigma_pos mm); (0, 0) is the perfect robot
LEVELS = ((0.0, 0.0), (0.02, 0.2), (0.1, 1.0), (0.2, 2.0))
LAYOUTS = {"one session": dict(session_views=12, single_views=0),
           "session + singles": dict(session_views=6, single_views=6)}
FIRST_SEED = 23100
TOL_PX = 0.5


def measure(r, tracks, views: list) -> dict:
    """Tracks, mean length and share within :data:`TOL_PX` of the truth in ``views``; the
    rotation error of the session's estimated rotations (deg, per axis RMS)."""
    uv = tracks.uv[views]
    seen = np.isfinite(uv[..., 0])
    keep = seen.sum(0) >= 2
    truth = r if "true_R" not in r.meta else replace(r, R=r.meta["true_R"], T=r.meta["true_T"])
    X, ghost = truth.track_truth(tracks.uv)
    proj = truth.project(X)[views]
    err = np.linalg.norm(uv - proj, axis=-1)
    judged = seen & (keep & np.isfinite(X).all(1) & ~ghost)[None]
    out = {"n_tracks": int(keep.sum()), "length": float(seen[:, keep].sum(0).mean()) if keep.any() else 0.0,
           "within": float(np.mean(err[judged] < TOL_PX)) if judged.any() else float("nan"),
           "n_judged": int(judged.sum())}
    group = next(g for g in tracks.info.groups if tuple(g.views) == tuple(views))
    if group.rotations_deg:
        est = np.array(group.rotations_deg)
        delta = r.meta.get("pose_error", np.zeros((r.n_views, 6)))[views, :3]
        true = np.degrees(delta @ r.R[views[0]].T)  # R_s delta_i, robot base frame
        d = (est - est.mean(0)) - (true - true.mean(0))
        out["rot_rms"] = float(np.sqrt(np.mean(d**2)))
        out["rot_true_rms"] = float(np.sqrt(np.mean((true - true.mean(0)) ** 2)))
        out["max_angle"] = float(max(group.angles_deg))
    return out


def trial(layout: str, seed: int) -> dict:
    """Every level of one seed: ``{level: row}``; a row is :func:`measure`'s dict or
    ``{"outcome": "refused" | "failed" | "crashed", "msg": ...}``."""
    opts = LAYOUTS[layout]
    n = opts["session_views"] + opts["single_views"]
    unit = sample_errors(n, 1.0, 1.0, rng=seed + 7)  # the same errors at every level, scaled
    rows = {}
    for sr, sp in LEVELS:
        err = None if sr == 0 else np.hstack([unit[:, :3] * sr, unit[:, 3:] * sp])
        r = robot_scene("eye-in-hand", rng=seed, pose_error=err, **opts)
        c0 = time.perf_counter()
        try:
            tr = track(r.images, T=r.T, rotations=r.R)
            row = {"outcome": "ok", **measure(r, tr, list(range(opts["session_views"])))}
        except RotatedViewsError as exc:
            row = {"outcome": "refused", "msg": str(exc)[:300]}
        except DegenerateError as exc:
            row = {"outcome": "failed", "msg": str(exc)[:300]}
        except Exception as exc:  # noqa: BLE001 - a crash is a result of the study
            row = {"outcome": "crashed", "msg": f"{type(exc).__name__}: {exc}"[:300]}
        row["time_s"] = time.perf_counter() - c0
        rows[(sr, sp)] = row
    return rows


def table(results: dict, command: str, elapsed: float) -> str:
    lines = ["# The session tracker with robot pose errors (issues 21, 22)", "",
             f"`{command}` ({elapsed:.0f} s). `robot_scene` eye-in-hand renders (640 x 480, preset effects and "
             "lens) at the true poses, tracked with the reported ones (`track(images, T, rotations)`). tracks, "
             "length: session tracks (2+ session views) and their mean length, as a ratio to the perfect robot's "
             f"render of the same seed (mean, min); within: share of session observations within {TOL_PX} px of "
             "the true projection (all trials pooled; tracks at occlusion edges left out); rot RMS: estimated "
             "rotations against the truth (deg per axis, mean removed), next to the truth's own RMS.", ""]
    head = ("| layout | sigma_rot deg | sigma_pos mm | N | refused | failed | crashed | tracks (ratio mean, min) | "
            "length (ratio mean, min) | within 0.5 px | rot RMS err deg (truth RMS) | max angle deg | s per track |")
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    for layout in LAYOUTS:
        for level in LEVELS:
            rows = [(t[level], t[LEVELS[0]]) for t in results.get(layout, [])]
            if not rows:
                continue
            ok = [(a, b) for a, b in rows if a["outcome"] == "ok" and b["outcome"] == "ok"]
            cnt = {o: sum(a["outcome"] == o for a, _ in rows) for o in ("refused", "failed", "crashed")}
            tr = np.array([a["n_tracks"] / max(b["n_tracks"], 1) for a, b in ok]) if ok else np.full(1, np.nan)
            ln = np.array([a["length"] / max(b["length"], 1e-9) for a, b in ok]) if ok else np.full(1, np.nan)
            judged = sum(a["n_judged"] for a, _ in ok)
            within = sum(a["within"] * a["n_judged"] for a, _ in ok) / max(judged, 1)
            rot = [a for a, _ in ok if "rot_rms" in a]
            rot_cell = (f"{np.sqrt(np.mean([a['rot_rms'] ** 2 for a in rot])):.3f} "
                        f"({np.sqrt(np.mean([a['rot_true_rms'] ** 2 for a in rot])):.3f})") if rot else "-"
            ang = f"{max(a['max_angle'] for a in rot):.2f}" if rot else "-"
            secs = np.median([a["time_s"] for a, _ in rows])
            lines.append(f"| {layout} | {level[0]} | {level[1]} | {len(rows)} | {cnt['refused']} | {cnt['failed']} | "
                         f"{cnt['crashed']} | {tr.mean():.3f}, {tr.min():.3f} | {ln.mean():.3f}, {ln.min():.3f} | "
                         f"{100 * within:.2f} % | {rot_cell} | {ang} | {secs:.1f} |")
    msgs = sorted({f"{layout} {lv}: {row['outcome']}: {row['msg'][:200]}" for layout, ts in results.items()
                   for t in ts for lv, row in t.items() if row["outcome"] != "ok"})
    return "\n".join(lines + ([""] + ["Not tracked:", ""] + [f"- {m}" for m in msgs] if msgs else [])) + "\n"


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--first-seed", type=int, default=FIRST_SEED)
    p.add_argument("--layouts", default=",".join(LAYOUTS))
    p.add_argument("--out", type=Path, default=OUT)
    a = p.parse_args(argv)
    command = "python benchmarks/bench_tracker_pose_error.py " + " ".join(sys.argv[1:] if argv is None else argv)
    results, t0 = {}, time.perf_counter()
    for k in range(a.trials):  # seeds interleaved over the layouts: a run cut short stays balanced
        for layout in a.layouts.split(","):
            results.setdefault(layout, []).append(trial(layout, a.first_seed + k))
        text = table(results, command.strip(), time.perf_counter() - t0)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(text)
        print(f"trial {k + 1}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    sys.stdout.write(text)
    return results


if __name__ == "__main__":
    main()
