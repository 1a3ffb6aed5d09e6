"""``transcalib calibrate`` with flange orientations: the hand-eye pose's outputs and summary lines."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def write_hand_eye(he, out: Path, unit: str) -> list[Path]:
    """``hand_eye.json`` (the transform, its std, undetermined directions, 4x4, tf) and
    ``hand_eye.yaml`` (easy_handeye's layout), atomically."""
    from ..handeye.export import easy_handeye_yaml, hand_eye_json
    from ..io import atomic_write, write_json

    write_json(out / "hand_eye.json", hand_eye_json(he, unit=unit))
    with atomic_write(out / "hand_eye.yaml", newline="\n", encoding="utf-8") as fh:
        fh.write(easy_handeye_yaml(he.R, he.t, unit=unit, eye_on_hand=he.setup == "eye-in-hand"))
    return [out / "hand_eye.json", out / "hand_eye.yaml"]


def hand_eye_text(he, unit: str, truth: dict | None) -> str:
    """The hand-eye lines of the summary (errors against ``truth`` when it has them)."""
    from ..geometry.rotation import rotation_angle_deg

    f, t, sd = he.frame, he.t, he.t_std
    title = "Camera in the flange (hand-eye)" if f == "flange" else "Camera in the robot base (eye-to-hand)"
    lines = ["", f"{title}, {he.n_sessions} session(s) of orientation:", f"  R_{f}_camera:"]
    lines += ["    [" + "  ".join(f"{x:+.6f}" for x in row) + "]" for row in he.R]
    undet = np.asarray(he.undetermined).reshape(3, -1)
    lines.append(f"  t_{f}_camera [{unit}]: " + ", ".join(f"{v:+.3f} ± {s:.3g}" for v, s in zip(t, sd))
                 + (f"  ({3 - undet.shape[1]} of 3 directions determined)" if undet.shape[1] else ""))
    if truth is not None and f"R_{f}_camera" in truth:
        Rt, tt = np.asarray(truth[f"R_{f}_camera"]), np.asarray(truth[f"t_{f}_camera"])
        tt = tt - undet @ (undet.T @ tt)  # compare the determined part
        lines.append(f"  error vs truth: R {rotation_angle_deg(he.R @ Rt.T):.4f} deg, "
                     f"t (determined part) {np.linalg.norm(t - tt):.3f} {unit}")
    lines += [f"  note: {n}" for n in he.notes]
    return "\n".join(lines)
