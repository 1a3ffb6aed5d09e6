"""``calibrate_sessions``: the former call for several orientations, kept one release as a thin alias.

:func:`transcalib.calibrate` serves every robot motion; this alias passes its arguments
on and wraps the result in the former result type, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..handeye.sessions import SESSION_TOLERANCE_DEG
from ..types import Calibration, Poses, RansacOptions, RefineOptions


@dataclass(frozen=True, eq=False)
class HandEyeCalibration:
    """The former result of :func:`calibrate_sessions`: the calibration and its hand-eye
    pose under the former names (``calibration.hand_eye`` holds them all)."""

    calibration: Calibration

    @property
    def K(self) -> np.ndarray:
        return self.calibration.K

    @property
    def camera(self):
        return self.calibration.camera

    @property
    def X(self) -> np.ndarray:
        return self.calibration.X

    @property
    def R_flange_camera(self) -> np.ndarray:
        return self.calibration.hand_eye.R

    @property
    def t_flange_camera(self) -> np.ndarray:
        return self.calibration.hand_eye.t

    @property
    def R_flange_camera_std_deg(self) -> np.ndarray:
        return self.calibration.hand_eye.R_std_deg

    @property
    def t_flange_camera_cov(self) -> np.ndarray:
        return self.calibration.hand_eye.t_cov

    @property
    def t_flange_camera_std(self) -> np.ndarray:
        return self.calibration.hand_eye.t_std

    @property
    def undetermined(self) -> np.ndarray:
        return self.calibration.hand_eye.undetermined

    @property
    def notes(self) -> tuple:
        return self.calibration.hand_eye.notes


def calibrate_sessions(uv, T, flange_rotations, *, session_of_view=None,
                       tolerance_deg: float = SESSION_TOLERANCE_DEG, distortion: str = "none", fix=None,
                       square_pixels: bool = False, estimate_skew: bool = False, sigma_T=None, sigma_px=None,
                       loss: str = "linear", loss_scale_px: float = 1.0, max_iterations: int = 100,
                       robust: bool = False, ransac: RansacOptions | None = None, rng=0) -> HandEyeCalibration:
    """Deprecated: ``transcalib.calibrate(uv, Poses.of(T, flange_rotations,
    session=session_of_view), session_tolerance_deg=tolerance_deg, ...)``, whose result
    holds the hand-eye pose in ``hand_eye``. The arguments are those of
    :class:`~transcalib.RefineOptions` and :func:`transcalib.calibrate`."""
    from . import calibrate

    warnings.warn("transcalib.calibrate_sessions is deprecated and will be removed in the next release: use "
                  "transcalib.calibrate(uv, transcalib.Poses.of(T, R)); the hand-eye pose is in its hand_eye field",
                  DeprecationWarning, stacklevel=2)
    opts = RefineOptions(distortion=distortion, fix=dict(fix or {}), square_pixels=square_pixels,
                         estimate_skew=estimate_skew, sigma_T=sigma_T, sigma_px=sigma_px, loss=loss,
                         loss_scale_px=loss_scale_px if loss != "linear" else None, max_iterations=max_iterations)
    poses = Poses.of(T, flange_rotations, session=session_of_view)
    cal = calibrate(uv, poses, session_tolerance_deg=tolerance_deg, robust=robust,
                    ransac=ransac if robust else None, refinement=opts, rng=rng)
    return HandEyeCalibration(cal)
