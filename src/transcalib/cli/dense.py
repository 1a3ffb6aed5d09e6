"""``transcalib dense``: depth maps and a metric point cloud from calibrated views.

Order of work: (1) check every option, input and the output folder
(:mod:`transcalib.io.folders`) - no computation yet; (2) read the images; (3)
:func:`transcalib.dense`; (4) write every output into a temporary folder beside
``--out``, renamed into place at the end. A failure or an interrupt (Ctrl-C, ``kill``)
at any point leaves ``--out`` as it was: complete or absent.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from .common import (OptionError, Progress, add_output_options, existing_file, positive_float, positive_int,
                     print_json)

NAME = "dense"
HELP = "dense depth maps and a metric point cloud of calibrated views (multi-baseline stereo)"


def depth_limits(text: str) -> tuple[float, float]:
    """``--depth-limits NEAR,FAR``: two numbers, ``0 < NEAR < FAR`` (FAR may be ``inf``)."""
    parts = text.replace(";", ",").split(",")
    try:
        near, far = (float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected NEAR,FAR (two numbers in the robot's unit), got {text!r}") from None
    if not (math.isfinite(near) and near > 0 and far > near):
        raise argparse.ArgumentTypeError(f"need 0 < NEAR < FAR (FAR may be inf), got {text!r}")
    return near, far


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"must be in [0, 1), got {text!r}")
    return value


def add_parser(sub) -> None:
    d = sub.add_parser(NAME, help=HELP, description=HELP)
    g = d.groups()
    i = g["inputs"]
    i.add_argument("--calibration", required=True, metavar="DIR", help="the --out folder of calibrate")
    i.add_argument("--images", required=True, nargs="+", metavar="IMAGE",
                   help="images in view order (or named in the image column of --poses)")
    i.add_argument("--poses", required=True, help="poses.csv (or .json) of the images, in the calibration's unit")
    i.add_argument("--rotation-format", default=None, choices=["quaternion", "rotvec", "ur", "euler_zyx", "kuka"],
                   help="orientation columns of --poses (default: found from the columns)")
    m = g["model"]
    m.add_argument("--reference-view", action="append", metavar="ID", dest="reference_views",
                   help="view id of a reference view (repeat for several, fused with a consistency check; "
                        "default: the most central view)")
    m.add_argument("--depth-limits", type=depth_limits, metavar="NEAR,FAR",
                   help="depth range along the optical axis, robot units (default: found by a coarse sweep)")
    m.add_argument("--depths", type=positive_int, default=256, metavar="N", help="depth hypotheses (default 256)")
    m.add_argument("--window", type=positive_int, default=7, metavar="PX", help="matching window side (odd, default 7)")
    m.add_argument("--max-turn-deg", type=positive_float, metavar="DEG",
                   help="also match views turned by up to DEG degrees against the reference (default: only the "
                        "views of its session, its flange orientation); for calibrations from general motion")
    r = g["robust"]
    r.add_argument("--best-k", type=positive_int, metavar="K",
                   help="views summed at each pixel (default: half of the other views, at least 1)")
    r.add_argument("--min-confidence", type=_fraction, default=0.5, metavar="C",
                   help="pixels of lower confidence are left unknown (default 0.5)")
    o = g["outputs"]
    o.add_argument("--out", required=True, metavar="DIR",
                   help="output folder: written whole or not at all; an earlier transcalib run there is replaced")
    o.add_argument("--no-report", action="store_true", help="do not write report.html")
    add_output_options(o)
    d.set_defaults(func=run)


def _options(args):
    from ..dense import DenseOptions
    from ..errors import InputError

    try:
        return DenseOptions(n_depths=args.depths, window_px=args.window, best_k=args.best_k,
                            min_confidence=args.min_confidence, max_turn_deg=args.max_turn_deg)
    except InputError as exc:
        names = {"window_px": "--window", "n_depths": "--depths", "max_turn_deg": "--max-turn-deg"}
        option = next((o for k, o in names.items() if k in str(exc)), "--best-k")
        raise OptionError(option, str(exc).removeprefix("DenseOptions: ")) from None


def check_all(args) -> dict:
    """Step (1): every check, before any computation; returns what the later steps need."""
    from ..dense.views import view_cameras
    from ..errors import InputError
    from ..io import read_poses
    from ..io.calibration_file import load_saved
    from ..io.folders import check_output_folder
    from ..io.ids import canonical_id
    from .calibrate import _order_images

    images = [existing_file("--images", p) for p in args.images]
    poses_path = existing_file("--poses", args.poses)
    check_output_folder(args.out, force=args.force, inputs=[args.calibration, poses_path, *images])
    plan = {"options": _options(args)}
    try:
        plan["saved"] = load_saved(args.calibration)
    except InputError as exc:
        raise OptionError("--calibration", str(exc)) from None
    poses = plan["poses"] = read_poses(poses_path, rotation_format=args.rotation_format)
    if len(images) != poses.n_views:
        raise OptionError("--images", f"{len(images)} images but {poses.n_views} poses in {str(poses_path)!r}; "
                          "give one image per pose")
    plan["images"] = _order_images(images, poses)
    refs = [canonical_id(v) for v in (args.reference_views or [])]
    missing = [v for v in refs if v not in poses.views]
    if missing or len(set(refs)) != len(refs):
        what = f"view(s) {', '.join(missing)} not in {str(poses_path)!r}" if missing else "a view given twice"
        raise OptionError("--reference-view", f"{what}; the views are {', '.join(poses.views[:20])}")
    plan["references"] = refs or None
    try:
        view_cameras(plan["saved"].calibration, poses)
    except InputError as exc:
        raise OptionError("--poses", str(exc)) from None
    return plan


def _read_images(paths, camera) -> list:
    import cv2

    imgs = []
    for p in paths:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise OptionError("--images", f"{str(p)!r} is not an image OpenCV can read")
        size = (img.shape[1], img.shape[0])
        if camera.image_size is not None and size != tuple(camera.image_size):
            raise OptionError("--images", f"{str(p)!r} is {size[0]}x{size[1]} px but the camera was calibrated at "
                              f"{camera.image_size[0]}x{camera.image_size[1]}")
        imgs.append(img)
    return imgs


def run(args) -> int:
    t0 = time.perf_counter()
    progress = args._progress = Progress(args.quiet)
    plan = check_all(args)
    plan["t_checks"] = time.perf_counter() - t0
    return _work(args, plan, progress, t0)


def _work(args, plan, progress: Progress, t0: float) -> int:
    from ..dense import dense
    from ..io.dense_files import write_dense
    from ..io.folders import MANIFEST, output_folder

    cal = plan["saved"].calibration
    imgs = _read_images(plan["images"], cal.camera)
    t_read = time.perf_counter()
    result = dense(cal, imgs, plan["poses"], reference_views=plan["references"], depth_limits=args.depth_limits,
                   options=plan["options"], progress=progress)
    t_dense = time.perf_counter()
    inputs = {"calibration": str(args.calibration), "poses": str(args.poses),
              "images": [str(p) for p in plan["images"]], "view_ids": list(plan["poses"].views)}
    with output_folder(args.out, command=NAME, force=args.force,
                       inputs=[args.calibration, args.poses, *plan["images"]]) as folder:
        names = write_dense(result, folder.path, inputs=inputs, report=not args.no_report)
    written = [Path(args.out) / name for name in names + [MANIFEST]]
    t_end = time.perf_counter()
    timings = {"checks_s": plan["t_checks"], "read_s": t_read - t0 - plan["t_checks"], "dense_s": t_dense - t_read,
               "write_s": t_end - t_dense, "total_s": t_end - t0}
    if args.json:
        print_json({"status": "ok", "exit_code": 0, "outputs": [str(p) for p in written], "run_timings_s": timings,
                    "reference_views": [{"view": m.view, "known_fraction": m.stats.known_fraction,
                                         "depth_limits": list(m.depth_limits)} for m in result.maps],
                    "points": len(result.points), "rejected": result.n_rejected, "unit": result.unit})
    else:
        unit = result.unit or "units"
        for m in result.maps:
            print(f"view {m.view}: {m.stats.known_fraction * 100:.1f} % of pixels with depth, range "
                  f"{m.depth_limits[0]:.4g}-{m.depth_limits[1]:.4g} {unit}, matched with views {', '.join(m.sources)}")
            step = m.stats.hypothesis_step_px
            if step > 1.0:
                print(f"  note: neighbouring depth hypotheses are {step:.2g} px apart in the view with the longest "
                      f"baseline; give --depths {int(np.ceil(args.depths * step))} (or narrower --depth-limits)")
        print(f"cloud: {len(result.points):,} points ({result.n_rejected:,} rejected by the consistency check)")
        print(f"\nWrote {len(written)} files to {args.out} in {timings['total_s']:.2f} s (read "
              f"{timings['read_s']:.2f} s, dense {timings['dense_s']:.2f} s, write {timings['write_s']:.2f} s)")
    return 0



