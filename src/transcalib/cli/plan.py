"""``transcalib plan``: where to move the robot, with the accuracy predicted (issue 12).

``transcalib plan --image-size WxH --focal-px F --distance D --box ... --views M --out DIR``
writes ``DIR/poses.csv`` (``view,x,y,z``), ``DIR/plan.json`` and ``DIR/manifest.json``
(the folder complete or absent); ``--evaluate poses.csv`` predicts what given moves
achieve and warns about weak designs (``DIR/evaluation.json`` with ``--out``). Parsing
and printing only: the numerics are :func:`transcalib.plan` and
:func:`transcalib.evaluate_plan`. Every value is checked by argparse or
:class:`~transcalib.planning.PlanOptions` before the search starts; a bad one is one line
naming the option, exit status 2.
"""

from __future__ import annotations

import re

import numpy as np

from .common import (OptionError, add_output_options, box, existing_file, fraction, image_size, nonnegative_float,
                     numbers, positive_float, positive_int, print_json)

__all__ = ["add_parser", "run"]

NAME = "plan"
HELP = "plan robot translations with the accuracy predicted, or --evaluate given ones"
#: PlanOptions field -> command-line option, to name the option in error messages.
_OPTION_OF = {"image_size": "--image-size", "focal_px": "--focal-px", "distance": "--distance",
              "depth_range": "--depth-range", "n_points": "--points", "noise_px": "--noise-px",
              "view_direction": "--view-direction", "robot_noise": "--robot-sigma",
              "robot_sigma_deg": "--robot-sigma-deg",
              "distortion": "--distortion", "dist": "--dist-coeffs", "criterion": "--criterion",
              "min_visible": "--min-visible", "margin_px": "--margin-px", "n_views": "--views", "box": "--box",
              "min_separation": "--min-separation"}
_KEYS = ("fx", "fy", "cx", "cy", "rx", "ry", "rz")


def add_parser(subparsers) -> None:
    """Add the ``plan`` sub-command to the main parser's ``subparsers``."""
    p = subparsers.add_parser(NAME, help=HELP,
                              description="Plan where to move the robot (or --evaluate a poses.csv) and predict "
                                          "the calibration's accuracy before taking any image.")
    # "--box -200,200,..." : let every word that starts with a minus sign and a digit be a
    # value, not an option (argparse only takes a lone number such as "-200" by default),
    # so that a typo in such a value is reported as the value's error
    p._negative_number_matcher = re.compile(r"^-\.?\d")
    g = p.groups()
    _camera(g["model"])
    i = g["inputs"]
    i.add_argument("--box", type=box, metavar="XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX",
                   help="reachable box of the camera (robot units): three MIN,MAX ranges, each of positive length")
    i.add_argument("--positions", metavar="CSV", help="allowed positions (view,x,y,z): choose among them instead of "
                                                     "the box")
    i.add_argument("--evaluate", metavar="POSES_CSV", help="predict what the translations of this poses.csv achieve")
    i.add_argument("--views", type=positive_int, metavar="M", help="number of views to plan (4..50)")
    i.add_argument("--min-separation", type=nonnegative_float, metavar="D",
                   help="smallest distance between planned views, robot units (default 5%% of the box)")
    o = g["outputs"]
    o.add_argument("--out", metavar="DIR", help="output folder: poses.csv and plan.json (evaluation.json with "
                                                "--evaluate), written whole or not at all")
    add_output_options(o, quiet=False)
    g["performance"].add_argument("--seed", type=int, default=0, metavar="N",
                                  help="seed of the model's random points (default 0: repeatable)")
    p.set_defaults(func=run)


def _camera(m) -> None:
    """The assumed camera and scene (:class:`~transcalib.planning.PlanOptions`)."""
    m.add_argument("--image-size", required=True, type=image_size, metavar="WxH",
                   help="image size in pixels, WxH or W,H such as 1280x1024")
    m.add_argument("--focal-px", required=True, type=positive_float, metavar="F",
                   help="approximate focal length in pixels")
    m.add_argument("--distance", required=True, type=positive_float, metavar="D",
                   help="working distance to the middle of the scene (robot units)")
    m.add_argument("--depth-range", type=nonnegative_float, default=0.0, metavar="R",
                   help="depth extent of the scene, below 2 x --distance (robot units; default 0: flat)")
    m.add_argument("--points", type=positive_int, default=100, metavar="N",
                   help="number of tracked points expected, at least 2 (default 100)")
    m.add_argument("--noise-px", type=positive_float, default=0.5, metavar="S",
                   help="pixel noise std per coordinate (default 0.5)")
    m.add_argument("--view-direction", default="-z",
                   help="optical axis in the robot frame: -z, +x, ... or a,b,c (default -z)")
    m.add_argument("--robot-sigma", "--robot-noise", dest="robot_noise", type=nonnegative_float, default=0.0,
                   metavar="SIGMA", help="robot pose error: per-axis std of each view's position error, robot "
                                         "units (default 0)")
    m.add_argument("--robot-sigma-deg", type=nonnegative_float, default=0.0, metavar="DEG",
                   help="robot pose error: per-axis std of each view's orientation error, degrees (default 0); "
                        "with it every view's pose error enters the prediction as calibrate estimates it")
    m.add_argument("--distortion", default="none", choices=["none", "radial1", "radial2", "opencv5"],
                   help="distortion model to be estimated (default none)")
    m.add_argument("--dist-coeffs", type=numbers, default=(), metavar="K1,K2,...",
                   help="assumed true distortion coefficients, OpenCV order, 1, 2, 4 or 5 of them (default: none)")
    m.add_argument("--criterion", default="focal", choices=["focal", "intrinsics"],
                   help="what the plan minimises: focal (the std of fx, fy; default) or intrinsics (fx, fy, cx, cy)")
    m.add_argument("--min-visible", type=fraction, default=0.5, metavar="FRACTION",
                   help="each view sees at least this fraction of the points, in [0, 1) (default 0.5)")
    m.add_argument("--margin-px", type=nonnegative_float, default=0.0, metavar="PX",
                   help="points nearer the image border than this count as unseen (default 0)")


def _options(args):
    from ..planning import PlanOptions

    return PlanOptions(image_size=args.image_size, focal_px=args.focal_px, distance=args.distance,
                       depth_range=args.depth_range, n_points=args.points, noise_px=args.noise_px,
                       view_direction=args.view_direction, robot_noise=args.robot_noise,
                       robot_sigma_deg=args.robot_sigma_deg, distortion=args.distortion,
                       dist=tuple(args.dist_coeffs), criterion=args.criterion, min_visible=args.min_visible,
                       margin_px=args.margin_px, min_separation=args.min_separation)


def _table(rows: dict) -> str:
    first = next(iter(rows.values())).predicted_std
    keys = _KEYS[:4] + tuple(k for k in first if k not in _KEYS) + _KEYS[4:]  # distortion after cy
    head = f"  {'design':<14}" + "".join(f"{k:>9}" for k in keys) + f"{'min seen':>10}"
    lines = [head, "  " + "-" * (len(head) - 2)]
    for name, ev in rows.items():
        lines.append(f"  {name:<14}" + "".join(f"{ev.predicted_std.get(k, float('nan')):9.3g}" for k in keys)
                     + f"{np.min(ev.visible):10.0%}")
    return "\n".join(lines)


def _checked(args):
    """Every option and path before the search: ``(options, inputs)``."""
    from ..errors import InputError
    from ..io.folders import check_output_folder

    try:
        options = _options(args)
    except InputError as exc:  # PlanOptions names its fields: name the options instead
        msg = str(exc)
        field = next((f for f in _OPTION_OF if msg.startswith(f + " ") or msg.startswith(f + "=")), None)
        raise OptionError(_OPTION_OF[field], msg[len(field):].lstrip(" ")) if field else exc from None
    if args.evaluate:
        for name in ("views", "positions", "min_separation"):
            if getattr(args, name) is not None:
                raise OptionError("--" + name.replace("_", "-"), "applies to planning, not to --evaluate")
    else:
        missing = [o for o, v in (("--box", args.box), ("--views", args.views), ("--out", args.out)) if v is None]
        if missing:
            raise OptionError(missing[0], f"planning needs {', '.join(missing)} (or use --evaluate POSES_CSV)")
        if not 4 <= args.views <= 50:
            raise OptionError("--views", f"must be in 4..50, got {args.views}")
    inputs = [existing_file(opt, p) for opt, p in (("--evaluate", args.evaluate), ("--positions", args.positions)) if p]
    if args.out is not None:
        check_output_folder(args.out, force=args.force, inputs=inputs)
    return options, inputs


def run(args) -> int:
    """Run ``transcalib plan``; returns the exit status."""
    from .. import io as tio
    from ..io.folders import output_folder
    from ..planning import evaluate_plan, plan

    options, inputs = _checked(args)
    if args.evaluate:
        T = tio.read_poses(args.evaluate).T
        ev = evaluate_plan(T, options, box=args.box, rng=args.seed)
        files = []
        if args.out is not None:
            with output_folder(args.out, command=NAME, force=args.force, inputs=inputs) as folder:
                tio.write_json(folder.file("evaluation.json"), ev.to_dict())
                files = folder.final_paths([folder.path / "evaluation.json"])
        if args.json:
            print_json({"status": "warnings" if ev.warnings else "ok", "exit_code": 0, "evaluation": ev.to_dict(),
                        "outputs": [str(f) for f in files]})
            return 0
        print(f"Predicted accuracy of {args.evaluate} ({len(T)} views; std in px, rotation in degrees):")
        print(_table({"given": ev}))
        print(f"  median predicted std of a reconstructed point: {ev.point_std:.3g} (robot units)")
        for w in ev.warnings:
            print(f"warning: {w}")
        if files:
            print(f"Wrote {files[0]} and manifest.json")
        return 0
    positions = None if args.positions is None else tio.read_poses(args.positions).T
    result = plan(args.box, args.views, options, positions=positions, rng=args.seed)
    with output_folder(args.out, command=NAME, force=args.force, inputs=inputs) as folder:
        _write_poses(folder.file("poses.csv"), result.T)
        tio.write_json(folder.file("plan.json"), result.to_dict())
        files = folder.final_paths([folder.path / "poses.csv", folder.path / "plan.json"])
    if args.json:
        print_json({"status": "warnings" if result.evaluation.warnings else "ok", "exit_code": 0,
                    "plan": result.to_dict(), "outputs": [str(f) for f in files]})
        return 0
    print(f"Plan: {args.views} views in the box {list(args.box)} ({result.criterion}), {result.time_s:.2f} s")
    print(_table({"plan": result.evaluation, **result.patterns}))
    for w in result.evaluation.warnings:
        print(f"warning: {w}")
    print(f"Wrote {files[0]}, {files[1]} and manifest.json")
    return 0


def _write_poses(path, T: np.ndarray) -> None:
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write("view,x,y,z\n")
        for i, t in enumerate(T):
            fh.write(f"{i},{float(t[0])!r},{float(t[1])!r},{float(t[2])!r}\n")
