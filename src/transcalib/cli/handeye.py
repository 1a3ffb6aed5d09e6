"""``transcalib calibrate`` with several sessions: the hand-eye model's call and outputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def calibrate_hand_eye(uv, plan, opts, args, progress):
    """:func:`transcalib.handeye.calibrate_sessions` with the command's options."""
    from ..handeye.calibrate import calibrate_sessions

    poses, grouping, r = plan["poses"], plan["sessions"], opts.refinement
    progress.log(f"{grouping.n_sessions} sessions (orientations) in {poses.n_views} views: hand-eye model")
    he = calibrate_sessions(uv, poses.T, poses.R, session_of_view=grouping.session_of_view,
                            tolerance_deg=grouping.tolerance_deg, distortion=r.distortion, fix=dict(r.fix),
                            square_pixels=r.square_pixels, estimate_skew=r.estimate_skew, sigma_T=r.sigma_T,
                            robust=opts.robust is not False, ransac=opts.ransac, rng=args.seed)
    progress.stage("hand-eye", {"sessions": grouping.n_sessions, "rms_px": he.calibration.rms_px})
    return he


def write_hand_eye(he, out: Path, unit: str) -> list[Path]:
    """``hand_eye.json`` (the transform, its std, undetermined directions, 4x4, tf) and
    ``hand_eye.yaml`` (easy_handeye's layout), atomically."""
    from ..handeye.export import easy_handeye_yaml, hand_eye_json
    from ..io import atomic_write, write_json

    write_json(out / "hand_eye.json", hand_eye_json(he, unit=unit))
    with atomic_write(out / "hand_eye.yaml", newline="\n", encoding="utf-8") as fh:
        fh.write(easy_handeye_yaml(he.R_flange_camera, he.t_flange_camera, unit=unit))
    return [out / "hand_eye.json", out / "hand_eye.yaml"]


def hand_eye_text(he, unit: str, truth: dict | None) -> str:
    """The hand-eye lines of the summary (errors against ``truth`` when it has them)."""
    from ..geometry.rotation import rotation_angle_deg

    t, sd = he.t_flange_camera, he.t_flange_camera_std
    lines = ["", "Camera in the flange (hand-eye):", "  R_flange_camera:"]
    lines += ["    [" + "  ".join(f"{x:+.6f}" for x in row) + "]" for row in he.R_flange_camera]
    lines.append(f"  t_flange_camera [{unit}]: " + ", ".join(f"{v:+.3f} ± {s:.3g}" for v, s in zip(t, sd)))
    if truth is not None and "R_flange_camera" in truth:
        Rt, tt = np.asarray(truth["R_flange_camera"]), np.asarray(truth["t_flange_camera"])
        undet = np.asarray(he.undetermined).reshape(3, -1)
        tt = tt - undet @ (undet.T @ tt)  # compare the determined part
        lines.append(f"  error vs truth: R {rotation_angle_deg(he.R_flange_camera @ Rt.T):.4f} deg, "
                     f"t (determined part) {np.linalg.norm(t - tt):.3f} {unit}")
    lines += [f"  note: {n}" for n in he.notes]
    return "\n".join(lines)
