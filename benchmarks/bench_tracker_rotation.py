"""The tracker's rotation test: false refusals and detection rates on rendered scenes.

    python benchmarks/bench_tracker_rotation.py [--quick] [--scenes N] [--rotated-scenes M] [--seed S]

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
tracks) or crashed (any other exception), and the CPU time of ``track``. ``N`` scenes
(default 300) for ``pure``, ``M`` (default 100) for the others. In the rotated studies a
scene the tracker accepts is calibrated (``calibrate(tracks.uv, T)``) and counted as
*named* when the calibration's rotation diagnostic (``view_rotation``) names the rotated
view: small rotations are the calibration's to find. Writes ``benchmarks/results/tracker_rotation.md`` (``--quick``: 20 scenes, a
scratch folder).
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


def named(tracks, T, view: int) -> bool:
    """Whether ``calibrate(tracks.uv, T)`` names ``view`` in its rotation diagnostic."""
    from transcalib import calibrate

    try:
        cal = calibrate(tracks.uv, T)
    except DegenerateError:
        return False
    return any(d.code == "view_rotation" and f"view {view}:" in str(d) for d in cal.diagnostics)


def decision(images, T=None) -> None:
    """The tracker's stages up to its rotation test (detection, matching, with ``T`` the
    views' rotations, epipoles, the test: ``session.verify_session``), which raises
    :class:`RotatedViewsError` where ``track`` would: the refusal decision alone, at about
    40 % of the cost of tracking."""
    from transcalib.images.detect import DetectOptions, detect_all
    from transcalib.images.frames import load_images
    from transcalib.images.session import SessionOptions, _matches, verify_session

    opts, rng = SessionOptions(), np.random.default_rng(0)
    grey, _, _ = load_images(images)
    xy = _matches(detect_all(grey, DetectOptions()), opts.ratio, lambda *a: None)
    verify_session(xy, grey, opts, rng, T=T)


def outcome(images, T=None, rotated_view: int = -1, T_true=None, decision_only: bool = False):
    """``("ok" | "named" | "refused" | "failed" | "crashed", cpu seconds, message)`` of
    tracking ``images`` (``"named"``: tracked, and the calibration's rotation diagnostic
    names ``rotated_view``)."""
    c0 = time.process_time()
    try:
        if decision_only:
            decision(images, T)
            return "ok", time.process_time() - c0, ""
        tracks = track(images, T=T)
        result, msg = "ok", ""
        if rotated_view >= 0 and named(tracks, T_true, rotated_view):
            result = "named"
    except RotatedViewsError as exc:
        result, msg = "refused", str(exc)
    except DegenerateError as exc:
        result, msg = "failed", str(exc)
    except Exception as exc:  # noqa: BLE001 - a crash of the tracker is a result of the study
        result, msg = "crashed", f"{type(exc).__name__}: {exc}"
    return result, time.process_time() - c0, msg


def run(n_scenes: dict, seed: int, studies=STUDIES, with_T: bool = False, log=print, checkpoint=None,
        decision_only: bool = False) -> dict:
    """Outcomes per study: ``{study: [(scene index, outcome, cpu s, config), ...]}``;
    ``n_scenes[study]`` scenes each; ``checkpoint(out)`` every 10 scenes (a long run
    stopped early still leaves its table)."""
    out = {name: [] for name in studies}
    for k in range(max(n_scenes.values())):
        for name, kw in studies.items():
            if k >= n_scenes[name]:
                continue
            sc = study_scene(seed + k, **kw)
            res, cpu, msg = outcome(sc.images, sc.T if with_T else None, sc.config["rotated_view"], sc.T,
                                    decision_only)
            out[name].append((k, res, cpu, sc.config, msg))
            if res not in ("ok", "named") and (name in ("pure", "pose error") or res != "refused"):
                log(f"  scene {seed + k} {name}: {res}: {msg[:160]} {sc.config}")
        if (k + 1) % 10 == 0:
            log(f"  {k + 1}/{max(n_scenes.values())} scenes")
            if checkpoint is not None:
                checkpoint(out)
    return out


def table(out: dict, named_column: bool = True) -> str:
    lines = ["| study | scenes | refused by the tracker | refused % | tracked, rotated view named by calibrate | "
             "refused or named % | failed (too few tracks) | crashed | CPU s per scene (median) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, rows in out.items():
        n = len(rows)
        ref = sum(r[1] == "refused" for r in rows)
        nam = sum(r[1] == "named" for r in rows)
        fail = sum(r[1] == "failed" for r in rows)
        crash = sum(r[1] == "crashed" for r in rows)
        cpu = float(np.median([r[2] for r in rows])) if rows else float("nan")
        named_cells = f"{nam} | {100 * (ref + nam) / max(n, 1):.1f}" if name.startswith("rotated") and named_column else "- | -"
        lines.append(f"| {name} | {n} | {ref} | {100 * ref / max(n, 1):.1f} | {named_cells} | {fail} | {crash} | "
                     f"{cpu:.2f} |")
    return "\n".join(lines)


def main(argv=()) -> dict:
    argv = list(argv)
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--scenes", type=int, default=None)
    ap.add_argument("--rotated-scenes", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--with-T", action="store_true", help="give the tracker the robot translations")
    ap.add_argument("--studies", default=",".join(STUDIES))
    ap.add_argument("--decision-only", action="store_true",
                    help="run the tracker only up to its rotation test (the refusal decision)")
    ap.add_argument("--out", default="tracker_rotation.md", help="file name in benchmarks/results")
    args = ap.parse_args(list(argv))
    n = args.scenes or (20 if args.quick else 300)
    m = args.rotated_scenes or (20 if args.quick else 100)
    studies = {k: STUDIES[k] for k in args.studies.split(",")}
    counts = {k: (n if k == "pure" else m) for k in studies}
    t0 = time.perf_counter()

    def write(out, final=False):
        text = (f"Rotation test of the tracker: random scenes (seeds from {args.seed}), "
                f"`track(images{', T=T' if args.with_T else ''})`; "
                f"`python benchmarks/bench_tracker_rotation.py {' '.join(argv)}` "
                f"({time.perf_counter() - t0:.0f} s{'' if final else ', run still going'}"
                f"{'; decision only: the stages up to the rotation test' if args.decision_only else ''})\n\n"
                + table(out, named_column=not args.decision_only))
        (results_dir(args.quick) / args.out).write_text(text + "\n")
        return text

    out = run(counts, args.seed, studies, with_T=args.with_T, log=lambda msg: print(msg, file=sys.stderr, flush=True),
              checkpoint=write, decision_only=args.decision_only)
    print(write(out, final=True))
    return out


if __name__ == "__main__":
    main(sys.argv[1:])
