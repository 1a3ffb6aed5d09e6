"""``transcalib simulate``: write a synthetic scene (tracks.csv, poses.csv, truth.json).

The ``paper`` preset is the paper's 24-corner scene in 4 views; ``random`` takes
``--points``, ``--views``, ``--planar`` and ``--missing``; ``robot`` is a camera on a flange
(or, ``--setup eye-to-hand``, fixed while the flange carries the scene) with ``--sessions``
wrist orientations of ``--views`` translations each (``--moves``) and ``--single-views`` at
their own orientations, the poses written with quaternions. Giving an option that the
chosen preset does not take is an error (it would be silently ignored otherwise).
"""

from __future__ import annotations

import numpy as np

from ..types.options import SETUPS
from .common import OptionError, add_output_options, fraction, nonnegative_float, positive_int, print_json

NAME = "simulate"
HELP = "write a synthetic scene: tracks.csv, poses.csv, truth.json"

#: The options each preset takes, with their defaults.
PRESET_OPTIONS = {
    "paper": {},
    "random": {"points": 100, "views": 4, "planar": False, "missing": 0.0},
    "robot": {"points": 60, "views": 6, "sessions": 3, "single_views": 0, "moves": "3d", "setup": "eye-in-hand"},
}


def add_parser(sub) -> None:
    s = sub.add_parser(NAME, help=HELP, description=HELP + ". The output folder is written whole or not at all.")
    g = s.groups()
    m = g["model"]
    m.add_argument("--preset", choices=list(PRESET_OPTIONS), default="paper",
                   help="paper: the paper's 24 points in 4 views (default); random: a random scene; robot: a camera "
                        "on a flange with several wrist orientations (hand-eye)")
    m.add_argument("--points", type=positive_int, metavar="N",
                   help="random/robot preset: number of points, at least 2 (default 100/60)")
    m.add_argument("--views", type=positive_int, metavar="M",
                   help="random preset: number of views, at least 4 (default 4); robot preset: views per session "
                        "(default 6)")
    m.add_argument("--planar", action="store_true", default=None, help="random preset: points on a plane")
    m.add_argument("--missing", type=fraction, metavar="FRACTION",
                   help="random preset: fraction of dropped observations, in [0, 1) (default 0)")
    m.add_argument("--sessions", type=int, metavar="N",
                   help="robot preset: wrist orientations with translations (default 3)")
    m.add_argument("--single-views", type=int, metavar="N",
                   help="robot preset: views each at its own orientation, tilted 15-40 deg (default 0)")
    m.add_argument("--moves", choices=["3d", "xy", "line"], help="robot preset: translations in a session (default 3d)")
    m.add_argument("--setup", choices=SETUPS, help="robot preset: where the camera is (default eye-in-hand)")
    r = g["robust"]
    r.add_argument("--noise-px", type=nonnegative_float, default=0.0, metavar="PX",
                   help="pixel noise std per coordinate (default 0)")
    r.add_argument("--robot-noise", type=nonnegative_float, default=0.0, metavar="SIGMA",
                   help="paper/random preset: robot translation noise std, in mm (default 0)")
    o = g["outputs"]
    o.add_argument("--out", required=True, metavar="DIR",
                   help="output folder: tracks, poses.csv, truth.json, manifest.json (written whole or not at all)")
    o.add_argument("--tracks-format", choices=["csv", "npz", "parquet"], default="csv",
                   help="format of the tracks file (default csv)")
    add_output_options(o, quiet=False)
    g["performance"].add_argument("--seed", type=int, default=0, metavar="N",
                                  help="random seed of the scene and the noise (default 0: repeatable)")
    s.set_defaults(func=run)


def _preset_options(args) -> dict:
    """The chosen preset's options (defaults filled in), after refusing any other preset's."""
    taken = PRESET_OPTIONS[args.preset]
    for name in sorted({n for opts in PRESET_OPTIONS.values() for n in opts} - set(taken)):
        if getattr(args, name) is not None:
            flag = "--" + name.replace("_", "-")
            users = [p for p, opts in PRESET_OPTIONS.items() if name in opts]
            raise OptionError(flag, f"applies to --preset {' or '.join(users)} only; add --preset {users[0]}")
    if args.preset == "robot" and args.robot_noise:
        raise OptionError("--robot-noise", "applies to the paper and random presets only")
    opts = {name: default if getattr(args, name) is None else getattr(args, name) for name, default in taken.items()}
    if args.preset == "random" and opts["views"] < 4:
        raise OptionError("--views", f"must be at least 4 (the method needs 4 views), got {opts['views']}")
    if "points" in opts and opts["points"] < 2:
        raise OptionError("--points", f"must be at least 2, got {opts['points']}")
    if args.preset == "robot" and (opts["sessions"] < 0 or opts["single_views"] < 0
                                   or opts["sessions"] + opts["single_views"] < 1):
        raise OptionError("--sessions", "--sessions and --single-views must be >= 0 and give at least one view, got "
                          f"{opts['sessions']} and {opts['single_views']}")
    return opts


def _robot_scene(opts: dict, noise_px: float, seed: int):
    """``(uv, poses, truth)`` of the robot preset: pixels, the columns of poses.csv, truth.json."""
    from ..handeye.simulate import session_scene

    sc = session_scene(seed, n_sessions=opts["sessions"], views_per_session=opts["views"], n_points=opts["points"],
                       moves=opts["moves"], single_views=opts["single_views"], setup=opts["setup"],
                       noise_px=noise_px)
    truth = {k: np.asarray(v).tolist() for k, v in sc.truth.items()}
    truth.update(points=sc.X.tolist(), noise_px=noise_px, units="mm", setup=sc.setup)
    return sc.uv, dict(T=sc.T, R=sc.R, session=list(sc.session_of_view)), truth


def run(args) -> int:
    from .. import io as tio
    from ..io.folders import check_output_folder, output_folder
    from ..synth import simulate

    opts = _preset_options(args)
    check_output_folder(args.out, force=args.force)
    if args.preset == "robot":
        uv, poses, truth = _robot_scene(opts, args.noise_px, args.seed)
    else:
        if args.preset == "paper":
            scene = simulate.paper_scene(noise_px=args.noise_px, robot_noise=args.robot_noise, rng=args.seed)
        else:
            scene = simulate.random_scene(opts["points"], opts["views"], planar=opts["planar"], noise_px=args.noise_px,
                                          robot_noise=args.robot_noise, missing=opts["missing"], rng=args.seed)
        uv, poses, truth = scene.uv, dict(T=scene.T), scene.truth_dict()
    with output_folder(args.out, command=NAME, force=args.force) as folder:
        tracks = folder.file(f"tracks.{args.tracks_format}")
        tio.write_tracks(tracks, uv)
        tio.write_poses_csv(folder.file("poses.csv"), **poses)
        tio.write_json(folder.file("truth.json"), truth)
        files = folder.final_paths([tracks, folder.path / "poses.csv", folder.path / "truth.json"])
    n_points, n_views, unit = uv.shape[1], uv.shape[0], truth["units"]
    if args.json:
        print_json({"status": "ok", "exit_code": 0, "preset": args.preset, "n_points": n_points,
                    "n_views": n_views, "noise_px": args.noise_px, "robot_noise": args.robot_noise,
                    "unit": unit, "outputs": [str(f) for f in files]})
    else:
        print(f"Wrote {', '.join(str(f) for f in files)}: {n_points} points in {n_views} views "
              f"({args.preset} preset, {args.noise_px} px noise, {args.robot_noise} {unit} robot noise)")
    return 0
