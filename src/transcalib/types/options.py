"""Option dataclasses of every stage: checked when they are made.

A misspelt option name is a ``TypeError``, a bad value an :class:`InputError` naming the
option. :class:`CalibrateOptions` records everything a calibration was asked to do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from types import MappingProxyType

import numpy as np

from ..errors import InputError
from ..geometry.camera import DIST_MODELS

#: Names of the intrinsic parameters, as used by ``fix`` and ``Calibration.std``.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "skew")
#: Parameters ``RefineOptions.fix`` accepts: intrinsics and distortion coefficients.
FIXABLE = INTRINSIC_NAMES + ("k1", "k2", "p1", "p2", "k3")
#: Robust losses of the refinement.
LOSSES = ("linear", "huber", "cauchy")
#: Where the camera is: on the flange (moved by the robot) or fixed, watching the flange.
SETUPS = ("eye-in-hand", "eye-to-hand")


def _positive(name: str, value, *, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(value) and value > 0):
        raise InputError(f"{name} must be a positive number, got {value!r}")


#: Default largest angle (degrees) between the flange orientations of two views of one session.
SESSION_TOLERANCE_DEG = 1.0


@dataclass(frozen=True)
class RansacOptions:
    """Options of the robust (RANSAC) stage.

    Attributes
    ----------
    threshold_px : float or None
        None (default): the pixel noise is estimated from the data and a track seen in
        ``k`` views is an inlier when its squared reprojection errors sum to less than
        ``sigma^2 chi2_{2k-3}(1 - false_rejection)``. A number overrides the estimate:
        the residual norm of one observation an inlier stays below with probability
        ``1 - false_rejection`` (sigma = threshold / sqrt(chi2_2(1 - false_rejection))).
    false_rejection : float
        Probability, in (0, 0.5), that the inlier rule rejects a good track.
    confidence : float
        Probability, in (0, 1), that an all-inlier pair was drawn when the loop stops.
    max_trials : int
        Upper bound on the hypotheses drawn.
    noise_spread : bool
        True (default): once the refined fit stands (the views whose pose is off left
        out), the tracks are judged again with the spread of their noise that each
        track's two halves of views show (:func:`transcalib.estimate.noise.noise_spread`),
        so the noisier good tracks stay in, and the fit is redone where that changes the
        inliers (docs/robust-and-diagnostics.md §2, "Tracks whose noise differs"). False:
        one noise for every track, the chi-square rule throughout. No effect with
        ``threshold_px``.
    """

    threshold_px: float | None = None
    false_rejection: float = 0.01
    confidence: float = 0.999
    max_trials: int = 1000
    noise_spread: bool = True

    def __post_init__(self):
        _positive("threshold_px", self.threshold_px, allow_none=True)
        if not (isinstance(self.false_rejection, (int, float)) and 0.0 < self.false_rejection < 0.5):
            raise InputError(f"false_rejection must be in (0, 0.5), got {self.false_rejection!r}")
        if not (isinstance(self.confidence, (int, float)) and 0.0 < self.confidence < 1.0):
            raise InputError(f"confidence must be in (0, 1), got {self.confidence!r}")
        if not isinstance(self.noise_spread, bool):
            raise InputError(f"noise_spread must be True or False, got {self.noise_spread!r}")
        if isinstance(self.max_trials, bool) or not isinstance(self.max_trials, (int, np.integer)) \
                or self.max_trials < 1:
            raise InputError(f"max_trials must be a positive integer, got {self.max_trials!r}")


#: What ``Calibration.std`` reports (``RefineOptions.uncertainty``).
UNCERTAINTIES = ("auto", "model", "robust", "max")


@dataclass(frozen=True)
class RefineOptions:
    """Options of the maximum-likelihood refinement (the bundle adjuster).

    Attributes
    ----------
    distortion : {"auto", "none", "radial1", "radial2", "opencv5"}
        Lens distortion model (OpenCV convention). ``"auto"`` (default): chosen from the
        data, climbing none -> radial2 -> opencv5 while a score test of the added
        coefficients is significant at 1 % and they are determined
        (``Calibration.stats.distortion_selection`` says why).
    estimate_skew : bool
        Estimate the skew ``K[0, 1]`` (else fixed at its start value, 0 by default).
    fix : mapping of str to float
        Parameters held at known values: any of ``fx, fy, cx, cy, skew`` and ``k1, k2,
        p1, p2, k3`` (e.g. ``{"cx": 320.0, "cy": 240.0}`` from the lens maker).
    square_pixels : bool
        One focal length: ``fx = fy``.
    sigma_T : float or tuple of float, optional
        Robot translation precision (user units), one value or one per view: the
        translations become measurements. None: exact translations. (The older model
        of position noise; it turns ``robot_error`` off. Prefer ``robot_sigma_pos``.)
    robot_error : bool or None
        Model each view's robot pose error (flange rotation and position,
        :mod:`transcalib.estimate.robot_error`) as nuisance parameters with Gaussian
        priors: None (default) or True. A component whose scale is not given is
        estimated from the data together with the pixel noise (variance components)
        when a score test at zero finds it (1 %), else it stays off (with a perfect
        robot the result is then the exact-pose model's); a fitted scale far above what
        that score showed (lower 0.1 % tail: the per-view errors absorbed a model misfit) is
        left out again (``RobotError.source`` ``"misfit"``). With ``distortion="auto"``
        the lens is chosen first, with exact poses. The covariance includes the
        components kept. False: exact poses. ``sigma_T`` turns it off.
    robot_sigma_deg : float, optional
        Known per-axis std of each view's flange rotation error (degrees; 0: exact
        orientations). None (default): estimated.
    robot_sigma_pos : float, optional
        Known per-axis std of each view's flange position error (robot units; 0: exact
        positions). None (default): estimated.
    loss : {"linear", "huber", "cauchy"}
        Loss of the residual norm; ``loss_scale_px`` its scale.
    loss_scale_px : float, optional
        Scale of a robust loss (pixels). None (default): from the pixel noise estimated
        robustly from the residuals (Huber 1.345 sigma, Cauchy 2.385 sigma).
    inlier_threshold_px : float, optional
        Residual norm above which a robust loss's observation is an outlier (default
        ``3.72 sigma``, exceeded by 0.1 % of Gaussian inliers; ``3 * loss_scale_px`` when
        a scale is given).
    sigma_px : float, optional
        Known pixel noise per coordinate; by default estimated from the residuals.
    max_iterations : int
        Maximum number of accepted Levenberg-Marquardt steps.
    tol : float
        Stop when a step moves the parameters by less than about ``sqrt(2 tol)``
        standard deviations.
    estimate_view_rotations : bool or tuple of int
        A rotation per view ``i >= 1`` (True) or per listed view: the model-violation
        alternative used by the rotation test.
    uncertainty : {"auto", "model", "robust", "max"}
        What ``Calibration.std`` / ``cov`` report (both are always in
        ``Calibration.uncertainty``): the model-based ``sigma^2 S^-1`` ("model"), the
        cluster-robust sandwich ("robust"), per parameter the larger ("max"), or per
        parameter the sandwich where it is significantly (5 %) larger than the model's
        (the model misses a misfit), else the model's ("auto", default;
        docs/uncertainty.md §7).
    view_field : bool
        Test the residuals for an error field alike over each view's points (a smooth
        field over the image of degree 1 and 2: a tracker's per-view bias) and, where the
        likelihood-ratio test finds it (5 %), include its effect in the model-based
        covariance (:mod:`transcalib.estimate.view_field`; docs/uncertainty.md §7.1).
        The estimate itself does not change. False: the model without it.
    session_error : bool
        With several sessions and the robot error modelled per view, test for a part of
        it common to each session's views and, where the likelihood-ratio test finds it
        (5 %), include its effect in the model-based covariance
        (:mod:`transcalib.estimate.session_error`; docs/uncertainty.md §7.2). The
        estimate itself does not change. False: the model without it.
    """

    distortion: str = "auto"
    estimate_skew: bool = False
    fix: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    square_pixels: bool = False
    sigma_T: float | tuple | None = None
    loss: str = "linear"
    loss_scale_px: float | None = None
    inlier_threshold_px: float | None = None
    sigma_px: float | None = None
    max_iterations: int = 100
    tol: float = 1e-6
    estimate_view_rotations: bool | tuple = False
    robot_error: bool | None = None
    robot_sigma_deg: float | None = None
    robot_sigma_pos: float | None = None
    uncertainty: str = "auto"
    view_field: bool = True
    session_error: bool = True

    def __post_init__(self):
        for name in ("view_field", "session_error"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InputError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if self.uncertainty not in UNCERTAINTIES:
            raise InputError(f"uncertainty must be one of {', '.join(UNCERTAINTIES)}, got {self.uncertainty!r}")
        if self.distortion not in ("auto", *DIST_MODELS):
            raise InputError(f"distortion must be 'auto' or one of {', '.join(DIST_MODELS)}, got {self.distortion!r}")
        if self.loss not in LOSSES:
            raise InputError(f"loss must be one of {', '.join(LOSSES)}, got {self.loss!r}")
        _positive("loss_scale_px", self.loss_scale_px, allow_none=True)
        _positive("inlier_threshold_px", self.inlier_threshold_px, allow_none=True)
        _positive("sigma_px", self.sigma_px, allow_none=True)
        if isinstance(self.max_iterations, bool) or int(self.max_iterations) != self.max_iterations \
                or self.max_iterations < 0:
            raise InputError(f"max_iterations must be a non-negative integer, got {self.max_iterations!r}")
        if not (isinstance(self.tol, (int, float)) and self.tol >= 0):
            raise InputError(f"tol must be a number >= 0, got {self.tol!r}")
        object.__setattr__(self, "fix", MappingProxyType(_check_fix(self.fix)))
        object.__setattr__(self, "sigma_T", _check_sigma_T(self.sigma_T))
        rot = self.estimate_view_rotations
        if not isinstance(rot, bool):
            try:
                rot = tuple(sorted({int(v) for v in rot}))
            except (TypeError, ValueError):
                raise InputError("estimate_view_rotations must be a bool or a sequence of view indices, "
                                 f"got {self.estimate_view_rotations!r}") from None
            object.__setattr__(self, "estimate_view_rotations", rot)
        if self.estimate_skew and "skew" in self.fix:
            raise InputError("estimate_skew=True contradicts fix['skew']: the skew cannot be both free and known")
        _check_robot(self)

    def __hash__(self):
        return hash((self.distortion, tuple(self.fix.items()), self.sigma_T, self.loss))


def check_fixed_distortion(opts: "RefineOptions") -> None:
    """A distortion coefficient in ``opts.fix`` needs a model that holds it: ``"auto"``
    starts without distortion, ``"radial1"`` has no ``k2``. Checked at the public
    boundary (``calibrate``, ``refine``), not in ``__post_init__``: the stages build
    distortion-free options with the same ``fix`` for their own ends.

    Raises
    ------
    InputError
        Naming the coefficients and the models that hold them.
    """
    fixed = [name for name in opts.fix if name in DIST_MODELS["opencv5"]]
    if not fixed:
        return
    holding = [m for m, names in DIST_MODELS.items() if set(fixed) <= set(names)]
    if opts.distortion == "auto":
        raise InputError(f"fix: {', '.join(fixed)} is a distortion coefficient, but distortion='auto' starts without "
                         f"distortion; give the model as well: distortion={holding[0]!r} (or one of "
                         f"{', '.join(map(repr, holding))})")
    missing = [name for name in fixed if name not in DIST_MODELS[opts.distortion]]
    if missing:
        raise InputError(f"fix: {', '.join(missing)} is not a coefficient of distortion={opts.distortion!r}; "
                         f"choose a model that has it: {', '.join(map(repr, holding))}")


def _check_fix(fix) -> dict:
    try:
        items = dict(fix).items()
    except (TypeError, ValueError):
        raise InputError(f"fix must be a mapping of parameter names to values, got {fix!r}") from None
    out = {}
    for name, value in items:
        if name not in FIXABLE:
            raise InputError(f"fix: unknown parameter {name!r}; expected some of {', '.join(FIXABLE)}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise InputError(f"fix: {name} must be a number, got {value!r}") from None
        if not math.isfinite(v) or (name in ("fx", "fy") and v <= 0):
            raise InputError(f"fix: {name} = {value!r} is not a valid value")
        out[name] = v
    return out


def _check_robot(o) -> None:
    """The robot pose error options: non-negative scales, not contradicting ``sigma_T``."""
    if o.robot_error is not None and not isinstance(o.robot_error, (bool, np.bool_)):
        raise InputError(f"robot_error must be True, False or None, got {o.robot_error!r}")
    for name in ("robot_sigma_deg", "robot_sigma_pos"):
        v = getattr(o, name)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating))
                              or not math.isfinite(v) or v < 0):
            raise InputError(f"{name} must be a number >= 0 (0: exact) or None (estimated), got {v!r}")
    given = o.robot_sigma_deg is not None or o.robot_sigma_pos is not None
    if given and o.robot_error is False:
        raise InputError("robot_sigma_deg / robot_sigma_pos need robot_error=True (or None)")
    if given and o.sigma_T is not None:
        raise InputError("sigma_T (the older position-noise model) and robot_sigma_deg / robot_sigma_pos are two "
                         "models of the same error: give robot_sigma_pos instead of sigma_T")


def _check_sigma_T(sigma_T):
    if sigma_T is None:
        return None
    try:
        s = np.asarray(sigma_T, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"sigma_T must be a number or one number per view, got {sigma_T!r}") from None
    if s.ndim > 1 or not np.all(np.isfinite(s)) or np.any(s < 0) or not np.any(s > 0):
        raise InputError(f"sigma_T must be a positive number, or one standard deviation >= 0 per view "
                         f"(0: exact) with at least one positive, got {sigma_T!r}")
    return float(s) if s.ndim == 0 else tuple(float(v) for v in s)


#: Default of :attr:`CalibrateOptions.subset_points`, and its smallest allowed value. 5000
#: tracks x 5 views determine the camera to a small fraction of a pixel; two Gauss-Newton
#: steps with every track reach the joint solution from there (docs/refinement.md §4a).
SUBSET_POINTS = 5_000
MIN_SUBSET_POINTS = 100


@dataclass(frozen=True)
class CalibrateOptions:
    """Everything :func:`transcalib.calibrate` was asked to do (``Calibration.options``).

    Attributes
    ----------
    refine : bool
        Maximum-likelihood refinement after the linear estimate.
    robust : bool or None
        RANSAC before the linear fit; None: on from ``ROBUST_MIN_POINTS`` points.
    ransac : RansacOptions
    refinement : RefineOptions
    check_rotation : bool
        Test for views where the robot rotated, and whether each view's image agrees with
        its recorded pose (needs ``refine``).
    keep_pose_outliers : bool
        Keep a view whose image contradicts its recorded pose in the fit (named by
        ``pose_outlier``); default: left out and the calibration refitted
        (``pose_left_out``).
    unit : str
        Name of the length unit of the translations (messages and files).
    subset_points : int or None
        With more tracks than this, the iterative stages (RANSAC, the refinement to
        convergence, the distortion choice, the re-judging and the rotation test) run on
        a random subset of this many tracks, and two Gauss-Newton steps of the camera
        with every track then give the maximum-likelihood solution of all the data
        (the subset's solution is a few of its standard deviations from it, where the
        cost is nearly quadratic; docs/refinement.md §4a). None: every stage uses every
        track.
    setup : {"eye-in-hand", "eye-to-hand"}
        The camera on the flange, or fixed and watching the flange (which carries the scene).
    session_tolerance_deg : float
        Views whose flange orientations differ by less than this form one session.
    """

    refine: bool = True
    robust: bool | None = None
    ransac: RansacOptions = field(default_factory=RansacOptions)
    refinement: RefineOptions = field(default_factory=RefineOptions)
    check_rotation: bool = True
    keep_pose_outliers: bool = False
    unit: str = "units"
    subset_points: int | None = SUBSET_POINTS
    setup: str = "eye-in-hand"
    session_tolerance_deg: float = SESSION_TOLERANCE_DEG

    def __post_init__(self):
        if self.setup not in SETUPS:
            raise InputError(f"setup must be one of {', '.join(SETUPS)}, got {self.setup!r}")
        _positive("session_tolerance_deg", self.session_tolerance_deg)
        n = self.subset_points
        if n is not None and (isinstance(n, bool) or int(n) != n or n < MIN_SUBSET_POINTS):
            raise InputError(f"subset_points must be None or an integer >= {MIN_SUBSET_POINTS}, got {n!r}")
        if not self.refine:
            changed = [f.name for f in fields(RefineOptions)
                       if getattr(self.refinement, f.name) != getattr(RefineOptions(), f.name)]
            if changed:
                raise InputError(f"refine=False ignores the refinement option(s) {', '.join(changed)}: the "
                                 "linear estimate has no distortion, robot noise, loss or fixed parameters; "
                                 "drop them or refine")
        if self.robust is False and self.ransac != RansacOptions():
            raise InputError("robust=False ignores the RANSAC options given; drop them or use robust=True/None")
