"""Options, results and the progress protocol shared by every stage (errors: :mod:`transcalib.errors`).

Conventions (see ``docs/conventions.md``):

* ``uv``  ``(n_views, n_points, 2)`` pixels, NaN where a point is not seen; the centre of
  the top-left pixel is (0, 0) (OpenCV).
* ``T``   ``(n_views, 3)`` robot translations in the world (robot) frame, user units.
* ``R``   world -> camera rotation (``R_cam_world``), det +1; camera x right, y down,
  z forward.
* ``K``   ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``; ``A = K R``.
* ``X``   ``(n_points, 3)`` scene points in world axes relative to the camera centre at
  robot position ``T = 0``.

Projection (paper eq. 2): ``lam_ij * [u_ij, v_ij, 1] = A (X_j - T_i)``.

Options are frozen dataclasses, checked when they are made: a misspelt option name is a
``TypeError``, a bad value an :class:`InputError` naming the option.
"""

from ..errors import DegenerateError, Diagnostic, InputError, MirroredError, TranscalibError
from ..geometry.camera import Camera
from .options import (FIXABLE, INTRINSIC_NAMES, LOSSES, MIN_SUBSET_POINTS, SETUPS, SUBSET_POINTS, CalibrateOptions,
                      RansacOptions, RefineOptions)
from .poses import Poses
from .progress import ProgressEvent, report
from .results import (Calibration, CalibrationStats, DistortionStep, HandEye, LinearEstimate, RansacStats,
                      RefineStats, RobotError, SessionErrorEstimate, Uncertainty, ViewFieldEstimate,
                      ViewRotations)

__all__ = ["TranscalibError", "InputError", "DegenerateError", "MirroredError", "Diagnostic", "RansacOptions",
           "RefineOptions", "CalibrateOptions", "LinearEstimate", "Calibration", "CalibrationStats", "RansacStats",
           "RefineStats", "DistortionStep", "ViewRotations", "RobotError", "Uncertainty", "ViewFieldEstimate",
           "SessionErrorEstimate", "HandEye", "Poses", "SETUPS", "Camera",
           "ProgressEvent", "report", "INTRINSIC_NAMES", "FIXABLE", "LOSSES", "SUBSET_POINTS", "MIN_SUBSET_POINTS"]
