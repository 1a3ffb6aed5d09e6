"""``transcalib track``: point tracks through images taken at translated positions."""

from __future__ import annotations

import numpy as np

from .common import Progress, existing_file, print_json

NAME = "track"
HELP = "track points through images taken at translated positions"


def add_parser(sub) -> None:
    t = sub.add_parser(NAME, help=HELP, description=HELP)
    t.add_argument("images", nargs="+", metavar="IMAGE")
    t.add_argument("-o", "--output", required=True, help="tracks file to write (.csv, .npz or .parquet)")
    t.add_argument("--target", choices=["squares"], help="detect the corners of dark squares")
    t.add_argument("--json", action="store_true", help="print a machine-readable summary on stdout")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(func=run)


def run(args) -> int:
    from .. import io as tio
    from .calibrate import track_images

    output = tio.check_writable_file(args.output, "-o/--output")
    if output.suffix.lower() not in (".csv", ".npz", ".parquet"):
        from .common import OptionError

        raise OptionError("-o/--output", f"{str(output)!r}: the extension must be .csv, .npz or .parquet")
    images = [existing_file("IMAGE", p) for p in args.images]
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
