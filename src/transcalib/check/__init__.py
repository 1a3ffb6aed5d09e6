"""Diagnostics: warnings that name the cause of a doubtful calibration and what to do.

Every check returns a list of :class:`~transcalib.types.Diagnostic` (a ``str`` with a
stable ``code``); an empty list means nothing suspicious. :func:`diagnose` runs them all
and is silent on healthy data. Modules: :mod:`.translations`, :mod:`.linear`,
:mod:`.points`, :mod:`.tracks`, :mod:`.rotation`, :mod:`.poses`, :mod:`.fixed`, :mod:`.robot` (and the start's
``pose_orientation_off``, :mod:`transcalib.handeye.join`).

=========================  ==============================================================
code                       meaning
=========================  ==============================================================
``translations_coplanar``  the translations of one orientation nearly lie in a plane
``translations_small``     the translations (within sessions) are tiny compared with the scene distance (not
                           checked with >= 2 single views: their orientations determine K and R)
``translations_coplanar_known_params``  coplanar translations made identifiable by known parameters
``null_space_2d``          the linear system has a nearly two-dimensional null space
``points_behind_camera``   reconstructed points behind the camera in some view
``view_few_points``        views that see very few points
``view_residuals``         views whose residuals stand out from the others
``outliers``               gross outliers left in the residuals (mismatched tracks)
``view_rotation``          model violation: the camera turned otherwise than the poses say
``pose_orientation_off``   a single view whose recorded orientation its image contradicts (left out)
``fix_contradicted``       a known parameter held fixed (``fix``, CLI ``--fix``) that the data contradict
``pose_outlier``           a view whose recorded position its image contradicts, with the size of the error
``pose_left_out``          such views left out by ``calibrate`` (the fit without them), each with its error
``pose_repeated``          two views at the same recorded pose whose images differ (a row copied)
``unit_implausible``       the scene's distance or the robot's moves are implausible in the unit given
``static_tracks``          tracks that do not move at all (left out)
``low_parallax``           tracks whose motion is below 5 x the pixel noise
``inliers_few``            fewer than half of the tracked points are inliers
``threshold_small``        a user inlier threshold too small for the noise the data show
``implausible_intrinsics`` intrinsics no real camera has (usually wrong tracks)
``robot_error_inseparable``  the data barely separate the robot's pose error from the camera (and what would)
``robot_error_dominates``  the robot's pose error, not the pixel noise, limits fx or cx
``robot_error_misfit``     a per-view pose error the score test found absorbed a model misfit instead (left out)
``check_skipped``          a check that could not run, and why (never silent by omission)
=========================  ==============================================================
"""

from __future__ import annotations

import numpy as np

from ..errors import DegenerateError, Diagnostic
from ..types import Calibration, LinearEstimate
from ..validate import WEAK_SPAN_RATIO, as_uv_T
from .common import camera_poses, depths
from .linear import check_null_space
from .fixed import check_fixed
from .poses import check_pose_outliers, check_repeated_poses, check_unit
from .points import check_outliers, check_points_behind, check_views
from .robot import check_robot_error
from .rotation import check_view_rotations, locate_view_rotation, view_rotation_test
from .tracks import check_inliers, check_intrinsics, check_parallax, check_threshold
from .translations import check_translations

__all__ = ["diagnose", "check_translations", "check_null_space", "check_points_behind", "check_views",
           "check_outliers", "check_view_rotations", "view_rotation_test", "locate_view_rotation",
           "check_robot_error", "skipped"]


def skipped(check: str, reason) -> Diagnostic:
    """The diagnostic of a check that could not run: never silent by omission."""
    return Diagnostic("check_skipped", f"the {check} could not run: {reason}")


def diagnose(uv, T, calibration, *, linear: LinearEstimate | None = None, check_rotation: bool = True,
             unit: str = "units", all_uv=None, rotation_data=None, sessions=None, views_left_out=None,
             view_ids=None, setup: str = "eye-in-hand") -> list:
    """Run every check on a calibration; an empty list on healthy data.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        The observations the calibration was computed from (tracks outside
        ``calibration.inliers`` may be included: every check but those on all tracks
        leaves them out).
    T : (n_views, 3) float
        Flange positions (as the calibration's model uses them).
    calibration : Calibration or LinearEstimate
        The result to check; its ``inliers`` (if any) select the points that count; its
        ``stats.ransac`` (the robust stage's noise estimate) is checked against a user
        threshold (``options.ransac.threshold_px``).
    linear : LinearEstimate, optional
        The linear estimate (default ``calibration.linear``) for the null-space check.
    check_rotation : bool
        Run the model-violation (rotation) test (a refined calibration only).
    unit : str
        Length unit named in the messages.
    all_uv : (n_views, n_points, 2) float, optional
        Every track (outliers included), for the parallax and inlier-fraction checks.
    rotation_data : (uv, Calibration), optional
        What the rotation test runs on instead of ``uv`` and ``calibration``: the subset
        of the tracks a large calibration was fitted on, and its fit (the test refits).
    sessions : (n_views,) int, optional
        Session of each view (views of one flange orientation; default
        ``calibration.hand_eye``'s, else one session): the motion within sessions is what
        determines the camera, and where image motion is parallax.
    views_left_out : (n_views,) bool, optional
        Views the start left out (their poses contradict their images; reported there).
    view_ids : sequence of str, optional
        The user's view ids, for the pose checks' messages (default the indices).
    setup : {"eye-in-hand", "eye-to-hand"}
        Eye-to-hand ``T`` holds the inverted poses: a pose error is named in the robot's terms.

    Returns
    -------
    list of Diagnostic
        In the order: contradicted fixed parameters, repeated poses, translations, unit,
        null space, points behind, tracks (parallax, inliers, threshold, plausibility),
        views, outliers, robot pose error, an outlying pose or else the rotation (neither with a
        contradicted fixed parameter); a ``check_skipped`` entry for each check that
        could not run.
    """
    uv, T = as_uv_T(uv, T, min_views=2)
    K, X = np.asarray(calibration.K, float), np.asarray(calibration.X, float)
    sessions = _sessions(calibration, sessions, len(T))
    R_cam, C = camera_poses(calibration, T)
    R_model = getattr(calibration, "flange_rotations", None)
    out = []
    if isinstance(calibration, Calibration):
        out += check_repeated_poses(uv, T, R_model, sigma_px=calibration.sigma_px, view_ids=view_ids, unit=unit)
    sizes = np.bincount(sessions)
    if np.sum(sizes == 1) < 2:  # >= 2 single views determine K and R whatever the moves
        moves, frame = _session_moves(T, calibration, sessions)
        # coplanar moves leave K and R undetermined at one orientation only; with several the
        # start's information test names what is undetermined
        ratio = WEAK_SPAN_RATIO if np.sum(sizes >= 1) == 1 else 0.0
        out += check_translations(moves, focal_px=0.5 * (K[0, 0] + K[1, 1]), distance=_scene_distance(R_cam, X, C),
                                  unit=unit, frame=frame, coplanar_ratio=ratio)
    out += check_unit(_scene_distance(R_cam, X, C), T, unit)
    if linear is None:
        linear = calibration if isinstance(calibration, LinearEstimate) else calibration.linear
    if linear is not None:
        out += check_null_space(linear)
    out += _behind(uv, T, calibration)
    if isinstance(calibration, Calibration):
        out += _track_checks(uv if all_uv is None else all_uv, calibration, sessions)
        out += check_views(uv, calibration.residuals_px, used=calibration.inliers, left_out=views_left_out)
        out += check_outliers(calibration.residuals_px, used=calibration.inliers)
        out += check_robot_error(calibration, unit)
        if check_rotation:
            fit = rotation_data if rotation_data is not None else (uv, calibration)
            fixed = _fixed_check(fit, T)
            out = fixed + out  # the likely cause of much of the rest: named first
            wrong_fix = any(d.code == "fix_contradicted" for d in fixed)
            out += _pose_checks(fit, T, view_ids, unit, setup, R_model) if not wrong_fix else [skipped(
                "test of the poses and the rotation test", "a parameter held fixed contradicts the data (see "
                "fix_contradicted): their residuals would be blamed on the poses")]
    return out


def _fixed_check(data, T) -> list:
    """The score test of the fixed parameters on the calibration's fit ``(uv, cal)``."""
    try:
        return check_fixed(data[0], T, data[1])
    except DegenerateError as exc:
        return [skipped("test of the fixed parameters (fix, CLI --fix)", exc)]


def _pose_checks(data, T, view_ids, unit, setup, R_model) -> list:
    """An outlying pose (named with its error) or else a rotated view: both tests on
    the calibration's fit ``data = (uv, calibration)``."""
    rot_uv, rot_cal = data
    try:
        found = check_pose_outliers(rot_uv, T, rot_cal, view_ids=view_ids, unit=unit, setup=setup, R_model=R_model)
    except DegenerateError as exc:
        found = [skipped("outlying-pose test (does every view's image agree with its pose?)", exc)]
    if any(d.code == "pose_outlier" for d in found):
        return found  # the rotation test would name the same error as a turned camera
    try:
        return found + check_view_rotations(rot_uv, T, rot_cal)
    except DegenerateError as exc:
        return found + [skipped("rotation test (did the camera turn otherwise than the poses say?)", exc)]


def _sessions(calibration, sessions, n_views: int) -> np.ndarray:
    """The session of each view: given, else the calibration's, else one session."""
    if sessions is not None:
        return np.asarray(sessions, int)
    he = getattr(calibration, "hand_eye", None)
    return np.zeros(n_views, int) if he is None else np.asarray(he.session_of_view, int)


def _session_moves(T, calibration, sessions) -> tuple:
    """``(moves (m, 3), frame)``: the moves that determine the camera, within each session
    of >= 2 views, in the model's flange frame (``R_s^T (T_i - mean_s T)``) and named in
    the user's terms: the robot axes for one orientation (or without rotations), the flange
    axes for several; eye-to-hand the model's flange frame is the robot base."""
    R_i = getattr(calibration, "flange_rotations", None)
    he = getattr(calibration, "hand_eye", None)
    if R_i is None or (he.setup == "eye-in-hand" and len(np.unique(sessions)) == 1):
        return T - T.mean(axis=0), "robot"
    moves = []
    for s in np.unique(sessions):
        views = np.flatnonzero(sessions == s)
        if len(views) >= 2:
            moves.append((T[views] - T[views].mean(axis=0)) @ np.asarray(R_i)[views[0]])
    return np.concatenate(moves), "flange" if he.setup == "eye-in-hand" else "robot base"


def _scene_distance(R_cam, X, C) -> float | None:
    """Median over the points of their depth seen from the views (user units; None
    without a point in front of a camera)."""
    with np.errstate(invalid="ignore"):
        z = depths(R_cam, X, C)
        z = z[np.isfinite(z) & (z > 0)]
    return float(np.median(z)) if z.size else None


def _behind(uv, T, calibration) -> list:
    """Points behind the camera now, or left out of the refinement for being behind."""
    behind = check_points_behind(uv, T, calibration)
    refined = calibration.stats.refine if isinstance(calibration, Calibration) else None
    n_excluded = 0 if refined is None else refined.n_points_behind_camera
    if behind or n_excluded == 0:
        return behind
    return [Diagnostic(
        "points_behind_camera",
        f"{n_excluded} point(s) were left out of the refinement because they lie behind the camera: these "
        "tracks are almost certainly mismatches. Remove them or run the robust estimator "
        "(calibrate(..., robust=True), CLI --robust).")]


def _track_checks(uv, calibration: Calibration, sessions) -> list:
    """Static and low-parallax tracks, the inlier fraction, a threshold small for the
    noise, implausible intrinsics."""
    out = []
    robust = calibration.stats.ransac
    sigma = calibration.sigma_px if calibration.sigma_px else (robust.sigma_px if robust is not None else None)
    if sigma:
        out += check_parallax(uv, sigma, sessions)
    else:
        out.append(skipped("parallax check", "no estimate of the pixel noise (refine the calibration)"))
    out += check_inliers(calibration.inliers, uv, calibration.residuals_px, calibration.sigma_px)
    if robust is not None and calibration.options is not None:
        ransac = calibration.options.ransac
        out += check_threshold(robust.sigma_px, robust.rule_sigma_px, ransac.threshold_px, ransac.false_rejection)
    out += check_intrinsics(calibration.K, calibration.image_size)
    return out
