"""``plan()`` and ``evaluate_plan()``: where to move the robot, and what given moves achieve.

Both predict the accuracy of a design from the Cramér–Rao bound of the scene model
(:mod:`.model`) — the covariance the maximum-likelihood calibration attains, with only
the observations that stay inside the image counted — so a plan is judged before a
single image is taken. Criterion (stated in every result): minimise the mean predicted
variance of ``fx`` and ``fy`` (``criterion="focal"``) or of ``fx, fy, cx, cy``
(``"intrinsics"``), subject to every view seeing at least ``min_visible`` of the points.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import DegenerateError, Diagnostic, InputError
from ..validate import WEAK_SPAN_RATIO
from .fisher import predict
from .model import CRITERIA, PlanOptions, check_box, options_from, scene_points, visible
from .optimise import optimise
from .patterns import PATTERNS, pattern_variants

__all__ = ["Plan", "Evaluation", "plan", "evaluate_plan"]

MIN_VIEWS, MAX_VIEWS = 4, 50
#: Warn when the typical image motion of the largest move is below this many noise sigmas.
SMALL_MOTION_SIGMAS = 20.0
#: Warn when the predicted std of fx exceeds this fraction of the focal length.
WEAK_FX_FRACTION = 0.01
#: Candidate grid of the exchange: positions per box axis.
GRID = 5
#: Default smallest distance between planned views, as a fraction of the box's largest side.
MIN_SEPARATION = 0.05


@dataclass(frozen=True, eq=False)
class Evaluation:
    """Predicted accuracy of a set of translations.

    Attributes
    ----------
    T : (n_views, 3) float
        The translations (robot frame and unit).
    predicted_std : dict of str to float
        CRLB std of ``fx, fy, cx, cy`` (px), distortion coefficients, ``rx, ry, rz`` (deg).
    criterion : float
        RMS predicted std of the criterion's parameters (px).
    point_std : float
        Median over points of the predicted std of a reconstructed point (RMS of x, y, z;
        robot units).
    visible : (n_views,) float
        Fraction of the points each view sees.
    warnings : list of Diagnostic
        Weak design: ``too_few_views``, ``coplanar_moves``, ``small_moves``, ``points_leave_image``,
        ``weak_design``, ``outside_box``.
    """

    T: np.ndarray
    predicted_std: dict
    criterion: float
    point_std: float
    visible: np.ndarray
    warnings: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"T": self.T.tolist(), "predicted_std": self.predicted_std, "criterion_px": self.criterion,
                "point_std_median": self.point_std, "visible_fraction": self.visible.tolist(),
                "warnings": [str(w) for w in self.warnings], "warning_codes": [w.code for w in self.warnings]}


@dataclass(frozen=True, eq=False)
class Plan:
    """A planned design, its prediction and the standard patterns' in the same box.

    Attributes
    ----------
    T : (n_views, 3) float
        Translations to command (robot frame and unit).
    R : (3, 3) float
        Assumed rotation robot -> camera.
    evaluation : Evaluation
        Prediction of ``T``.
    patterns : dict of str to Evaluation
        Best variant of each standard pattern (:mod:`.patterns`), same views, same box.
    options : PlanOptions
    box : (3, 2) float
    criterion : str
        Statement of what was minimised.
    time_s : float
    """

    T: np.ndarray
    R: np.ndarray
    evaluation: Evaluation
    patterns: dict
    options: PlanOptions
    box: np.ndarray
    criterion: str
    time_s: float

    @property
    def predicted_std(self) -> dict:
        return self.evaluation.predicted_std

    def to_dict(self) -> dict:
        o = self.options
        return {
            "R": self.R.tolist(), "predicted_std": self.predicted_std, "criterion": self.criterion,
            "criterion_px": self.evaluation.criterion, "point_std_median": self.evaluation.point_std,
            "visible_fraction": self.evaluation.visible.tolist(), "T": self.T.tolist(),
            "warnings": [str(w) for w in self.evaluation.warnings],
            "patterns": {k: {"T": v.T.tolist(), "predicted_std": v.predicted_std, "criterion_px": v.criterion,
                             "visible_fraction": v.visible.tolist(), "warnings": [str(w) for w in v.warnings]}
                         for k, v in self.patterns.items()},
            "box": self.box.tolist(), "time_s": self.time_s,
            "options": {"image_size": list(o.image_size), "focal_px": o.focal_px, "distance": o.distance,
                        "depth_range": o.depth_range, "n_points": o.n_points, "noise_px": o.noise_px,
                        "view_direction": o.view_direction if isinstance(o.view_direction, str)
                        else list(np.asarray(o.view_direction, float)), "robot_noise": o.robot_noise,
                        "robot_sigma_deg": o.robot_sigma_deg, "distortion": o.distortion, "dist": list(o.dist), "min_visible": o.min_visible,
                        "margin_px": o.margin_px},
        }


def _criterion_text(options: PlanOptions) -> str:
    names = ", ".join(CRITERIA[options.criterion])
    return (f"minimise the mean predicted variance (CRLB) of {names}, every view seeing at least "
            f"{options.min_visible:.0%} of the points")


def _check_T(T) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.ndim != 2 or T.shape[1] != 3 or not np.all(np.isfinite(T)):
        raise InputError(f"translations must be a finite (n_views, 3) array, got shape {T.shape}")
    return T


def _std_dict(p, b=None) -> dict:
    """The camera's predicted std, without the views' own nuisance parameters (the
    translations' priors ``T<i>_*``, the pose errors ``robot<i>_*``)."""
    return {k: float(v if b is None else v[b]) for k, v in p.std.items() if not k.startswith(("T", "robot"))}


def _warnings(options: PlanOptions, X, T, p, box) -> list:
    w = []
    m = len(T)
    if m < MIN_VIEWS:
        w.append(Diagnostic("too_few_views", f"{m} views: at least {MIN_VIEWS} are needed (three independent "
                                             "moves from a reference view); nothing is determined"))
    elif m == MIN_VIEWS:
        w.append(Diagnostic("too_few_views", f"only {m} views, the minimum: no redundancy to detect a bad view; "
                                             "each doubling of the views divides the std by about 1.4"))
    sv = np.linalg.svd(T - T.mean(axis=0), compute_uv=False) if m >= 2 else np.zeros(3)
    sv = np.pad(sv, (0, 3 - len(sv)))
    if sv[0] == 0 or sv[2] < WEAK_SPAN_RATIO * sv[0]:
        w.append(Diagnostic("coplanar_moves", f"the moves are nearly coplanar (spread {sv[2]:.3g} across the plane "
                                              f"vs {sv[0]:.3g} along it): move out of the plane too, the focal "
                                              "length and the principal point need 3-D moves"))
    uv = _project(options, X, T)
    shift = np.linalg.norm(uv - uv[:1], axis=2)  # (m, n), NaN where unseen in view 0 or i
    motion = np.array([np.median(r[np.isfinite(r)]) if np.isfinite(r).any() else 0.0 for r in shift[1:]] or [0.0])
    if motion.max() < SMALL_MOTION_SIGMAS * options.noise_px:
        w.append(Diagnostic("small_moves", f"the moves are too small for the noise: the largest typical image "
                                           f"motion is {motion.max():.3g} px, under {SMALL_MOTION_SIGMAS:g} x "
                                           f"the {options.noise_px:g} px noise; make larger moves"))
    few = np.flatnonzero(p.visible < options.min_visible)
    if len(few):
        w.append(Diagnostic("points_leave_image", f"views {few.tolist()} see only {np.min(p.visible):.0%} of the "
                                                  f"points (fewer than {options.min_visible:.0%}): smaller sideways "
                                                  "moves or a longer working distance"))
    fx = float(np.asarray(p.std["fx"]))
    if not np.isfinite(fx) or fx > WEAK_FX_FRACTION * options.focal_px:
        w.append(Diagnostic("weak_design", f"predicted std of fx is {fx:.3g} px ({fx / options.focal_px:.2%} of "
                                           "the focal length): a weak design; plan one with `transcalib plan`"))
    if m >= 2:
        dist = np.linalg.norm(T[:, None] - T[None], axis=2)[np.triu_indices(m, 1)]
        side = np.max(np.ptp(T, axis=0))
        if np.min(dist) <= 1e-6 * max(side, 1e-300):
            w.append(Diagnostic("repeated_positions", "two views are at the same position: a repeat adds no "
                                                      "geometry and the linear start of the calibration breaks "
                                                      "down on exact repeats; move it elsewhere"))
    if box is not None and np.any((T < box[:, 0] - 1e-9) | (T > box[:, 1] + 1e-9)):
        w.append(Diagnostic("outside_box", "some translations are outside the given box"))
    return w


def _project(options, X, T):
    from ..geometry.camera import project

    uv = project(options.K, options.R, X, T, options.dist)
    uv[~visible(options, X, T)] = np.nan
    return uv


def _evaluation(options, X, T, box) -> Evaluation:
    p = predict(options, X, T, points=True)
    std = _std_dict(p)
    crit = float(np.sqrt(np.mean([std[k] ** 2 for k in CRITERIA[options.criterion]])))
    pstd = float(np.nanmedian(p.point_std)) if np.isfinite(p.point_std).any() else float("inf")
    return Evaluation(T.copy(), std, crit, pstd, np.asarray(p.visible), _warnings(options, X, T, p, box))


def evaluate_plan(T, options: PlanOptions | None = None, *, box=None, rng=0, **option_kwargs) -> Evaluation:
    """Predict what given translations achieve, and warn about a weak design.

    Parameters
    ----------
    T : (n_views, 3) float
        Robot translations (robot frame and unit).
    options : PlanOptions, optional
        The camera and scene; or give its fields as keyword arguments.
    box : 6 floats, optional
        The reachable box ``xmin, xmax, ..., zmax``: the model's camera for the scene is at its
        centre (default: the centre of the translations' bounding box).
    rng : seed or Generator
        Draws the model's points (:func:`.model.scene_points`).

    Returns
    -------
    Evaluation
    """
    options = options_from(options, option_kwargs)
    T = _check_T(T)
    b = None if box is None else check_box(box)
    centre = (T.min(axis=0) + T.max(axis=0)) / 2 if b is None else b.mean(axis=1)
    X = scene_points(options, centre, rng)
    return _evaluation(options, X, T, b)


def plan(box, n_views: int, options: PlanOptions | None = None, *, positions=None, rng=0,
         **option_kwargs) -> Plan:
    """Plan the robot translations that calibrate the camera best, with the accuracy predicted.

    Parameters
    ----------
    box : 6 floats ``xmin, xmax, ymin, ymax, zmin, zmax``
        Reachable box of the camera centre (robot frame and unit).
    n_views : int
        Number of views (4..50).
    options : PlanOptions, optional
        Camera, scene, robot precision and criterion; or give its fields as keyword
        arguments (``image_size=(1280, 1024), focal_px=1000, distance=800, ...``).
    positions : (K, 3) float, optional
        Allowed positions (e.g. a robot's taught points): the plan picks ``n_views`` of them
        (no two closer than ``min_separation``); by default any position in the box.
    rng : seed or Generator
        Draws the model's points.

    Returns
    -------
    Plan
        ``T``, ``predicted_std`` and the standard patterns' predictions.

    Notes
    -----
    Criterion ``c(T) = sqrt(mean_k [sigma_px^2 S(T)^-1]_kk)`` over ``k`` in ``fx, fy`` (or
    ``fx, fy, cx, cy``), ``S`` the reduced Fisher information of :mod:`.fisher`; minimised
    over designs whose every view sees at least ``min_visible`` of the points (:mod:`.optimise`).
    """
    t0 = time.perf_counter()
    options = options_from(options, option_kwargs)
    b = check_box(box)
    if isinstance(n_views, bool) or int(n_views) != n_views or not (MIN_VIEWS <= n_views <= MAX_VIEWS):
        raise InputError(f"n_views must be an integer in {MIN_VIEWS}..{MAX_VIEWS}, got {n_views!r}")
    n_views = int(n_views)
    if positions is not None:
        cand = _check_T(positions)
        if len(cand) < 1:
            raise InputError("positions must hold at least one allowed position")
        b = np.column_stack([np.minimum(b[:, 0], cand.min(0)), np.maximum(b[:, 1], cand.max(0))])
    flat = [axis for axis, (lo, hi) in zip("xyz", b) if not hi > lo]
    if flat:
        raise DegenerateError(f"no design in this box determines the calibration: the box has no extent along "
                              f"{', '.join(flat)}, and the moves must span all three axes")
    X = scene_points(options, b.mean(axis=1), rng)
    patterns = {name: _best_variant(options, X, pattern_variants(name, b, n_views), b) for name in PATTERNS}
    if positions is None:
        axes = [np.linspace(lo, hi, GRID) for lo, hi in b]
        cand = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    feasible = [v for v in patterns.values() if np.all(v.visible >= options.min_visible)]
    start = min(feasible or patterns.values(), key=lambda e: e.criterion).T
    if positions is not None:  # start from the allowed positions nearest to it
        start = cand[np.argmin(np.linalg.norm(start[:, None] - cand[None], axis=2), axis=1)]
    side = float(np.max(b[:, 1] - b[:, 0]))
    min_sep = MIN_SEPARATION * side if options.min_separation is None else options.min_separation
    T, _ = optimise(options, X, start, b, cand, polish=positions is None, step=side / (GRID - 1) / 2,
                    min_sep=min_sep)
    ev = _evaluation(options, X, T, b)
    best = min(feasible, key=lambda e: e.criterion, default=None)
    if positions is None and best is not None and best.criterion < ev.criterion:  # search left out robot noise
        T, ev = best.T.copy(), best
    if not np.isfinite(ev.criterion):
        raise DegenerateError("no design in this box determines the calibration: the box must allow moves "
                              "along all three axes, and the points must stay in view")
    return Plan(T, options.R, ev, patterns, options, b, _criterion_text(options), time.perf_counter() - t0)


def _best_variant(options, X, variants: np.ndarray, box) -> Evaluation:
    """The variant of a pattern with the best criterion (feasible ones first)."""
    p = predict(options, X, variants)
    crit = np.sqrt(np.mean([p.std[k] ** 2 for k in CRITERIA[options.criterion]], axis=0))
    ok = np.all(p.visible >= options.min_visible, axis=1)
    order = np.lexsort((crit, ~ok))
    return _evaluation(options, X, variants[order[0]], box)
