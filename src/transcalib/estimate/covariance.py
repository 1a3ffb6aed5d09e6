"""Uncertainty: the reduced Fisher information, the covariance at a solution, the CRLB.

With the Jacobian ``J`` of the whitened residuals at the solution and the points
eliminated (:func:`transcalib.estimate.schur.schur`), the information of the global
parameters is ``S = U - sum_j W_j V_j^-1 W_j^T`` (pixel units, unscaled), so

    cov(g) = sigma^2 S^-1,    cov(X_j) = sigma^2 (V_j^-1 + Z_j^T S^-1 Z_j),  Z_j = W_j V_j^-1

At the ground truth of a simulated scene with the true noise, ``sigma^2 S^-1`` is the
Cramér-Rao lower bound (:func:`crlb`). A (numerically) singular ``S`` means the posed
problem does not determine some parameters: :func:`check_identifiable` names them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from ..errors import DegenerateError, InputError
from ..geometry.camera import DIST_MODELS, pad_dist
from ..types import RefineOptions
from .bundle import BundleProblem, cost, reduced_rows, reduced_system
from .layout import FlangeModel, Layout, State, robot_sigma
from .observations import build_data
from .robot_error import COMPONENTS
from .schur import Reduced
from .solvers import levenberg_marquardt

__all__ = ["reduced_information", "covariance", "sandwich", "Sandwich", "check_identifiable", "crlb", "bound_std", "linearise", "profile_step"]

#: Relative eigenvalue of the (Jacobi-scaled) reduced information below which a parameter
#: combination counts as undetermined.
IDENTIFIABILITY_RTOL = 1e-10
#: Determinant of a point's Jacobi-scaled 3x3 information block at or below which the
#: point counts as undetermined (its rays are, to rounding, parallel). Eliminating a
#: point puts rounding of about ``10 eps / det`` of its own information into ``S``; where
#: the points absorb nearly all of a parameter's information (the hand-eye offset with
#: one session and a few single views keeps ~1e-6 of it) that must stay far below what
#: is left: at 1e-12 one point of det 1e-11 made a render's ``S`` indefinite (t free).
UNDETERMINED_POINT_DET = 1e-8


def reduced_information(state: State, lay: Layout, data, obs_weight=None, ok=None) -> Reduced:
    """The reduced system (:func:`transcalib.estimate.bundle.reduced_system`) whose ``S
    (p, p)`` is the information with the points eliminated.

    ``obs_weight``: per-view weights (default ones); ``ok`` (n,) bool: points that count
    (the others are left out of ``S``). Points whose 3x3 block is, to rounding, singular
    (``det <= UNDETERMINED_POINT_DET``: their rays parallel) are left out too: their
    elimination would put rounding noise at the scale of their information into ``S``,
    enough to make it indefinite. ``det`` keeps their determinants, so that
    ``det > UNDETERMINED_POINT_DET`` marks the points that count among ``ok``.
    """
    red = reduced_system(state, lay, data, "linear", 1.0, obs_weight, ok)
    undetermined = red.det <= UNDETERMINED_POINT_DET
    if ok is not None:
        undetermined &= ok
    if not undetermined.any():
        return red
    counted = ~undetermined if ok is None else ok & ~undetermined
    kept = reduced_system(state, lay, data, "linear", 1.0, obs_weight, counted)
    return replace(kept, det=np.where(undetermined, red.det, kept.det))


def check_identifiable(S: np.ndarray, names: tuple, hint="", scale=None) -> tuple[np.ndarray, np.ndarray]:
    """Raise :class:`DegenerateError` naming the undetermined parameters if ``S`` is singular.

    ``hint``: what would determine them, a string or a callable of the undetermined names.
    ``scale (p,)``: the information of each parameter before the points were eliminated
    (:attr:`Reduced.U_diag`; default the diagonal of ``S``): ``S`` scaled by it has
    eigenvalues that are fractions of that information, and rounding noise stays
    small in them.

    Returns the eigen-decomposition ``(evals, evecs)`` of the scaled ``S`` and the
    scaling ``d`` folded into the vectors (``S^-1 = (V / w) V^T`` scaled by ``d``).
    """
    d = 1.0 / np.sqrt(np.maximum(np.diag(S) if scale is None else scale, 1e-300))
    evals, evecs = np.linalg.eigh(S * d[:, None] * d[None, :])
    weak = evals <= IDENTIFIABILITY_RTOL * max(evals[-1], 1e-300)
    if weak.any():
        v = np.abs(evecs[:, weak]).max(axis=1)
        involved = [names[k] for k in np.argsort(-v) if v[k] > 0.2 * v.max()]
        hint = hint(involved) if callable(hint) else hint
        raise DegenerateError(
            "the data do not determine all parameters: the combination of "
            f"{', '.join(involved)} is free (the Fisher information is singular in {int(weak.sum())} "
            "direction(s)). " + (hint or "Use a simpler distortion model, more points spread over the image, "
                                        "more views, or fix known parameters."))
    return evals, evecs * d[:, None]


class Covariance(NamedTuple):
    """:func:`covariance`'s result: ``Sinv (p, p)``, the points' variances ``var_X (n,
    3)`` (unit noise), the mask ``ok (n,)`` of points that count and the reduced
    ``system`` it came from (its ``Y`` serves :func:`sandwich`)."""

    Sinv: np.ndarray
    var_X: np.ndarray
    ok: np.ndarray
    system: Reduced


def covariance(state: State, lay: Layout, data, obs_weight=None, hint: str = "", system: Reduced | None = None):
    """Unscaled covariances at the solution (:class:`Covariance`): ``S^-1 (p, p)`` and
    each point's diagonal ``(n, 3)``, with the mask ``ok`` of points whose covariance
    exists.

    Observations with weight 0 are left out; so are points left with fewer than 2
    observations or whose 3x3 block is (numerically) singular (variances NaN).
    ``system``: the reduced system of ``data`` linearised at (or one converging
    Gauss-Newton step before) ``state``, used when every point is determined.
    """
    weights = [np.ones(len(p)) for p in data.pts] if obs_weight is None else obs_weight
    n_w = np.zeros(data.n_points, int)
    for pts, w in zip(data.pts, weights):
        n_w += np.bincount(pts, weights=w > 0, minlength=data.n_points).astype(int)
    ok = n_w >= 2
    reuse = system is not None and obs_weight is None and ok.all() and (system.det > UNDETERMINED_POINT_DET).all()
    red = system if reuse else reduced_information(state, lay, data, obs_weight, None if ok.all() else ok)
    ok &= red.det > UNDETERMINED_POINT_DET  # rays (nearly) parallel: left out of S
    Sinv = _checked_inverse(red, lay, hint)
    var_X = red.point_variances(Sinv)
    var_X[~ok] = np.nan
    return Covariance(Sinv, var_X, ok, red)


def _checked_inverse(red: Reduced, lay: Layout, hint) -> np.ndarray:
    """``S^-1`` after :func:`check_identifiable`. With robot pose errors the check is made
    on the other parameters with the errors held fixed (the data must determine the
    camera; the errors' directions are determined by their priors, which a relative
    eigenvalue test at the data's scale would take for undetermined), and ``S`` is
    inverted Jacobi-scaled."""
    names = lay.names()
    if not lay.i_robot:
        evals, evecs = check_identifiable(red.S, names, hint, red.U_diag)
        return (evecs / evals) @ evecs.T
    keep = np.flatnonzero([not nm.startswith("robot") for nm in names])
    check_identifiable(red.S[np.ix_(keep, keep)], tuple(names[k] for k in keep), hint, red.U_diag[keep])
    d = 1.0 / np.sqrt(np.maximum(np.diag(red.S), 1e-300))
    evals, evecs = np.linalg.eigh(red.S * d[:, None] * d[None, :])
    evecs = evecs * d[:, None]
    return (evecs / evals) @ evecs.T


def crlb(scene, *, distortion: str | None = None, estimate_skew: bool = False, fix=None,
         square_pixels: bool = False, estimate_view_rotations=False) -> dict:
    """Cramér-Rao lower bound on the parameter standard deviations of a simulated scene.

    The Fisher information ``J^T J / noise_px^2`` (plus ``1 / robot_noise^2`` on the
    translations of views ``i >= 1`` when the scene has robot noise, as
    :func:`transcalib.synth.simulate.observe` draws it) at the ground truth, for the
    observation pattern of ``scene.uv``; the points eliminated as in the refinement.

    Parameters
    ----------
    scene : transcalib.synth.simulate.Scene
        With ``noise_px > 0``.
    distortion : {"none", "radial1", "radial2", "opencv5"}, optional
        Model whose parameters are bounded; default from the number of true coefficients.
    estimate_skew : bool
        Include the skew as a parameter.
    fix : mapping, optional
        Parameters known exactly (names as :class:`transcalib.RefineOptions`).
    square_pixels : bool
        One focal length ``f`` (``fx = fy``).
    estimate_view_rotations : bool or sequence of int
        Include a rotation per view ``i >= 1`` or per listed view, at zero: the bound on
        how well a robot rotation could be detected (``view{i}_rx`` ..., degrees).

    Returns
    -------
    dict of str to float
        Lower bound of the standard deviation of each parameter, named as in
        ``Calibration.std`` (rotations in degrees; with square pixels ``f`` and also
        ``fx``, ``fy``).
    """
    if not scene.noise_px > 0:
        raise InputError(f"the CRLB needs a scene with pixel noise > 0, got noise_px={scene.noise_px!r}")
    red, lay, _ = scene_information(scene, distortion=distortion, estimate_skew=estimate_skew, fix=fix,
                                    square_pixels=square_pixels, estimate_view_rotations=estimate_view_rotations)
    return bound_std(red.S, lay, scene.noise_px, red.U_diag)


def scene_information(scene, *, distortion: str | None = None, estimate_skew: bool = False, fix=None,
                      square_pixels: bool = False, estimate_view_rotations=False):
    """The reduced Fisher information (unit pixel noise) at the ground truth of a simulated
    scene, for the observation pattern of ``scene.uv``: the problem :func:`crlb` bounds
    (its parameters; the robot-noise priors of ``scene.robot_noise``; with
    ``scene.robot_sigma_deg`` every view's pose error instead, rotation and position, as
    nuisance parameters with their priors: :mod:`transcalib.estimate.robot_error`).

    Returns
    -------
    red : Reduced
        ``S`` and the per-point blocks of the points that count.
    lay : Layout
    used : (n_points,) bool
        Points that count: seen in >= 2 views, their 3x3 block determined (rays not parallel).
    """
    if distortion is None:
        distortion = {0: "none", 1: "radial1", 2: "radial2"}.get(np.asarray(scene.dist).size, "opencv5")
    if distortion not in DIST_MODELS:
        raise InputError(f"distortion must be one of {', '.join(DIST_MODELS)}, got {distortion!r}")
    n_views = scene.uv.shape[0]
    seen = np.isfinite(scene.uv[..., 0])
    used_idx = np.flatnonzero(seen.sum(axis=0) >= 2)
    s_rot = np.radians(getattr(scene, "robot_sigma_deg", 0.0))
    robot = scene.robot_noise > 0 and s_rot == 0  # position noise alone: the translation priors
    sigma_T = (0.0,) + (scene.robot_noise,) * (n_views - 1) if robot else None  # view 0: exact
    lay = Layout.from_options(RefineOptions(distortion=distortion, fix=dict(fix or {}), estimate_skew=estimate_skew,
                                            square_pixels=square_pixels, sigma_T=sigma_T,
                                            estimate_view_rotations=estimate_view_rotations), n_views)
    K = scene.K
    state = State(np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]]), pad_dist(scene.dist), scene.R.copy(),
                  np.tile(np.eye(3), (n_views, 1, 1)), scene.T_true.copy(), scene.X[used_idx].copy())
    tw = np.where(robot & (np.arange(n_views) > 0), scene.noise_px / max(scene.robot_noise, 1e-300), 0.0)
    robot_weight = (0.0, 0.0)
    if s_rot > 0:  # every view's pose error, rotation (and position): the robot error's priors
        lay = replace(lay, robot=("rot", "pos") if scene.robot_noise > 0 else ("rot",))
        state = replace(state, E=np.zeros((n_views, 6)))
        robot_weight = (scene.noise_px / s_rot, scene.noise_px / scene.robot_noise if scene.robot_noise > 0 else 0.0)
    data = build_data(scene.uv_true, seen, used_idx, scene.T_true, tw, robot_weight)
    red = reduced_information(state, lay, data)
    ok = red.det > UNDETERMINED_POINT_DET  # rays (nearly) parallel: such a point determines nothing
    used = np.zeros(scene.uv.shape[1], bool)
    used[used_idx[ok]] = True
    return red, lay, used


def bound_std(S: np.ndarray, lay: Layout, noise_px: float, scale=None) -> dict:
    """Standard deviations ``noise_px sqrt(diag(S^-1))`` by parameter name (rotations in
    degrees; with square pixels ``f`` and also ``fx``, ``fy``) of a reduced information
    ``S`` (unit pixel noise); raises naming the parameters if ``S`` is singular
    (:func:`check_identifiable` with ``scale``)."""
    evals, evecs = check_identifiable(S, lay.names(), scale=scale)
    sd = noise_px * np.sqrt(np.sum(evecs**2 / evals, axis=1))
    sd = np.where(lay.rotation_mask(), np.degrees(sd), sd)
    out = {nm: float(v) for nm, v in zip(lay.names(), sd)}
    if "f" in out:
        out["fx"] = out["fy"] = out["f"]
    return out


@dataclass(frozen=True, eq=False)
class Linearised:
    """A calibration's problem linearised at its solution, ready for score tests of
    extra parameters: ``state``, the calibration's own ``layout``, the ``data`` of the
    points it used (its inliers), ``dof`` (residual degrees of freedom) and ``sigma_px``."""

    state: State
    layout: Layout
    data: object
    dof: int
    sigma_px: float

    def system(self, layout: Layout):
        """``(S, b, sse)``: reduced normal equations (points eliminated) of ``layout``
        (the calibration's plus extra parameters at their current values) and the
        residual sum of squares."""
        red = reduced_system(self.state, layout, self.data)
        return red.S, red.rhs, 2.0 * cost(self.state, layout, self.data, "linear", 1.0)


def linearise(uv, T, calibration, opts, polish: int = 5, flange=None) -> Linearised:
    """The refined calibration's problem at its solution (``polish`` LM steps make sure it
    is the ML one): layout from ``opts`` (a RefineOptions), points with finite ``X``
    among ``calibration.inliers``, translation priors from ``opts.sigma_T``; with
    ``flange`` (a :class:`transcalib.estimate.layout.FlangeModel`; default the model of
    the calibration) the hand-eye model."""
    flange = flange if flange is not None else FlangeModel.of(calibration)
    n_views = uv.shape[0]
    seen = np.isfinite(uv[..., 0])
    X = np.asarray(calibration.X, float)
    use = np.isfinite(X).all(axis=1) & (seen.sum(axis=0) >= 2)
    if calibration.inliers is not None:
        use &= np.asarray(calibration.inliers, bool)
    idx = np.flatnonzero(use)
    t_sigma = robot_sigma(opts.sigma_T, n_views)
    layout = Layout.from_options(replace(opts, estimate_view_rotations=False), n_views,
                                 None if flange is None else flange.t_basis)
    sigma_px = calibration.sigma_px or max(calibration.rms_px / np.sqrt(2), 1e-6)
    tw = np.where(t_sigma > 0, sigma_px / np.where(t_sigma > 0, t_sigma, 1.0), 0.0)
    T_start = np.asarray(calibration.T, float) if t_sigma.any() else T
    layout, E, robot_w = _robot_model(calibration, layout, sigma_px)
    state = State(calibration.camera.intrinsics, calibration.camera.dist5, np.array(calibration.R),
                  np.tile(np.eye(3), (n_views, 1, 1)), T_start.copy(), X[idx].copy(),
                  None if flange is None else flange.F, np.zeros(3) if flange is None else np.array(flange.t0, float),
                  E)
    data = build_data(uv, seen, idx, T, tw, robot_w)
    dof = layout.residual_dof(data.n_obs, len(idx))
    if dof <= 3:
        raise DegenerateError(f"too few observations ({data.n_obs}) for a test of extra parameters")
    if polish:
        state = levenberg_marquardt(BundleProblem(layout, data), state, max_iterations=polish, tol=1e-9).state
    return Linearised(state, layout, data, int(dof), float(sigma_px))


def _robot_model(calibration, layout: Layout, sigma_px: float):
    """``layout`` with the robot pose error of ``calibration`` (its components with a
    positive scale, the side of eq. 2 as the calibration fitted it), the errors ``E
    (n_views, 6)`` (None without) and the priors' weights ``(2,)``."""
    re = getattr(calibration, "robot_error", None)
    if re is None or not re.active:
        return layout, None, np.zeros(2)
    sig = np.array([np.radians(re.sigma_rot_deg), re.sigma_pos])
    layout = replace(layout, robot=tuple(c for c, s in zip(("rot", "pos"), sig) if s > 0),
                     robot_inverted=bool(re.scene_side))
    E = np.hstack([np.radians(np.asarray(re.rot_deg, float)), np.asarray(re.pos, float)])
    return layout, E, np.where(sig > 0, sigma_px / np.where(sig > 0, sig, 1.0), 0.0)


def profile_step(S: np.ndarray, b: np.ndarray, test: np.ndarray, nuisance: np.ndarray):
    """One Gauss-Newton step of the ``test`` parameters with the ``nuisance`` ones profiled
    out: ``(step (k,), covariance / sigma^2 (k, k), RSS reduction)``. The reduction over
    ``sigma^2`` is the score statistic for ``test = 0`` (chi-square(k) under the null)."""
    S_tn = S[np.ix_(test, nuisance)]
    Sn_inv = np.linalg.pinv(S[np.ix_(nuisance, nuisance)], rcond=1e-13, hermitian=True)
    info_t = S[np.ix_(test, test)] - S_tn @ Sn_inv @ S_tn.T
    g = b[test] - S_tn @ Sn_inv @ b[nuisance]
    cov = np.linalg.pinv(info_t, rcond=1e-13, hermitian=True)
    w = cov @ g
    return w, cov, float(g @ w)


# ----------------------------------------------------------------------------------------
# Cluster-robust (sandwich) covariance
# ----------------------------------------------------------------------------------------

#: Points per block of :func:`sandwich` (its reduced rows are ``p x 2 n_views`` per point).
SANDWICH_BLOCK = 2048
#: A cluster's leverage (an eigenvalue of ``H_cc``) from which it alone determines some
#: parameter combination: no CR2 correction, no sandwich.
LEVERAGE_ONE = 1.0 - 1e-6
#: Clusters whose total leverage ``tr H_cc`` is below this take ``(I - H_cc)^(-1/2)`` as
#: the power series of ``(1 - x)^(-1/2)`` (at most 34 terms to :data:`CR2_RTOL`; a few
#: with many points), the others from an eigen-decomposition (numpy's batched one costs
#: ~17 us per cluster: at 10^5 points it would take most of the sandwich's time).
SERIES_LEVERAGE = 0.5
#: Relative accuracy of that series.
CR2_RTOL = 1e-10


@dataclass(frozen=True, eq=False)
class Sandwich:
    """A cluster-robust covariance of the global parameters (:func:`sandwich`).

    Attributes
    ----------
    cov : (p, p) float
        ``S^-1 M S^-1`` in the parameters' own units (px^2 for K; rotations in radians):
        no ``sigma^2`` factor, the residuals carry the scale.
    meat : (p, p) float
        ``M = sum_c g*_c g*_c^T`` over the clusters (points, then each view's priors).
    dof : (p,) float
        Satterthwaite's effective degrees of freedom of each diagonal element of ``cov``
        under the model: ``(sum_c q_ck)^2 / sum_c q_ck^2``, ``q_ck = a_k^T S_c a_k``,
        ``a_k = S^-1 e_k``. Its relative sampling std is ``sqrt(2 / dof)``.
    n_clusters : int
        Points that count plus views with priors.
    """

    cov: np.ndarray
    meat: np.ndarray
    dof: np.ndarray
    n_clusters: int


def sandwich(state: State, lay: Layout, data, red: Reduced, Sinv: np.ndarray, ok=None) -> Sandwich:
    """Cluster-robust covariance ``S^-1 M S^-1`` of the global parameters, clustered by
    point (and by view for the priors), at the least-squares solution ``state``.

    Each point ``j`` is a cluster: its Schur-reduced score ``g_j = J_cj^T r_j - Y_j
    J_Xj^T r_j = sum_i R_ij r_ij`` (:func:`transcalib.estimate.bundle.reduced_rows`;
    ``Y = W V^-1`` of ``red``) carries the point's own parameters profiled out, so its
    residuals may be correlated along the track and heteroscedastic across points.
    Each view's priors (robot pose errors, translations: pseudo-observations ``0 = w
    e_i``, ``w T_i^meas = w T_i``, rows ``w I``) form one more cluster. At the solution
    the scores (with the priors') sum to zero.

    Small-sample correction (CR2, Bell & McCaffrey 2002): in the reduced model ``r_c =
    (I - H) e`` the cluster's residuals have covariance ``sigma^2 (I - H_cc)``, so ``g_c``
    underestimates its spread by the cluster's leverage ``H_cc = R_c S^-1 R_c^T``. With

        g*_c = R_c^T (I - H_cc)^(-1/2) r_c

    ``E[g*_c g*_c^T] = sigma^2 S_c`` exactly when the model holds, so ``E[M] = sigma^2 S``
    and ``E[cov] = sigma^2 S^-1``: the model's covariance (at a perfect model only the
    sandwich's own sampling noise, ``dof``, separates the two). ``H_cc`` is small (two
    rows per observation of the point): O(p^2 n_obs) time (BLAS), no ``p x p`` block per
    point, O(n) memory, points :data:`SANDWICH_BLOCK` at a time.

    A view without an observation that counts (left out while its orientation is in
    doubt) has parameters its priors alone determine: no cluster replicates them, so
    their rows and columns of ``cov`` (and their ``dof``) are NaN, and the others' come
    from the other clusters (its columns do not couple to them in ``S``).

    Parameters
    ----------
    red : Reduced
        The reduced system at (or one converging step before) ``state``
        (:class:`Covariance.system`), unit weights.
    Sinv : (p, p) float
        ``S^-1`` of ``red`` (:func:`covariance`).
    ok : (n,) bool, optional
        Points that count (:class:`Covariance.ok`).

    Returns
    -------
    Sandwich
    """
    p = lay.size
    M, q1, q2 = np.zeros((p, p)), np.zeros(p), np.zeros(p)
    n_clusters = 0
    blocks = [reduced_rows(state, lay, data, red.Y, lo, min(lo + SANDWICH_BLOCK, data.n_points), ok)
              for lo in range(0, data.n_points, SANDWICH_BLOCK)]
    sizes = [min(SANDWICH_BLOCK, data.n_points - lo) for lo in range(0, data.n_points, SANDWICH_BLOCK)]
    unseen = _unseen_views(data, ok)
    prior = _prior_rows(state, lay, data)
    if prior is not None:
        R, r, views = prior
        R[..., unseen], r[:, unseen] = 0.0, 0.0  # determined by their priors alone: no cluster of their own
        blocks.append([(R, r, views)])
        sizes.append(lay.n_views)
    for rows, nb in zip(blocks, sizes):
        Gs = _cr2_scores(rows, nb, Sinv)
        M += Gs @ Gs.T
        q = _cluster_sum(rows, nb, p, lambda R, r, pts: _squared_rows(Sinv @ R.reshape(p, -1), R.shape))
        q1 += q.sum(axis=1)
        q2 += np.sum(q * q, axis=1)
        n_clusters += int(_has_rows(rows, nb).sum())
    M = 0.5 * (M + M.T)
    dof = q1**2 / np.where(q2 > 0, q2, np.inf)
    cov = Sinv @ M @ Sinv
    alone = np.zeros(p, bool)
    for i in np.flatnonzero(unseen):
        alone[lay.view_columns(i)[lay.n_common:]] = True
    cov[alone], cov[:, alone], dof[alone] = np.nan, np.nan, np.nan
    return Sandwich(cov, M, dof, n_clusters)


def _unseen_views(data, ok=None) -> np.ndarray:
    """(n_views,) bool: views without an observation of a point that counts."""
    return np.array([not (len(pts) and (ok is None or ok[pts].any())) for pts in data.pts])


def _cluster_sum(rows: list, n: int, p: int, term) -> np.ndarray:
    """``(p, n)``: per cluster the sum over its row groups of ``term(R, r, pts) (p, m)``
    (each cluster appears at most once in a group, so ``+=`` on ``pts`` adds)."""
    out = np.zeros((p, n))
    for R, r, pts in rows:
        out[:, pts] += term(R, r, pts)
    return out


def _squared_rows(SR: np.ndarray, shape: tuple) -> np.ndarray:
    """``(p, m)``: per cluster column the squares of ``S^-1 R`` (``(p, k m)``, one BLAS
    product) summed over its ``k`` rows: the sandwich's effective dof terms."""
    return np.sum(SR.reshape(shape) ** 2, axis=1)


def _has_rows(rows: list, n: int) -> np.ndarray:
    """(n,) bool: clusters with a non-zero row."""
    out = np.zeros(n, bool)
    for R, _, pts in rows:
        out[pts] |= np.any(R != 0, axis=(0, 1))
    return out


def _cr2_scores(rows: list, n: int, Sinv: np.ndarray) -> np.ndarray:
    """CR2-corrected scores ``g*_c = R_c^T (I - H_cc)^(-1/2) r_c`` ``(p, n)`` of the ``n``
    clusters of ``rows`` (:func:`sandwich`), with ``H_cc = R_c S^-1 R_c^T``.

    Each cluster's rows are gathered from the groups (views) that hold them, the
    clusters with the same number of rows together: one BLAS product ``R S^-1`` per row
    count, then :func:`_inverse_sqrt_times`. Raises if a leverage reaches
    :data:`LEVERAGE_ONE` (the cluster alone determines some parameter combination).
    """
    p = Sinv.shape[0]
    R = np.concatenate([Rg.reshape(p, -1) for Rg, _, _ in rows], axis=1)  # (p, K): every row of every group
    r = np.concatenate([rg.reshape(-1) for _, rg, _ in rows])
    cluster = np.concatenate([np.tile(pts, Rg.shape[1]) for Rg, _, pts in rows])
    order = np.argsort(cluster, kind="stable")
    counts = np.bincount(cluster, minlength=n)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = np.zeros((p, n))
    for k in np.unique(counts[counts > 0]):
        members = np.flatnonzero(counts == k)
        at = order[first[members, None] + np.arange(k)]  # (m, k) columns of R
        Rc = R.T[at]  # (m, k, p)
        H = (Rc.reshape(-1, p) @ Sinv).reshape(Rc.shape) @ Rc.transpose(0, 2, 1)
        out[:, members] = np.einsum("mkp,mk->pm", Rc, _inverse_sqrt_times(0.5 * (H + H.transpose(0, 2, 1)), r[at]))
    return out


def _inverse_sqrt_times(H: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``(I - H_c)^(-1/2) r_c`` ``(m, k)`` of leverage blocks ``H (m, k, k)`` (symmetric,
    eigenvalues in [0, 1)) and ``r (m, k)``: the series ``sum_t b_t H^t r`` (``b_0 = 1,
    b_t = b_(t-1) (2t - 1) / (2t)``) where ``tr H`` < :data:`SERIES_LEVERAGE`, else
    ``Q diag(1 - h)^(-1/2) Q^T r`` from ``H = Q diag(h) Q^T``."""
    out = np.empty_like(r)
    lev = np.trace(H, axis1=1, axis2=2)  # >= the largest eigenvalue
    low = lev < SERIES_LEVERAGE
    if low.any():
        Hl, term = H[low], r[low]
        y, h = term.copy(), float(lev[low].max())
        terms = 0 if h <= 0 else int(np.ceil(np.log(CR2_RTOL) / np.log(h)))
        for t in range(1, terms + 1):
            term = (2 * t - 1) / (2 * t) * np.einsum("mkl,ml->mk", Hl, term)
            y += term
        out[low] = y
    if not low.all():
        h, Q = np.linalg.eigh(H[~low])
        if h.max() >= LEVERAGE_ONE:
            raise DegenerateError("the sandwich covariance is not defined: a point (or a view's priors) alone "
                                  "determines some parameter combination (leverage 1)")
        f = 1.0 / np.sqrt(1.0 - np.maximum(h, 0.0))
        out[~low] = np.einsum("mkl,ml->mk", Q, f * np.einsum("mlk,ml->mk", Q, r[~low]))
    return out


def _prior_rows(state: State, lay: Layout, data):
    """The priors as one group of clusters, one per view: ``(R (p, k, V), r (k, V),
    arange(V))`` with the rows ``w I`` and residuals of the translation priors ``t_w
    (T^meas - T)`` and robot pose error priors ``w (0 - e)`` (as ``_add_priors``
    weights them); None without priors."""
    if not lay.i_T and not lay.robot:
        return None
    V = lay.n_views
    k = 3 * (1 + len(lay.robot))
    R, r = np.zeros((lay.size, k, V)), np.zeros((k, V))
    eye = np.arange(3)
    for i, s in lay.i_T.items():
        tw = data.t_weight[i]
        R[s + eye, eye, i] = tw
        r[eye, i] = tw * (data.T_meas[i] - state.T[i])
    for c, comp in enumerate(lay.robot):
        w = data.robot_weight[COMPONENTS.index(comp)]
        at = 0 if comp == "rot" else 3
        for i, cols in zip(lay.i_robot, lay.robot_columns(comp)):
            R[cols, 3 + 3 * c + eye, i] = w
            e = np.zeros(3) if state.E is None else state.E[i, at: at + 3]
            r[3 + 3 * c + eye, i] = -w * e
    return R, r, np.arange(V)
