"""The hand-eye transform in the formats robot software reads.

Eye-in-hand, ``T_flange_camera = [[R_X, t_X], [0, 1]]`` maps camera coordinates to flange
coordinates (the camera pose in the flange frame; ROS ``tf`` from ``robot_effector_frame``
(parent) to the camera frame (child)); eye-to-hand, ``T_base_camera`` the fixed camera's
pose in the robot base frame (``tf`` from ``robot_base_frame``). Provided as a 4x4 matrix,
as translation + quaternion ``qx, qy, qz, qw`` (ROS ``tf``), in easy_handeye's YAML layout
(metres), and as ``hand_eye.json``. The camera frame is OpenCV's (x right, y down, z
forward), i.e. a ROS *optical* frame.
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


def easy_handeye_yaml(R_X, t_X, *, unit: str = "mm", eye_on_hand: bool = True, robot_base_frame: str = "base_link",
                      robot_effector_frame: str = "tool0", tracking_base_frame: str = "camera_optical_frame",
                      namespace: str | None = None) -> str:
    """easy_handeye's calibration YAML (translation in metres).

    The ``transformation`` is ``robot_effector_frame -> tracking_base_frame`` (the camera),
    i.e. ``T_flange_camera`` (eye-on-hand), or ``robot_base_frame -> tracking_base_frame``,
    ``T_base_camera`` (eye-to-hand). No marker frame: this calibration uses no target.
    """
    tf = hand_eye_tf(R_X, t_X, unit=unit, to_unit="m")
    tr, q = tf["translation"], tf["rotation"]
    namespace = namespace or ("/transcalib_eye_on_hand/" if eye_on_hand else "/transcalib_eye_on_base/")
    lines = ["parameters:", f"  eye_on_hand: {'true' if eye_on_hand else 'false'}", "  freehand_robot_movement: false",
             f"  namespace: {namespace}", f"  robot_base_frame: {robot_base_frame}",
             f"  robot_effector_frame: {robot_effector_frame}", f"  tracking_base_frame: {tracking_base_frame}",
             "  tracking_marker_frame: none", "transformation:"]
    lines += [f"  q{k}: {q[k]!r}" for k in "wxyz"] + [f"  {k}: {tr[k]!r}" for k in "xyz"]
    return "\n".join(lines) + "\n"


def hand_eye_json(he, unit: str = "mm") -> dict:
    """``hand_eye.json`` of a :class:`~transcalib.types.HandEye`.

    Keys (``frame`` is ``flange`` eye-in-hand, ``base`` eye-to-hand): ``setup``,
    ``R_<frame>_camera`` (3x3), ``t_<frame>_camera`` (3, robot units), their std,
    ``undetermined_directions`` (list of unit vectors in that frame; ``t`` has zero
    component along each; empty when determined), ``convention``,
    ``matrix_<frame>_camera`` (4x4), ``tf`` (translation in metres + quaternion),
    ``sessions`` (count, labels, the session of each view), ``notes``.
    """
    undet = np.asarray(he.undetermined).reshape(3, -1)
    f = he.frame
    convention = ("x ~ K (R_i R_X)^T (X - T_i - R_i t_X); R_i flange->base; R_X camera->flange; t_X camera centre "
                  "in the flange frame" if f == "flange" else
                  "x ~ K R_bc^T (R_i P + T_i - t_bc); R_i flange->base; R_bc camera->base; t_bc camera centre in the "
                  "base frame; P the scene points in the flange frame")
    return {
        "setup": he.setup,
        f"R_{f}_camera": np.asarray(he.R).tolist(),
        f"t_{f}_camera": np.asarray(he.t).tolist(),
        "unit": unit,
        f"R_{f}_camera_std_deg": np.asarray(he.R_std_deg).tolist(),
        f"t_{f}_camera_std": np.asarray(he.t_std).tolist(),
        "undetermined_directions": undet.T.tolist(),
        "convention": convention + "; zero component of t along each undetermined direction",
        f"matrix_{f}_camera": hand_eye_matrix(he.R, he.t).tolist(),
        "tf": hand_eye_tf(he.R, he.t, unit=unit),
        "sessions": {"count": int(he.n_sessions), "labels": list(he.session_labels),
                     "session_of_view": np.asarray(he.session_of_view).tolist()},
        "notes": list(he.notes),
    }
