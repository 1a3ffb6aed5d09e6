"""A start from general robot motion: views at their own flange orientations, no
pure-translation session needed (the idea of Andreff, Horaud & Espiau, "Robot hand-eye
calibration using structure-from-motion", IJRR 2001, in the form known flange poses allow).

Every view's camera has the rotation ``R_c,i = R_X^T R_i^T`` (world -> camera) and the
centre ``C_i = T_i + R_i t_X`` (the eye-in-hand form; eye-to-hand poses arrive inverted).
Two views ``i, j`` that share points give their fundamental matrix ``F_ij``
(``p_j^T F_ij p_i = 0``; the eight-point solver inside the project's robust loop, Sampson
errors). For a camera ``K``, ``E_ij = K^T F_ij K = [t]x R_E`` with

    R_E = R_X^T (R_j^T R_i) R_X,        t ~ R_c,j (C_i - C_j),

so ``R_X rotvec(R_E) = rotvec(R_j^T R_i)``: a conjugated rotation keeps its angle and
turns its axis by ``R_X``. Hence:

1. **K**: the principal point in the middle of the observed pixels, and the focal length
   ``f`` that makes the pairs' rotations agree best with the flange's: for each ``f`` on a
   log grid, ``R_X`` by orthogonal Procrustes on the rotation vectors and the cost
   ``sum_ij |rotvec(R_X R_E R_X^T (R_j^T R_i)^T)|^2``; the best grid point refined by a
   bounded scalar search. (Of the two rotations an essential matrix allows, the one whose
   angle is nearer the flange's is taken.)
2. **R_X** by Procrustes at that ``f``.
3. **t_X** linear: ``[t]x R_X^T R_j^T ((R_i - R_j) t_X + T_i - T_j) = 0`` for every pair,
   least squares (the minimum-norm solution where the rotations leave it free).
4. **The points** triangulated with every view's camera.

A view whose recorded orientation is wrong makes every pair it belongs to misfit by about
its error: a view whose median misfit exceeds the session tolerance and the other views'
spread is named with that angle and left out, and the start is made again without it.

It only has to land in the basin of the bundle adjuster, which refines everything.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DegenerateError
from ..estimate.ransac import least_singular_vector, lo_ransac
from ..geometry.rotation import matrix_to_rotvec, nearest_rotation, rotation_angle_deg, skew
from ..geometry.triangulate import triangulate
from .join import spread_limits

__all__ = ["GeneralStart", "general_start", "check_turns"]

#: Points two views must share for their epipolar geometry to be used.
MIN_COMMON = 12
#: Partners per view (those sharing the most points), to keep the number of pairs O(n_views).
MAX_PARTNERS = 8
#: Focal lengths tried, as multiples of the observed pixels' extent.
FOCAL_RANGE = (0.2, 10.0)
FOCAL_GRID = 64
#: Smallest singular value ratio of the pairs' rotation vectors for R_X to be determined.
AXES_RTOL = 1e-3


@dataclass(frozen=True, eq=False)
class GeneralStart:
    """The start from general motion.

    Attributes
    ----------
    K : (3, 3) float
        ``[[f, 0, cx], [0, f, cy], [0, 0, 1]]``.
    R_X : (3, 3) float
        Camera -> flange rotation.
    t_X : (3,) float
        Camera centre in the flange (minimum norm along directions the pairs leave free).
    X : (n_points, 3) float
        Triangulated points (base frame; NaN where fewer than 2 views).
    pairs : (m, 2) int
        The view pairs used.
    planar : (m,) bool
        Pairs whose motion came from their homography (its rotation nearer the flange's:
        a flat scene, or one of little relief, leaves the epipolar geometry weak).
    off_views : tuple of (int, float)
        Views left out, with the angle (deg) by which their images contradict their
        recorded orientation.
    """

    K: np.ndarray
    R_X: np.ndarray
    t_X: np.ndarray
    X: np.ndarray
    pairs: np.ndarray
    planar: np.ndarray
    off_views: tuple = ()


def general_start(uv: np.ndarray, T: np.ndarray, R: np.ndarray, tolerance_deg: float = 1.0,
                  rng=None) -> GeneralStart:
    """The start of a calibration from views at any flange poses (module docstring).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen.
    T : (n_views, 3) float
        Flange positions (robot units).
    R : (n_views, 3, 3) float
        Flange -> base rotations.
    tolerance_deg : float
        The session tolerance: a view whose recorded orientation its images contradict by
        more (and by more than the other views' spread) is left out.
    rng : seed or Generator

    Raises
    ------
    DegenerateError
        Too few view pairs share points, or their rotations are all about one axis.
    """
    rng = np.random.default_rng(rng)
    pairs = view_pairs(uv)
    geometry = [_pair_geometry(uv[i], uv[j], rng) for i, j in pairs]
    keep = np.array([g is not None for g in geometry], bool)
    pairs, geometry = pairs[keep], [g for g in geometry if g is not None]
    F = np.stack([g.F for g in geometry]) if geometry else np.zeros((0, 3, 3))
    H = np.stack([g.H for g in geometry]) if geometry else np.zeros((0, 3, 3))
    flange = np.einsum("pba,pbc->pac", R[pairs[:, 1]], R[pairs[:, 0]])  # R_j^T R_i
    check_turns(flange)
    centre, extent = _pixel_centre_and_extent(uv)
    motion = _motion(F, H, flange, centre, extent)
    off = _views_off(motion[3], pairs, len(T), tolerance_deg)
    if off:  # the rest without them
        use = ~np.isin(pairs, [v for v, _ in off]).any(axis=1)
        check_turns(flange[use])
        pairs, F, H, flange = pairs[use], F[use], H[use], flange[use]
        motion = _motion(F, H, flange, centre, extent)
    K, R_X, (R_E, t_dir, planar), _ = motion
    t_X = _offset(R_X, R, T, pairs, t_dir)
    R_cam = np.transpose(R @ R_X, (0, 2, 1))
    X = triangulate(K @ R_cam, uv, T + R @ t_X)
    return GeneralStart(K, R_X, t_X, X, pairs, planar, tuple(off))


def _motion(F, H, flange, centre, extent):
    """``(K, R_X, (R_E, t_dir, planar), misfit_deg (m,))`` of the pairs."""
    K = _intrinsics(_best_focal(F, H, flange, centre, extent), centre)
    pair = _pair_motions(F, H, K, flange)
    R_X = _procrustes(pair[0], flange)
    misfit = rotation_angle_deg(R_X @ pair[0] @ R_X.T @ np.transpose(flange, (0, 2, 1)))
    return K, R_X, pair, misfit


def _views_off(misfit_deg: np.ndarray, pairs: np.ndarray, n_views: int, tolerance_deg: float) -> list:
    """Views whose recorded orientation their images contradict, with the angle: each
    view's median misfit over its pairs, beyond the tolerance and the other views' spread
    (:func:`~transcalib.handeye.join.spread_limits`)."""
    angle = np.array([np.median(misfit_deg[(pairs == v).any(axis=1)]) if (pairs == v).any() else 0.0
                      for v in range(n_views)])
    limits = spread_limits(angle, tolerance_deg)
    return [(int(v), float(angle[v])) for v in np.flatnonzero(angle > limits)]


def view_pairs(uv: np.ndarray) -> np.ndarray:
    """Pairs ``(m, 2)`` of views (i < j) sharing at least :data:`MIN_COMMON` points, each
    view with at most :data:`MAX_PARTNERS` partners (those sharing the most)."""
    seen = np.isfinite(uv[..., 0]).astype(np.int32)
    common = seen @ seen.T
    np.fill_diagonal(common, 0)
    rank = np.argsort(-common, axis=1, kind="stable")[:, :MAX_PARTNERS]
    chosen = np.zeros_like(common, bool)
    np.put_along_axis(chosen, rank, True, axis=1)
    chosen &= common >= MIN_COMMON
    chosen |= chosen.T
    i, j = np.nonzero(np.triu(chosen, 1))
    return np.stack([i, j], axis=1)


def check_turns(flange: np.ndarray) -> None:
    """Refuse when relative flange rotations ``flange (m, 3, 3)`` cannot fix ``R_X``
    (fewer than two independent rotation axes: no turn at all, or every turn about one
    axis, as a SCARA wrist turns)."""
    n_pairs = len(flange)
    w = matrix_to_rotvec(flange) if n_pairs else np.zeros((0, 3))
    s = np.linalg.svd(w, compute_uv=False) if n_pairs >= 2 else np.zeros(1)
    if n_pairs < 2 or s[1] <= AXES_RTOL * max(s[0], 1e-300):
        raise DegenerateError(
            f"the views give no start: {n_pairs} view pair(s) share >= {MIN_COMMON} points, and their relative "
            "flange rotations "
            + ("are all about one axis" if n_pairs >= 2 else "are too few")
            + ". A start needs either a pure-translation session (4 or more views at one flange orientation whose "
            "translations span 3-D) or views turned about at least two different axes that see common points.")


def _pixel_centre_and_extent(uv: np.ndarray) -> tuple[np.ndarray, float]:
    """The middle of the observed pixels (the start's principal point) and their extent."""
    lo, hi = np.nanmin(uv, axis=(0, 1)), np.nanmax(uv, axis=(0, 1))
    return 0.5 * (lo + hi), float(np.max(hi - lo))


def _intrinsics(f: float, centre: np.ndarray) -> np.ndarray:
    return np.array([[f, 0.0, centre[0]], [0.0, f, centre[1]], [0.0, 0.0, 1.0]])


def _best_focal(F: np.ndarray, H: np.ndarray, flange: np.ndarray, centre: np.ndarray, extent: float) -> float:
    """The focal length (px) whose pair rotations agree best with the flange's."""
    from scipy.optimize import minimize_scalar  # here: scipy.optimize costs every command 0.1 s to import

    def cost(log_f: float) -> float:
        R_E = _pair_motions(F, H, _intrinsics(np.exp(log_f), centre), flange)[0]
        return _rotation_misfit(R_E, flange, _procrustes(R_E, flange))

    grid = np.log(extent) + np.linspace(np.log(FOCAL_RANGE[0]), np.log(FOCAL_RANGE[1]), FOCAL_GRID)
    costs = np.array([cost(g) for g in grid])
    k = int(np.argmin(costs))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, FOCAL_GRID - 1)]
    res = minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
    return float(np.exp(res.x if res.fun <= costs[k] else grid[k]))


def _pair_motions(F: np.ndarray, H: np.ndarray, K: np.ndarray,
                  flange: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pair's camera rotation ``R_E (m, 3, 3)`` and translation direction ``t (m, 3)``
    (``x_j = R_E x_i + t``) with the camera ``K``: of the two rotations its essential
    matrix ``K^T F K`` allows and the two its calibrated homography ``K^-1 H K`` allows
    (``F``, ``H`` (m, 3, 3), NaN where not fitted), the one whose angle is nearest the
    flange's relative rotation ``flange (m, 3, 3)`` (conjugation keeps the angle); and
    whether it came from the homography ``(m,)``."""
    R_e, t_e = _essential_motions(np.einsum("ba,pbc,cd->pad", K, np.nan_to_num(F), K))
    R_h, t_h = _homography_motions(np.einsum("ab,pbc,cd->pad", np.linalg.inv(K), np.nan_to_num(H), K))
    candidates = np.concatenate([R_e, R_h], axis=1)  # (m, 4, 3, 3)
    t = np.concatenate([np.repeat(t_e[:, None], 2, axis=1), t_h], axis=1)  # (m, 4, 3)
    off = np.abs(rotation_angle_deg(candidates) - rotation_angle_deg(flange)[:, None])
    fitted = np.repeat(np.stack([np.isfinite(F[:, 0, 0]), np.isfinite(H[:, 0, 0])], axis=1), 2, axis=1)
    take = np.argmin(np.where(fitted, off, np.inf), axis=1)
    rows = np.arange(len(F))
    return candidates[rows, take], t[rows, take], take >= 2


def _essential_motions(E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two rotations ``(m, 2, 3, 3)`` and the translation direction ``(m, 3)`` an
    essential matrix ``E = [t]x R`` allows (Hartley & Zisserman, result 9.19)."""
    U, _, Vt = np.linalg.svd(E)
    U = U * np.sign(np.linalg.det(U))[:, None, None]
    Vt = Vt * np.sign(np.linalg.det(Vt))[:, None, None]
    W = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return np.stack([U @ W @ Vt, U @ W.T @ Vt], axis=1), U[:, :, 2]


def _homography_motions(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two rotations ``(m, 2, 3, 3)`` and translation directions ``(m, 2, 3)`` a
    calibrated plane homography ``H ~ R + t n^T`` allows (Ma, Soatto, Kosecka & Sastry,
    *An Invitation to 3-D Vision*, section 5.3.3): with ``H`` scaled to its middle
    singular value 1 and positive determinant, ``H^T H = V diag(s1^2, 1, s3^2) V^T``,
    ``u = (sqrt(1 - s3^2) v1 +- sqrt(s1^2 - 1) v3) / sqrt(s1^2 - s3^2)``,
    ``R = [H v2, H u, [H v2]x H u] [v2, u, [v2]x u]^T``, ``n = [v2]x u``, ``t = (H - R) n``.
    Without translation (``s1 = s3``) ``H`` is the rotation and ``t = 0``."""
    sv = np.linalg.svd(H, compute_uv=False)
    H = H / sv[:, 1:2, None] * np.sign(np.linalg.det(H))[:, None, None]
    w, V = np.linalg.eigh(np.transpose(H, (0, 2, 1)) @ H)  # ascending: s3^2, 1, s1^2
    s3, s1 = w[:, 0], w[:, 2]
    v1, v2, v3 = V[:, :, 2], V[:, :, 1], V[:, :, 0]
    spread = np.sqrt(np.maximum(s1 - s3, 1e-300))[:, None]
    a, b = np.sqrt(np.clip(1 - s3, 0, None))[:, None], np.sqrt(np.clip(s1 - 1, 0, None))[:, None]
    Rs, ts = [], []
    for u in ((a * v1 + b * v3) / spread, (a * v1 - b * v3) / spread):
        n = np.cross(v2, u)
        Hv2, Hu = np.einsum("pab,pb->pa", H, v2), np.einsum("pab,pb->pa", H, u)
        Rm = np.stack([Hv2, Hu, np.cross(Hv2, Hu)], axis=2) @ np.transpose(np.stack([v2, u, n], axis=2), (0, 2, 1))
        Rs.append(Rm)
        ts.append(np.einsum("pab,pb->pa", H - Rm, n))
    R, t = np.stack(Rs, axis=1), np.stack(ts, axis=1)
    still = (s1 - s3 < 1e-12)[:, None]
    nearest = np.stack([nearest_rotation(h) for h in H])[:, None]
    return np.where(still[..., None, None], nearest, R), np.where(still[..., None], 0.0, t)


def _procrustes(R_E: np.ndarray, flange: np.ndarray) -> np.ndarray:
    """``R_X`` minimising ``sum |R_X rotvec(R_E) - rotvec(flange)|^2``."""
    a, b = matrix_to_rotvec(R_E), matrix_to_rotvec(flange)
    return nearest_rotation(b.T @ a)


def _rotation_misfit(R_E: np.ndarray, flange: np.ndarray, R_X: np.ndarray) -> float:
    """``sum |rotvec(R_X R_E R_X^T flange^T)|^2`` (rad^2)."""
    D = R_X @ R_E @ R_X.T @ np.transpose(flange, (0, 2, 1))
    return float(np.sum(matrix_to_rotvec(D) ** 2))


def _offset(R_X: np.ndarray, R: np.ndarray, T: np.ndarray, pairs: np.ndarray, t_dir: np.ndarray) -> np.ndarray:
    """``t_X`` from the pairs' translation directions: ``[t]x M ((R_i - R_j) t_X + T_i - T_j) = 0``
    with ``M = R_X^T R_j^T``, least squares, minimum norm."""
    i, j = pairs[:, 0], pairs[:, 1]
    M = skew(t_dir) @ R_X.T @ np.transpose(R[j], (0, 2, 1))  # (m, 3, 3)
    A = (M @ (R[i] - R[j])).reshape(-1, 3)
    b = -np.einsum("pab,pb->pa", M, T[i] - T[j]).ravel()
    return np.linalg.lstsq(A, b, rcond=1e-9)[0]


@dataclass(frozen=True, eq=False)
class _PairGeometry:
    """Two views' fundamental matrix ``F`` and homography ``H`` (pixels, ``i -> j``; NaN
    where its robust fit found no consensus)."""

    F: np.ndarray
    H: np.ndarray


def _pair_geometry(uv_i: np.ndarray, uv_j: np.ndarray, rng) -> _PairGeometry | None:
    """The epipolar geometry of two views (``p_j^T F p_i = 0``) and their homography (a
    flat scene, or one of little relief, leaves ``F`` undetermined or ill-conditioned;
    the homography then gives the motion); None without a consensus of
    :data:`MIN_COMMON` for either."""
    both = np.isfinite(uv_i[:, 0]) & np.isfinite(uv_j[:, 0])
    if both.sum() < MIN_COMMON:
        return None
    p1, p2 = uv_i[both], uv_j[both]
    fits = [lo_ransac(problem, sigma=None, rng=rng, stage="view pair") for problem in
            (_EightPoint(p1, p2), _FourPoint(p1, p2))]
    ok = [f.hypothesis is not None and f.n_inliers >= MIN_COMMON for f in fits]
    if not any(ok):
        return None
    F, H = (f.hypothesis.reshape(3, 3) if good else np.full((3, 3), np.nan) for f, good in zip(fits, ok))
    return _PairGeometry(F, H)


def _normaliser(p: np.ndarray) -> np.ndarray:
    """Hartley's similarity (3, 3): centroid to the origin, mean distance sqrt(2)."""
    mu = p.mean(axis=0)
    s = np.sqrt(2.0) / max(float(np.mean(np.linalg.norm(p - mu, axis=1))), 1e-12)
    return np.array([[s, 0.0, -s * mu[0]], [0.0, s, -s * mu[1]], [0.0, 0.0, 1.0]])


class _TwoViews:
    """Correspondences ``p1, p2 (n, 2)`` (pixels) of two views as data of the generic loop:
    homogeneous pixels ``h1, h2``, Hartley-normalised ``q1, q2`` (normalisers ``N1, N2``);
    the subclasses give ``sample_size``, ``DOF``, ``errors`` and ``_fit``."""

    sample_size: int
    DOF: int

    def __init__(self, p1: np.ndarray, p2: np.ndarray):
        n = len(p1)
        self.h1, self.h2 = np.c_[p1, np.ones(n)], np.c_[p2, np.ones(n)]
        self.N1, self.N2 = _normaliser(p1), _normaliser(p2)
        self.q1, self.q2 = self.h1 @ self.N1.T, self.h2 @ self.N2.T
        self.dof = np.full(n, self.DOF)
        self.scorable = np.ones(n, bool)
        self.samplable = np.ones(n, bool)

    def sample(self, rng, size: int) -> np.ndarray:
        return np.argsort(rng.random((size, len(self.h1))), axis=1)[:, : self.sample_size]

    def solve(self, samples: np.ndarray):
        return self._fit(self.q1[samples], self.q2[samples])

    def refit(self, inliers: np.ndarray):
        return self._fit(self.q1[inliers][None], self.q2[inliers][None])


class _EightPoint(_TwoViews):
    """Two views' fundamental matrix as hooks of the generic loop: a hypothesis is ``F``
    flattened (9,), in pixels; errors are Sampson's squared distances (px^2, 1 degree of
    freedom)."""

    sample_size, DOF = 8, 1

    def errors(self, hypotheses: np.ndarray) -> np.ndarray:
        F = hypotheses.reshape(-1, 3, 3)
        Fp1 = np.einsum("hab,nb->hna", F, self.h1)
        Ftp2 = np.einsum("hba,nb->hna", F, self.h2)
        num = np.einsum("na,hna->hn", self.h2, Fp1) ** 2
        den = Fp1[..., 0] ** 2 + Fp1[..., 1] ** 2 + Ftp2[..., 0] ** 2 + Ftp2[..., 1] ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(den > 0, num / den, np.inf)

    def _fit(self, q1: np.ndarray, q2: np.ndarray):
        """Batched eight-point (m >= 8) on normalised coordinates ``(B, m, 3)``, rank 2
        enforced, returned in pixels with unit norm: ``(B, 9)`` and validity."""
        A = (q2[:, :, :, None] * q1[:, :, None, :]).reshape(q1.shape[0], q1.shape[1], 9)
        Fn = least_singular_vector(A).reshape(-1, 3, 3)
        U, s, Vt = np.linalg.svd(Fn)
        s[:, 2] = 0.0
        F = self.N2.T @ (U * s[:, None, :]) @ Vt @ self.N1
        F /= np.linalg.norm(F, axis=(1, 2))[:, None, None]
        return F.reshape(-1, 9), np.all(np.isfinite(F), axis=(1, 2))


class _FourPoint(_TwoViews):
    """Two views' homography as hooks of the generic loop: a hypothesis is ``H`` flattened
    (9,), in pixels; errors are squared transfer errors in the second view (px^2, 2
    degrees of freedom)."""

    sample_size, DOF = 4, 2

    def errors(self, hypotheses: np.ndarray) -> np.ndarray:
        q = np.einsum("hab,nb->hna", hypotheses.reshape(-1, 3, 3), self.h1)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = q[..., :2] / q[..., 2:3] - self.h2[None, :, :2]
        e = np.sum(d * d, axis=2)
        return np.where(np.isfinite(e), e, np.inf)

    def _fit(self, q1: np.ndarray, q2: np.ndarray):
        """Batched DLT (m >= 4) on normalised coordinates ``(B, m, 3)``: ``q2 x (H q1) = 0``,
        returned in pixels with unit norm ``(B, 9)`` and validity."""
        B, m = q1.shape[:2]
        A = np.zeros((B, 2 * m, 9))
        A[:, 0::2, 3:6] = -q2[..., 2:3] * q1
        A[:, 0::2, 6:9] = q2[..., 1:2] * q1
        A[:, 1::2, 0:3] = q2[..., 2:3] * q1
        A[:, 1::2, 6:9] = -q2[..., 0:1] * q1
        Hn = least_singular_vector(A).reshape(-1, 3, 3)
        H = np.linalg.inv(self.N2) @ Hn @ self.N1
        H /= np.linalg.norm(H, axis=(1, 2))[:, None, None]
        return H.reshape(-1, 9), np.all(np.isfinite(H), axis=(1, 2))
