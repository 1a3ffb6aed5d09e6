"""The calibration in the terms of the robot motion it came from: flange rotations and the hand-eye pose.

The stages fit one constant orientation with the flange axes as the world axes (the
paper's problem, the fast path); when the poses give that orientation ``R_0``, the result
is turned into the flange form here: ``R <- R R_0`` (flange -> camera), the flange
rotations recorded, and the hand-eye pose with the camera's rotation in the flange
determined and its offset not (one orientation leaves ``t_X`` free). For several
orientations the refinement already has that form; the setup, the sessions and the
notes on what the motion leaves undetermined are added.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..types import Calibration, HandEye
from .motion import Motion

#: Said of one flange orientation: what it leaves undetermined.
ONE_ORIENTATION = ("one flange orientation: the camera's offset in the flange (t) is not determined and reported as "
                   "0, the points are relative to the camera centre at T = 0; add sessions with the wrist turned by "
                   ">= 15 deg about two different axes to determine it")


def with_motion(cal: Calibration, motion: Motion, notes: tuple = ()) -> Calibration:
    """``cal`` with the flange rotations and the hand-eye pose of ``motion`` (module
    docstring); unchanged without orientations in the poses."""
    if motion.R is None:
        return cal
    sessions = dict(setup=motion.setup, session_of_view=motion.session_of_view, session_labels=motion.labels)
    if cal.flange_rotations is not None:  # several orientations: the refinement's pose, with the motion's facts
        return replace(cal, hand_eye=replace(cal.hand_eye, **sessions, notes=tuple(notes)))
    R0 = motion.R[0]
    R_std = np.array([cal.std.get(k, np.nan) for k in ("rx", "ry", "rz")])
    hand_eye = HandEye(R=(cal.R @ R0).T, t=np.zeros(3), R_std_deg=R_std, t_cov=np.zeros((3, 3)),
                       undetermined=np.eye(3), **sessions, notes=(ONE_ORIENTATION, *notes))
    return replace(cal, camera=replace(cal.camera, R=cal.R @ R0), flange_rotations=motion.R, hand_eye=hand_eye)
