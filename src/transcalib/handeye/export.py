"""The hand-eye transform in the formats robot software reads.

``T_flange_camera = [[R_X, t_X], [0, 1]]`` maps camera coordinates to flange coordinates
(the camera pose in the flange frame; ROS ``tf`` from ``robot_effector_frame`` (parent) to
the camera frame (child)). Provided as a 4x4 matrix, as translation + quaternion
``qx, qy, qz, qw`` (ROS ``tf``), in easy_handeye's YAML layout (eye-in-hand, metres), and
as the JSON dict of ``calibration.json``'s ``hand_eye`` entry. The camera frame is
OpenCV's (x right, y down, z forward), i.e. a ROS *optical* frame.
"""

from __future__ import annotations

import numpy as np

from ..geometry.rotation import matrix_to_quaternion
from ..geometry.units import length_scale

__all__ = ["easy_handeye_yaml", "hand_eye_json"]


def hand_eye_matrix(R_X: np.ndarray, t_X: np.ndarray) -> np.ndarray:
    """``T_flange_camera`` (4, 4): ``[R_X t_X; 0 0 0 1]`` (t_X in robot units)."""
    M = np.eye(4)
    M[:3, :3] = np.asarray(R_X, float)
    M[:3, 3] = np.asarray(t_X, float)
    return M


def hand_eye_tf(R_X, t_X, *, unit: str = "mm", to_unit: str = "m") -> dict:
    """ROS ``tf`` translation + rotation: ``{"translation": {x, y, z}, "rotation": {x, y, z, w}}``
    (translation converted from ``unit`` to ``to_unit``, metres by default as in ROS)."""
    t = np.asarray(t_X, float) * length_scale(unit, to_unit)
    q = matrix_to_quaternion(R_X)
    return {"translation": dict(zip("xyz", map(float, t))), "rotation": dict(zip("xyzw", map(float, q)))}


def easy_handeye_yaml(R_X, t_X, *, unit: str = "mm", robot_base_frame: str = "base_link",
                      robot_effector_frame: str = "tool0", tracking_base_frame: str = "camera_optical_frame",
                      namespace: str = "/transcalib_eye_on_hand/") -> str:
    """easy_handeye's calibration YAML (eye-in-hand; translation in metres).

    The ``transformation`` is ``robot_effector_frame -> tracking_base_frame`` (the camera),
    i.e. ``T_flange_camera``. No marker frame: this calibration uses no target.
    """
    tf = hand_eye_tf(R_X, t_X, unit=unit, to_unit="m")
    tr, q = tf["translation"], tf["rotation"]
    lines = ["parameters:", "  eye_on_hand: true", "  freehand_robot_movement: false",
             f"  namespace: {namespace}", f"  robot_base_frame: {robot_base_frame}",
             f"  robot_effector_frame: {robot_effector_frame}", f"  tracking_base_frame: {tracking_base_frame}",
             "  tracking_marker_frame: none", "transformation:"]
    lines += [f"  q{k}: {q[k]!r}" for k in "wxyz"] + [f"  {k}: {tr[k]!r}" for k in "xyz"]
    return "\n".join(lines) + "\n"


def hand_eye_json(he, unit: str = "mm") -> dict:
    """``calibration.json``'s ``hand_eye`` entry of a :class:`HandEyeCalibration`.

    Keys: ``R_flange_camera`` (3x3), ``t_flange_camera`` (3, robot units), their std,
    ``undetermined_directions`` (list of flange-frame unit vectors; ``t_flange_camera`` has
    zero component along each), ``convention``, ``matrix_flange_camera`` (4x4), ``tf``
    (translation in metres + quaternion), ``sessions`` (count and labels), ``notes``.
    """
    undet = np.asarray(he.undetermined).reshape(3, -1)
    return {
        "R_flange_camera": np.asarray(he.R_flange_camera).tolist(),
        "t_flange_camera": np.asarray(he.t_flange_camera).tolist(),
        "unit": unit,
        "R_flange_camera_std_deg": np.asarray(he.R_flange_camera_std_deg).tolist(),
        "t_flange_camera_std": np.asarray(he.t_flange_camera_std).tolist(),
        "undetermined_directions": undet.T.tolist(),
        "convention": ("x ~ K (R_i R_X)^T (X - T_i - R_i t_X); R_i flange->base; R_X camera->flange; t_X camera "
                       "centre in the flange frame; zero component of t_X along each undetermined direction"),
        "matrix_flange_camera": hand_eye_matrix(he.R_flange_camera, he.t_flange_camera).tolist(),
        "tf": hand_eye_tf(he.R_flange_camera, he.t_flange_camera, unit=unit),
        "sessions": {"count": int(he.sessions.n_sessions), "labels": list(he.sessions.labels),
                     "tolerance_deg": he.sessions.tolerance_deg},
        "notes": list(he.notes),
    }
