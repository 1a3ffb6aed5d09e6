"""The tracker's rotation test: false refusals and detection rates on rendered scenes.

    python benchmarks/bench_tracker_rotation.py [--quick] [--scenes N] [--seed S]

``track(images)`` must refuse views that are not pure translations of each other (the
camera rotated: ``RotatedViewsError``) and must not refuse valid ones. Scenes from
``_tracker_scenes.study_scene``: a floor or a wall with a cube and spheres, textures
drawn from checkers, tiles and noise, robot moves of 3-50 % of the scene distance, 4-6
views of 480 x 360, a quarter with lens distortion, 30 % JPEG. Four studies on the same
scene draws (seed ``S + k`` for scene ``k``):

- ``pure``: pure translations -> every refusal is a false refusal;
- ``pose error``: every view's orientation off by 0.02-0.2 deg (what real robots do, left
  to the calibration's robot-error model) -> a refusal here is a false refusal too;
- ``rotated 0.5``: one view rotated by 0.5 deg about a random axis -> detection rate;
- ``rotated 2``: the same at 2 deg.

Also counted: scenes where tracking failed otherwise (``DegenerateError``: too few
tracks) or crashed (any other exception), and the CPU time of ``track``. Writes ``benchmarks/results/tracker_rotation.md``
(``--quick``: 20 scenes, a scratch folder).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import results_dir  # noqa: E402
from _tracker_scenes import study_scene  # noqa: E402

from transcalib.errors import DegenerateError  # noqa: E402
from transcalib.images import RotatedViewsError, track  # noqa: E402

STUDIES = {"pure": {}, "pose error": {"pose_error_deg": (0.02, 0.2)}, "rotated 0.5": {"rotate_deg": 0.5},
           "rotated 2": {"rotate_deg": 2.0}}


def outcome(images, T=None) -> tuple[str, float, str]:
    """``("ok" | "refused" | "failed", cpu seconds, message)`` of tracking ``images``."""
    c0 = time.process_time()
    try:
        track(images, T=T)
        result, msg = "ok", ""
    except RotatedViewsError as exc:
        result, msg = "refused", str(exc)
    except DegenerateError as exc:
        result, msg = "failed", str(exc)
    except Exception as exc:  # noqa: BLE001 - a crash of the tracker is a result of the study
        result, msg = "crashed", f"{type(exc).__name__}: {exc}"
    return result, time.process_time() - c0, msg


def run(n_scenes: int, seed: int, studies=STUDIES, with_T: bool = False, log=print) -> dict:
    """Outcomes per study: ``{study: [(scene index, outcome, cpu s, config), ...]}``."""
    out = {name: [] for name in studies}
    for k in range(n_scenes):
        for name, kw in studies.items():
            sc = study_scene(seed + k, **kw)
            res, cpu, msg = outcome(sc.images, sc.T if with_T else None)
            out[name].append((k, res, cpu, sc.config, msg))
            if res != "ok" and (name in ("pure", "pose error") or res != "refused"):
                log(f"  scene {seed + k} {name}: {res}: {msg[:160]} {sc.config}")
        if (k + 1) % 25 == 0:
            log(f"  {k + 1}/{n_scenes} scenes")
    return out


def table(out: dict) -> str:
    lines = ["| study | scenes | refused | refused % | failed (too few tracks) | crashed | CPU s per scene (median) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, rows in out.items():
        n = len(rows)
        ref = sum(r[1] == "refused" for r in rows)
        fail = sum(r[1] == "failed" for r in rows)
        crash = sum(r[1] == "crashed" for r in rows)
        cpu = float(np.median([r[2] for r in rows])) if rows else float("nan")
        lines.append(f"| {name} | {n} | {ref} | {100 * ref / max(n, 1):.1f} | {fail} | {crash} | {cpu:.2f} |")
    return "\n".join(lines)


def main(argv=()) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--scenes", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--with-T", action="store_true", help="give the tracker the robot translations")
    ap.add_argument("--studies", default=",".join(STUDIES))
    args = ap.parse_args(list(argv))
    n = args.scenes or (20 if args.quick else 300)
    studies = {k: STUDIES[k] for k in args.studies.split(",")}
    t0 = time.perf_counter()
    out = run(n, args.seed, studies, with_T=args.with_T, log=lambda m: print(m, file=sys.stderr, flush=True))
    text = (f"Rotation test of the tracker: {n} random scenes per study (seeds {args.seed}..{args.seed + n - 1}), "
            f"`track(images{', T=T' if args.with_T else ''})`; "
            f"`python benchmarks/bench_tracker_rotation.py{' --quick' if args.quick else ''}` "
            f"({time.perf_counter() - t0:.0f} s)\n\n" + table(out))
    print(text)
    (results_dir(args.quick) / "tracker_rotation.md").write_text(text + "\n")
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
