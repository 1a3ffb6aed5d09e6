"""``transcalib extract``: the views a ``calibrate --bag`` run would use, as PNG images
and a ``poses.csv`` (metres, quaternions) for the images + poses route.

Also the bag input options that ``calibrate`` shares (:func:`add_bag_arguments`,
:func:`bag_options`, :func:`read_bag_views`).
"""

from __future__ import annotations

import time

from .common import OptionError, Progress, add_output_options, positive_float, print_json

NAME = "extract"
HELP = "write the still images of a ROS bag (one per stop) as PNG and their flange poses as poses.csv"

#: BagOptions field (or BagError parameter) -> the option a user types.
BAG_OPTIONS = {"path": "--bag", "image_topic": "--image-topic", "base_frame": "--base-frame",
               "flange_frame": "--flange-frame", "tf": "--bag", "still": "--bag",
               "still_mm": "--still-mm", "still_deg": "--still-deg", "still_window_s": "--still-window"}


def add_bag_arguments(parser, *, with_bag: bool) -> None:
    """The ROS bag input options, as one group of ``parser`` (``--bag`` itself too when
    ``with_bag``; ``calibrate`` has it among its inputs)."""
    from ..io.bag.options import STILL_DEG, STILL_MM, STILL_WINDOW_S

    g = parser.add_argument_group("ROS bag input (with --bag)")
    if with_bag:
        g.add_argument("--bag", required=True, metavar="RUN",
                       help="a ROS 2 bag folder, a single .mcap or .db3 file, or a ROS 1 .bag file")
    g.add_argument("--image-topic", metavar="TOPIC", help="sensor_msgs/Image or CompressedImage topic")
    g.add_argument("--base-frame", metavar="BASE", help="tf frame of the robot base")
    g.add_argument("--flange-frame", metavar="FLANGE", help="tf frame of the flange (the tree may have frames between)")
    g.add_argument("--still-mm", type=positive_float, default=None, metavar="MM",
                   help=f"an image is used when the flange moved at most this far within the window (default {STILL_MM:g})")
    g.add_argument("--still-deg", type=positive_float, default=None, metavar="DEG",
                   help=f"... and turned at most this much (default {STILL_DEG:g})")
    g.add_argument("--still-window", type=positive_float, default=None, metavar="S",
                   help=f"length of the window centred on the image's stamp, seconds (default {STILL_WINDOW_S:g})")


def bag_options(args):
    """:class:`~transcalib.io.bag.BagOptions` of the command line, or None without
    ``--bag``; the bag options without ``--bag``, or a missing required one, are errors."""
    from ..io.bag import BagError, BagOptions

    given = {"image_topic": args.image_topic, "base_frame": args.base_frame, "flange_frame": args.flange_frame,
             "still_mm": args.still_mm, "still_deg": args.still_deg, "still_window_s": args.still_window}
    if args.bag is None:
        extra = [BAG_OPTIONS[k] for k, v in given.items() if v is not None]
        if extra:
            raise OptionError(extra[0], "applies to --bag only")
        return None
    for key in ("image_topic", "base_frame", "flange_frame"):
        if given[key] is None:
            raise OptionError(BAG_OPTIONS[key], "required with --bag")
    try:
        return BagOptions(**{k: v for k, v in given.items() if v is not None})
    except BagError as exc:
        raise OptionError(BAG_OPTIONS[exc.parameter], str(exc)) from None


def check_bag_path(args):
    """``--bag`` exists and is a kind of bag (before any other work)."""
    from pathlib import Path

    from ..io.bag import BagError
    from ..io.bag.messages import bag_kind

    try:
        bag_kind(Path(args.bag))
    except BagError as exc:
        raise OptionError("--bag", str(exc)) from None
    return Path(args.bag)


def read_bag_views(args, options, progress: Progress):
    """The views of ``--bag`` (:func:`~transcalib.io.bag.read_bag`), its errors naming
    the option at fault."""
    from ..io.bag import BagError, read_bag

    progress.log(f"reading {args.bag} ...")
    try:
        views = read_bag(args.bag, options, log=lambda line: progress.log(f"  {line}"))
    except BagError as exc:
        raise OptionError(BAG_OPTIONS.get(exc.parameter, "--bag"), str(exc)) from None
    return views


def add_parser(sub) -> None:
    e = sub.add_parser(NAME, help=HELP, description=HELP + ". The output folder is written whole or not at all.")
    g = e.groups()
    g["outputs"].add_argument("--out", required=True, metavar="DIR",
                              help="output folder: view000.png, ..., poses.csv, manifest.json (written whole or not "
                                   "at all; an earlier transcalib run there is replaced)")
    add_output_options(g["outputs"])
    add_bag_arguments(e, with_bag=True)
    e.set_defaults(func=run)


def write_views(views, out, force: bool = False, inputs=()) -> list:
    """The images as PNG (grey or colour, 8 or 16 bit as decoded) and ``poses.csv``
    (``view,x,y,z,qx,qy,qz,qw,image``, metres) in ``out``, complete or absent
    (:func:`transcalib.io.folders.output_folder`)."""
    from ..io.folders import output_folder

    with output_folder(out, command=NAME, force=force, inputs=inputs) as folder:
        names = _write_files(views, folder.path)
    return [out / name for name in names]


def _write_files(views, folder) -> list[str]:
    """The PNGs and ``poses.csv`` in ``folder``; their names, poses.csv last."""
    import cv2

    from ..io import write_poses_csv

    for name, image in zip(views.names, views.images):
        if not cv2.imwrite(str(folder / name), image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
            raise OSError(f"PNG writing of {folder / name} failed")
    poses = views.poses()
    write_poses_csv(folder / "poses.csv", poses.T, poses.views, images=poses.images, R=poses.R)
    return views.names + ["poses.csv"]


def run(args) -> int:
    from ..io.folders import check_output_folder

    t0 = time.perf_counter()
    progress = args._progress = Progress(args.quiet)
    out = check_output_folder(args.out, force=args.force, inputs=[args.bag])
    options = bag_options(args)
    check_bag_path(args)
    views = read_bag_views(args, options, progress)
    written = write_views(views, out, force=args.force, inputs=[args.bag])
    if args.json:
        print_json({"status": "ok", "exit_code": 0, "n_views": views.n_views, "counts": views.counts(),
                    "unit": "m", "outputs": [str(p) for p in written], "time_s": time.perf_counter() - t0})
    else:
        print(views.describe(options))
        print(f"Wrote {views.n_views} images and poses.csv (metres) to {out} in {time.perf_counter() - t0:.2f} s")
    return 0
