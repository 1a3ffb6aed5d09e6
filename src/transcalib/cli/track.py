"""``transcalib track``: point tracks through images taken at translated positions."""

from __future__ import annotations

import numpy as np

from .common import OptionError, Progress, add_output_options, existing_file, print_json

NAME = "track"
HELP = "track points through images taken at translated positions"


def add_parser(sub) -> None:
    t = sub.add_parser(NAME, help=HELP, description=HELP + ". The tracks file is written whole or not at all.")
    g = t.groups()
    g["inputs"].add_argument("images", nargs="+", metavar="IMAGE",
                             help="the images in view order, at least 2 (4 or more for a calibration), each after a robot move")
    g["model"].add_argument("--target", choices=["squares"],
                            help="detect the corners of dark squares instead of tracking features")
    g["outputs"].add_argument("-o", "--output", required=True, metavar="FILE",
                              help="tracks file to write: .csv (view,point,u,v), .npz or .parquet")
    add_output_options(g["outputs"], folder=False)
    t.set_defaults(func=run)


def run(args) -> int:
    from .. import io as tio
    from .calibrate import distinct_images, track_images

    output = tio.check_writable_file(args.output, "-o/--output")
    if output.suffix.lower() not in (".csv", ".npz", ".parquet"):
        raise OptionError("-o/--output", f"{str(output)!r}: the extension must be .csv, .npz or .parquet")
    images = distinct_images([existing_file("IMAGE", p) for p in args.images], "IMAGE")
    if any(p.resolve() == output.resolve() for p in images):
        raise OptionError("-o/--output", f"{str(output)!r} is one of the input images; give another file name")
    progress = args._progress = Progress(args.quiet)
    tracks = track_images(images, args.target, progress)
    tio.write_tracks(output, tracks.uv, tracks.ids)
    n_obs = int(np.isfinite(tracks.uv[..., 0]).sum())
    if args.json:
        print_json({"status": "ok", "exit_code": 0, "n_tracks": tracks.uv.shape[1], "n_observations": n_obs,
                    "n_views": tracks.uv.shape[0], "outputs": [str(output)]})
    else:
        print(f"Wrote {output}: {tracks.uv.shape[1]} tracks, {n_obs} observations in {tracks.uv.shape[0]} views")
    return 0
