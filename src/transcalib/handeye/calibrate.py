"""``calibrate_sessions``: K, the hand-eye transform and the points from several sessions.

Stages: group the views into sessions (:mod:`.sessions`), the linear start (:mod:`.linear`),
the observability of ``t_X`` from the Fisher information (:mod:`.observability`), then the
project's one bundle adjuster (:func:`transcalib.estimate.refine.fit_refine` with a
:class:`~transcalib.estimate.refine.FlangeModel`) on the model ::

    x_ij ~ K (R_i R_X)^T (X_j - T_i - R_i t_X)        (+ distortion)

with the measured flange rotation ``R_i`` of every view (not the session mean) and
``t_X`` free only along its determined directions (zero along the others: the stated
convention of :mod:`.observability`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..estimate.refine import FlangeModel, fit_refine
from ..geometry.rotation import ROTATION_TOL, rotation_defect
from ..types import Calibration, RansacOptions, RefineOptions
from ..validate import as_uv_T
from .linear import SessionsLinear, sessions_linear
from .observability import Observability, offset_observability
from .sessions import SESSION_TOLERANCE_DEG, SessionGrouping, group_sessions

__all__ = ["HandEyeCalibration", "calibrate_sessions"]


@dataclass(frozen=True, eq=False)
class HandEyeCalibration:
    """Result of :func:`calibrate_sessions`.

    Attributes
    ----------
    calibration : Calibration
        The refined model: ``camera`` (``K``, distortion; ``camera.R`` is ``R_X^T``),
        ``X`` (base frame, absolute), residuals, ``cov``/``std`` (``t_x, t_y, t_z`` or
        ``t_0 ..`` along ``determined``), ``t_flange_camera``.
    R_flange_camera : (3, 3) float
        ``R_X``: camera axes in the flange frame (camera -> flange).
    t_flange_camera : (3,) float
        ``t_X``: camera centre in the flange frame (robot units), zero along ``undetermined``.
    R_flange_camera_std_deg : (3,) float
        Std of the small rotation ``w`` in ``R_X <- R_X exp(-[w]x)`` (about the camera axes).
    t_flange_camera_cov : (3, 3) float
        Covariance of ``t_X`` (zero along ``undetermined``).
    t_flange_camera_std : (3,) float
        Square roots of its diagonal.
    undetermined : (3, k) float
        Directions of ``t_X`` (flange frame) the data leave free; empty (3, 0) if none.
    observability : Observability
    sessions : SessionGrouping
    linear : SessionsLinear
    X : (n_points, 3) float
        Scene points in robot base coordinates (absolute).
    notes : tuple of str
        Observability and grouping messages for the user.
    inliers : (n_sessions, n_points) bool or None
        With ``robust``: the (point, session) pairs kept.
    """

    calibration: Calibration
    R_flange_camera: np.ndarray
    t_flange_camera: np.ndarray
    R_flange_camera_std_deg: np.ndarray
    t_flange_camera_cov: np.ndarray
    t_flange_camera_std: np.ndarray
    undetermined: np.ndarray
    observability: Observability
    sessions: SessionGrouping
    linear: SessionsLinear
    X: np.ndarray
    notes: tuple
    inliers: np.ndarray | None = None

    @property
    def K(self) -> np.ndarray:
        return self.calibration.K

    @property
    def camera(self):
        return self.calibration.camera


def _check_rotations(R, n_views: int) -> np.ndarray:
    try:
        R = np.asarray(R, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"flange_rotations must be an array of numbers ({exc})") from None
    if R.shape != (n_views, 3, 3):
        raise InputError(f"flange_rotations must have shape (n_views, 3, 3) = ({n_views}, 3, 3), got {R.shape}")
    bad = np.flatnonzero(rotation_defect(R) > ROTATION_TOL)
    if bad.size:
        raise InputError(f"flange_rotations of views {bad[:10].tolist()} are not rotation matrices (orthonormal, "
                         "det +1); read the controller's orientations with transcalib.io.read_poses")
    return R


def calibrate_sessions(uv, T, flange_rotations, *, session_of_view=None, tolerance_deg: float = SESSION_TOLERANCE_DEG,
                       distortion: str = "none", fix=None, square_pixels: bool = False, estimate_skew: bool = False,
                       sigma_T=None, sigma_px=None, loss: str = "linear", loss_scale_px: float = 1.0,
                       max_iterations: int = 100, robust: bool = False, ransac: RansacOptions | None = None,
                       rng=None) -> HandEyeCalibration:
    """Calibrate K and the camera-to-flange transform from translation sessions.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen; a point keeps its index across sessions.
    T : (n_views, 3) float
        Flange positions in the robot base frame (robot units; every length out is in them).
    flange_rotations : (n_views, 3, 3) float
        Flange -> base rotations ``R_i`` (read them with
        :func:`transcalib.io.read_poses`: ``Poses.R``).
    session_of_view : (n_views,) sequence, optional
        Session labels; default: grouping by orientation within ``tolerance_deg``.
    tolerance_deg : float
        Largest orientation difference inside a session (degrees).
    distortion, fix, square_pixels, estimate_skew, sigma_T, sigma_px, loss, loss_scale_px, max_iterations
        As :class:`transcalib.RefineOptions`.
    robust : bool
        RANSAC on the stacked sessions (:func:`transcalib.estimate.robust.fit_robust`;
        options ``ransac``); the observations of a point rejected in a session are left
        out of that session (``he.inliers``). Combine with ``loss="huber"`` to downweight
        single bad observations in the refinement.
    ransac : RansacOptions, optional
    rng : seed or Generator, optional
        For RANSAC (the estimate is otherwise deterministic).

    Returns
    -------
    HandEyeCalibration

    Raises
    ------
    InputError
        Malformed input.
    DegenerateError
        Moves not spanning 3-D in the flange frame (named, including the SCARA case), too
        few points or views, or intrinsics the data do not determine.
    """
    uv, T = as_uv_T(uv, T, min_views=2)
    R = _check_rotations(flange_rotations, len(T))
    opts = RefineOptions(distortion=distortion, fix=dict(fix or {}), square_pixels=square_pixels,
                         estimate_skew=estimate_skew, sigma_T=sigma_T, sigma_px=sigma_px, loss=loss,
                         loss_scale_px=loss_scale_px, max_iterations=max_iterations)
    grouping = group_sessions(R, tolerance_deg, session_of_view)
    lin = sessions_linear(uv, T, grouping, ransac=(ransac or RansacOptions()) if robust else None, rng=rng)
    if lin.inliers is not None:  # drop the rejected (point, session) observations
        uv = np.where(lin.inliers[grouping.session_of_view][..., None], uv, np.nan)
    F = np.transpose(R, (0, 2, 1))
    obs = offset_observability(lin.K, np.zeros(5), lin.R_X.T, lin.t_X, lin.X, uv, T, F, grouping.rotations,
                               grouping.labels, fix=opts.fix, estimate_skew=estimate_skew,
                               square_pixels=square_pixels, distortion="none" if distortion == "auto" else distortion)
    lin = lin.with_offset_basis(obs.determined)
    cal = fit_refine(uv, T, lin.as_linear_estimate(), opts, flange=FlangeModel(F, lin.t_X, obs.determined))
    names = list(cal.param_names)
    i_t = [names.index(nm) for nm in names if nm.startswith("t_")]
    B = obs.determined
    cov_t = B @ cal.cov[np.ix_(i_t, i_t)] @ B.T if i_t else np.zeros((3, 3))
    R_std = np.array([cal.std[k] for k in ("rx", "ry", "rz")])
    notes = tuple(m for m in [obs.message, *grouping.messages()] if m)
    return HandEyeCalibration(cal, cal.camera.R.T, np.asarray(cal.t_flange_camera, float), R_std, cov_t,
                              np.sqrt(np.clip(np.diag(cov_t), 0, None)), obs.undetermined, obs, grouping, lin,
                              cal.X, notes, lin.inliers)
