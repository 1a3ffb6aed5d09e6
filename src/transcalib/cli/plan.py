"""``transcalib plan``: where to move the robot, with the accuracy predicted (issue 12).

``transcalib plan --image-size W,H --focal-px F --distance D --box ... --views M --out DIR``
writes ``DIR/poses.csv`` (``view,x,y,z``) and ``DIR/plan.json``; ``--evaluate poses.csv``
predicts what given moves achieve and warns about weak designs. Parsing and printing
only: the numerics are :func:`transcalib.plan` and :func:`transcalib.evaluate_plan`.
Registered in the main parser by ``add_parser(subparsers)``; bad options give one line
naming the option and exit status 2.
"""

from __future__ import annotations

import argparse
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["add_parser", "run"]

EXIT_INPUT = 2
#: PlanOptions field -> command-line option, to name the option in error messages.
_OPTION_OF = {"image_size": "--image-size", "focal_px": "--focal-px", "distance": "--distance",
              "depth_range": "--depth-range", "n_points": "--points", "noise_px": "--noise-px",
              "view_direction": "--view-direction", "robot_noise": "--robot-sigma",
              "distortion": "--distortion", "dist": "--dist-coeffs", "criterion": "--criterion", "min_visible": "--min-visible",
              "margin_px": "--margin-px", "n_views": "--views", "box": "--box", "min_separation": "--min-separation"}
_KEYS = ("fx", "fy", "cx", "cy", "rx", "ry", "rz")


def _one_line_error(message: str):
    """argparse errors as a single line naming the option (no usage dump), status 2."""
    print(f"transcalib plan: error: {message}", file=sys.stderr)
    raise SystemExit(EXIT_INPUT)


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``plan`` sub-command to the main parser's ``subparsers``."""
    p = subparsers.add_parser("plan",
                              help="plan robot translations with the accuracy predicted, or --evaluate given ones",
                              description="Plan where to move the robot (or --evaluate a poses.csv) and predict "
                                          "the calibration's accuracy before taking any image.")
    p.error = _one_line_error
    known = p.parse_known_args

    def parse_known_args(args=None, namespace=None):  # unknown options: one line here, not the main usage
        ns, extra = known(args, namespace)
        if extra:
            _one_line_error(f"unrecognized arguments: {' '.join(extra)}")
        return ns, extra

    p.parse_known_args = parse_known_args
    # "--box -200,200,..." : let values that start with a minus sign and hold only numbers
    # and commas be values, not options (argparse only accepts "-200" alone by default)
    p._negative_number_matcher = re.compile(r"^-\.?\d[\d.,eE+-]*$")
    a = p.add_argument
    a("--image-size", required=True, metavar="W,H", help="image width,height in pixels")
    a("--focal-px", required=True, metavar="F", help="approximate focal length in pixels")
    a("--distance", required=True, metavar="D", help="working distance to the middle of the scene (robot units)")
    a("--depth-range", default="0", metavar="R", help="depth extent of the scene (robot units; default 0: flat)")
    a("--points", default="100", metavar="N", help="number of tracked points expected (default 100)")
    a("--noise-px", default="0.5", metavar="S", help="pixel noise std per coordinate (default 0.5)")
    a("--box", metavar="xmin,xmax,ymin,ymax,zmin,zmax", help="reachable box of the camera (robot units)")
    a("--views", metavar="M", help="number of views to plan (4..50)")
    a("--view-direction", default="-z", help="optical axis in the robot frame: -z, +x, ... or a,b,c (default -z)")
    a("--robot-sigma", "--robot-noise", dest="robot_noise", default="0", metavar="SIGMA",
      help="robot pose error: per-axis std of each view's position error (robot units; default 0)")
    a("--distortion", default="none", help="distortion model to be estimated: none, radial1, radial2, opencv5")
    a("--dist-coeffs", default="", metavar="K1,K2,...",
      help="assumed true distortion coefficients, OpenCV order (default none: 0)")
    a("--criterion", default="focal", help="focal (default: std of fx, fy) or intrinsics (fx, fy, cx, cy)")
    a("--min-visible", default="0.5", metavar="FRACTION", help="each view sees at least this fraction of points")
    a("--margin-px", default="0", help="points nearer the image border than this count as unseen")
    a("--min-separation", default=None, help="smallest distance between planned views (default 5%% of the box)")
    a("--positions", metavar="CSV", help="allowed positions (view,x,y,z): choose among them instead of the box")
    a("--evaluate", metavar="POSES_CSV", help="predict what the translations of this poses.csv achieve")
    a("--seed", default="0", help="seed of the model's random points (default 0)")
    a("--out", metavar="DIR", help="output folder: poses.csv and plan.json (evaluation.json with --evaluate)")
    p.set_defaults(func=run)
    return p


def _numbers(args, name: str, count: int | None = None, integer: bool = False) -> list:
    text = getattr(args, name)
    opt = "--" + name.replace("_", "-")
    try:
        vals = [int(v) if integer else float(v) for v in str(text).split(",")]
    except ValueError:
        raise InputError(f"{opt} expects {'integers' if integer else 'numbers'}"
                         f"{f' ({count} separated by commas)' if count and count > 1 else ''}, got {text!r}") from None
    if count is not None and len(vals) != count:
        raise InputError(f"{opt} expects {count} numbers separated by commas, got {text!r}")
    if not all(np.isfinite(vals)):
        raise InputError(f"{opt} must be finite, got {text!r}")
    return vals


def _options(args):
    from ..planning import PlanOptions

    kw = dict(image_size=tuple(_numbers(args, "image_size", 2, integer=True)),
              focal_px=_numbers(args, "focal_px", 1)[0], distance=_numbers(args, "distance", 1)[0],
              depth_range=_numbers(args, "depth_range", 1)[0], n_points=_numbers(args, "points", 1, True)[0],
              noise_px=_numbers(args, "noise_px", 1)[0], view_direction=args.view_direction,
              robot_noise=_numbers(args, "robot_noise", 1)[0], distortion=args.distortion,
              dist=tuple(_numbers(args, "dist_coeffs")) if args.dist_coeffs.strip() else (),
              criterion=args.criterion, min_visible=_numbers(args, "min_visible", 1)[0],
              margin_px=_numbers(args, "margin_px", 1)[0],
              min_separation=None if args.min_separation is None else _numbers(args, "min_separation", 1)[0])
    return PlanOptions(**kw)


def _writable(out: str) -> Path:
    path = Path(out)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise InputError(f"--out {out}: cannot write there ({exc.strerror or exc})") from None
    return path


def _write_poses(path: Path, T: np.ndarray) -> None:
    from ..io import atomic_write

    with atomic_write(path, encoding="utf-8", newline="\n") as fh:
        fh.write("view,x,y,z\n")
        for i, t in enumerate(T):
            fh.write(f"{i},{float(t[0])!r},{float(t[1])!r},{float(t[2])!r}\n")


def _table(rows: dict) -> str:
    first = next(iter(rows.values())).predicted_std
    keys = _KEYS[:4] + tuple(k for k in first if k not in _KEYS) + _KEYS[4:]  # distortion after cy
    head = f"  {'design':<14}" + "".join(f"{k:>9}" for k in keys) + f"{'min seen':>10}"
    lines = [head, "  " + "-" * (len(head) - 2)]
    for name, ev in rows.items():
        lines.append(f"  {name:<14}" + "".join(f"{ev.predicted_std.get(k, float('nan')):9.3g}" for k in keys)
                     + f"{np.min(ev.visible):10.0%}")
    return "\n".join(lines)


def run(args) -> int:
    """Run ``transcalib plan``; returns the exit status."""
    try:
        return _run(args)
    except InputError as exc:
        msg = str(exc)
        for field, opt in _OPTION_OF.items():
            if msg.startswith(field + " ") or msg.startswith(field + "="):
                msg = opt + msg[len(field):]
                break
        print(f"transcalib plan: error: {msg}", file=sys.stderr)
        return EXIT_INPUT


def _run(args) -> int:
    from .. import io as tio
    from ..planning import evaluate_plan, plan

    options = _options(args)
    seed = _numbers(args, "seed", 1, integer=True)[0]
    box = None if args.box is None else _numbers(args, "box", 6)
    out = None if args.out is None else _writable(args.out)
    if args.evaluate:
        T = tio.read_poses(args.evaluate).T
        ev = evaluate_plan(T, options, box=box, rng=seed)
        print(f"Predicted accuracy of {args.evaluate} ({len(T)} views; std in px, rotation in degrees):")
        print(_table({"given": ev}))
        print(f"  median predicted std of a reconstructed point: {ev.point_std:.3g} (robot units)")
        for w in ev.warnings:
            print(f"warning: {w}")
        if out is not None:
            tio.write_json(out / "evaluation.json", ev.to_dict())
            print(f"Wrote {out / 'evaluation.json'}")
        return 0
    if box is None or args.views is None or out is None:
        missing = [o for o, v in (("--box", box), ("--views", args.views), ("--out", out)) if v is None]
        raise InputError(f"planning needs {', '.join(missing)} (or use --evaluate POSES_CSV)")
    n_views = _numbers(args, "views", 1, integer=True)[0]
    positions = None if args.positions is None else tio.read_poses(args.positions).T
    result = plan(box, n_views, options, positions=positions, rng=seed)
    _write_poses(out / "poses.csv", result.T)
    tio.write_json(out / "plan.json", result.to_dict())
    print(f"Plan: {n_views} views in the box {box} ({result.criterion}), {result.time_s:.2f} s")
    print(_table({"plan": result.evaluation, **result.patterns}))
    for w in result.evaluation.warnings:
        print(f"warning: {w}")
    print(f"Wrote {out / 'poses.csv'} and {out / 'plan.json'}")
    return 0

