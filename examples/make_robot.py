"""Render the robot examples of issue 20: ``examples/robot_mixed/`` and ``examples/eye_to_hand/``.

:func:`transcalib.synth.robot.robot_scene` at 640 x 480: one 3-D pure-translation session of
6 views plus 6 single views turned 15-45 deg from it, the scene 0.5-1 m from the camera,
the camera effects on (mild barrel distortion, vignetting, per-view exposure, shot and read
noise, a specular highlight, JPEG 90), no robot error.

- ``robot_mixed/`` eye-in-hand: the camera on the flange (``R_X, t_X`` of
  :mod:`transcalib.handeye.simulate`) looks down at a work cell (a textured table top, a
  fine-textured mat, four textured boxes, textured walls; base frame, z up, mm).
- ``eye_to_hand/``: a camera fixed beside the robot watches a textured plate and box
  carried by the flange, in front of a static textured wall.

Each folder gets ``view00.jpg`` ... ``view11.jpg`` (the JPEG is the camera's: the rendered
views are compressed once, at quality 90, when written), ``poses.csv``
(``view,x,y,z,qx,qy,qz,qw,session,image``: flange poses in the base frame, mm, ROS
quaternions; the reader of ``transcalib calibrate --poses``) and ``truth.json``
(:meth:`RobotRendered.truth_dict`: ``R_<frame>_camera``, ``t_<frame>_camera`` named as in
the ``hand_eye.json`` that ``calibrate`` writes, K, dist, image size, unit, sessions, the
exact box and plate corners). Deterministic: a second run writes the same files.

    python examples/make_robot.py [OUT_ROOT]
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import cv2

from transcalib.io import write_poses_csv
from transcalib.synth.robot import robot_scene
from transcalib.synth.robot_layout import preset_degradations

IMAGE_SIZE = (640, 480)
#: Folder, setup and seed of each example.
EXAMPLES = (("robot_mixed", "eye-in-hand", 2026), ("eye_to_hand", "eye-to-hand", 2027))
SCENES = {"eye-in-hand": "work cell: textured table top, mat and four boxes, textured walls; base frame z up, mm",
          "eye-to-hand": "a textured plate and box carried by the flange (flange frame, mm) before a static "
                         "textured wall (base frame)"}
MODELS = {"eye-in-hand": "x ~ K (R_i R_X)^T (X - T_i - R_i t_X); R_i, T_i the flange pose in the base frame",
          "eye-to-hand": "x ~ K R_X^T (R_i P + T_i - t_X); R_X, t_X the camera in the base frame, P in the flange "
                         "frame"}


def example_scene(setup: str, seed: int, images: bool = True):
    """The :class:`~transcalib.synth.robot.RobotRendered` of one example (``images=False``:
    its poses and truth only)."""
    degrade = replace(preset_degradations(IMAGE_SIZE), jpeg_quality=None)  # JPEG when written
    return robot_scene(setup, image_size=IMAGE_SIZE, degrade=degrade, rng=seed, images=images)


def write_example(out: Path, setup: str, seed: int) -> Path:
    """Render one example into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    r = example_scene(setup, seed)
    quality = preset_degradations(IMAGE_SIZE).jpeg_quality
    names = [f"view{i:02d}.jpg" for i in range(r.n_views)]
    for name, img in zip(names, r.images):
        if not cv2.imwrite(str(out / name), img, [cv2.IMWRITE_JPEG_QUALITY, quality]):
            raise OSError(f"could not write {out / name}")
    write_poses_csv(out / "poses.csv", r.T, R=r.R, session=[str(s) for s in r.session_of_view], images=names)
    truth = r.truth_dict()
    truth.update(scene=SCENES[setup], model=MODELS[setup], seed=seed, jpeg_quality=quality,
                 degradations=list(r.meta["degrade"]) + ["jpeg_quality"], robot_error="none")
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return out


def main(root: str | Path | None = None) -> list[Path]:
    root = Path(root) if root is not None else Path(__file__).resolve().parent
    return [write_example(root / name, setup, seed) for name, setup, seed in EXAMPLES]


if __name__ == "__main__":
    for p in main(sys.argv[1] if len(sys.argv) > 1 else None):
        print(p)
