"""Single views at their own orientation join a start from the sessions: pose, check, offset.

After the sessions' start (``K``, ``R_X``, the offset ``t_0`` zero along its undetermined
directions ``U``, the points ``X^0``), each single view ``i`` (flange pose ``R_i, T_i``)
sees some of those points. Its camera pose follows from the images alone (PnP with known
K: the linear 6-point DLT inside the project's robust loop, then Gauss-Newton), and it is
checked against the recorded orientation: the camera rotation ``R_c`` should be
``R_X^T R_i^T``, i.e. each view implies the camera's rotation in the flange
``Q_i = R_i^T R_c^T``. The start's own ``R_X`` carries the error of its sessions (a weak
session: ~1 deg, and a principal point error turns every PnP rotation alike), so the views
are judged against the consensus of ``R_X`` and all ``Q_i`` (the chordal mean around the
most central, :func:`~transcalib.geometry.rotation.central_mean_rotation`): a view whose
``Q_i`` differs from it by more than the session tolerance — or, when the other views
scatter more, by more than their scatter allows — significantly, is named with the angle
and left out (a wrong pose, or the camera moved on the flange). Each view's pose has its
own inlier rule, from its own residuals: the start's ``K`` and points are off by more
than the pixel noise.

The view's centre then gives the offset along ``U``. Moving the offset by ``U c`` moves
every point of the start by the same ``R_r U c`` (``R_r`` the orientation of any session:
along the undetermined directions the sessions agree), so the centre the images give in
the start's frame, ``C'_i``, satisfies ::

    (R_i - R_r) U c = C'_i - T_i - R_i t_0                         (3 equations per view)

a linear least-squares problem for ``c``; a single view determines ``c`` but along the
axis of ``R_r^T R_i``, two views with different axes determine it all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..estimate.distributions import chi2_ppf
from ..estimate.noise import SIGMA_FLOOR_PX
from ..estimate.ransac import least_singular_vector, lo_ransac
from ..geometry.camera import pixels_to_rays
from ..geometry.rotation import central_mean_rotation, matrix_to_rotvec, rotation_angle_deg, rotvec_to_matrix

#: Fewest correspondences with the start's points for a view to get its own pose.
MIN_POINTS = 6
#: False-alarm rate of the orientation check (chi-square(3) of the rotation difference).
ORIENTATION_ALPHA = 1e-3
#: Median of the angle of a rotation whose rotation vector has unit std per axis (the
#: Maxwell distribution's median).
MAXWELL_MEDIAN = 1.5382
#: Relative singular value below which a direction of the offset counts as undetermined.
OFFSET_RTOL = 1e-9


@dataclass(frozen=True, eq=False)
class ViewPose:
    """A single view's camera pose from its images: rotation world -> camera ``R``, centre
    ``C`` (in the start's frame), inlier observations ``inliers (n_points,)``, the
    rotation's covariance at unit pixel noise ``rotation_cov (3, 3)`` (``R <- exp([w]x) R``)
    and the pixel noise of its own residuals ``sigma_px``."""

    view: int
    R: np.ndarray
    C: np.ndarray
    inliers: np.ndarray
    rotation_cov: np.ndarray
    sigma_px: float


@dataclass(frozen=True, eq=False)
class Joined:
    """The start with the single views joined: the offset ``t``, its undetermined
    directions ``undetermined (3, k)``, the points ``X`` (moved with the offset), the poses
    of the views that joined, and the views left out with their orientation error
    ``off_views`` ((view, degrees), ...)."""

    t: np.ndarray
    undetermined: np.ndarray
    X: np.ndarray
    poses: tuple
    off_views: tuple


def join_single_views(uv, T, R, views, K, R_X, t0, U, X0, R_ref, tolerance_deg: float, rng=None) -> Joined:
    """Join the single ``views`` to a start from the sessions (module docstring).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float
        Flange positions.
    R : (n_views, 3, 3) float
        Flange -> base rotations.
    views : sequence of int
        The single views.
    K, R_X : (3, 3) float
        From the sessions' start.
    t0 : (3,) float
        The offset of the start (zero along ``U``).
    U : (3, k) float
        Orthonormal directions of the offset the sessions leave free.
    X0 : (n_points, 3) float
        The start's points (NaN: none).
    R_ref : (3, 3) float
        The orientation of a session of the start.
    tolerance_deg : float
        The session tolerance: a larger difference between a view's recorded orientation
        and the one its image shows, when significant, leaves the view out.
    """
    found = [p for p in (view_pose(uv[i], X0, K, i, rng) for i in views) if p is not None]
    poses, off = judge_orientations(found, R, R_X, tolerance_deg)
    t, undetermined, shift = np.asarray(t0, float), U, np.zeros(3)
    if U.shape[1] and poses:
        G = np.concatenate([(R[p.view] - R_ref) @ U for p in poses])  # (3 m, k)
        h = np.concatenate([p.C - T[p.view] - R[p.view] @ t0 for p in poses])
        _, s, Vt = np.linalg.svd(G, full_matrices=True)
        rank = int(np.sum(s > OFFSET_RTOL * max(s[0], 1e-300)))
        c = Vt[:rank].T @ ((Vt[:rank] @ np.linalg.lstsq(G, h, rcond=None)[0]))  # zero along the free directions
        t, undetermined, shift = t + U @ c, U @ Vt[rank:].T, R_ref @ U @ c
    return Joined(t, undetermined, X0 + shift, tuple(poses), tuple(off))


def judge_orientations(found: list, R: np.ndarray, R_X: np.ndarray, tolerance_deg: float) -> tuple[list, list]:
    """Split the single views' image poses ``found`` (:class:`ViewPose`) into those whose
    recorded flange orientation ``R[view]`` agrees with their image and those off,
    ``(poses, [(view, degrees), ...])``: each against the consensus of ``R_X`` and every
    view's implied ``Q_i = R_i^T R_c^T`` (module docstring), beyond the session tolerance
    or the others' scatter (:func:`spread_limits`) and significantly (chi-square(3) at
    :data:`ORIENTATION_ALPHA`)."""
    R_X_agreed = central_mean_rotation(np.stack([R_X] + [R[p.view].T @ p.R.T for p in found]), tolerance_deg)[0]
    errors = [orientation_error(p, R_X_agreed.T @ R[p.view].T) for p in found]
    limits = spread_limits(np.array([deg for deg, _ in errors]), tolerance_deg)
    poses, off = [], []
    for p, (off_deg, chi2), limit in zip(found, errors, limits):
        if off_deg > limit and chi2 > chi2_ppf(1.0 - ORIENTATION_ALPHA, 3):
            off.append((p.view, off_deg))
        else:
            poses.append(p)
    return poses, off


def spread_limits(angles_deg: np.ndarray, tolerance_deg: float) -> np.ndarray:
    """The angle ``(m,)`` above which each of ``m`` views' orientation is off: the session
    tolerance, or more when the other views scatter more (the start's ``K`` turns every
    view's rotation a little, differently): the ``1 - ORIENTATION_ALPHA`` quantile of an
    isotropic rotation error whose scale is the median of the others' angles (a rotation
    with per-axis std ``s`` has median angle ``1.538 s``). Needs >= 2 other views."""
    limits = np.full(len(angles_deg), float(tolerance_deg))
    if len(angles_deg) < 3:
        return limits
    quantile = np.sqrt(chi2_ppf(1.0 - ORIENTATION_ALPHA, 3)) / MAXWELL_MEDIAN
    others = np.array([np.median(np.delete(angles_deg, i)) for i in range(len(angles_deg))])
    return np.maximum(limits, quantile * others)


def view_pose(uv_i: np.ndarray, X: np.ndarray, K: np.ndarray, view: int, rng=None) -> ViewPose | None:
    """The camera pose of one view from its observations ``uv_i (n_points, 2)`` of the
    points ``X (n_points, 3)`` (NaN: not used), robust (6-point DLT in
    :func:`~transcalib.estimate.ransac.lo_ransac`), refined by Gauss-Newton; None with
    fewer than :data:`MIN_POINTS` correspondences or no consensus.

    The inlier rule's noise is estimated from the view's own residuals, not taken from the
    sessions: the start's ``K`` and points are only the start's (a few pixels off at the
    edges of a weak session), and a rule at the pixel noise would reject most of the
    view's correct observations with them."""
    use = np.flatnonzero(np.isfinite(uv_i[:, 0]) & np.all(np.isfinite(X), axis=1))
    if len(use) < MIN_POINTS:
        return None
    problem = _PnP(pixels_to_rays(K, uv_i[use])[:, :2], X[use], K)
    best = lo_ransac(problem, sigma=None, rng=rng, stage="single view")
    if best.hypothesis is None or best.n_inliers < MIN_POINTS:
        return None
    R, C = _polish(problem, best.hypothesis, best.inliers)
    inliers = np.zeros(len(uv_i), bool)
    inliers[use[best.inliers]] = True
    sigma_px = max(float(best.sigma), SIGMA_FLOOR_PX)
    return ViewPose(int(view), R, C, inliers, _rotation_covariance(problem, R, C, best.inliers), sigma_px)


def orientation_error(pose: ViewPose, R_pred: np.ndarray) -> tuple[float, float]:
    """``(angle_deg, chi2)``: how far the pose's rotation is from the predicted one
    ``R_pred`` (world -> camera), and the chi-square statistic (3 degrees of freedom) of
    that difference under the pose's covariance at its own noise."""
    w = matrix_to_rotvec(pose.R @ R_pred.T)  # camera frame
    cov_w = pose.rotation_cov * pose.sigma_px ** 2
    return rotation_angle_deg(pose.R @ R_pred.T), float(w @ np.linalg.lstsq(cov_w, w, rcond=None)[0])


class _PnP:
    """The pose of a calibrated camera from 2-D / 3-D correspondences, as hooks of the
    generic loop: data are the correspondences (normalised image coordinates ``x (n,
    2)``, points ``X (n, 3)``); a hypothesis is ``[R | C]`` flattened (12,); errors are
    squared pixel errors (2 degrees of freedom)."""

    sample_size = MIN_POINTS

    def __init__(self, x: np.ndarray, X: np.ndarray, K: np.ndarray):
        self.x, self.X, self.K = x, X, K
        n = len(x)
        self.dof = np.full(n, 2)
        self.scorable = np.ones(n, bool)
        self.samplable = np.ones(n, bool)

    def sample(self, rng, size: int) -> np.ndarray:
        n = len(self.x)
        return np.argsort(rng.random((size, n)), axis=1)[:, : self.sample_size]

    def solve(self, samples: np.ndarray):
        return _dlt(self.x[samples], self.X[samples])

    def errors(self, hypotheses: np.ndarray) -> np.ndarray:
        R, C = hypotheses[:, :9].reshape(-1, 3, 3), hypotheses[:, 9:]
        p = np.einsum("hab,hnb->hna", R, self.X[None] - C[:, None])  # (H, n, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[..., :2] / p[..., 2:3]
        d = (xy - self.x[None]) @ self.K[:2, :2].T  # pixels (skew included)
        e2 = np.sum(d * d, axis=2)
        return np.where(p[..., 2] > 0, e2, np.inf)

    def refit(self, inliers: np.ndarray):
        return _dlt(self.x[inliers][None], self.X[inliers][None])


def _dlt(x: np.ndarray, X: np.ndarray):
    """Poses from correspondences by the linear DLT, batched: ``x (B, m, 2)``, ``X (B, m,
    3)`` (m >= 6) -> hypotheses ``(B, 12)`` (``R`` row-major, then ``C``) and validity."""
    mu = X.mean(axis=1, keepdims=True)
    s = np.sqrt(np.mean(np.sum((X - mu) ** 2, axis=2), axis=1))[:, None, None]
    Xn = (X - mu) / np.where(s > 0, s, 1.0)
    B, m = x.shape[:2]
    A = np.zeros((B, 2 * m, 12))
    ones = np.ones((B, m, 1))
    h = np.concatenate([Xn, ones], axis=2)  # (B, m, 4)
    A[:, 0::2, 0:4] = -h
    A[:, 0::2, 8:12] = x[..., :1] * h
    A[:, 1::2, 4:8] = -h
    A[:, 1::2, 8:12] = x[..., 1:2] * h
    M = least_singular_vector(A).reshape(B, 3, 4)  # lam [s R | R mu + t], det(lam s R) = (lam s)^3
    M = M * np.where(np.linalg.det(M[:, :, :3]) < 0, -1.0, 1.0)[:, None, None]  # lam > 0
    U, sv, Vt = np.linalg.svd(M[:, :, :3])
    R = U @ Vt  # the rotation nearest to M's left block (det +1 when det M > 0)
    lam = sv.mean(axis=1) / s[:, 0, 0]
    t = M[:, :, 3] / lam[:, None] - np.einsum("bij,bj->bi", R, mu[:, 0])
    C = -np.einsum("bji,bj->bi", R, t)
    depth = np.einsum("bj,bmj->bm", R[:, 2], X - C[:, None])
    valid = (np.all(np.isfinite(R), axis=(1, 2)) & np.all(np.isfinite(C), axis=1) & (np.linalg.det(R) > 0)
             & (np.sum(depth > 0, axis=1) > m / 2))
    return np.concatenate([R.reshape(B, 9), C], axis=1), valid


def _residuals_jacobian(problem: _PnP, R, C, inliers):
    """Pixel residuals ``(2 m,)`` of the inliers and their Jacobian ``(2 m, 6)`` in the
    rotation ``R <- exp([w]x) R`` and the centre ``C``."""
    X, x, K = problem.X[inliers], problem.x[inliers], problem.K
    p = (X - C) @ R.T  # (m, 3)
    z = p[:, 2]
    xy = p[:, :2] / z[:, None]
    r = ((x - xy) @ K[:2, :2].T).ravel()
    P = np.zeros((len(p), 2, 3))  # d normalised / d p
    P[:, 0, 0] = P[:, 1, 1] = 1.0 / z
    P[:, :, 2] = -xy / z[:, None]
    P = np.einsum("ab,mbc->mac", K[:2, :2], P)  # d pixel / d p
    px = np.zeros((len(p), 3, 3))  # -[p]x: d p / d w
    px[:, 0, 1], px[:, 0, 2], px[:, 1, 2] = p[:, 2], -p[:, 1], p[:, 0]
    px -= np.transpose(px, (0, 2, 1))
    J = np.concatenate([P @ px, -P @ R], axis=2).reshape(-1, 6)
    return r, J


def _polish(problem: _PnP, hypothesis: np.ndarray, inliers: np.ndarray, steps: int = 5):
    """Gauss-Newton on the reprojection error of the inliers from a DLT hypothesis."""
    R, C = hypothesis[:9].reshape(3, 3), hypothesis[9:].copy()
    for _ in range(steps):
        r, J = _residuals_jacobian(problem, R, C, inliers)
        step = np.linalg.lstsq(J, r, rcond=None)[0]
        R, C = rotvec_to_matrix(step[:3]) @ R, C + step[3:]
    return R, C


def _rotation_covariance(problem: _PnP, R, C, inliers) -> np.ndarray:
    """``(J^T J)^-1`` of the rotation (3, 3) at the pose (unit pixel noise)."""
    _, J = _residuals_jacobian(problem, R, C, inliers)
    return np.linalg.pinv(J.T @ J)[:3, :3]
