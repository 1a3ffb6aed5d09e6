"""The ``transcalib`` command: ``calibrate``, ``simulate``, ``track``.

Errors in the input are printed as one clear message (no traceback) and exit with
status 2; an interrupted run exits with 130. Output files are written atomically.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from .. import __version__
from .. import io as tio
from ..types import RansacOptions, RefineOptions, TranscalibError
from .plan import add_parser as add_plan_parser

EXIT_INPUT = 2


def _log(quiet: bool):
    def log(msg: str) -> None:
        if not quiet:
            print(msg, file=sys.stderr, flush=True)

    return log


# --------------------------------------------------------------------------------------
# calibrate
# --------------------------------------------------------------------------------------


def _calibration_json(cal, point_ids, unit: str, views) -> dict:
    r2 = np.sum(cal.residuals_px**2, axis=2)  # (n_views, n_points)
    seen = np.isfinite(r2)
    per_point = np.sqrt(np.where(seen, r2, 0).sum(axis=0) / np.maximum(seen.sum(axis=0), 1))
    per_point[seen.sum(axis=0) == 0] = np.nan
    out = {
        "transcalib_version": __version__,
        "units": unit,
        "n_views": cal.n_views,
        "n_points": cal.n_points,
        "K": cal.K,
        "R": cal.R,
        "dist": cal.dist,
        "dist_model": cal.dist_model,
        "dist_opencv": cal.dist_opencv,
        "rms_px": cal.rms_px,
        "std": cal.std,
        "param_names": list(cal.param_names),
        "cov": cal.cov,
        "diagnostics": [str(d) for d in cal.diagnostics],
        "diagnostic_codes": [getattr(d, "code", "") for d in cal.diagnostics],
        "views": views,
        "T": cal.T,
        "point_ids": point_ids,
        "points": cal.X,
        "points_std": cal.X_std,
        "inliers": None if cal.inliers is None else cal.inliers.astype(bool),
        "point_rms_px": per_point,
        "residuals_px": cal.residuals_px,
        "info": {k: v for k, v in cal.info.items()},
    }
    if cal.linear is not None:
        out["linear"] = {"K": cal.linear.K, "R": cal.linear.R, "singular_values": cal.linear.singular_values}
    return out


def _fmt_param(cal, name: str, value: float, unit: str = "") -> str:
    std = cal.std.get(name)
    pm = f" ± {std:<9.3g}" if std is not None and np.isfinite(std) else " " * 12
    return f"{name:>5} = {value:12.4f}{pm}{unit}"


def _summary(cal, unit: str, truth: dict | None, point_ids: list) -> str:
    K = cal.K
    values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "skew": K[0, 1]}
    true_vals = None
    if truth is not None:
        Kt = np.asarray(truth["K"], float)
        true_vals = {"fx": Kt[0, 0], "fy": Kt[1, 1], "cx": Kt[0, 2], "cy": Kt[1, 2], "skew": Kt[0, 1]}
    stages = " → ".join(cal.info.get("stages", []))
    lines = [f"transcalib: {cal.n_points} points in {cal.n_views} views ({stages})", "", "Intrinsics [px]:"]
    for name, v in values.items():
        if name == "skew" and "skew" not in cal.std and v == 0:
            continue
        line = "  " + _fmt_param(cal, name, v)
        if true_vals is not None:
            line += f" truth {true_vals[name]:12.4f}   error {v - true_vals[name]:+.4f}"
        lines.append(line)
    if cal.dist.size:
        lines.append(f"Distortion ({cal.dist_model}, OpenCV order):")
        for name, v in zip(["k1", "k2", "p1", "p2", "k3"], cal.dist):
            lines.append("  " + _fmt_param(cal, name, v))
    lines.append("Rotation R (robot → camera):")
    for row in cal.R:
        lines.append("  [" + "  ".join(f"{x:+.6f}" for x in row) + "]")
    if "rx" in cal.std:
        lines.append("  std of rotation [deg]: " + ", ".join(f"{k} {cal.std[k]:.3g}" for k in ("rx", "ry", "rz")))
    if truth is not None:
        from ..geometry.rotation import rotation_angle_deg

        lines.append(f"  angle to truth: {rotation_angle_deg(cal.R @ np.asarray(truth['R']).T):.4f} deg")
    n_rec = int(np.isfinite(cal.X[:, 0]).sum())
    lines.append(f"Reprojection RMS: {cal.rms_px:.4f} px; {n_rec} points reconstructed [{unit}]")
    if cal.inliers is not None:
        lines.append(f"Inliers: {int(cal.inliers.sum())} of {cal.n_points} points")
    if truth is not None and "points" in truth and point_ids and all(str(p).isdigit() for p in point_ids):
        Xt = np.asarray(truth["points"], float)
        idx = np.array([int(p) for p in point_ids])
        if idx.size and idx.max() < len(Xt):  # simulated ids index the true points
            err = np.linalg.norm(cal.X - Xt[idx], axis=1)
            lines.append(f"Point error vs truth: median {np.nanmedian(err):.4g} {unit}, max {np.nanmax(err):.4g} {unit}")
    if cal.diagnostics:
        lines.append("Warnings:")
        lines += [f"  - {d}" for d in cal.diagnostics]
    else:
        lines.append("No warnings.")
    return "\n".join(line.rstrip() for line in lines)


def cmd_calibrate(args) -> int:
    from ..pipeline import calibrate

    log = _log(args.quiet)
    t_start = time.perf_counter()
    poses = tio.read_poses(args.poses)
    out = Path(args.out)
    if args.images:
        images = _order_images(args.images, poses)
        log(f"tracking {len(images)} images ...")
        tracks = _track_images(images, args.target, args.quiet)
        uv, point_ids = tracks.uv, [str(i) for i in tracks.ids]
        if uv.shape[0] != len(poses.views):
            raise TranscalibError(f"{uv.shape[0]} images but {len(poses.views)} poses; give one pose per image")
        tio.write_tracks_csv(out / "tracks.csv", uv, point_ids, poses.views)
    elif args.tracks:
        uv, point_ids = tio.tracks_to_uv(args.tracks, poses)
    else:
        raise TranscalibError("give --tracks tracks.csv or --images IMAGE ...")
    log(f"read {uv.shape[1]} points in {uv.shape[0]} views")

    def progress(stage, info):
        log(f"  {stage}: " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in info.items()))

    refinement = RefineOptions(distortion=args.distortion, estimate_skew=args.estimate_skew, sigma_T=args.robot_sigma,
                               loss=args.loss, loss_scale_px=args.loss_scale_px)
    cal = calibrate(
        uv, poses.T,
        refine=not args.no_refine,
        robust=args.robust,
        ransac=RansacOptions(threshold_px=args.threshold_px) if args.threshold_px is not None else None,
        refinement=refinement if not args.no_refine else None,
        quaternions=poses.quaternions,
        unit=args.unit,
        rng=args.seed,
        progress=progress,
    )
    truth = json.loads(Path(args.truth).read_text()) if args.truth else None
    tio.write_json(out / "calibration.json", _calibration_json(cal, point_ids, args.unit, poses.views))
    tio.write_points_csv(out / "points.csv", point_ids, cal.X, cal.X_std, cal.inliers)
    # simulated tracks carry the true point indices as ids; image tracks do not
    print(_summary(cal, args.unit, truth, point_ids if args.tracks else []))
    print(f"\nWrote {out / 'calibration.json'} and {out / 'points.csv'}" + (f" and {out / 'tracks.csv'}" if args.images else "")
          + f" in {time.perf_counter() - t_start:.2f} s")
    return 0


def _track_images(images, target: str | None, quiet: bool):
    """Tracks from images: ``target="squares"`` finds the corners of dark squares."""
    progress = None if quiet else _progress_printer()
    if target == "squares":
        from ..images import track_squares

        return track_squares(images, progress=progress)
    from ..images import track

    return track(images, progress=progress)


def _progress_printer():
    """Progress of the image front-end on stderr, about four lines per stage."""
    def show(stage: str, done: int, total: int) -> None:
        if done == total or done % -(-total // 4) == 0:  # every ceil(total / 4) steps
            print(f"  tracking, {stage}: {done}/{total}", file=sys.stderr, flush=True)

    return show


def _order_images(images: list[str], poses) -> list[str]:
    """Images in view order: by the ``image`` column of poses.csv when present."""
    if poses.images is None:
        return list(images)
    by_name = {Path(p).name: p for p in images}
    missing = [name for name in poses.images if Path(name).name not in by_name]
    if missing:
        raise TranscalibError(f"poses.csv names image(s) {missing[:5]} that are not among the --images given")
    return [by_name[Path(name).name] for name in poses.images]


# --------------------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------------------


def cmd_simulate(args) -> int:
    from ..synth import simulate

    if args.preset == "paper":
        scene = simulate.paper_scene(noise_px=args.noise_px, robot_noise=args.robot_noise, rng=args.seed)
    else:
        scene = simulate.random_scene(
            args.points, args.views, planar=args.planar, noise_px=args.noise_px, robot_noise=args.robot_noise,
            missing=args.missing, rng=args.seed,
        )
    out = Path(args.out)
    tio.write_tracks_csv(out / "tracks.csv", scene.uv)
    tio.write_poses_csv(out / "poses.csv", scene.T)
    tio.write_json(out / "truth.json", scene.truth_dict())
    print(f"Wrote {out / 'tracks.csv'}, {out / 'poses.csv'} and {out / 'truth.json'}: "
          f"{scene.n_points} points in {scene.n_views} views ({args.preset} preset, "
          f"{args.noise_px} px noise, {args.robot_noise} {scene.unit} robot noise)")
    return 0


# --------------------------------------------------------------------------------------
# track
# --------------------------------------------------------------------------------------


def cmd_track(args) -> int:
    tracks = _track_images(args.images, args.target, args.quiet)
    tio.write_tracks_csv(args.output, tracks.uv, [str(i) for i in tracks.ids])
    n_obs = int(np.isfinite(tracks.uv[..., 0]).sum())
    print(f"Wrote {args.output}: {tracks.uv.shape[1]} tracks, {n_obs} observations in {tracks.uv.shape[0]} views")
    return 0


# --------------------------------------------------------------------------------------


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="transcalib",
        description="Camera calibration and metric reconstruction from known robot translations.",
    )
    p.add_argument("--version", action="version", version=f"transcalib {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    c = sub.add_parser("calibrate", help="calibrate from tracks (or images) and robot poses")
    src = c.add_mutually_exclusive_group(required=True)
    src.add_argument("--tracks", help="tracks.csv: view,point,u,v")
    src.add_argument("--images", nargs="+", metavar="IMAGE", help="images in view order (or named in poses.csv)")
    c.add_argument("--poses", required=True, help="poses.csv: view,x,y,z[,qx,qy,qz,qw][,image]")
    c.add_argument("--out", required=True, help="output folder (created if missing)")
    c.add_argument("--unit", default="mm", help="length unit of the poses; every output length is in it (default mm)")
    c.add_argument("--target", choices=["squares"], help="with --images: detect the corners of dark squares")
    c.add_argument("--no-refine", action="store_true", help="stop at the paper's linear estimate")
    rob = c.add_mutually_exclusive_group()
    rob.add_argument("--robust", dest="robust", action="store_true", default=None,
                     help="RANSAC against mismatched tracks (default: on from 8 points)")
    rob.add_argument("--no-robust", dest="robust", action="store_false")
    c.add_argument("--threshold-px", type=float, default=None,
                   help="RANSAC inlier threshold in pixels (default: from the pixel noise estimated from the data)")
    c.add_argument("--distortion", choices=["none", "radial2", "opencv5"], default="none",
                   help="lens distortion model (OpenCV convention; default none)")
    c.add_argument("--estimate-skew", action="store_true", help="estimate the skew (default: fixed at 0)")
    c.add_argument("--robot-sigma", type=float, default=None,
                   help="robot translation precision in --unit: treat translations as noisy measurements")
    c.add_argument("--loss", choices=["linear", "huber", "cauchy"], default="linear", help="refinement loss")
    c.add_argument("--loss-scale-px", type=float, default=None,
                   help="scale of a robust loss in pixels (default: from the estimated pixel noise)")
    c.add_argument("--truth", help="truth.json of a simulated scene: print the errors")
    c.add_argument("--seed", type=int, default=0, help="random seed of RANSAC (default 0: repeatable)")
    c.add_argument("--quiet", action="store_true", help="no progress messages")
    c.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("simulate", help="write a synthetic scene: tracks.csv, poses.csv, truth.json")
    s.add_argument("--preset", choices=["paper", "random"], default="paper")
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--points", type=int, default=100, help="random preset: number of points")
    s.add_argument("--views", type=int, default=4, help="random preset: number of views (>= 4)")
    s.add_argument("--planar", action="store_true", help="random preset: points on a plane")
    s.add_argument("--missing", type=float, default=0.0, help="random preset: fraction of dropped observations")
    s.add_argument("--noise-px", type=float, default=0.0, help="pixel noise std (default 0)")
    s.add_argument("--robot-noise", type=float, default=0.0, help="robot translation noise std (default 0)")
    s.add_argument("--seed", type=int, default=0)
    s.set_defaults(func=cmd_simulate)

    t = sub.add_parser("track", help="track points through images taken at translated positions")
    t.add_argument("images", nargs="+", metavar="IMAGE")
    t.add_argument("-o", "--output", required=True, help="tracks.csv to write")
    t.add_argument("--target", choices=["squares"], help="detect the corners of dark squares")
    t.add_argument("--quiet", action="store_true")
    t.set_defaults(func=cmd_track)
    add_plan_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    for stream in (sys.stdout, sys.stderr):  # "±" and "→" on a terminal that is not UTF-8
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="replace")
    args = _parser().parse_args(argv)
    try:
        return args.func(args)
    except TranscalibError as exc:
        print(f"transcalib: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("transcalib: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into a command that stopped reading (head)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
