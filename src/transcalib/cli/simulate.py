"""``transcalib simulate``: write a synthetic scene (tracks.csv, poses.csv, truth.json).

The ``paper`` preset is the paper's 24-corner scene in 4 views; ``random`` takes
``--points``, ``--views``, ``--planar`` and ``--missing``. Giving one of those with the
paper preset is an error (it would be silently ignored otherwise).
"""

from __future__ import annotations

from .common import OptionError, fraction, nonnegative_float, positive_int, print_json

NAME = "simulate"
HELP = "write a synthetic scene: tracks.csv, poses.csv, truth.json"

#: Options of the random preset, with their defaults.
RANDOM_ONLY = {"points": 100, "views": 4, "planar": False, "missing": 0.0}


def add_parser(sub) -> None:
    s = sub.add_parser(NAME, help=HELP, description=HELP)
    s.add_argument("--preset", choices=["paper", "random"], default="paper")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--points", type=positive_int, help="random preset: number of points (default 100)")
    s.add_argument("--views", type=positive_int, help="random preset: number of views, at least 4 (default 4)")
    s.add_argument("--planar", action="store_true", default=None, help="random preset: points on a plane")
    s.add_argument("--missing", type=fraction, help="random preset: fraction of dropped observations (default 0)")
    s.add_argument("--noise-px", type=nonnegative_float, default=0.0, help="pixel noise std (default 0)")
    s.add_argument("--robot-noise", type=nonnegative_float, default=0.0, help="robot translation noise std (default 0)")
    s.add_argument("--tracks-format", choices=["csv", "npz", "parquet"], default="csv",
                   help="format of the tracks file (default csv)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--json", action="store_true", help="print a machine-readable summary on stdout")
    s.set_defaults(func=run)


def _random_options(args) -> dict:
    given = [name for name in RANDOM_ONLY if getattr(args, name) is not None]
    if args.preset != "random":
        if given:
            raise OptionError(f"--{given[0]}", f"applies to --preset random only (the {args.preset} preset has "
                              "a fixed scene); add --preset random")
        return {}
    opts = {name: RANDOM_ONLY[name] if getattr(args, name) is None else getattr(args, name) for name in RANDOM_ONLY}
    if opts["views"] < 4:
        raise OptionError("--views", f"must be at least 4 (the method needs 4 views), got {opts['views']}")
    if opts["points"] < 2:
        raise OptionError("--points", f"must be at least 2, got {opts['points']}")
    return opts


def run(args) -> int:
    from .. import io as tio
    from ..synth import simulate

    opts = _random_options(args)
    out = tio.check_writable_dir(args.out, "--out")
    if args.preset == "paper":
        scene = simulate.paper_scene(noise_px=args.noise_px, robot_noise=args.robot_noise, rng=args.seed)
    else:
        scene = simulate.random_scene(opts["points"], opts["views"], planar=opts["planar"], noise_px=args.noise_px,
                                      robot_noise=args.robot_noise, missing=opts["missing"], rng=args.seed)
    tracks = out / f"tracks.{args.tracks_format}"
    tio.write_tracks(tracks, scene.uv)
    tio.write_poses_csv(out / "poses.csv", scene.T)
    tio.write_json(out / "truth.json", scene.truth_dict())
    files = [tracks, out / "poses.csv", out / "truth.json"]
    if args.json:
        print_json({"status": "ok", "exit_code": 0, "preset": args.preset, "n_points": scene.n_points,
                    "n_views": scene.n_views, "noise_px": args.noise_px, "robot_noise": args.robot_noise,
                    "unit": scene.unit, "outputs": [str(f) for f in files]})
    else:
        print(f"Wrote {', '.join(str(f) for f in files)}: {scene.n_points} points in {scene.n_views} views "
              f"({args.preset} preset, {args.noise_px} px noise, {args.robot_noise} {scene.unit} robot noise)")
    return 0
