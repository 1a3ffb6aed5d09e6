"""Poses that cannot be silently wrong: repeated poses, an outlying pose, an implausible
unit, a truth of another scene (``pose_repeated``, ``pose_outlier``, ``unit_implausible``).

**Outlying pose** (:func:`pose_test`). A view's recorded flange pose is off by a small
error: its position by ``dT_i`` (robot units) and the camera's orientation by a rotation
``Q_i = exp([w_i]x)`` (camera frame). Linearised at the maximum-likelihood solution with
the points eliminated (the machinery of :mod:`.rotation`), the score test of the six
parameters ``p_i = (dT_i, w_i)`` of one view, every other parameter profiled out, is::

    p_i = I_i^-1 g_i,    d_i = g_i^T I_i^-1 g_i,    F_i = (d_i / 6) / s_i^2 ~ F(6, dof - 6)

with ``g_i`` the gradient of ``0.5 |r|^2`` and ``I_i`` the profiled information of
``p_i``, ``s_i^2 = (RSS - d_i) / (dof - 6)``. Views are selected forward (the view whose
pose explains most, jointly with those already chosen, while its extra reduction is
significant at ``alpha / n_views``), provided it stands out (its reduction exceeds the
next view's significantly: with four views any view's pose explains another's error)
and its position part is needed: the reduction beyond the best rotation of any single
view, ``d_i - max_k d_k^rot``, significant (``F(3, dof - 6)``) and moving the view's
points by at least ``MIN_POSITION_SHIFT_PX`` RMS. Otherwise the rotation test
(:mod:`.rotation`) names the view as turned. The named views'
poses are then refitted (:func:`transcalib.refine` with their translations free and
their rotations estimated) for the size of each error in robot units and degrees.

A 30 mm typo in one view's x (8 views, 200 points, 0.5 px: ``tests/test_poses_check.py``)
is named as a position error of 29.3 mm in that view, x +29.3 mm.

**With the robot error in the model** a wrong pose is absorbed as that view's error:
:func:`robot_error_test` refits without the view whose estimated error stands out and
:func:`pose_contradiction` tests its recorded pose against that fit, its camera resected
from the points the other views triangulate. **A pose error so large that the robust
stage drops the view's tracks** leaves the score test nothing to see:
:func:`resection_test` names the view with the fewest inliers. :func:`find_pose_outliers`
runs the three in turn; ``transcalib.pipeline.views_off`` leaves the views named out.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import DegenerateError, Diagnostic
from ..estimate.covariance import linearise, profile_step
from ..estimate.distributions import chi2_sf, f_sf
from ..estimate.noise import median_sigma
from ..estimate.refine import refine
from ..types import Calibration
from .common import camera_poses, fmt_vec, inlier_uv
from .rotation import _refinement

__all__ = ["pose_test", "robot_error_test", "pose_contradiction", "find_pose_outliers", "describe_pose_outlier",
           "PoseOutlier", "check_pose_outliers", "check_repeated_poses", "check_unit", "truth_mismatch",
           "POSE_ALPHA", "REPEATED_ALPHA", "SCENE_DISTANCE_M", "ROBOT_SPAN_M"]

#: Family-wise false-alarm rate of the outlying-pose test on correct poses (Bonferroni over views).
POSE_ALPHA = 1e-3
#: A view's estimated robot error that stands out at this level (family-wise) is tested by
#: refitting without it (:func:`robot_error_test`): it sets only how often that refit runs.
ROBOT_GATE = 0.05
#: Practical significance: the position error must move the view's points by at least
#: this much (RMS, px) beyond what a rotation explains.
MIN_POSITION_SHIFT_PX = 0.1
#: False-alarm rate of the test that the images of two views at one pose differ.
REPEATED_ALPHA = 1e-3
#: Plausible distance (metres) from the camera's centre to the scene: nearer than the
#: first or farther than the second, with robot moves of a robot, is a unit error.
SCENE_DISTANCE_M = (0.01, 1e4)
#: Largest plausible span of a robot's moves (metres).
ROBOT_SPAN_M = 20.0
#: Length units whose size is known (metres per unit).
UNIT_METRES = {"mm": 1e-3, "cm": 1e-2, "m": 1.0, "um": 1e-6, "in": 0.0254}


def view_name(view_ids, i: int) -> str:
    """``view <id>``: the user's view id of index ``i`` (the index itself without ids)."""
    return f"view {i if view_ids is None else view_ids[i]}"


# --------------------------------------------------------------------------------------
# outlying pose
# --------------------------------------------------------------------------------------


class _PoseSystem:
    """Reduced normal equations at the ML solution with a pose error ``(dT_i, w_i)`` for
    every view (module docstring); ``cols(i)`` the six columns of view ``i`` (position
    first), ``nuisance`` the calibration's own parameters."""

    def __init__(self, uv, T, calibration: Calibration):
        lin = linearise(uv, T, calibration, _refinement(calibration), polish=0)
        n = uv.shape[0]
        prior = set(lin.layout.i_T)  # views whose translation has a prior (robot precision)
        self.layout = replace(lin.layout, rot_views=tuple(range(n)), T_views=tuple(range(n)))
        self.S, self.b, self.sse = lin.system(self.layout)
        self.dof = lin.dof
        self.n_obs = np.array([len(p) for p in lin.data.pts])
        lay = self.layout
        own = list(range(lay.n_common)) + [c for i in prior for c in range(lay.i_T[i], lay.i_T[i] + 3)]
        self.nuisance = np.array(sorted(own))

    def cols(self, i: int, part: str = "pose") -> np.ndarray:
        pos, rot = self.layout.i_T[i] + np.arange(3), self.layout.i_vrot[i] + np.arange(3)
        return {"pose": np.concatenate([pos, rot]), "position": pos, "rotation": rot}[part]

    def step(self, views, part: str = "pose"):
        """``(step, covariance / sigma^2, RSS reduction)`` of ``views``' pose errors."""
        test = np.concatenate([self.cols(i, part) for i in views])
        nuisance = np.setdiff1d(self.nuisance, test)
        return profile_step(self.S, self.b, test, nuisance)


def pose_test(uv, T, calibration: Calibration, *, alpha: float = POSE_ALPHA) -> dict:
    """Test every view's pose against its image (module docstring).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Observations the calibration was fitted on, NaN where unseen.
    T : (n_views, 3) float
        Flange positions as the calibration's model uses them.
    calibration : Calibration
        The maximum-likelihood solution (its inliers and options as fitted).
    alpha : float
        Family-wise false-alarm rate on correct poses.

    Returns
    -------
    dict
        ``flagged`` (views with a position error, most significant first),
        ``statistic``, ``p_value`` ``(n_views,)`` of the six-parameter score test,
        ``step (n_views, 6)`` (linearised ``dT`` in robot units, ``w`` in radians: the
        correction from the recorded pose to the one the image implies), ``dof``,
        ``level``.
    """
    sys_ = _PoseSystem(uv, T, calibration)
    n = uv.shape[0]
    level = alpha / n
    d = sys_.dof - 6
    stat, pval, step = np.full(n, np.nan), np.full(n, np.nan), np.zeros((n, 6))
    for i in range(n):
        w, _, r = sys_.step([i])
        s2 = max((sys_.sse - r) / d, 1e-300)
        stat[i], pval[i], step[i] = r / s2, f_sf(r / s2 / 6.0, 6, d), w
    flagged = _select(sys_, pval, level)
    return {"flagged": flagged, "statistic": stat, "p_value": pval, "step": step, "dof": sys_.dof, "level": level}


def _select(sys_: _PoseSystem, pval, level: float, max_views: int = 3) -> list:
    """Forward selection of views with a position error (module docstring)."""
    flagged, reduction = [], 0.0
    candidates = [i for i in np.argsort(pval) if pval[i] < level]
    while candidates and len(flagged) < max_views:
        d = sys_.dof - 6 * (len(flagged) + 1)
        if d <= 0:
            break
        ranked = sorted(((sys_.step(flagged + [k])[2], k) for k in range(len(pval)) if k not in flagged),
                        reverse=True)
        (r, i), r_next = ranked[0], ranked[1][0] if len(ranked) > 1 else 0.0
        s2 = max((sys_.sse - r) / d, 1e-300)
        if i not in candidates or not f_sf((r - reduction) / 6.0 / s2, 6, d) < level:
            break
        if not f_sf((r - r_next) / 6.0 / s2, 6, d) < level:  # another view's pose explains it as well
            break
        r_rot = max(_rotation_reduction(sys_, flagged, k) for k in range(len(pval)) if k not in flagged)
        beyond = r - r_rot  # what the position explains beyond a rotation of any view
        if not (f_sf(beyond / 3.0 / s2, 3, d) < level and beyond >= sys_.n_obs[i] * MIN_POSITION_SHIFT_PX**2):
            break
        flagged.append(int(i))
        candidates.remove(i)
        reduction = r
    return flagged


def _rotation_reduction(sys_: _PoseSystem, flagged, k: int) -> float:
    """RSS reduction of the poses of ``flagged`` and the rotation alone of view ``k``."""
    test = np.concatenate([sys_.cols(v) for v in flagged] + [sys_.cols(k, "rotation")])
    return profile_step(sys_.S, sys_.b, test, np.setdiff1d(sys_.nuisance, test))[2]


def _refit(uv, T, calibration: Calibration, views) -> tuple:
    """The named views' poses refitted: ``(dT (k, 3), angle_deg (k,), std_mm (k, 3))``,
    the correction of each recorded position (model frame) and the rotation angle, or
    None when the refit fails."""
    opts = _refinement(calibration)
    n = uv.shape[0]
    scale = float(np.ptp(T, axis=0).max()) or 1.0
    sigma = np.zeros(n) if opts.sigma_T is None else np.broadcast_to(np.asarray(opts.sigma_T, float), (n,)).copy()
    sigma[list(views)] = 1e3 * scale  # free: the prior carries no information
    others = [v for v in range(n) if v not in views]
    rot = tuple(views) if others else ()
    uv = inlier_uv(uv, calibration)
    try:
        c = refine(uv, T, calibration, options=replace(opts, sigma_T=sigma, estimate_view_rotations=rot or False,
                                                       robot_sigma_deg=None, robot_sigma_pos=None))  # sigma_T's model
    except DegenerateError:
        return None
    dT = np.asarray(c.T)[list(views)] - np.asarray(T)[list(views)]
    ang = np.zeros(len(views)) if c.view_rotations is None else \
        np.linalg.norm(np.asarray(c.view_rotations.deg)[list(views)], axis=1)
    std = np.full((len(views), 3), np.nan) if c.T_std is None else np.asarray(c.T_std)[list(views)]
    return dT, ang, std


def resection_test(uv, T, calibration: Calibration, *, alpha: float = POSE_ALPHA, min_points: int = 6) -> dict:
    """Views whose tracks the calibration mostly rejected, their camera resected from the
    points triangulated by the other views: a pose error so large that the robust stage
    dropped the view's tracks leaves the score test nothing to see.

    For each view ``v`` whose fraction of inlier tracks (among those seen in >= 3 views)
    is below half of the views' median (and below 1/2): its tracks seen in >= 2 other
    views triangulated from the other views with the
    calibration's cameras, ``v``'s camera centre and rotation refitted to them (6
    parameters, soft-L1 loss at 3 sigma), and the centre's move tested against its
    covariance ``sigma^2 (J^T J)^-1`` (chi-square(3) at ``alpha / n_views``; its
    Gauss-Newton information from the observations the fit keeps within 7.5 sigma). The
    most significant view is named.

    Returns
    -------
    dict
        ``flagged`` (views), ``dC (n_views, 3)`` (recorded minus fitted centre, model
        frame), ``angle_deg (n_views,)``, ``p_value (n_views,)``.
    """
    n = uv.shape[0]
    out = {"flagged": [], "dC": np.zeros((n, 3)), "angle_deg": np.zeros(n), "p_value": np.ones(n)}
    if calibration.inliers is None or not calibration.sigma_px:
        return out
    seen = np.isfinite(uv[..., 0])
    R_cam, C = camera_poses(calibration, T)
    R_cam = np.broadcast_to(R_cam, (n, 3, 3))
    inl = np.asarray(calibration.inliers, bool)
    multi = seen.sum(axis=0) >= 3
    fraction = np.array([inl[seen[v] & multi].mean() if (seen[v] & multi).any() else 1.0 for v in range(n)])
    for v in np.flatnonzero(fraction < 0.5 * min(1.0, np.median(fraction))):
        fit = _resect(uv, calibration, R_cam, C, v, min_points)
        if fit is None:
            continue
        x, cov = fit
        stat = float(x[3:] @ np.linalg.pinv(cov[3:, 3:]) @ x[3:])
        out["dC"][v], out["angle_deg"][v], out["p_value"][v] = -x[3:], np.degrees(np.linalg.norm(x[:3])), \
            float(chi2_sf(stat, 3))
    best = int(np.argmin(out["p_value"]))
    out["flagged"] = [best] if out["p_value"][best] < alpha / n else []  # the one view that stands out
    return out


def _resect(uv, calibration: Calibration, R_cam, C, v: int, min_points: int = 6, K=None):
    """View ``v``'s camera refitted to its tracks triangulated from the other views
    (cameras ``R_cam (n, 3, 3)``, centres ``C (n, 3)``, intrinsics ``K`` or the
    calibration's): ``(x, cov)``, ``x = (w, d)`` the rotation vector (rad; the camera
    becomes ``exp([w]x) R_cam[v]``) and the centre's move, ``cov (6, 6)`` = ``sigma^2 (J^T
    J)^-1`` from the observations kept within 7.5 sigma (soft-L1 at 3 sigma); None with
    fewer than ``min_points`` tracks."""
    from scipy.optimize import least_squares  # here: a tenth of a second, rarely needed

    from ..geometry.camera import project
    from ..geometry.rotation import rotvec_to_matrix
    from ..geometry.triangulate import triangulate

    seen = np.isfinite(uv[..., 0])
    others = np.delete(np.arange(uv.shape[0]), v)
    tracks = seen[v] & (seen[others].sum(axis=0) >= 2)
    if tracks.sum() < min_points:
        return None
    K = calibration.K if K is None else K
    dist, sigma = calibration.dist, calibration.sigma_px
    X = triangulate(K @ R_cam[others], uv[others][:, tracks], C[others], K=K, dist=dist)
    ok = np.repeat(np.isfinite(X[:, 0]), 2)

    def residuals(p):
        x = project(K, rotvec_to_matrix(p[:3]) @ R_cam[v], np.nan_to_num(X), (C[v] + p[3:])[None], dist)[0]
        return np.nan_to_num((uv[v, tracks] - x).ravel()[ok], nan=1e6)

    fit = least_squares(residuals, np.zeros(6), loss="soft_l1", f_scale=3 * sigma, x_scale="jac")
    r = fit.fun.reshape(-1, 2)
    keep = np.repeat(np.hypot(r[:, 0], r[:, 1]) < 3 * sigma * 2.5, 2)
    if keep.sum() < 2 * min_points:
        return None
    J = fit.jac[keep]
    return fit.x, sigma**2 * np.linalg.pinv(J.T @ J)


def _resect_predictive(uv, calibration: Calibration, R_cam, C, v: int):
    """:func:`_resect` with the intrinsics' uncertainty in its covariance: ``cov + B C_K
    B^T``, ``C_K`` the covariance of fx, fy, cx, cy and ``B (6, 4)`` the resection's
    change per unit of each (the points triangulated again), by differences of one std;
    None as :func:`_resect`."""
    fit = _resect(uv, calibration, R_cam, C, v)
    if fit is None or calibration.cov is None:
        return fit
    names = list(calibration.param_names)
    where = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
    free = [k for k in where if k in names]
    idx = [names.index(k) for k in free]
    C_K = np.asarray(calibration.cov, float)[np.ix_(idx, idx)]
    B = np.zeros((6, len(free)))
    for a, k in enumerate(free):
        step = np.sqrt(C_K[a, a])
        K = np.array(calibration.K, float)
        K[where[k]] += step
        moved = _resect(uv, calibration, R_cam, C, v, K=K) if step > 0 else None
        if moved is not None:
            B[:, a] = (moved[0] - fit[0]) / step
    return fit[0], fit[1] + B @ C_K @ B.T


@dataclass(frozen=True)
class PoseOutlier:
    """A view whose image contradicts its recorded pose.

    Attributes
    ----------
    view : int
        Index of the view.
    dT : (3,) float
        Recorded minus implied position, in the model's frame (robot units).
    angle_deg : float
        Angle of the orientation's error (degrees).
    p_value : float
        Of the test that named it (the score test, or the resection's).
    """

    view: int
    dT: np.ndarray
    angle_deg: float
    p_value: float


def robot_error_test(uv, T, calibration: Calibration, *, alpha: float = POSE_ALPHA) -> dict:
    """A view whose recorded pose the robot's pose error does not explain, with the
    robot error in the model (:attr:`Calibration.robot_error` estimated).

    There a wrong pose is absorbed as that view's error, the error's scale inflated and
    part of it spread over the calibration: the score test sees nothing. The candidate is
    the view whose estimated error stands out most from the others' (per axis ``e^2`` over
    the median of all views' ``e^2``, as chi-square(1)); when it stands out at
    ``ROBOT_GATE`` (Bonferroni over the axes), the calibration is refitted without the
    view (the robot error's scales estimated again) and :func:`pose_contradiction` tests
    the view's recorded pose against that fit.

    Returns
    -------
    dict
        ``flagged`` (at most one view), ``dC (n_views, 3)`` (recorded minus resected
        centre, model frame), ``angle_deg (n_views,)``, ``p_value (n_views,)``.
    """
    n = uv.shape[0]
    out = {"flagged": [], "dC": np.zeros((n, 3)), "angle_deg": np.zeros(n), "p_value": np.ones(n)}
    v = _robot_error_candidate(calibration.robot_error)
    if v is None:
        return out
    others = np.where((np.arange(n) == v)[:, None, None], np.nan, inlier_uv(uv, calibration))
    opts = replace(calibration.options.refinement if calibration.options is not None else _refinement(calibration),
                   distortion=calibration.dist_model)
    try:
        found = pose_contradiction(uv, T, refine(others, T, calibration, options=opts), v)
    except DegenerateError:
        return out
    if found is not None:
        out["dC"][v], out["angle_deg"][v], out["p_value"][v] = found.dT, found.angle_deg, found.p_value
        out["flagged"] = [v] if found.p_value < alpha else []
    return out


def pose_contradiction(uv, T, calibration: Calibration, v: int):
    """View ``v``'s recorded pose tested against a calibration fitted without it: its
    camera resected from the points the other views triangulate (:func:`_resect`), the
    intrinsics' uncertainty included (:func:`_resect_predictive`). The recorded pose is
    contradicted when the centre's move ``d`` or the rotation ``w`` exceeds what the
    calibration's robot error predicts::

        d^T (C_d + (sigma_pos^2 + sigma_rot^2 |l|^2) I)^-1 d,    w^T (C_w + sigma_rot^2 I)^-1 w

    each chi-square(3), or F(3, r) with a scale estimated on ``r`` degrees of freedom
    (its redundancy); ``l`` the rotation error's lever (the camera's offset from the
    flange; eye-to-hand the camera centre in the model frame; zero for one orientation,
    where the position error is the camera centre's). The view was chosen among
    ``n_views``: the smaller p-value times ``2 n_views``.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Every observation, view ``v``'s included.
    T : (n_views, 3) float
        Flange positions as the calibration's model uses them.
    calibration : Calibration
        Fitted without view ``v``'s observations.

    Returns
    -------
    PoseOutlier or None
        ``dT`` recorded minus resected centre (model frame), the rotation's angle and the
        p-value; None when the view has too few tracks the others see.
    """
    n = uv.shape[0]
    R_cam, C = camera_poses(calibration, T)
    R_cam = np.array(np.broadcast_to(R_cam, (n, 3, 3)))
    C = np.array(C, float)
    Ri = calibration.flange_rotations
    R_cam[v], C[v] = (x[0] for x in calibration.camera_poses(T[[v]], None if Ri is None else np.asarray(Ri)[[v]]))
    fit = _resect_predictive(uv, calibration, R_cam, C, v)
    if fit is None:
        return None
    x, cov = fit
    re = calibration.robot_error
    s_rot, s_pos = (0.0, 0.0) if re is None else (np.radians(re.sigma_rot_deg), re.sigma_pos)
    r_rot, r_pos = (0.0, 0.0) if re is None else re.redundancy
    eye_in_hand = calibration.hand_eye is None or calibration.hand_eye.setup == "eye-in-hand"
    lever = 0.0 if Ri is None else float(np.linalg.norm(C[v] - (T[v] if eye_in_hand else 0.0)))
    p_pos = _predictive_p(x[3:], cov[3:, 3:], s_pos**2 + (s_rot * lever) ** 2, r_pos if s_pos > 0 else r_rot)
    p_rot = _predictive_p(x[:3], cov[:3, :3], s_rot**2, r_rot)
    return PoseOutlier(int(v), -x[3:], float(np.degrees(np.linalg.norm(x[:3]))),
                       float(min(1.0, 2 * n * min(p_pos, p_rot))))


def _predictive_p(x: np.ndarray, cov: np.ndarray, prior_var: float, dof: float) -> float:
    """p-value of ``x (3,)`` against ``N(0, cov + prior_var I)``: chi-square(3), or with a
    prior variance estimated on ``dof`` degrees of freedom F(3, dof) (its own scatter)."""
    d = float(x @ np.linalg.solve(cov + prior_var * np.eye(3), x))
    return float(f_sf(d / 3.0, 3, dof)) if prior_var > 0 and dof > 0 else float(chi2_sf(d, 3))


def _robot_error_candidate(re) -> int | None:
    """The view whose estimated robot error stands out most (:func:`robot_error_test`),
    or None when none stands out at ``ROBOT_GATE`` or no component is estimated."""
    if re is None:
        return None
    z2 = [np.asarray(e, float) ** 2 / median_sigma(np.asarray(e, float) ** 2, 1, floor=1e-150) ** 2
          for e, source in ((re.rot_deg, re.source[0]), (re.pos, re.source[1])) if source == "estimated"]
    if not z2:
        return None
    z2 = np.hstack(z2)
    worst = z2.max(axis=1)
    v = int(np.argmax(worst))
    return v if z2.size * chi2_sf(worst[v], 1) < ROBOT_GATE else None


def find_pose_outliers(uv, T, calibration: Calibration, *, alpha: float = POSE_ALPHA) -> list:
    """The views whose recorded position their images contradict, most significant first:
    :func:`pose_test`, each named view's pose refitted for the size of its error; when it
    names none, :func:`robot_error_test` (the robot error in the model absorbed the wrong
    pose), then :func:`resection_test` (a view whose tracks the robust stage dropped).

    ``uv``, ``T``, ``calibration``, ``alpha`` as :func:`pose_test`. Returns a list of
    :class:`PoseOutlier`."""
    res = pose_test(uv, T, calibration, alpha=alpha)
    views = res["flagged"]
    if views:
        fit = _refit(uv, T, calibration, views)
        dT = -res["step"][views, :3] if fit is None else -fit[0]  # recorded minus implied
        ang = np.degrees(np.linalg.norm(res["step"][views, 3:], axis=1)) if fit is None else fit[1]
    else:
        for test in (robot_error_test, resection_test):
            res = test(uv, T, calibration, alpha=alpha)
            if res["flagged"]:
                break
        views = res["flagged"]
        dT, ang = res["dC"][views], res["angle_deg"][views]
    return [PoseOutlier(int(i), np.asarray(dT[k], float), float(ang[k]), float(res["p_value"][i]))
            for k, i in enumerate(views)]


def describe_pose_outlier(o: PoseOutlier, *, view_ids=None, unit: str = "units", setup: str = "eye-in-hand",
                          R_model=None) -> str:
    """``view <id>: its recorded position is off by about ... and its orientation by ...``
    in the robot's terms (eye-to-hand the model's positions are the inverted poses: the
    error is turned back; ``R_model (n_views, 3, 3)`` the model's flange rotations)."""
    d = _robot_frame(o.dT, o.view, setup, R_model)
    axes = "x, y, z" if setup == "eye-in-hand" else "robot base x, y, z"
    return (f"{view_name(view_ids, o.view)}: its recorded position is off by about {np.linalg.norm(d):.3g} {unit} "
            f"({axes} {fmt_vec(d)} {unit}) and its orientation by {o.angle_deg:.2g} deg (p = {o.p_value:.1e})")


def check_pose_outliers(uv, T, calibration: Calibration, *, view_ids=None, unit: str = "units",
                        setup: str = "eye-in-hand", R_model=None, alpha: float = POSE_ALPHA) -> list:
    """``pose_outlier`` naming each view whose recorded position its image contradicts,
    with the size of the error in robot units (and the orientation's in degrees):
    :func:`find_pose_outliers`, described by :func:`describe_pose_outlier`."""
    found = find_pose_outliers(uv, T, calibration, alpha=alpha)
    if not found:
        return []
    parts = [describe_pose_outlier(o, view_ids=view_ids, unit=unit, setup=setup, R_model=R_model) for o in found]
    return [Diagnostic(
        "pose_outlier",
        f"the image of some view(s) contradicts the recorded pose: {'; '.join(parts)}. The calibration is biased: "
        "check those poses for a typo, a swapped or missing digit, a move that did not finish or a row of another "
        "view; correct them or drop the views.")]


def _robot_frame(dT_model: np.ndarray, i: int, setup: str, R_model) -> np.ndarray:
    """An error of the model's position of view ``i`` as an error of the recorded one:
    the same eye-in-hand; eye-to-hand (``T_m = -R_m T``, ``R_m = R_i^T``) ``-R_m^T dT_m``."""
    if setup == "eye-in-hand":
        return dT_model
    return -dT_model if R_model is None else -np.asarray(R_model)[i].T @ dT_model


# --------------------------------------------------------------------------------------
# repeated poses, units, truth
# --------------------------------------------------------------------------------------


def repeated_pairs(T, R=None, rtol: float = 1e-9) -> list:
    """Pairs ``(i, j)``, ``i < j``, of views with the same position (within ``rtol`` of
    the span of the positions) and orientation."""
    T = np.asarray(T, float)
    tol = rtol * max(float(np.ptp(T, axis=0).max()), 1e-300)
    close = np.all(np.abs(T[:, None] - T[None]) <= tol, axis=2)
    if R is not None:
        R = np.asarray(R, float)
        close &= np.all(np.abs(R[:, None] - R[None]) <= 1e-9, axis=(2, 3))
    i, j = np.nonzero(np.triu(close, 1))
    return list(zip(i.tolist(), j.tolist()))


def check_repeated_poses(uv, T, R=None, *, sigma_px: float | None, view_ids=None, unit: str = "units",
                         alpha: float = REPEATED_ALPHA) -> list:
    """``pose_repeated``: two views at one recorded pose whose images differ beyond the
    pixel noise: ``sum_j |uv_ij - uv_kj|^2 / (2 sigma^2)`` over their common points
    exceeds the chi-square(2 n) quantile at ``1 - alpha`` (a pose copied from another row).
    Two views at one pose with the same image are a repeat, not an error."""
    out = []
    if not sigma_px:
        return out
    for i, k in repeated_pairs(T, R):
        d = uv[i] - uv[k]
        common = np.isfinite(d[:, 0])
        n = int(common.sum())
        if n == 0:
            continue
        e2 = np.sum(d[common] ** 2, axis=1)
        if chi2_sf(float(e2.sum()) / (2 * sigma_px**2), 2 * n) < alpha:
            out.append(Diagnostic(
                "pose_repeated",
                f"{view_name(view_ids, i)} and {view_name(view_ids, k)} have the same recorded pose (position "
                f"{fmt_vec(T[i])} {unit}) but their images differ: the {n} points both see moved by a median of "
                f"{np.median(np.sqrt(e2)):.3g} px (noise {sigma_px:.2g} px). One of the two poses is probably a copy "
                "of another row: correct it (or drop the view)."))
    return out


def check_unit(distance: float | None, T, unit: str) -> list:
    """``unit_implausible``: with a known length ``unit``, a scene nearer than
    ``SCENE_DISTANCE_M[0]`` or farther than ``SCENE_DISTANCE_M[1]`` from the camera, or
    robot moves spanning more than ``ROBOT_SPAN_M``: the poses are in another unit."""
    if unit not in UNIT_METRES or distance is None:
        return []
    m = UNIT_METRES[unit]
    span = float(np.ptp(np.asarray(T, float), axis=0).max())
    lo, hi = SCENE_DISTANCE_M
    if lo <= distance * m <= hi and span * m <= ROBOT_SPAN_M:
        return []
    # the unit in which the scene would be nearest to half a metre away
    guess = min(("mm", "m"), key=lambda u: abs(np.log10(distance * UNIT_METRES[u] / 0.5)))
    return [Diagnostic(
        "unit_implausible",
        f"in the unit given ({unit}) the scene is {distance:.3g} {unit} from the camera and the robot's moves span "
        f"{span:.3g} {unit}: implausible for a camera on a robot (expected a scene {lo * 1e3:g} mm to {hi:g} m away, "
        f"moves within {ROBOT_SPAN_M:g} m). The poses are probably in another unit: "
        + (f"if they are in {guess}, say so (unit='{guess}', CLI --unit {guess}) or convert them"
           if guess != unit else "check the unit of the pose file") + "; every output length is in the unit given.")]


def truth_mismatch(T_truth, T, robot_noise: float = 0.0, unit: str = "units") -> str | None:
    """Why a simulated scene's truth is not that of poses ``T``: another number of views,
    or translations that differ by more than 10 x its robot noise (plus rounding);
    None when they match."""
    T_truth, T = np.asarray(T_truth, float).reshape(-1, 3), np.asarray(T, float)
    if len(T_truth) != len(T):
        return f"it has {len(T_truth)} views, the poses {len(T)}"
    tol = 10.0 * robot_noise + 1e-6 * max(float(np.abs(T).max()), 1.0)
    d = np.linalg.norm(T_truth - T, axis=1)
    if d.max() <= tol:
        return None
    return (f"its translations differ from the poses by up to {d.max():.3g} {unit} (view index {int(np.argmax(d))}; "
            f"robot noise {robot_noise:g})")
