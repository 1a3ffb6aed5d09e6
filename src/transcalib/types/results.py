"""Results of the stages: frozen dataclasses, never changed once made.

:class:`LinearEstimate` (the paper's linear estimate), :class:`Calibration` (what
:func:`transcalib.calibrate` returns) and the typed records of how each stage ran
(:class:`RansacStats`, :class:`RefineStats`, :class:`DistortionStep`, gathered in
:class:`CalibrationStats`). Arrays of a :class:`Calibration` are read-only views,
its mappings read-only proxies and its lists tuples, so that no later stage can change a
result another one holds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType

import numpy as np

from ..errors import Diagnostic, InputError
from ..geometry.camera import Camera
from .options import CalibrateOptions


def _read_only(a):
    """A read-only view of array ``a`` (None stays None); ``a`` itself stays writeable."""
    if a is None:
        return None
    view = np.asarray(a).view()
    view.setflags(write=False)
    return view


def _freeze(obj, arrays=(), mappings=(), sequences=()) -> None:
    """In a frozen dataclass's ``__post_init__``: the named fields as read-only arrays,
    read-only mappings and tuples."""
    for name in arrays:
        object.__setattr__(obj, name, _read_only(getattr(obj, name)))
    for name in mappings:
        object.__setattr__(obj, name, MappingProxyType(dict(getattr(obj, name))))
    for name in sequences:
        object.__setattr__(obj, name, tuple(getattr(obj, name)))


@dataclass(frozen=True, eq=False)
class LinearEstimate:
    """The paper's linear (total-least-squares) estimate.

    Attributes
    ----------
    K : (3, 3) float
        Intrinsics, positive diagonal, ``K[2, 2] = 1``.
    R : (3, 3) float
        Rotation world -> camera, ``det R = +1``.
    A : (3, 3) float
        ``A = K R`` scaled so that ``||A[2]|| = 1`` (then ``depth`` is camera z).
    X : (n_points, 3) float
        Scene points (world axes, user units, relative to the camera centre at ``T = 0``),
        triangulated from all views with ``A`` and the known translations. NaN for
        points that were not used (seen in fewer than 2 views).
    depth : (n_views, n_points) float
        Projective depths lambda of the TLS solution (paper eq. 3), equal to the camera
        z-coordinate for exact data; NaN where a point is not seen or not used.
    singular_values : (k,) float
        The smallest singular values of the normalised system ``C b = 0``, ascending.
        Their ratio ``s[0] / s[1]`` measures how well the solution is determined
        (near 1: ill-conditioned).
    n_used_points : int
        Number of points that entered the estimate.
    used : (n_points,) bool
        Which points entered the estimate.
    method : str
        ``"fast"`` (O(n) block elimination), ``"dense"`` (SVD of the whole system) or
        ``"coplanar"`` (the 2-axis start with known parameters).
    static : (n_points,) bool or None
        Tracks left out because they do not move between views (no depth information).
    """

    K: np.ndarray
    R: np.ndarray
    A: np.ndarray
    X: np.ndarray
    depth: np.ndarray
    singular_values: np.ndarray
    n_used_points: int
    used: np.ndarray
    method: str = "fast"
    static: np.ndarray | None = None

    def __eq__(self, other) -> bool:
        return isinstance(other, LinearEstimate) and _same_fields(self, other)

    __hash__ = None


@dataclass(frozen=True)
class RansacStats:
    """How the robust stage ran (:attr:`CalibrationStats.ransac`).

    Attributes
    ----------
    trials : int
        Minimal-sample hypotheses drawn.
    trials_needed : float
        Trials the adaptive stopping rule asked for at the end (inf if never met).
    n_inliers : int
        Tracks kept.
    sigma_px : float
        Pixel noise per coordinate estimated from the inliers.
    rule_sigma_px : float
        The sigma of the inlier rule (``sigma_px``, or the one a user threshold implies).
    time_s : float
    """

    trials: int
    trials_needed: float
    n_inliers: int
    sigma_px: float
    rule_sigma_px: float
    time_s: float


@dataclass(frozen=True)
class RefineStats:
    """How a refinement ran (:attr:`CalibrationStats.refine`).

    Attributes
    ----------
    iterations : int
        Accepted Levenberg-Marquardt (or Gauss-Newton) steps.
    cost : float
        Final cost ``0.5 sum rho(|r|^2)`` (+ the translation priors), px^2.
    stop_reason : str
    converged : bool
    dof : int
        Residual degrees of freedom of the final least-squares stage.
    n_observations, n_points_used, n_points_excluded, n_points_behind_camera : int
        Observations of the used points; points used; left out (not triangulated, seen
        once, or behind the camera at the start); of those, behind the camera.
    n_points_undetermined : int
        Used points whose position the data do not determine (no covariance).
    inlier_threshold_px : float or None
        Residual norm above which a robust loss's observation is an outlier.
    time_s : float
    """

    iterations: int
    cost: float
    stop_reason: str
    converged: bool
    dof: int
    n_observations: int
    n_points_used: int
    n_points_excluded: int
    n_points_behind_camera: int
    n_points_undetermined: int
    inlier_threshold_px: float | None
    time_s: float


@dataclass(frozen=True)
class DistortionStep:
    """One step of the distortion choice (``distortion="auto"``): the score test of the
    coefficients ``model`` adds, ``F`` and its ``p_value`` against the level ``alpha``,
    whether the model was taken and, if not although the test asked for it, why;
    ``robot_error_held``: a step of the climb made again with the robot error's scales
    held (it decides the model)."""

    model: str
    F: float
    p_value: float
    alpha: float
    chosen: bool
    reason: str = ""
    robot_error_held: bool = False


@dataclass(frozen=True)
class CalibrationStats:
    """How a calibration was obtained (:attr:`Calibration.stats`).

    Attributes
    ----------
    stages : tuple of str
        Stages run, in order (``"robust"`` or ``"linear"``, ``"refine"``,
        ``"reclassify+refine"``, ``"reclassify+refine (lens chosen again)"`` (the
        inliers grew well beyond the set the lens was chosen on), after a robot error
        misfit ``"reclassify+refine (scales held)"`` and ``"refine (scales
        estimated)"``, ``"all tracks"``).
    timings_s : mapping of str to float
        Seconds per stage (``robust_s`` / ``linear_s``, ``refine_s``, ``all_tracks_s``,
        ``diagnostics_s``).
    ransac : RansacStats or None
        The robust stage, when it ran.
    refine : RefineStats or None
        The (last) refinement, when it ran.
    subset : RefineStats or None
        With more tracks than ``subset_points``: the refinement of the subset that the
        Gauss-Newton steps with every track started from.
    distortion_selection : tuple of DistortionStep
        The steps of the distortion choice (``distortion="auto"``).
    sigma_truncation_factor : float or None
        Factor by which the inlier rule shrank the estimated noise variance, undone in
        ``sigma_px`` and every variance (about 0.98).
    """

    stages: tuple = ()
    timings_s: Mapping = field(default_factory=dict)
    ransac: RansacStats | None = None
    refine: RefineStats | None = None
    subset: RefineStats | None = None
    distortion_selection: tuple = ()
    sigma_truncation_factor: float | None = None

    def __post_init__(self):
        _freeze(self, mappings=("timings_s",), sequences=("stages", "distortion_selection"))


@dataclass(frozen=True, eq=False)
class ViewRotations:
    """Rotations fitted per view (the rotation test's alternative model): camera-frame
    rotation vectors ``deg (n_views, 3)`` in degrees, their ``std_deg (n_views, 3)`` and
    the Wald statistics ``chi2 (n_views,)`` (chi-square(3) for a view that did not rotate);
    zero for views without a rotation parameter."""

    deg: np.ndarray
    std_deg: np.ndarray
    chi2: np.ndarray

    def __post_init__(self):
        _freeze(self, arrays=("deg", "std_deg", "chi2"))

    def __eq__(self, other) -> bool:
        return isinstance(other, ViewRotations) and _same_fields(self, other)

    __hash__ = None


@dataclass(frozen=True, eq=False)
class ViewFieldEstimate:
    """An error field alike over each view's points, as the residuals show it
    (:mod:`transcalib.estimate.view_field`; docs/uncertainty.md §7.1).

    Attributes
    ----------
    rms_px : float
        A view's field, RMS per image coordinate over the tracked area (px): each
        view's shift, linear and quadratic field together.
    rms_std_px : float
        Its std (NaN at 0).
    tau_px2 : (3,) float
        Variance of each coefficient of degree 0, 1, 2 (px^2).
    p_value : float
        Likelihood-ratio test of no field.
    included : bool
        Whether the model-based covariance (``Uncertainty.std_model``) includes the
        fields' effect (the test at 5 %).
    """

    rms_px: float
    rms_std_px: float
    tau_px2: np.ndarray
    p_value: float
    included: bool

    def __post_init__(self):
        _freeze(self, arrays=("tau_px2",))

    def __eq__(self, other) -> bool:
        return isinstance(other, ViewFieldEstimate) and _same_fields(self, other)

    __hash__ = None


@dataclass(frozen=True, eq=False)
class SessionErrorEstimate:
    """The robot error common to each session's views, as the per-view errors show it
    (:mod:`transcalib.estimate.session_error`; docs/uncertainty.md §7.2).

    Attributes
    ----------
    sigma_rot_deg, sigma_pos : float
        Per-axis std of a session's common rotation (degrees) and position (robot
        units) error: where found, the std's mean over its likelihood (its square is
        what the covariance takes in), else its maximum-likelihood value; 0 where
        neither shows.
    sigma_rot_std_deg, sigma_pos_std : float
        Their std at the maximum (Fisher information, delta method; NaN at 0).
    p_value : float
        Likelihood-ratio test of no common error.
    n_sessions : int
        Sessions of two views or more.
    included : bool
        Whether the model-based covariance includes their effect (the test at 5 %).
    """

    sigma_rot_deg: float
    sigma_rot_std_deg: float
    sigma_pos: float
    sigma_pos_std: float
    p_value: float
    n_sessions: int
    included: bool

    def __eq__(self, other) -> bool:
        return isinstance(other, SessionErrorEstimate) and _same_fields(self, other)

    __hash__ = None


@dataclass(frozen=True, eq=False)
class Uncertainty:
    """The model-based and the cluster-robust (sandwich) uncertainty of a refined
    calibration, and which one :attr:`Calibration.std` reports
    (:func:`transcalib.estimate.covariance.sandwich`; docs/uncertainty.md §7).

    Attributes
    ----------
    std_model : mapping of str to float
        ``sigma sqrt(diag S^-1)``: exact when the model (white pixel noise of one scale,
        the robot error model) is right; the Cramér-Rao bound at the truth. With
        ``view_field.included`` the views' error fields' share added, with
        ``session_error.included`` the sessions' common robot error's.
    std_robust : mapping of str to float
        ``sqrt(diag(S^-1 M S^-1))`` with ``M`` the CR2-corrected outer products of each
        point's (and each view's priors') score: valid when pixel errors are correlated
        along a track or heteroscedastic across points, i.e. under model misfit. With
        ``session_error.included`` the sessions' share added: the fit's robot error
        columns take a session's error out of the residuals, so no cluster holds it.
    cov_robust : (p, p) float
        The sandwich covariance, with the sessions' share (names and units as
        :attr:`Calibration.cov`).
    dof : mapping of str to float
        Effective degrees of freedom of each robust variance (its relative std is
        ``sqrt(2 / dof)``).
    p_value : mapping of str to float
        ``P(chi2(dof)/dof >= (std_robust/std_model)^2)``, both without the sessions'
        share: small when the model-based std is too small for that parameter.
    reported : mapping of str to str
        ``"model"`` or ``"robust"``: which one :attr:`Calibration.std` / ``cov`` use.
    misfit : float
        ``tr(S^-1 M) / (sigma^2 p)``: 1 in expectation under the model.
    n_clusters : int
        Points (and views with priors) whose scores form ``M``.
    view_field : ViewFieldEstimate or None
        The per-view error field the residuals show (None: not tested,
        ``RefineOptions.view_field=False``).
    session_error : SessionErrorEstimate or None
        The robot error common to each session (None: not measurable: one orientation
        or fewer than two sessions of two views).
    """

    std_model: Mapping
    std_robust: Mapping
    cov_robust: np.ndarray
    dof: Mapping
    p_value: Mapping
    reported: Mapping
    misfit: float
    n_clusters: int
    view_field: ViewFieldEstimate | None = None
    session_error: SessionErrorEstimate | None = None

    def __post_init__(self):
        _freeze(self, arrays=("cov_robust",), mappings=("std_model", "std_robust", "dof", "p_value", "reported"))

    def __eq__(self, other) -> bool:
        return isinstance(other, Uncertainty) and _same_fields(self, other)

    def scaled(self, c: float) -> "Uncertainty":
        """Both covariances divided by ``c`` (std by ``sqrt(c)``): a variance correction
        common to every residual (``pipeline.stages.untruncated``); the test statistics
        are ratios and stay."""
        root = float(np.sqrt(c))
        return replace(self, std_model={k: v / root for k, v in self.std_model.items()},
                       std_robust={k: v / root for k, v in self.std_robust.items()}, cov_robust=self.cov_robust / c)

    __hash__ = None


@dataclass(frozen=True, eq=False)
class RobotError:
    """The robot's pose error as the refinement found it (:attr:`Calibration.robot_error`).

    Each view's true flange pose is the reported one times a small error: a rotation
    ``delta_i`` in the flange frame and a position error ``eps_i`` in the base frame, with
    per-axis standard deviations ``sigma_rot_deg`` and ``sigma_pos``
    (:mod:`transcalib.estimate.robot_error`; docs/uncertainty.md).

    Attributes
    ----------
    sigma_rot_deg, sigma_pos : float
        Per-axis std of the flange rotation error (degrees) and position error (robot
        units); 0 when the component is off or the data show none.
    sigma_rot_std_deg, sigma_pos_std : float
        Their standard deviations (``sigma / sqrt(2 r)``, ``r`` the component's redundancy);
        0 when given or off.
    source : tuple of str
        For ``(rot, pos)``: ``"estimated"``, ``"given"``, ``"not detected"`` (the score
        test at zero did not find it, p-value in ``p_values``; or found it, p-value below
        1 %, and the fit's variance-component rounds brought its scale back to zero),
        ``"misfit"`` (the score test found it, but the fitted scale is far above what the
        score shows: the per-view errors absorbed a model misfit, p-value in
        ``consistency_p``; the poses are taken as exact for it) or ``"off"``.
    rot_deg : (n_views, 3) float
        Each view's estimated rotation error ``delta_i`` (degrees, flange frame; one
        orientation: the camera's rotation error in the robot axes).
    pos : (n_views, 3) float
        Each view's estimated position error ``eps_i`` (robot units, base frame; one
        orientation: the camera centre's).
    rot_std_deg, pos_std : (n_views, 3) float
        Their standard deviations.
    redundancy : (2,) float
        Redundancy (share of the residual degrees of freedom) of the two priors.
    p_values : (2,) float
        p-values of the score tests of ``sigma = 0`` (NaN where not tested).
    scene_side : bool
        The errors act as eye-to-hand (eq. 2 of :mod:`transcalib.estimate.robot_error`:
        the flange carries the scene) rather than on the camera (eq. 1).
    consistency_p : (2,) float
        Lower-tail p-values of each fitted scale against its score at zero, every fitted
        component present (:class:`transcalib.estimate.variance_components.JointScore`;
        NaN where not fitted); below 1 %: ``"misfit"``.
    score_scales : (2,) float
        ``(sigma_rot_deg, sigma_pos)`` as the score tests at zero estimated them (their
        moment estimates, each component alone: the data's first-order evidence; NaN
        where not tested). Where a component is a misfit, the tracks are judged with
        these scales (:func:`transcalib.pipeline.stages.refine_and_rejudge`).
    """

    sigma_rot_deg: float
    sigma_pos: float
    sigma_rot_std_deg: float
    sigma_pos_std: float
    source: tuple
    rot_deg: np.ndarray
    pos: np.ndarray
    rot_std_deg: np.ndarray
    pos_std: np.ndarray
    redundancy: np.ndarray
    p_values: np.ndarray
    scene_side: bool = False
    consistency_p: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    score_scales: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))

    def __post_init__(self):
        _freeze(self, arrays=("rot_deg", "pos", "rot_std_deg", "pos_std", "redundancy", "p_values", "consistency_p",
                              "score_scales"),
                sequences=("source",))

    def __eq__(self, other) -> bool:
        return isinstance(other, RobotError) and _same_fields(self, other)

    __hash__ = None

    @property
    def active(self) -> bool:
        """Whether the calibration modelled a robot pose error."""
        return self.sigma_rot_deg > 0 or self.sigma_pos > 0


@dataclass(frozen=True, eq=False)
class HandEye:
    """The camera's pose relative to the robot (:attr:`Calibration.hand_eye`).

    Eye-in-hand: the camera in the flange frame, ``R_flange_camera``, ``t_flange_camera``
    (``R_X``, ``t_X``). Eye-to-hand: the fixed camera in the robot base frame,
    ``R_base_camera``, ``t_base_camera``; the scene points are then in the flange frame.

    Attributes
    ----------
    setup : {"eye-in-hand", "eye-to-hand"}
    R : (3, 3) float
        Camera -> flange (eye-in-hand) or camera -> base (eye-to-hand) rotation.
    t : (3,) float
        The camera centre in that frame (robot units); zero along ``undetermined``.
    R_std_deg : (3,) float
        Standard deviation of the small rotation ``w`` in ``R <- R exp(-[w]x)`` (about the
        camera axes, degrees).
    t_cov : (3, 3) float
        Covariance of ``t`` (zero along ``undetermined``).
    undetermined : (3, k) float
        Orthonormal directions of ``t`` the motion leaves free; (3, 0) when determined.
    session_of_view : (n_views,) int
        Session of each view (views of one flange orientation; a single view at its own
        orientation is a session of one view).
    session_labels : tuple of str
    notes : tuple of str
        What the motion leaves undetermined and what would determine it; views off their
        session's orientation.
    """

    setup: str
    R: np.ndarray
    t: np.ndarray
    R_std_deg: np.ndarray
    t_cov: np.ndarray
    undetermined: np.ndarray
    session_of_view: np.ndarray
    session_labels: tuple = ()
    notes: tuple = ()

    def __post_init__(self):
        _freeze(self, arrays=("R", "t", "R_std_deg", "t_cov", "undetermined", "session_of_view"),
                sequences=("session_labels", "notes"))

    @property
    def t_std(self) -> np.ndarray:
        """(3,) standard deviations of ``t`` (robot units)."""
        return np.sqrt(np.clip(np.diag(self.t_cov), 0.0, None))

    @property
    def frame(self) -> str:
        """The frame ``R`` and ``t`` are in: ``"flange"`` or ``"base"``."""
        return "flange" if self.setup == "eye-in-hand" else "base"

    @property
    def n_sessions(self) -> int:
        return len(self.session_labels)

    def __eq__(self, other) -> bool:
        return isinstance(other, HandEye) and _same_fields(self, other)

    __hash__ = None


@dataclass(frozen=True, eq=False, kw_only=True)
class Calibration:
    """A complete calibration: what :func:`transcalib.calibrate` returns.

    Attributes
    ----------
    camera : Camera
        ``K``, ``R``, distortion and image size (also as the properties ``K``, ``R``,
        ``dist``, ``dist_model``, ``image_size``). ``R`` maps flange vectors to the camera
        frame; without orientations in the poses the flange axes are the robot axes, so
        ``R`` is then the robot -> camera rotation. :meth:`camera_poses` gives each view's.
    X : (n_points, 3) float
        Scene points in world axes and user units; NaN for unused points.
    residuals_px : (n_views, n_points, 2) float
        Observed minus predicted pixel positions; NaN where a point is not seen or could
        not be triangulated.
    rms_px : float
        ``sqrt(mean(du**2 + dv**2))`` over the used observations (OpenCV's RMS convention).
    T : (n_views, 3) float
        The flange positions used (the measured ones, or their refined values when the
        robot noise was modelled); eye-to-hand: the base origin in the flange frame
        ``-R_i^T T_i``.
    sigma_px : float or None
        Pixel noise per coordinate: estimated from the residuals (or the known value).
    diagnostics : tuple of Diagnostic
        Warnings, each naming the cause and what to do; empty when the data look healthy.
    linear : LinearEstimate or None
        The linear estimate the result started from.
    cov : (p, p) float or None
        Covariance of the parameters named by ``param_names`` (refined results only;
        rotations in degrees).
    std : mapping of str to float
        Standard deviations by parameter name (rotation angles in degrees).
    param_names : tuple of str
        Names of the parameters in ``cov``.
    X_std : (n_points, 3) float or None
        Standard deviation of each scene point coordinate.
    inliers : (n_points,) bool or None
        Points classified as inliers (robust estimation), else None (all used).
    T_std : (n_views, 3) float or None
        Standard deviation of each refined translation (robot noise modelled: ``sigma_T``).
    view_rotations : ViewRotations or None
        Rotations fitted per view (``RefineOptions.estimate_view_rotations``).
    flange_rotations : (n_views, 3, 3) float or None
        The flange orientation of each view as the model uses it (flange -> base ``R_i``;
        eye-to-hand: base -> flange ``R_i^T``); None without orientations in the poses.
    hand_eye : HandEye or None
        The camera relative to the robot (with orientations in the poses).
    robot_error : RobotError or None
        The robot's pose error: its scales and each view's error (refined runs).
    uncertainty : Uncertainty or None
        The model-based and the cluster-robust (sandwich) std side by side, and which
        one ``std`` / ``cov`` report (refined runs).
    options : CalibrateOptions or None
        What the calibration was asked to do.
    stats : CalibrationStats
        How it was obtained: stages, timings, the robust stage, the refinement, the
        distortion choice.
    info : mapping
        Free-form extras (read-only).
    """

    camera: Camera
    X: np.ndarray
    residuals_px: np.ndarray
    rms_px: float
    T: np.ndarray
    sigma_px: float | None = None
    diagnostics: tuple = ()
    linear: LinearEstimate | None = None
    cov: np.ndarray | None = None
    std: Mapping = field(default_factory=dict)
    param_names: tuple = ()
    X_std: np.ndarray | None = None
    inliers: np.ndarray | None = None
    T_std: np.ndarray | None = None
    view_rotations: ViewRotations | None = None
    flange_rotations: np.ndarray | None = None
    hand_eye: HandEye | None = None
    robot_error: RobotError | None = None
    uncertainty: Uncertainty | None = None
    options: CalibrateOptions | None = None
    stats: CalibrationStats = field(default_factory=CalibrationStats)
    info: Mapping = field(default_factory=dict)

    def __post_init__(self):
        _freeze(self, arrays=("X", "residuals_px", "T", "cov", "X_std", "inliers", "T_std", "flange_rotations"),
                mappings=("std", "info"), sequences=("diagnostics", "param_names"))

    @property
    def K(self) -> np.ndarray:
        return self.camera.K

    @property
    def R(self) -> np.ndarray:
        return self.camera.R

    @property
    def dist(self) -> np.ndarray:
        return self.camera.dist

    @property
    def dist_model(self) -> str:
        return self.camera.dist_model

    @property
    def image_size(self) -> tuple | None:
        return self.camera.image_size

    @property
    def A(self) -> np.ndarray:
        """``K @ R`` (3, 3)."""
        return self.camera.K @ self.camera.R

    @property
    def dist_opencv(self) -> np.ndarray:
        """The five OpenCV coefficients ``k1, k2, p1, p2, k3`` (zeros beyond the model),
        ready for ``cv2.undistort`` / ``cv2.projectPoints``."""
        return self.camera.dist5

    @property
    def n_views(self) -> int:
        return int(self.residuals_px.shape[0])

    def camera_poses(self, T=None, flange_rotations=None) -> tuple[np.ndarray, np.ndarray]:
        """Each view's camera pose in the frame of ``X``: rotations world -> camera
        ``(n_views, 3, 3)`` and centres ``(n_views, 3)``.

        ``R_cam,i = R R_i^T`` and ``C_i = T_i + R_i t`` with the flange rotations ``R_i``
        (identity without orientations) and ``t`` the camera's offset (``hand_eye.t``;
        zero without orientations: the points are then relative to the camera centre at
        ``T = 0``).

        ``T (n, 3)`` and ``flange_rotations (n, 3, 3)`` place other flange poses (in the
        model's form, eye-to-hand inverted as in ``flange_rotations``) with the same
        camera: views the calibration did not see. Without orientations the
        calibration's one orientation is used, and ``flange_rotations`` must be None."""
        R = np.asarray(self.R)
        if T is None:
            re = self.robot_error
            if re is not None and re.active:  # the calibration's own views: their poses corrected
                return self._camera_poses_with_robot_error(R, re)
            T, Ri = self.T, self.flange_rotations
        else:
            T, Ri = np.asarray(T, dtype=float), flange_rotations
            if (Ri is None) != (self.flange_rotations is None):
                raise InputError("camera_poses: give flange rotations exactly when the calibration has them")
        if Ri is None:
            return np.broadcast_to(R, (len(T), 3, 3)).copy(), np.array(T, dtype=float)
        Ri = np.asarray(Ri, dtype=float)
        t = np.zeros(3) if self.hand_eye is None else np.asarray(self.hand_eye.t)
        return R @ np.transpose(Ri, (0, 2, 1)), T + Ri @ t

    def _camera_poses_with_robot_error(self, R: np.ndarray, re: "RobotError"):
        """:meth:`camera_poses` of the true poses, the reported ones times the estimated
        errors (:mod:`transcalib.estimate.robot_error`): on the camera side ``R_cam = R
        exp(-[delta]x) R_i^T``, ``C = T + eps + R_i exp([delta]x) t``; on the scene side
        ``R_cam = R R_i^T exp([delta]x)``, ``C = exp(-[delta]x) (T + R_i t - R_i eps)``."""
        from ..geometry.rotation import rotvec_to_matrix

        n = self.n_views
        Ri = np.tile(np.eye(3), (n, 1, 1)) if self.flange_rotations is None else np.asarray(self.flange_rotations)
        t = np.zeros(3) if self.hand_eye is None else np.asarray(self.hand_eye.t, float)
        H = rotvec_to_matrix(np.radians(np.asarray(re.rot_deg, float)))
        Rt = np.transpose(Ri, (0, 2, 1))
        eps = np.asarray(re.pos, float)
        T = np.asarray(self.T, float)
        if re.scene_side:
            C = np.einsum("vba,vb->va", H, T + Ri @ t - np.einsum("vab,vb->va", Ri, eps))
            return R @ Rt @ H, C
        return R @ np.transpose(H, (0, 2, 1)) @ Rt, T + eps + np.einsum("vab,vbc,c->va", Ri, H, t)

    @property
    def n_points(self) -> int:
        return int(self.residuals_px.shape[1])

    def __eq__(self, other) -> bool:
        return isinstance(other, Calibration) and _same_fields(self, other)

    __hash__ = None


def _same_fields(a, b) -> bool:
    return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))


def _same(a, b) -> bool:
    """Equality of result values: arrays element-wise (NaN equals NaN), containers deeply."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and bool(np.all((a == b) | (_isnan(a) & _isnan(b))))
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, Diagnostic) or isinstance(b, Diagnostic):
        return str(a) == str(b) and getattr(a, "code", None) == getattr(b, "code", None)
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def _isnan(a: np.ndarray) -> np.ndarray:
    return np.isnan(a) if np.issubdtype(a.dtype, np.floating) else np.zeros(a.shape, bool)
