"""``transcalib validate``: a saved calibration checked on views it never saw.

The new views' tracks name the calibration's points by their ids (track every image,
those of the calibration and the new ones, in one ``transcalib track`` run, then
calibrate on some views and validate on the others). The numerics are
:func:`transcalib.validate_views` (``pipeline/validate.py``).
"""

from __future__ import annotations

import numpy as np

from .common import EXIT_OK, EXIT_WARNINGS, OptionError, add_output_options, existing_file, print_json

NAME = "validate"
HELP = "predict new views (tracks and poses) with a saved calibration and compare with what they show"


def add_parser(sub) -> None:
    v = sub.add_parser(NAME, help=HELP, description=HELP)
    g = v.groups()
    i = g["inputs"]
    i.add_argument("--calibration", required=True, metavar="DIR", help="the --out folder of calibrate")
    i.add_argument("--tracks", required=True, metavar="FILE",
                   help="tracks of the new views: view,point,u,v (.csv, .npz, .parquet), point ids those of the "
                        "calibration's tracks")
    i.add_argument("--poses", required=True, metavar="FILE",
                   help="poses of the new views (as for calibrate; the calibration's unit and setup)")
    i.add_argument("--rotation-format", default=None, choices=["quaternion", "rotvec", "ur", "euler_zyx", "kuka"],
                   help="orientation columns of --poses (default: found from the columns)")
    o = g["outputs"]
    add_output_options(o, folder=False, quiet=False)
    o.add_argument("--strict", action="store_true",
                   help="exit with status 4 when the new views are predicted significantly worse than the "
                        "calibration's covariance says")
    v.set_defaults(func=run)


def run(args) -> int:
    from ..io import read_poses, tracks_to_uv
    from ..io.calibration_file import load_saved

    saved = load_saved(_folder(args.calibration))
    poses = read_poses(existing_file("--poses", args.poses), rotation_format=args.rotation_format)
    uv, ids = tracks_to_uv(existing_file("--tracks", args.tracks), poses)
    cal = saved.calibration
    uv = _aligned(uv, ids, saved.point_ids, cal.n_points, args.tracks)
    from ..pipeline.validate import validate_views

    result = validate_views(cal, uv, poses)
    unit = saved.document.get("unit") or "units"
    status = EXIT_WARNINGS if args.strict and result.flagged else EXIT_OK
    if args.json:
        print_json({"status": "warnings" if result.diagnostics else "ok", "exit_code": status, "unit": unit,
                    **result.as_dict()})
    else:
        print(_text(result, unit))
    return status


def _folder(path: str):
    from pathlib import Path

    p = Path(path)
    if not p.exists():
        raise OptionError("--calibration", f"{str(p)!r} does not exist; give the --out folder of calibrate")
    return p


def _aligned(uv: np.ndarray, ids: np.ndarray, cal_ids, n_points: int, tracks) -> np.ndarray:
    """The new views' pixels in the calibration's point order ``(n_views, n_points, 2)``."""
    cal_ids = np.arange(n_points) if cal_ids is None else np.asarray(cal_ids)
    a, b = (cal_ids, ids) if cal_ids.dtype.kind == np.asarray(ids).dtype.kind else (cal_ids.astype(str),
                                                                                     np.asarray(ids).astype(str))
    _, i_cal, i_new = np.intersect1d(a, b, return_indices=True)
    if not len(i_cal):
        raise OptionError("--tracks", f"none of the {len(ids)} point ids of {str(tracks)!r} is a point of the "
                          "calibration; track the new images together with the calibration's (one transcalib "
                          "track run) so that the ids agree")
    out = np.full((uv.shape[0], n_points, 2), np.nan)
    out[:, i_cal] = uv[:, i_new]
    return out


def _text(result, unit: str) -> str:
    """Per view and overall figures, the fitted offset, the comparison, warnings."""
    lines = [f"{len(result.per_view)} new view(s), {result.n_points} observations of the calibration's points",
             "", "view          RMS px   median px   points"]
    for v in result.per_view:
        rms = "-" if v["rms_px"] is None else f"{v['rms_px']:.4f}"
        med = "-" if v["median_px"] is None else f"{v['median_px']:.4f}"
        lines.append(f"{v['view']:<12} {rms:>7}   {med:>9}   {v['n_points']:>6}")
    lines.append(f"{'all':<12} {result.rms_px:>7.4f}   {result.median_px:>9.4f}   {result.n_points:>6}"
                 f"   (max {result.max_px:.4g} px)")
    if result.noise_px is not None:
        lines.append(f"The new views' tracks by themselves (each view's pose refitted): noise {result.noise_px:.4f} px "
                     "per coordinate")
    lines.append(f"The calibration's covariance predicts: RMS {result.predicted_rms_px:.4f} px, median "
                 f"{result.predicted_median_px:.4f} px (sign test p = {result.p_value:.2g})")
    for f in result.fitted:
        lines.append(f"Fitted on the new views (left undetermined by the calibration): {f['name']} = "
                     f"{f['value']:.4g} {unit}" + ("" if f["determined"] else " (only partly determined)"))
    lines += [f"Warning: {d}" for d in result.diagnostics] or ["No warnings."]
    return "\n".join(lines)
