"""A calibration checked on views it never saw: ``validate_views(calibration, uv, poses)``.

New views at any flange pose see some of the calibration's points. Each view's camera
follows from the calibration's model (docs/hand-eye.md; the camera ``(R_X, t_X)`` in the
flange, the view's pose ``(R_i, T_i)``; eye-to-hand the poses inverted once, as
:func:`.motion.motion_of` does)::

    R_cam,i = R R_i^T,   C_i = T_i + R_i t,   x_ij ~ K R_cam,i (X_j - C_i)  (+ distortion)

and every observation is compared with its predicted pixel, ``e_ij = uv_ij - pi(X_j;
i)``: per view and overall the RMS of ``|e|`` (the definition of the calibration's
``rms_px``), the median and the maximum.

**What the calibration left undetermined** (one orientation leaves all of ``t``, two
sessions its component along their common rotation axis: the columns ``U`` of
``hand_eye.undetermined``) is fitted on the new views: moving ``t`` by ``U a`` moves the
points by ``R_ref U a`` (``R_ref`` any calibration view's flange rotation, the same for
all along ``U``), so ``C_i(a) = C_i + R_i U a`` and ``X_j(a) = X_j + R_ref U a``;
``a`` minimises a Huber cost (scale 3 sigma) of the new views' errors, in the directions
the new views determine (listed as ``fitted``).

**What the covariance predicts.** Each observation's expected squared error is
``E|e|^2 = 2 s^2 + sigma^2 (tr(G_j S^-1 G_j^T) + tr(J_X V_j^-1 J_X^T))``: the pixel noise
of the observation plus the calibration's uncertainty carried into the prediction, the
camera's and the point's with their correlation, exactly as the leave-one-view-out
prediction (:mod:`transcalib.check.prediction`). ``S``, ``V_j`` and ``Y_j`` come from the
calibration's problem rebuilt from what it saved (its observations are its predictions
plus its residuals) and linearised at its solution; a new view enters as one more view
of the same model. ``sigma`` is the calibration's pixel noise; ``s`` the new
observations', the larger of ``sigma`` and the noise the new views' tracks show by
themselves (``noise_px``: each view's camera pose refitted freely, the calibration's
camera and points held; tracks linked across orientations are often less precise than
those within a pure-translation session). A wrong calibration cannot be absorbed by
one pose per view, so its errors with the recorded poses stay above that noise (fx 2 %
off in ``benchmarks/bench_validate.py``: median 2.6 px, the views' own noise 0.6 px).
With an offset fitted on the new views the prediction leaves out the fit (which absorbs
part of the error): it is then an upper bound. Under a right calibration
``|e|^2 / (E|e|^2 / 2)`` is chi-square(2), whose median is ``2 ln 2``; the test counts
the observations above their own predicted median (a sign test, robust to the few
mismatched tracks a tracker leaves): more than ``Binomial(n, 1/2)`` allows at
``VALIDATE_ALPHA``, with the median error over ``PRACTICAL_RATIO`` times its predicted
value, is a ``prediction_error`` warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..check.common import camera_poses
from ..check.prediction import prediction_variance
from ..check.rotation import _refinement
from ..errors import Diagnostic, InputError
from ..estimate.bundle import predict_view
from ..estimate.covariance import check_identifiable, linearise, reduced_information
from ..estimate.layout import State
from ..geometry.camera import project
from ..types import Calibration
from .motion import motion_of

__all__ = ["validate_views", "ViewValidation", "VALIDATE_ALPHA", "PRACTICAL_RATIO"]

#: False-alarm rate of the test that the new views' errors exceed the prediction.
VALIDATE_ALPHA = 1e-3
#: ... and the least ratio of the median error to its prediction that counts.
PRACTICAL_RATIO = 1.2
#: Huber scale of the fit of the undetermined offset, in pixel-noise sigmas.
HUBER_SIGMAS = 3.0


@dataclass(frozen=True, eq=False)
class ViewValidation:
    """The calibration's prediction of new views (module docstring).

    Attributes
    ----------
    rms_px, median_px, max_px : float
        Of the error norms ``|e|`` of every observation predicted.
    n_points : int
        Observations predicted (points of the calibration seen in the new views).
    per_view : tuple of dict
        ``{view, rms_px, median_px, n_points}`` per new view.
    fitted : tuple of dict
        ``{name, value, determined}`` of each component of the offset (flange frame,
        the calibration's unit) the calibration left undetermined, fitted on the new
        views; ``determined`` False when the new views determine only some
        combinations of them (the others stay 0).
    predicted_rms_px, predicted_median_px : float
        What the calibration's covariance predicts for ``rms_px`` and ``median_px``.
    p_value : float
        Of the sign test (errors above their predicted median).
    flagged : bool
        The errors are significantly and practically larger than predicted.
    noise_px : float or None
        The pixel noise (per coordinate) of the new views' tracks by themselves (each
        view's pose refitted freely); the prediction's noise is the larger of it and the
        calibration's ``sigma_px``.
    residuals_px : (n_views, n_points, 2) float
        ``e``, NaN where not predicted.
    diagnostics : tuple of Diagnostic
    """

    rms_px: float
    median_px: float
    max_px: float
    n_points: int
    per_view: tuple
    fitted: tuple
    predicted_rms_px: float
    predicted_median_px: float
    p_value: float
    flagged: bool
    noise_px: float | None
    residuals_px: np.ndarray = field(repr=False)
    diagnostics: tuple = ()

    def as_dict(self) -> dict:
        """The figures as plain JSON values (``--json``)."""
        keys = ("rms_px", "median_px", "max_px", "n_points", "predicted_rms_px", "predicted_median_px", "p_value",
                "flagged", "noise_px")
        return {**{k: getattr(self, k) for k in keys}, "per_view": list(self.per_view), "fitted": list(self.fitted),
                "diagnostics": [{"code": d.code, "message": str(d)} for d in self.diagnostics]}


@dataclass(frozen=True, eq=False)
class _Model:
    """The calibration's model of new views: intrinsics, distortion, ``R`` (flange ->
    camera, or world -> camera without orientations), offset ``t``, points ``X``."""

    intr: np.ndarray
    dist5: np.ndarray
    R: np.ndarray
    t: np.ndarray
    X: np.ndarray
    dist_model: str

    def cameras(self, R_i, T_i, shift=np.zeros(3)):
        """``(R_cam (n, 3, 3) or (3, 3), C (n, 3))`` of views with flange rotations ``R_i``
        (None: one orientation, the world axes) and positions ``T_i``; ``shift`` moves ``t``."""
        if R_i is None:
            return self.R, T_i
        return self.R @ np.transpose(R_i, (0, 2, 1)), T_i + R_i @ (self.t + shift)

    def project(self, R_cam, X, C) -> np.ndarray:
        """:func:`project` with this model's intrinsics and distortion."""
        from ..geometry.camera import K_from_params

        slots = {"none": [], "radial1": [0], "radial2": [0, 1], "opencv5": [0, 1, 2, 3, 4]}[self.dist_model]
        return project(K_from_params(*self.intr), R_cam, np.nan_to_num(X), C, self.dist5[slots])

    def predict(self, R_i, T_i, shift=np.zeros(3), moved=None) -> np.ndarray:
        """Pixels ``(n_views, n_points, 2)`` of the views with flange rotations ``R_i``
        and positions ``T_i`` (:meth:`cameras`); ``moved`` (3,) moves the points (the
        undetermined offset)."""
        R_cam, C = self.cameras(R_i, T_i, shift)
        return self.project(R_cam, self.X if moved is None else self.X + moved, C)

    def view_noise(self, uv, R_i, T_i, shift, moved) -> float | None:
        """The pixel noise (per coordinate) the new views' tracks show by themselves: each
        view's camera pose refitted freely (6 parameters; the calibration's camera and
        points held, a soft-L1 loss against mismatches), ``median |e| / sqrt(2 ln 2)``
        over every view's residuals, scaled by ``sqrt(2 m / (2 m - 6 k))`` for the ``k``
        poses fitted to ``m`` observations. None with too few observations."""
        from scipy.optimize import least_squares

        from ..geometry.rotation import rotvec_to_matrix

        X = self.X if moved is None else self.X + moved
        R_cam, C = self.cameras(R_i, T_i, shift)
        R_cam = np.broadcast_to(R_cam, (len(uv), 3, 3))
        errors, k = [], 0
        for i in range(len(uv)):
            seen = np.isfinite(uv[i, :, 0]) & np.isfinite(X[:, 0])
            if seen.sum() < 6:
                continue

            def residuals(p, i=i, seen=seen):
                R = rotvec_to_matrix(p[:3]) @ R_cam[i]
                return (uv[i, seen] - self.project(R, X[seen], C[i: i + 1] + p[3:])[0]).ravel()

            r = least_squares(residuals, np.zeros(6), loss="soft_l1", x_scale="jac").fun.reshape(-1, 2)
            errors.append(np.hypot(r[:, 0], r[:, 1]))
            k += 1
        m = sum(len(e) for e in errors)
        if 2 * m <= 12 * k:
            return None
        return float(np.median(np.concatenate(errors)) / np.sqrt(2 * np.log(2)) * np.sqrt(2 * m / (2 * m - 6 * k)))


def _model(cal: Calibration) -> _Model:
    t = np.zeros(3) if cal.hand_eye is None else np.asarray(cal.hand_eye.t, float)
    return _Model(np.asarray(cal.camera.intrinsics, float), np.asarray(cal.camera.dist5, float),
                  np.asarray(cal.R, float), t, np.asarray(cal.X, float), cal.dist_model)


def validate_views(calibration: Calibration, uv, poses, *, view_ids=None,
                   alpha: float = VALIDATE_ALPHA) -> ViewValidation:
    """Predict new views with a calibration and compare (module docstring).

    Parameters
    ----------
    calibration : Calibration
        What :func:`transcalib.calibrate` returned or :func:`transcalib.load` read;
        refined (its ``sigma_px`` and covariance are the prediction).
    uv : array_like (n_views, n_points, 2)
        Pixels of the calibration's points (the same columns as ``calibration.X``) in
        the new views, NaN where unseen.
    poses : transcalib.Poses or array_like (n_views, 3)
        The new views' flange poses, in the calibration's unit and setup.
    view_ids : sequence of str, optional
        Names of the new views (default the poses' view ids, else the indices).
    alpha : float
        False-alarm rate of the test against the prediction.

    Returns
    -------
    ViewValidation

    Raises
    ------
    InputError
        Shapes that do not match the calibration, orientations missing on one side, no
        point of the calibration seen, a calibration without noise estimate.
    """
    cal, uv, motion = _checked(calibration, uv, poses)
    ids = view_ids or getattr(poses, "views", None) or [str(i) for i in range(len(uv))]
    model = _model(cal)
    U, R_ref = _undetermined(cal, motion)
    shift, fitted, moved = _fit_offset(model, uv, motion, U, R_ref, cal.sigma_px)
    pred = model.predict(motion.R, motion.T, shift, moved)
    e = uv - pred
    e2 = np.sum(e**2, axis=2)
    seen = np.isfinite(e2)
    noise = model.view_noise(uv, motion.R, motion.T, shift, moved)
    sigma_obs = max(cal.sigma_px, noise or 0.0)
    expected = _expected_sq(cal, motion, shift, moved, seen, sigma_obs)
    return _result(e, e2, seen, expected, ids, fitted, cal, alpha, noise)


def _checked(calibration, uv, poses):
    """``(calibration, uv (n_views, n_points, 2) float, Motion)`` or InputError."""
    if not isinstance(calibration, Calibration):
        raise InputError(f"calibration must be a transcalib.Calibration, got {type(calibration).__name__}")
    if not calibration.sigma_px:
        raise InputError("the calibration has no estimate of the pixel noise (sigma_px): validate a refined "
                         "calibration (calibrate with refine=True)")
    uv = np.asarray(uv, float)
    if uv.ndim != 3 or uv.shape[1:] != (calibration.n_points, 2):
        raise InputError(f"uv must be (n_views, {calibration.n_points}, 2), one column per point of the calibration; "
                         f"got shape {uv.shape}")
    setup = calibration.hand_eye.setup if calibration.hand_eye is not None else (
        calibration.options.setup if calibration.options is not None else "eye-in-hand")
    motion = motion_of(poses, setup)
    if motion.n_views != len(uv):
        raise InputError(f"{len(uv)} views in uv but {motion.n_views} poses")
    if (motion.R is None) != (calibration.flange_rotations is None):
        raise InputError("the new poses have orientations but the calibration's had none" if motion.R is not None
                         else "the calibration was made with flange orientations: give the new views' orientations "
                              "too (rotation_format, CLI --rotation-format)")
    uv = np.where(np.isfinite(calibration.X[:, 0])[None, :, None], uv, np.nan)  # points it reconstructed
    if not np.isfinite(uv[..., 0]).any():
        raise InputError("no point of the calibration is seen in the new views (the point ids must be those of "
                         "the calibration's tracks)")
    return calibration, uv, motion


def _undetermined(cal: Calibration, motion):
    """``(U (3, k), R_ref (3, 3))``: the offset's undetermined directions (flange frame)
    and a calibration view's flange rotation (k = 0 without orientations)."""
    if cal.hand_eye is None or cal.flange_rotations is None:
        return np.zeros((3, 0)), np.eye(3)
    U = np.asarray(cal.hand_eye.undetermined, float).reshape(3, -1)
    return U, np.asarray(cal.flange_rotations, float)[0]


def _fit_offset(model: _Model, uv, motion, U, R_ref, sigma: float):
    """Fit ``a`` (the offset along ``U``) on the new views: ``(shift (3,), fitted, moved
    (3,) or None)``; only directions the new views determine (relative singular value of
    the Jacobian above 1e-6) move."""
    if U.shape[1] == 0:
        return np.zeros(3), (), None
    a, c = np.zeros(U.shape[1]), HUBER_SIGMAS * sigma
    for _ in range(8):  # Gauss-Newton with Huber weights, central-difference Jacobian
        r0 = _offset_residuals(model, uv, motion, U, R_ref, a)
        h = 1e-4 * (1.0 + np.abs(model.t).max())
        J = np.stack([(_offset_residuals(model, uv, motion, U, R_ref, a + h * e) -
                       _offset_residuals(model, uv, motion, U, R_ref, a - h * e)) / (2 * h) for e in np.eye(len(a))],
                     axis=1)
        ok = np.isfinite(r0) & np.all(np.isfinite(J), axis=1)
        w = np.sqrt(np.minimum(1.0, c / np.maximum(np.abs(r0[ok]), 1e-300)))
        u_, s, vt = np.linalg.svd(J[ok] * w[:, None], full_matrices=False)
        keep = s > 1e-6 * max(s[0], 1e-300)
        step = -(vt[keep].T @ ((u_[:, keep].T @ (r0[ok] * w)) / s[keep]))
        a += step
        if np.abs(step).max() < 1e-9 * (1.0 + np.abs(a).max()):
            break
    directions = vt[keep]  # (k', k): the combinations the new views determine
    a = directions.T @ (directions @ a)
    names = ("t_x", "t_y", "t_z") if U.shape[1] == 3 else tuple(
        "t along (" + ", ".join(f"{x:+.3f}" for x in u) + ")" for u in U.T)
    complete = bool(keep.sum() == len(a))
    fitted = tuple({"name": nm, "value": float(v), "determined": complete} for nm, v in zip(names, a))
    return U @ a, fitted, R_ref @ U @ a


def _offset_residuals(model: _Model, uv, motion, U, R_ref, a) -> np.ndarray:
    """The new views' residuals (flat) with the offset moved by ``U a``."""
    return (uv - model.predict(motion.R, motion.T, U @ a, R_ref @ U @ a)).ravel()


def _expected_sq(cal: Calibration, motion, shift, moved, seen, sigma_obs: float) -> np.ndarray:
    """``E|e|^2`` per observation (n_views, n_points), NaN where not seen, with the new
    observations' noise ``sigma_obs`` (px per coordinate): the
    calibration's problem rebuilt from its saved observations (its predictions plus
    residuals), linearised at its solution, and each new view appended as a view of the
    same model (module docstring; :func:`transcalib.check.prediction.prediction_variance`)."""
    R_cam, C = camera_poses(cal, cal.T)
    uv_cal = project(cal.K, R_cam, np.nan_to_num(cal.X), C, cal.dist) + cal.residuals_px
    lin = linearise(uv_cal, np.asarray(cal.T, float), cal, _refinement(cal), polish=0)
    red = reduced_information(lin.state, lin.layout, lin.data)
    evals, evecs = check_identifiable(red.S, lin.layout.names(), scale=red.U_diag)
    Sinv = (evecs / evals) @ evecs.T
    used = np.isfinite(cal.X).all(axis=1) & (np.isfinite(uv_cal[..., 0]).sum(axis=0) >= 2)
    idx = np.flatnonzero(used if cal.inliers is None else used & np.asarray(cal.inliers, bool))
    state, n_cal = _with_new_views(lin.state, motion, shift, moved), len(cal.T)
    local = np.full(cal.n_points, -1)
    local[idx] = np.arange(len(idx))
    out = np.full(seen.shape, np.nan)
    for i in range(motion.n_views):
        pts = local[seen[i] & (local >= 0)]
        if len(pts):
            _, _, Jg, JX = predict_view(state, lin.layout, n_cal + i, pts)
            var = prediction_variance(red, Sinv, lin.layout.view_columns(n_cal + i), Jg, JX, pts)
            out[i, idx[pts]] = 2.0 * sigma_obs**2 + cal.sigma_px**2 * var
    return out


def _with_new_views(state: State, motion, shift, moved) -> State:
    """The calibration's state with the new views appended (their flange rotations,
    positions, no rotation error) and the fitted offset applied."""
    n = motion.n_views
    F = None if state.F is None else np.concatenate([state.F, np.transpose(motion.R, (0, 2, 1))])
    X = state.X if moved is None else state.X + moved
    return State(state.intr, state.dist5, state.R, np.concatenate([state.Q, np.tile(np.eye(3), (n, 1, 1))]),
                 np.concatenate([state.T, motion.T]), X, F, state.t + shift)


def _result(e, e2, seen, expected, ids, fitted, cal: Calibration, alpha: float, noise) -> ViewValidation:
    """The figures, the sign test and its warning."""
    from scipy.stats import binom

    err, ex = np.sqrt(e2[seen]), expected[seen]
    over = e2[seen] > 2.0 * np.log(2.0) * ex / 2.0  # above the observation's predicted median
    p = float(binom.sf(int(over.sum()) - 1, len(over), 0.5))
    pred_median = float(np.sqrt(np.log(2.0) * np.median(ex)))
    median = float(np.median(err))
    flagged = bool(p < alpha and median > PRACTICAL_RATIO * pred_median)
    per_view = tuple({"view": str(ids[i]), "rms_px": _rms(np.sqrt(e2[i][seen[i]])),
                      "median_px": float(np.median(np.sqrt(e2[i][seen[i]]))) if seen[i].any() else None,
                      "n_points": int(seen[i].sum())} for i in range(len(e2)))
    diags = ()
    if flagged:
        worst = max((v for v in per_view if v["n_points"]), key=lambda v: v["median_px"])
        diags = (Diagnostic(
            "prediction_error",
            f"the calibration predicts the new views worse than its covariance says: median error {median:.3g} px, "
            f"predicted {pred_median:.3g} px ({int(over.sum())} of {len(over)} observations above their predicted "
            f"median, p = {p:.1e}; worst view {worst['view']}: median {worst['median_px']:.3g} px). The calibration "
            "is biased (a wrong fixed parameter, bad poses, unmodelled distortion), the robot's poses are less "
            "accurate than the calibration assumed, or the new views' poses or tracks are wrong."),)
    return ViewValidation(_rms(err), median, float(err.max()), int(len(err)), per_view, tuple(fitted),
                          float(np.sqrt(np.mean(ex))), pred_median, p, flagged, noise,
                          np.where(seen[..., None], e, np.nan), diags)


def _rms(err: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(err**2))) if len(err) else None
