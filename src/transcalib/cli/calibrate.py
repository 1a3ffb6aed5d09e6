"""``transcalib calibrate``: tracks (or images) and robot poses in; calibration, exports
and report out.

Order of work: (1) check every option, input file and the output folder (no
computation yet); (2) read or track; (3) calibrate; (4) write every output into a
temporary folder, renamed into place at the end (:mod:`transcalib.io.folders`). A failure
in (1) costs nothing; a failure or Ctrl-C later leaves ``--out`` as it was.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from ..handeye.sessions import SESSION_TOLERANCE_DEG
from ..types import MIN_SUBSET_POINTS, SUBSET_POINTS
from .common import (EXIT_OK, EXIT_WARNINGS, OptionError, Progress, add_output_options, existing_file, image_size,
                     import_in_background, nonnegative_float, positive_float, positive_int, print_json)
from .extract import add_bag_arguments

NAME = "calibrate"
HELP = "calibrate from tracks (or images) and robot poses; write calibration, exports and report"


def subset_points(text: str) -> int | None:
    """``--subset-points``: ``all`` (None) or an integer of at least ``MIN_SUBSET_POINTS``."""
    if text.strip().lower() == "all":
        return None
    value = positive_int(text)
    if value < MIN_SUBSET_POINTS:
        raise argparse.ArgumentTypeError(f"must be 'all' or at least {MIN_SUBSET_POINTS}, got {text!r}")
    return value


def add_parser(sub) -> None:
    c = sub.add_parser(NAME, help=HELP, description=HELP + ". The output folder is written whole or not at all.")
    g = c.groups()
    _inputs(g["inputs"])
    _model(g["model"])
    _robust(g["robust"])
    out = g["outputs"]
    out.add_argument("--out", required=True, metavar="DIR",
                     help="output folder, written whole or not at all (an earlier transcalib run there is replaced)")
    out.add_argument("--formats", default="all", metavar="LIST",
                     help="comma-separated outputs among json,csv,opencv,ros,colmap,ply,report (default all)")
    out.add_argument("--truth", metavar="FILE", help="truth.json of a simulated scene: print and plot the errors")
    out.add_argument("--strict", action="store_true", help="exit with status 4 when the calibration has warnings")
    add_output_options(out)
    add_bag_arguments(c, with_bag=False)
    perf = g["performance"]
    perf.add_argument("--subset-points", type=subset_points, default=SUBSET_POINTS, metavar="N|all",
                      help=f"with more tracks, fit a random subset of N (default {SUBSET_POINTS}) to convergence, "
                           "then take Gauss-Newton steps with every track; 'all': every stage uses every track")
    perf.add_argument("--seed", type=int, default=0, metavar="N",
                      help="random seed of RANSAC and the subset (default 0: repeatable)")
    c.set_defaults(func=run)


def _inputs(g) -> None:
    src = g.add_mutually_exclusive_group(required=True)
    src.add_argument("--tracks", metavar="FILE", help="tracks file: view,point,u,v (.csv), or .npz / .parquet")
    src.add_argument("--images", nargs="+", metavar="IMAGE",
                     help="images in view order (or matched to the image column of --poses); tracked first")
    src.add_argument("--bag", metavar="RUN", help="a ROS 2 bag folder, .mcap or .db3 file, or ROS 1 .bag: its still "
                                                  "images and their flange poses from tf (see ROS bag input)")
    g.add_argument("--poses", metavar="FILE",
                   help="poses.csv (or .json): view,x,y,z[,orientation][,session][,image]: the flange pose of "
                        "each view; with orientations, the camera's pose on the flange (hand-eye) too "
                        "(required, except with --bag)")
    g.add_argument("--unit", default=None,
                   help="length unit of the poses; every output length is in it (default mm; with --bag m, tf's unit)")
    g.add_argument("--rotation-format", default=None, choices=["quaternion", "rotvec", "ur", "euler_zyx", "kuka"],
                   help="orientation columns of --poses: qx,qy,qz,qw (ROS tf), rx,ry,rz (UR rotation vector) "
                        "or a,b,c (KUKA Z-Y-X Euler, degrees); default: found from the columns")
    g.add_argument("--image-size", type=image_size, metavar="WxH",
                   help="image size in pixels, WxH or W,H such as 640x480 (default: from the images or --truth); "
                        "every tracked point must lie inside it")
    g.add_argument("--target", choices=["squares"], help="with --images: detect the corners of dark squares")


def _model(g) -> None:
    g.add_argument("--setup", choices=["eye-in-hand", "eye-to-hand"], default="eye-in-hand",
                   help="eye-in-hand: the camera on the flange (default); eye-to-hand: the camera fixed, watching "
                        "an object carried by the flange (the points are then in the flange frame)")
    g.add_argument("--session-tolerance-deg", type=positive_float, default=SESSION_TOLERANCE_DEG, metavar="DEG",
                   help="views whose orientations differ by less than this form one session "
                        f"(default {SESSION_TOLERANCE_DEG:g} deg)")
    g.add_argument("--no-refine", action="store_true",
                   help="stop at the paper's linear estimate (no maximum-likelihood refinement)")
    g.add_argument("--distortion", choices=["auto", "none", "radial1", "radial2", "opencv5"],
                   help="lens distortion model (OpenCV convention; default auto: chosen from the data)")
    g.add_argument("--estimate-skew", action="store_true", help="estimate the skew (default: fixed at 0)")
    g.add_argument("--fix", metavar="NAME=VALUE,...",
                   help="known parameters held fixed, e.g. cx=320,cy=240 or principal-point=centre "
                        "(the image centre; needs the image size); names: fx, fy, cx, cy, skew, k1, k2, p1, p2, k3 "
                        "(a distortion coefficient needs --distortion with it); each name once")
    g.add_argument("--square-pixels", action="store_true", help="one focal length: fx = fy")
    g.add_argument("--robot-sigma", "--robot-noise", type=nonnegative_float, metavar="SIGMA",
                   help="robot pose error: per-axis std of each view's flange position error in --unit "
                        "(0: exact positions; turns the robot error on, the other scale estimated)")
    g.add_argument("--robot-sigma-deg", type=nonnegative_float, metavar="DEG",
                   help="robot pose error: per-axis std of each view's flange rotation error in degrees "
                        "(0: exact orientations; turns the robot error on)")
    g.add_argument("--robot-error", action="store_true",
                   help="estimate each view's robot pose error (rotation and position) with the pixel noise and "
                        "include it in the uncertainty (the default: a score test switches each component on only "
                        "when the data show it, and one that absorbs a model misfit is left out with a "
                        "robot_error_misfit warning; docs/uncertainty.md)")
    g.add_argument("--no-robot-error", action="store_true",
                   help="take the robot's poses as exact (the model before issue 22)")
    g.add_argument("--uncertainty", choices=("auto", "model", "robust", "max"), default=None,
                   help="which std to report: 'auto' (default) per parameter the sandwich (cluster-robust) std "
                        "where it is significantly larger than the model-based one, 'model', 'robust' (the "
                        "sandwich), or 'max' (the larger); both are written to calibration.json "
                        "(docs/uncertainty.md §7)")
    g.add_argument("--no-view-field", action="store_true",
                   help="do not test the residuals for an error field alike over each view's points (by default a "
                        "field the test finds is included in the model-based std; docs/uncertainty.md §7.1)")
    g.add_argument("--no-session-error", action="store_true",
                   help="do not test for a robot error common to each session's views (by default, with several "
                        "sessions, one the test finds is included in the std, model-based or sandwich; "
                        "docs/uncertainty.md §7.2)")
    g.add_argument("--keep-pose-outliers", action="store_true",
                   help="keep a view whose image contradicts its recorded pose in the fit, named by a pose_outlier "
                        "warning (default: such views are left out and the calibration refitted without them, at "
                        "most a quarter of the views; pose_left_out names each with the size of its error)")


def _robust(g) -> None:
    rob = g.add_mutually_exclusive_group()
    rob.add_argument("--robust", dest="robust", action="store_true", default=None,
                     help="RANSAC against mismatched tracks (default: on from 8 points)")
    rob.add_argument("--no-robust", dest="robust", action="store_false",
                     help="no RANSAC: every track is used as it comes")
    g.add_argument("--threshold-px", type=positive_float, metavar="PX",
                   help="RANSAC inlier threshold in pixels (default: from the pixel noise estimated from the data)")
    g.add_argument("--one-noise", action="store_true",
                   help="judge the tracks with one pixel noise for all (the chi-square rule); default: the final "
                        "fit judges them again with the spread of their noise that the tracks show, so the "
                        "noisier good tracks stay in")
    g.add_argument("--loss", choices=["linear", "huber", "cauchy"],
                   help="loss of the refinement's residuals (default linear: least squares)")
    g.add_argument("--loss-scale-px", type=positive_float, metavar="PX",
                   help="scale of a robust loss in pixels (default: from the estimated pixel noise)")


# --------------------------------------------------------------------------------------
# (1) checks: no computation
# --------------------------------------------------------------------------------------


def read_truth(path) -> dict:
    """``truth.json`` of a simulated scene (``K`` at least), its ``points`` as one
    ``(n, 3)`` array (parsed by orjson: 10^5 points in 0.05 s, three times faster than
    the standard library, which makes Python floats of every coordinate)."""
    import orjson

    p = existing_file("--truth", path)
    try:
        truth = orjson.loads(p.read_bytes())
        K = np.asarray(truth["K"], dtype=float)
        if "points" in truth:
            truth["points"] = np.asarray(truth["points"], dtype=float).reshape(-1, 3)
    except (ValueError, KeyError, TypeError):  # orjson's JSONDecodeError is a ValueError
        raise OptionError("--truth", f"{str(p)!r} is not a truth.json written by transcalib simulate "
                          "(a JSON object with K, R, points)") from None
    if K.shape != (3, 3):
        raise OptionError("--truth", f"{str(p)!r}: K must be 3x3, got shape {K.shape}")
    return truth


def parse_formats(text: str) -> tuple:
    from ..io.export import FORMATS

    names = tuple(f.strip().lower() for f in text.split(",") if f.strip())
    if names in ((), ("all",)):
        return FORMATS
    unknown = [f for f in names if f not in FORMATS]
    if unknown:
        raise OptionError("--formats", f"unknown format(s) {', '.join(unknown)}; choose among {','.join(FORMATS)}")
    return names


def parse_fix(text: str | None, size) -> dict:
    """``--fix``: ``NAME=VALUE`` pairs, ``principal-point=centre`` for the image centre
    ``((w - 1) / 2, (h - 1) / 2)`` (pixel (0, 0) is the centre of the top-left pixel)."""
    from ..types import FIXABLE

    out = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        name, sep, value = (x.strip().lower() for x in item.partition("="))
        if not sep:
            raise OptionError("--fix", f"expected NAME=VALUE, got {item.strip()!r}")
        given = ("cx", "cy") if name == "principal-point" else (name,)
        twice = [n for n in given if n in out]
        if twice:
            raise OptionError("--fix", f"{twice[0]} is given twice ({twice[0]}={out[twice[0]]:g} and {item.strip()}); "
                              "give each parameter once")
        if name == "principal-point":
            if value not in ("centre", "center"):
                raise OptionError("--fix", f"principal-point takes the value centre, got {value!r}")
            if size is None:
                raise OptionError("--fix", "principal-point=centre needs the image size: give --image-size WxH")
            out.update(cx=(size[0] - 1) / 2, cy=(size[1] - 1) / 2)
            continue
        if name not in FIXABLE:
            raise OptionError("--fix", f"unknown parameter {name!r}; expected some of {', '.join(FIXABLE)}, "
                              "principal-point")
        try:
            out[name] = float(value)
        except ValueError:
            raise OptionError("--fix", f"{name}={value!r} is not a number") from None
        if not np.isfinite(out[name]) or (name in ("fx", "fy") and out[name] <= 0):
            why = "a focal length is a positive number" if name in ("fx", "fy") else "give a finite number"
            raise OptionError("--fix", f"{name}={value} is not a valid value ({why})")
    return out


def build_options(args, size=None):
    """The option dataclasses of the run, checked now (an option that would have no
    effect, such as ``--distortion`` with ``--no-refine``, is an error)."""
    from ..types import CalibrateOptions, RansacOptions, RefineOptions

    fixed = parse_fix(args.fix, size)
    _check_refinement_options(args, fixed)
    if args.one_noise and (args.robust is False or args.threshold_px is not None):
        raise OptionError("--one-noise", "has no effect with --no-robust or --threshold-px (no track is judged "
                                         "by the noise the data show)")
    ransac = RansacOptions(noise_spread=not args.one_noise,
                           **({} if args.threshold_px is None else {"threshold_px": args.threshold_px}))
    if args.no_robot_error and (args.robot_error or args.robot_sigma is not None
                                or args.robot_sigma_deg is not None):
        raise OptionError("--no-robot-error", "contradicts --robot-error / --robot-sigma / --robot-sigma-deg")
    given = {"distortion": args.distortion, "robot_sigma_pos": args.robot_sigma,
             "robot_sigma_deg": args.robot_sigma_deg,
             "robot_error": False if args.no_robot_error else True if args.robot_error else None,
             "loss": args.loss, "uncertainty": args.uncertainty, "view_field": False if args.no_view_field else None,
             "session_error": False if args.no_session_error else None,
             "loss_scale_px": args.loss_scale_px, "estimate_skew": args.estimate_skew or None,
             "square_pixels": args.square_pixels or None, "fix": fixed or None}
    refinement = RefineOptions(**{k: v for k, v in given.items() if v is not None})
    options = CalibrateOptions(refine=not args.no_refine, robust=args.robust, ransac=ransac, refinement=refinement,
                               keep_pose_outliers=args.keep_pose_outliers, unit=args.unit,
                               subset_points=args.subset_points, setup=args.setup,
                               session_tolerance_deg=args.session_tolerance_deg)
    if args.target and not (args.images or args.bag):
        raise OptionError("--target", "applies to --images or --bag only")
    _check_fixed_distortion(fixed, args)
    return options


def _check_refinement_options(args, fixed: dict) -> None:
    """Options of the refinement that ``--no-refine`` would ignore, and ``--estimate-skew``
    against a fixed skew: errors naming the options."""
    if args.no_refine:
        given = [opt for opt, value in (("--distortion", args.distortion), ("--robot-sigma", args.robot_sigma),
                                        ("--robot-sigma-deg", args.robot_sigma_deg),
                                        ("--robot-error", args.robot_error),
                                        ("--uncertainty", args.uncertainty), ("--no-view-field", args.no_view_field),
                                        ("--no-session-error", args.no_session_error),
                                        ("--keep-pose-outliers", args.keep_pose_outliers),
                                        ("--loss", args.loss), ("--loss-scale-px", args.loss_scale_px),
                                        ("--estimate-skew", args.estimate_skew),
                                        ("--square-pixels", args.square_pixels), ("--fix", fixed)) if value]
        if given:
            raise OptionError(" and ".join(given), "would do nothing with --no-refine (the linear "
                              "estimate has no distortion, robot noise, loss or known parameters); drop "
                              f"{'it' if len(given) == 1 else 'them'} or --no-refine")
    if args.estimate_skew and "skew" in fixed:
        raise OptionError("--estimate-skew", f"contradicts --fix skew={fixed['skew']:g}: the skew cannot be both "
                          "estimated and known; drop one")


def _check_fixed_distortion(fixed: dict, args) -> None:
    """A fixed distortion coefficient needs ``--distortion`` naming a model that has it
    (the automatic choice starts without distortion)."""
    from ..geometry.camera import DIST_MODELS

    coeffs = [n for n in fixed if n in DIST_MODELS["opencv5"]]
    if not coeffs or args.no_refine:
        return
    holding = [m for m, names in DIST_MODELS.items() if set(coeffs) <= set(names)]
    model = args.distortion or "auto"
    if model == "auto" or not set(coeffs) <= set(DIST_MODELS[model]):
        now = "the automatic choice starts without distortion" if model == "auto" else \
            f"--distortion {model} has {', '.join(DIST_MODELS[model]) or 'no coefficient'}"
        raise OptionError("--fix", f"{', '.join(coeffs)} is a distortion coefficient and {now}; add --distortion "
                          f"{holding[0]} (or {' or '.join(holding[1:]) or holding[0]})")


def check_all(args) -> dict:
    """Every check of step (1); returns what the later steps need."""
    from ..io import read_poses
    from ..io.folders import check_output_folder
    from .extract import bag_options

    args.unit = _input_unit(args)
    inputs = [p for p in (args.tracks, args.poses, args.truth, args.bag, *(args.images or ())) if p]
    out = check_output_folder(args.out, force=args.force, inputs=inputs)
    plan = {"out": out, "inputs": inputs, "formats": parse_formats(args.formats)}
    build_options(args, args.image_size or (1, 1))  # every option but the image size checked now
    plan["truth"] = read_truth(args.truth) if args.truth else None
    bag = bag_options(args)
    if args.tracks:
        plan["tracks"] = existing_file("--tracks", args.tracks)
    if bag is not None:
        return _plan_bag(args, plan, bag)
    if args.poses is None:
        raise OptionError("--poses", "required with --tracks or --images (the flange pose of each view)")
    poses = read_poses(existing_file("--poses", args.poses), rotation_format=args.rotation_format)
    plan["poses"] = poses
    if plan["truth"] is not None:
        _check_truth(plan["truth"], poses, args)
    plan["sessions"] = _sessions(poses, args.session_tolerance_deg)
    size = args.image_size
    if args.images:
        images = distinct_images([existing_file("--images", p) for p in args.images], "--images")
        plan["images"] = _order_images(images, poses)
        if len(images) != len(poses.views):
            raise OptionError("--images", f"{len(images)} images but {len(poses.views)} poses in {args.poses}; "
                              "give one pose per image")
        actual = _image_size_of(plan["images"][0])
        if size is not None and tuple(size) != actual:
            raise OptionError("--image-size", f"{size[0]}x{size[1]} but the images are {actual[0]}x{actual[1]} px "
                              f"({str(plan['images'][0])!r}); drop --image-size or give their size")
        size = actual
    elif size is None and plan["truth"] is not None and "image_size" in plan["truth"]:
        size = tuple(int(v) for v in plan["truth"]["image_size"])
    plan["image_size"] = size
    plan["options"] = build_options(args, size)
    return plan


def _input_unit(args) -> str:
    """``--unit``: mm by default; with ``--bag`` metres, tf's unit, and nothing else."""
    if not args.bag:
        return args.unit or "mm"
    if args.unit not in (None, "m"):
        raise OptionError("--unit", f"tf lengths are in metres: a --bag run takes --unit m (or none), got {args.unit!r}")
    return "m"


def _plan_bag(args, plan: dict, options) -> dict:
    """The rest of :func:`check_all` for ``--bag``: the bag read (its still images and
    flange poses), the sessions, the image size and the options."""
    from .extract import check_bag_path, read_bag_views

    for option, value in (("--poses", args.poses), ("--rotation-format", args.rotation_format)):
        if value is not None:
            raise OptionError(option, "not with --bag: the flange poses come from the bag's tf")
    check_bag_path(args)
    views = read_bag_views(args, options, args._progress)
    args._progress.log(f"  {views.describe(options)}")
    plan.update(bag=views, poses=views.poses(), images=list(views.images))
    plan["sessions"] = _sessions(plan["poses"], args.session_tolerance_deg)
    plan["image_size"] = args.image_size or (views.images[0].shape[1], views.images[0].shape[0])
    plan["options"] = build_options(args, plan["image_size"])
    return plan


def distinct_images(images: list[Path], option: str) -> list[Path]:
    """``images``, after checking that no two are the same file or the same bytes: the
    robot must move between views, and an image given twice is a slip of the shell."""
    import hashlib

    seen = {}
    for path in images:
        key = hashlib.sha256(path.read_bytes()).hexdigest()
        if key in seen:
            same = "the same file" if seen[key].resolve() == path.resolve() else "identical images"
            raise OptionError(option, f"{str(seen[key])!r} and {str(path)!r} are {same}; each view needs its own "
                              "image, taken after a robot move")
        seen[key] = path
    return images


def check_points_inside(uv, size, source: str) -> None:
    """Every observed pixel inside the image of ``size`` (half a pixel beyond the border
    allowed): a size that contradicts the tracks would silently misplace the principal
    point's prior and the exports' image size."""
    if size is None:
        return
    w, h = size
    finite = np.isfinite(uv[..., 0])
    if not finite.any():
        return
    u, v = uv[..., 0][finite], uv[..., 1][finite]
    lo, hi = (float(u.min()), float(v.min())), (float(u.max()), float(v.max()))
    if lo[0] < -1.0 or lo[1] < -1.0 or hi[0] > w or hi[1] > h:
        raise OptionError(source, f"the image is {w}x{h} px but the tracks reach u {lo[0]:.1f}..{hi[0]:.1f}, "
                          f"v {lo[1]:.1f}..{hi[1]:.1f} px; give the size of the images the tracks come from")


def _check_truth(truth: dict, poses, args) -> None:
    """``--truth`` must be the truth of this scene: its setup, and its translations those
    of ``--poses`` within its robot noise (when it records them)."""
    from ..check.poses import truth_mismatch

    if truth.get("setup", args.setup) != args.setup:
        raise OptionError("--truth", f"{args.truth!r} is the truth of an {truth['setup']} scene, but --setup is "
                          f"{args.setup}; give the truth.json of this scene (or the right --setup)")
    if "T_true" in truth:
        why = truth_mismatch(truth["T_true"], poses.T, float(truth.get("robot_noise") or 0.0), _input_unit(args))
        if why is not None:
            raise OptionError("--truth", f"{args.truth!r} is not the truth of the scene of --poses {args.poses!r}: "
                              f"{why}; give the truth.json written with these poses")


def _sessions(poses, tolerance_deg: float):
    """The views grouped into sessions by orientation (or the ``session`` column) when
    there is more than one session: the hand-eye model; else None (one orientation, or
    none given: the paper's model)."""
    if poses.R is None:
        return None
    from ..handeye.sessions import group_sessions

    grouping = group_sessions(poses.R, tolerance_deg, poses.session)
    return grouping if grouping.n_sessions > 1 else None


def _image_size_of(path: Path) -> tuple[int, int]:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise OptionError("--images", f"{str(path)!r} is not an image OpenCV can read")
    return int(img.shape[1]), int(img.shape[0])


def _order_images(images: list[Path], poses) -> list[Path]:
    """Images in view order: by the ``image`` column of poses.csv when present."""
    if poses.images is None:
        return list(images)
    by_name = {p.name: p for p in images}
    missing = [name for name in poses.images if Path(name).name not in by_name]
    if missing:
        raise OptionError("--images", f"poses.csv names image(s) {missing[:5]} that are not among the images given")
    return [by_name[Path(name).name] for name in poses.images]


# --------------------------------------------------------------------------------------
# (2)-(4) work
# --------------------------------------------------------------------------------------


def track_images(images, target, progress: Progress, poses=None, tolerance_deg: float = SESSION_TOLERANCE_DEG,
                 setup: str = "eye-in-hand"):
    """Tracks from images (paths, or a bag's pixels): ``target="squares"`` finds the
    corners of dark squares; else features, with the robot ``poses`` when given: their
    translations check the epipoles and their orientations group the views into sessions
    and single views, tracked each and linked across orientations
    (:func:`transcalib.images.track`). Eye-to-hand, the camera moves relative to the
    scene the flange carries as the inverted poses say (:func:`~transcalib.pipeline.motion.motion_of`)."""
    images = [p if isinstance(p, np.ndarray) else str(p) for p in images]
    if target == "squares":
        from ..images import track_squares

        return track_squares(images, progress=progress)
    from ..images import track

    if poses is None:
        return track(images, progress=progress)
    from ..pipeline.motion import motion_of

    motion = motion_of(poses, setup, tolerance_deg)
    return track(images, progress=progress, T=motion.T, rotations=motion.R, sessions=poses.session,
                 session_tolerance_deg=tolerance_deg)


def _observations(args, plan, folder, progress: Progress):
    """``(uv, point_ids, colors, view_names)`` from the images (their tracks written to
    ``folder``) or the tracks file; the tracks checked against ``--image-size``."""
    from .. import io as tio
    from ..io.ids import point_id_array

    poses = plan["poses"]
    if args.images or args.bag:
        progress.log(f"tracking {len(plan['images'])} images ...")
        tracks = track_images(plan["images"], args.target, progress, poses, args.session_tolerance_deg, args.setup)
        ids = point_id_array(tracks.ids)
        tio.write_tracks_csv(folder.file("tracks.csv"), tracks.uv, ids, poses.views)
        names = plan["bag"].names if args.bag else [p.name for p in plan["images"]]
        return tracks.uv, ids, tracks.colors, names
    uv, ids = tio.tracks_to_uv(plan["tracks"], poses)
    check_points_inside(uv, plan["image_size"], "--image-size" if args.image_size else "--truth")
    names = poses.images or [f"view{v}.png" for v in poses.views]
    return uv, ids, None, names


def run(args) -> int:
    """Check, then read / track, calibrate and write the output folder (complete or
    absent: :mod:`transcalib.io.folders`), then print the summary."""
    from ..io.folders import output_folder, replacing, uninterrupted

    t_start = time.perf_counter()
    progress = args._progress = Progress(args.quiet)
    plan = check_all(args)  # (1): before importing the numerics
    # heavy imports while we read / track (the pipeline's half second among them); a
    # tracks file's reader needs pyarrow.compute, writing tracks.csv pyarrow.csv alone
    reader = ("pyarrow.compute",) if plan.get("tracks") else ()
    import_in_background("scipy.special", "transcalib.pipeline.run", "pyarrow.csv", *reader)
    note = replacing(plan["out"])
    if note:
        progress.log(note)
    with output_folder(plan["out"], command=NAME, force=args.force, inputs=plan["inputs"]) as folder:
        worker = _start_report_worker(plan["formats"])
        try:  # the worker writes into the folder: stopped before the folder is kept or removed
            result = _work(args, plan, folder, progress, t_start, worker)
        finally:
            if worker is not None:
                uninterrupted(worker.close)  # a second Ctrl-C must not leave it writing
    result["timings"]["total_s"] = time.perf_counter() - t_start
    return _print_result(args, plan, result)


def _start_report_worker(formats):
    """A process drawing the report on the other core (it imports matplotlib while we
    read and calibrate), or None when no report is asked for."""
    if "report" not in formats:
        return None
    from ..report.worker import ReportWorker

    return ReportWorker()


def _work(args, plan, folder, progress: Progress, t_start: float, worker) -> dict:
    """Steps (2)-(4) of :func:`run` into ``folder`` (an :class:`~transcalib.io.folders.OutputFolder`);
    the report is drawn by ``worker`` when given. Returns what the summary needs."""
    t_read = time.perf_counter()
    uv, point_ids, colors, view_names = _observations(args, plan, folder, progress)
    t_imports = time.perf_counter()
    progress.log(f"read {uv.shape[1]} points in {uv.shape[0]} views ({t_imports - t_read:.2f} s)")
    from ..io.export import ExportContext, export_calibration  # after the reading: see import_in_background
    from ..pipeline.run import calibrate
    from .handeye import write_hand_eye
    opts = plan["options"]
    memory = {"after_read": _peak_rss_gib()}
    t_cal = time.perf_counter()
    if plan["sessions"] is not None:
        progress.log(f"{plan['sessions'].n_sessions} flange orientations in {uv.shape[0]} views ({opts.setup})")
    cal = calibrate(uv, plan["poses"], setup=opts.setup, session_tolerance_deg=opts.session_tolerance_deg,
                    refine=opts.refine, robust=opts.robust, ransac=opts.ransac,
                    refinement=opts.refinement if opts.refine else None, image_size=plan["image_size"],
                    keep_pose_outliers=opts.keep_pose_outliers, unit=args.unit, subset_points=opts.subset_points,
                    rng=args.seed, progress=progress)
    t_write = time.perf_counter()
    memory["after_calibrate"] = _peak_rss_gib()
    inputs = {"tracks": None if args.tracks is None else str(args.tracks),
              "poses": None if args.poses is None else str(args.poses),
              **({} if not args.bag else {"bag": str(args.bag), "bag_images": plan["bag"].counts()}),
              "images": None if not args.images else [str(p) for p in plan["images"]],
              "view_ids": list(plan["poses"].views), "n_observations": int(np.isfinite(uv[..., 0]).sum()),
              "image_size_from": _size_source(args, plan)}
    ctx = ExportContext(point_ids=point_ids, view_names=view_names, colors=colors, uv=uv, inputs=inputs,
                        truth=plan["truth"])
    write_timings = {}
    written = export_calibration(cal, folder.path, plan["formats"], ctx, timings=write_timings, report_worker=worker)
    if cal.hand_eye is not None:
        written += write_hand_eye(cal.hand_eye, folder.path, args.unit)
    if args.images or args.bag:
        written.insert(0, folder.path / "tracks.csv")
    notes = _size_notes(cal, uv, plan)
    for note in notes:
        progress.log(f"note: {note}")
    memory["after_write"] = _peak_rss_gib()
    timings = {"start_s": t_read - t_start, "read_s": t_imports - t_read, "imports_s": t_cal - t_imports,
               "calibrate_s": t_write - t_cal, "write_s": time.perf_counter() - t_write}
    return {"cal": cal, "uv": uv, "point_ids": point_ids, "written": folder.final_paths(written), "notes": notes,
            "timings": timings, "write_timings": write_timings, "memory": memory}


def _print_result(args, plan, r: dict) -> int:
    """The summary (text or ``--json``) of a written run; returns the exit status."""
    from ..io.folders import MANIFEST
    from .handeye import hand_eye_text
    from .summary import summary_json, summary_text

    cal, timings = r["cal"], r["timings"]
    simulated_ids = r["point_ids"] if args.tracks else None
    status = EXIT_WARNINGS if args.strict and cal.diagnostics else EXIT_OK
    if args.json:
        summary = summary_json(cal, args.unit, plan["truth"], simulated_ids, r["uv"])
        summary.update(status="warnings" if cal.diagnostics else "ok", exit_code=status,
                       outputs=[str(p) for p in r["written"]], run_timings_s=timings,
                       write_timings_s=r["write_timings"], memory_peak_gib=r["memory"], notes=r["notes"])
        print_json(summary)
        return status
    print(summary_text(cal, args.unit, plan["truth"], simulated_ids, r["uv"]))
    if cal.hand_eye is not None:
        print(hand_eye_text(cal.hand_eye, args.unit, plan["truth"]))
    print(f"\nWrote {len(r['written'])} files and {MANIFEST} to {plan['out']} in {timings['total_s']:.2f} s "
          f"(checks {timings['start_s']:.2f} s, read {timings['read_s']:.2f} s, "
          f"imports {timings['imports_s']:.2f} s, calibrate {timings['calibrate_s']:.2f} s, "
          f"write {timings['write_s']:.2f} s)")
    return status


def _peak_rss_gib() -> float:
    """Peak resident memory of this process so far (GiB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def _size_notes(cal, uv, plan) -> list[str]:
    """What the outputs could not know: the image size, without images, ``--image-size``
    or ``--truth``, for the formats that state it."""
    if plan["image_size"] is not None or not {"opencv", "ros", "colmap"} & set(plan["formats"]):
        return []
    from ..io.formats import image_size_or_extent

    w, h = image_size_or_extent(cal, uv)
    return [f"the image size is unknown (tracks only): camera.yaml, camera_info.yaml and COLMAP state {w}x{h}, the "
            "extent of the tracked pixels; give --image-size WIDTHxHEIGHT for the true size"]


def _size_source(args, plan) -> str | None:
    if args.image_size:
        return "--image-size"
    if args.images or args.bag:
        return "images"
    if plan["image_size"] is not None:
        return "--truth"
    return None
