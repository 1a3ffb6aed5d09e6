"""Robust estimation: a two-point minimal solver inside an MSAC / LO-RANSAC loop.

Two points seen in four views determine ``A = K R`` (paper §2.1), so RANSAC draws pairs
of points, solves for ``A`` from them alone, triangulates *every* point with that ``A``
and the known translations, and scores the hypothesis by the reprojection errors.

Minimal solver
--------------
For point ``j`` seen in view ``i``, paper eq. 2 reads, with ``Y_j = A X_j``::

    lam_ij u_ij = Y_j - A T_i                        (u_ij = [u, v, 1], 3 equations)

Unknowns ``lam_ij`` (one per view), ``Y_j`` (3) and ``a = vec(A)`` (9, row-major, so
that ``A T_i = kron(I_3, T_i^T) a``). Eliminating ``lam_ij`` projects each block
onto the plane orthogonal to ``u_ij`` (``N_ij = I - u u^T / |u|^2``); eliminating
``Y_j`` leaves one quadratic form per point::

    m_j(a) = a^T M_j a,   M_j = sum_i kron(N_ij, T_i T_i^T) - W_j^T S_j^-1 W_j,
    S_j = sum_i N_ij,     W_j = sum_i kron(N_ij, T_i^T)          (S_j 3 x 3, W_j 3 x 9)

A point seen in ``k`` views constrains ``a`` by ``2k - 3`` equations, so a pair of
points seen in four views each (10 constraints, 8 degrees of freedom) determines ``A``
up to scale: ``a`` is the eigenvector of ``M_j1 + M_j2`` for the smallest eigenvalue
(exactly zero for noise-free data). Hypotheses are solved in batches (one batched 9 x 9
``eigh``), in Hartley-normalised coordinates (pixels: zero mean, mean distance
``sqrt(2)``; translations: unit mean norm). The same form summed over the inliers gives
the local-optimisation refit in O(n).

Scoring
-------
With ``A`` known the linear triangulation of point ``j`` (paper eq. 2 divided out, as in
:mod:`transcalib.triangulate`) is ``Y_j = G_j^-1 sum_i P_ij A T_i`` with
``P_ij = r_u r_u^T + r_v r_v^T``, ``r_u = (1, 0, -u)``, ``r_v = (0, 1, -v)`` and
``G_j = sum_i P_ij``: ``G_j^-1 P_ij`` do not depend on ``A`` and are computed once, so
scoring a hypothesis costs O(n_views n_points) multiply-adds, vectorised over
hypotheses and points. The **error of a point** is the largest reprojection error (pixel
norm) over the views that see it, infinite when it lies behind the camera in some view;
a point is an **inlier** when that error is below ``threshold_px``. Hypotheses are ranked
by the MSAC cost ``sum_j min(e_j^2, threshold_px^2)``.

Loop: adaptive number of trials ``log(1 - confidence) / log(1 - p)`` (``p`` the
probability of drawing two inliers at the best inlier ratio so far); each new best
hypothesis is refined by local optimisation (refit on its inliers, rescore, repeat while
the cost drops). Problems with more than ``SCORE_POINTS`` points draw and score the
hypotheses on a random subset of that many points (the ranking of hypotheses needs no
more); every point is then classified with the best hypothesis. The final model is
:func:`transcalib.estimate_linear` on the inliers, with the inliers reclassified from it
(weighted triangulation, all points) until they settle.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from .linear import estimate_linear
from ..geometry.triangulate import triangulate
from ..types import DegenerateError, InputError, LinearEstimate, MirroredError
from ..validate import as_uv_T, check_translations_span

__all__ = ["RobustEstimate", "estimate_robust", "solve_minimal", "point_errors"]

#: Points on which hypotheses are scored (a random subset of larger problems).
SCORE_POINTS = 4096
#: Fewest inliers (sampled pair included) that count as a consensus.
MIN_CONSENSUS = 4
#: Relative singular value below which a set of translations counts as not spanning 3-D.
_SPAN_TOL = 1e-6
#: Largest number of (hypothesis x view x point) entries scored at once (memory bound).
_SCORE_BLOCK = 2_000_000


@dataclass(frozen=True, eq=False)
class RobustEstimate:
    """Result of :func:`estimate_robust`.

    Attributes
    ----------
    linear : LinearEstimate
        The paper's linear estimate refitted on the inliers (``linear.used == inliers``;
        ``linear.X`` is NaN for outliers).
    inliers : (n_points,) bool
        Points whose reprojection error is below ``threshold_px`` in **every** view that
        sees them, under the final ``linear.A``.
    error_px : (n_points,) float
        Per-point score: the largest reprojection error (pixels) over the views that see
        the point, each point triangulated from all its views with the final ``A``;
        ``inf`` if it falls behind the camera, NaN if it is seen in fewer than 2 views.
    residuals_px : (n_views, n_points, 2) float
        Observed minus predicted pixels for every observation under the final ``A``
        (outliers included); NaN where unseen.
    trials : int
        Minimal-sample hypotheses drawn.
    inlier_ratio : float
        ``inliers.sum() / n_points``.
    threshold_px : float
        The inlier threshold used.
    cost : float
        MSAC cost ``sum_j min(error_px_j^2, threshold_px^2)`` of the final model (px^2).
    info : dict
        ``trials_needed``, ``lo_steps``, ``refits``, ``time_s``, ``n_candidates``
        (points eligible for sampling), ``n_scored`` (points hypotheses were scored on).
    """

    linear: LinearEstimate
    inliers: np.ndarray
    error_px: np.ndarray
    residuals_px: np.ndarray
    trials: int
    inlier_ratio: float
    threshold_px: float
    cost: float
    info: dict

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


# ----------------------------------------------------------------------------------------
# Normalisation and the per-point quadratic forms
# ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Problem:
    """Normalised data: ``x (n, V, 2)`` pixels (0 where unseen), ``seen (n, V)``,
    ``T (V, 3)`` translations, ``scale`` (normalised units per pixel), ``H``, ``t_scale``."""

    x: np.ndarray
    seen: np.ndarray
    T: np.ndarray
    scale: float
    H: np.ndarray
    t_scale: float


def _normalise(uv: np.ndarray, T: np.ndarray) -> _Problem:
    seen = np.isfinite(uv[..., 0]).T  # (n, V)
    centre = np.nanmean(uv, axis=(0, 1))
    spread = np.nanmean(np.hypot(uv[..., 0] - centre[0], uv[..., 1] - centre[1]))
    scale = float(np.sqrt(2.0) / spread) if spread > 0 else 1.0
    x = np.where(seen[..., None], (uv.transpose(1, 0, 2) - centre) * scale, 0.0)
    H = np.array([[scale, 0.0, -scale * centre[0]], [0.0, scale, -scale * centre[1]], [0.0, 0.0, 1.0]])
    T_mean = T.mean(axis=0)
    t_scale = float(np.linalg.norm(T - T_mean, axis=1).mean())
    return _Problem(x=x, seen=seen, T=(T - T_mean) / t_scale, scale=scale, H=H, t_scale=t_scale)


def _forms(pb: _Problem, idx: np.ndarray) -> np.ndarray:
    """Quadratic forms ``M_j`` (len(idx), 9, 9) of the points ``idx`` (module docstring)."""
    x, seen, T = pb.x[idx], pb.seen[idx], pb.T
    u = np.concatenate([x, np.ones(x.shape[:2] + (1,))], axis=2)  # (n, V, 3)
    N = np.eye(3) - u[..., :, None] * u[..., None, :] / np.einsum("nva,nva->nv", u, u)[..., None, None]
    N *= seen[..., None, None]
    S = N.sum(axis=1)  # (n, 3, 3)
    W = np.einsum("nvab,vd->nabd", N, T).reshape(-1, 3, 9)
    TT = T[:, :, None] * T[:, None, :]
    M = np.einsum("nvab,vcd->nacbd", N, TT).reshape(-1, 9, 9)
    with np.errstate(all="ignore"):
        SW = np.linalg.solve(S, W)
    M -= np.einsum("nak,nal->nkl", W, SW)
    return M


def _forms_sum(pb: _Problem, idx: np.ndarray, chunk: int = 8192) -> np.ndarray:
    """``sum_j M_j`` over the points ``idx`` (9, 9), in chunks."""
    total = np.zeros((9, 9))
    for lo in range(0, len(idx), chunk):
        M = _forms(pb, idx[lo: lo + chunk])
        total += np.nansum(M, axis=0)
    return total


def _null_vectors(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvectors for the smallest eigenvalue of symmetric ``M`` (B, 9, 9) and a
    validity mask (False where the null space is not one-dimensional)."""
    M = 0.5 * (M + M.transpose(0, 2, 1))
    w, v = np.linalg.eigh(M)
    ok = np.isfinite(w).all(axis=1) & (w[:, 1] > 1e-10 * np.maximum(w[:, -1], 1e-300))
    return v[:, :, 0], ok


# ----------------------------------------------------------------------------------------
# Scoring: triangulation with a hypothesised A, vectorised over hypotheses and points
# ----------------------------------------------------------------------------------------


class _Scorer:
    """Precomputes ``L_ij = G_j^-1 P_ij`` (module docstring) for the scorable points."""

    def __init__(self, pb: _Problem):
        self.pb = pb
        x, seen = pb.x, pb.seen
        n, V = seen.shape
        P = np.zeros((n, V, 3, 3))
        P[..., 0, 0] = P[..., 1, 1] = 1.0
        P[..., 0, 2] = P[..., 2, 0] = -x[..., 0]
        P[..., 1, 2] = P[..., 2, 1] = -x[..., 1]
        P[..., 2, 2] = x[..., 0] ** 2 + x[..., 1] ** 2
        P *= seen[..., None, None]
        G = P.sum(axis=1)
        # points seen in >= 2 views with non-parallel rays can be triangulated
        det = np.linalg.det(G)
        self.ok = (seen.sum(axis=1) >= 2) & (np.abs(det) > 1e-12 * np.abs(np.einsum("naa->n", G)) ** 3)
        G[~self.ok] = np.eye(3)
        L = np.linalg.solve(G[:, None], P)  # (n, V, 3, 3)
        L[~self.ok] = 0.0
        del P, G
        # as one matrix (3 n, 3 V): Y = L2 @ vec(A T_i) is a BLAS product per batch
        self.L2 = np.ascontiguousarray(L.transpose(0, 2, 1, 3).reshape(3 * n, 3 * V))
        self.n, self.V = n, V

    def errors(self, A: np.ndarray) -> np.ndarray:
        """Largest reprojection error per point (H, n) in **pixels** for normalised
        hypotheses ``A`` (H, 3, 3); inf if behind the camera, NaN if not scorable."""
        pb = self.pb
        Hn = A.shape[0]
        out = np.empty((Hn, self.n))
        step = max(1, _SCORE_BLOCK // max(1, self.n * self.V))
        for lo in range(0, Hn, step):
            out[lo: lo + step] = self._errors(A[lo: lo + step])
        out[:, ~self.ok] = np.nan
        return out / pb.scale

    def _errors(self, A):
        pb = self.pb
        c = np.einsum("hab,vb->hva", A, pb.T)  # A T_i: (H, V, 3)
        Y = (self.L2 @ c.reshape(len(A), -1).T).T.reshape(len(A), self.n, 3)  # (H, n, 3)
        p = Y[:, :, None, :] - c[:, None, :, :]  # (H, n, V, 3) = A (X_j - T_i)
        z = p[..., 2]
        seen = pb.seen[None]
        # fix each hypothesis' sign so that most depths are positive
        sign = np.sign(np.sum(np.where(seen, np.sign(z), 0.0), axis=(1, 2)))
        sign[sign == 0] = 1.0
        z = z * sign[:, None, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = sign[:, None, None] / z
            du = p[..., 0] * inv - pb.x[None, ..., 0]
            dv = p[..., 1] * inv - pb.x[None, ..., 1]
        e2 = du * du + dv * dv
        e2 = np.where(z > 0, e2, np.inf)
        e2 = np.where(seen, e2, 0.0)
        return np.sqrt(e2.max(axis=2))


def _msac_cost(err: np.ndarray, thr: float) -> np.ndarray:
    """``sum_j min(e_j^2, thr^2)`` over scorable points, per hypothesis (H,)."""
    e2 = np.minimum(np.nan_to_num(err, nan=0.0, posinf=np.inf) ** 2, thr * thr)
    e2 = np.where(np.isnan(err), 0.0, e2)
    return e2.sum(axis=-1)


def _to_pixels(pb: _Problem, a: np.ndarray) -> np.ndarray:
    """Normalised ``a`` (..., 9) -> pixel ``A`` (..., 3, 3), ``||A[2]|| = 1`` (sign kept)."""
    A = np.linalg.solve(pb.H, a.reshape(-1, 3, 3)) / pb.t_scale
    return A / np.linalg.norm(A[:, 2], axis=1)[:, None, None]


# ----------------------------------------------------------------------------------------
# Sampling
# ----------------------------------------------------------------------------------------


def _spans(T: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """For boolean view masks (m, V): do the translations of those views span 3-D?"""
    uniq, inv = np.unique(masks, axis=0, return_inverse=True)
    good = np.zeros(len(uniq), bool)
    for k, m in enumerate(uniq):  # one per distinct visibility pattern (few)
        if m.sum() < 4:
            continue
        t = T[m] - T[m][0]
        s = np.linalg.svd(t, compute_uv=False)
        good[k] = s[0] > 0 and s[2] > _SPAN_TOL * s[0]
    return good[np.ravel(inv)]


def _draw_pairs(rng, pool: np.ndarray, k_views: np.ndarray, seen: np.ndarray, T: np.ndarray, B: int):
    """``B`` random valid pairs of pool points (rejection sampling), as indices (B', 2).

    Valid: the two points are seen in ``k1 + k2 >= 8`` views in all (``2 k - 3``
    constraints each; a 4 + 3 split leaves a two-dimensional solution space) and the
    views seeing either of them have translations spanning 3-D."""
    m = len(pool)
    out = []
    got = 0
    for _ in range(20):
        i = rng.integers(m, size=2 * B)
        j = rng.integers(m - 1, size=2 * B)
        j += j >= i
        a, b = pool[i], pool[j]
        valid = k_views[a] + k_views[b] >= 8
        if valid.any():
            valid[valid] = _spans(T, seen[a[valid]] | seen[b[valid]])
        pairs = np.column_stack([a, b])[valid]
        out.append(pairs)
        got += len(pairs)
        if got >= B:
            break
    pairs = np.concatenate(out)[:B] if out else np.zeros((0, 2), int)
    return pairs


def _trials_needed(n_in: int, m: int, confidence: float) -> float:
    """``log(1 - confidence) / log(1 - p)``, ``p = n_in (n_in - 1) / (m (m - 1))``."""
    if m < 2 or n_in < 2:
        return math.inf
    p = min(1.0, n_in * (n_in - 1) / (m * (m - 1)))
    if p >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log1p(-p)


# ----------------------------------------------------------------------------------------
# Public API
# ----------------------------------------------------------------------------------------


def solve_minimal(uv, T, pairs) -> np.ndarray:
    """``A = K R`` from pairs of points (the two-point minimal solver, paper §2.1).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen.
    T : (n_views, 3) float
        Translations.
    pairs : (n_pairs, 2) int
        Point indices; the two points should be seen in >= 8 views counted per point
        (e.g. both in 4 views) whose translations span 3-D.

    Returns
    -------
    A : (n_pairs, 3, 3) float
        Pixel-unit ``A`` with ``||A[2]|| = 1`` and the sign that puts the pair in front of
        the camera; NaN for pairs that do not determine ``A``. Exact (to rounding) on
        noise-free data.
    """
    uv, T = as_uv_T(uv, T)
    pairs = np.asarray(pairs, dtype=int).reshape(-1, 2)
    pb = _normalise(uv, T)
    M = _forms(pb, pairs.ravel()).reshape(-1, 2, 9, 9).sum(axis=1)
    a, ok = _null_vectors(M)
    A = _to_pixels(pb, a)
    # sign: depths of the pair positive (triangulate with this A)
    for k in range(len(A)):  # one triangulation per pair: small, reference use only
        X = triangulate(A[k], uv[:, pairs[k]], T)
        z = np.einsum("a,vna->vn", A[k, 2], X[None] - T[:, None])
        if np.nanmedian(z) < 0:
            A[k] = -A[k]
    A[~ok] = np.nan
    return A


def point_errors(A: np.ndarray, uv: np.ndarray, T: np.ndarray):
    """Reprojection errors of every point triangulated with a known ``A``.

    Parameters
    ----------
    A : (3, 3) float
        ``K R`` in pixels, any scale; the sign is chosen so that most depths are positive.
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float

    Returns
    -------
    error_px : (n_points,) float
        Largest reprojection error over the views seeing the point (pixels); inf behind
        the camera, NaN if seen in fewer than 2 views.
    residuals_px : (n_views, n_points, 2) float
        Observed minus predicted, NaN where unseen.
    """
    A = A / np.linalg.norm(A[2])
    X = triangulate(A, uv, T)
    p = np.einsum("ab,vnb->vna", A, X[None] - T[:, None])
    seen = np.isfinite(uv[..., 0])
    z = p[..., 2][seen & np.isfinite(p[..., 2])]
    if z.size and np.median(z) < 0:  # A given with the other sign: most depths negative
        p = -p
    with np.errstate(divide="ignore", invalid="ignore"):
        pred = p[..., :2] / p[..., 2:3]
    res = uv - pred
    e = np.where(seen, np.hypot(res[..., 0], res[..., 1]), 0.0)
    e = np.where(seen & ~(p[..., 2] > 0), np.inf, e)
    err = e.max(axis=0)
    err[~(seen.sum(axis=0) >= 2) | ~np.isfinite(X).all(axis=1)] = np.nan
    return err, res


def estimate_robust(
    uv,
    T,
    *,
    threshold_px: float = 2.0,
    confidence: float = 0.999,
    max_trials: int = 1000,
    rng=None,
    progress=None,
) -> RobustEstimate:
    """Calibrate linearly despite gross outliers: two-point LO-MSAC, then a TLS refit.

    Parameters
    ----------
    uv : array_like (n_views, n_points, 2)
        Pixels (OpenCV convention), NaN where a point is not seen.
    T : array_like (n_views, 3)
        Robot translations spanning 3-D (``n_views >= 4``).
    threshold_px : float
        Inlier threshold (pixels) on a point's **largest** reprojection error over its
        views, the point triangulated from all its views with the hypothesised ``A``.
        About 3-4x the pixel noise (per coordinate) keeps > 99% of the inliers.
    confidence : float
        Probability, in ``(0, 1)``, that at least one all-inlier pair was drawn when the
        adaptive loop stops.
    max_trials : int
        Upper bound on the hypotheses drawn.
    rng : seed or numpy Generator
        Randomness of the sampling.
    progress : callable, optional
        Called after every batch of hypotheses with a dict
        ``{trials, trials_needed, best_inliers, best_cost}``.

    Returns
    -------
    RobustEstimate
        ``linear`` (the TLS refit on the inliers), ``inliers``, ``error_px``,
        ``residuals_px``, ``trials``, ``inlier_ratio``, ``threshold_px``, ``cost``, ``info``.

    Raises
    ------
    InputError
        Malformed input or options.
    DegenerateError
        No two points can be sampled (each needs 3+ views, together 8+ views whose
        translations span 3-D), or no consensus of at least ``MIN_CONSENSUS`` points.
    MirroredError
        The inliers imply a mirrored camera (left-handed robot frame, swapped axes).
    """
    t0 = time.perf_counter()
    uv, T = as_uv_T(uv, T)
    if not (np.isfinite(threshold_px) and threshold_px > 0):
        raise InputError(f"threshold_px must be a positive number of pixels, got {threshold_px!r}")
    if not 0.0 < confidence < 1.0:
        raise InputError(f"confidence must be in (0, 1), got {confidence!r}")
    if not isinstance(max_trials, (int, np.integer)) or max_trials < 1:
        raise InputError(f"max_trials must be a positive integer, got {max_trials!r}")
    check_translations_span(T)
    rng = np.random.default_rng(rng)
    thr = float(threshold_px)
    n_views, n_points = uv.shape[:2]

    pb_all = _normalise(uv, T)
    # hypotheses are drawn and scored on a random subset of at most SCORE_POINTS points;
    # the final classification and refit use every point
    scorable = np.flatnonzero(pb_all.seen.sum(axis=1) >= 2)
    if len(scorable) > SCORE_POINTS:
        subset = np.sort(rng.choice(scorable, SCORE_POINTS, replace=False))
    else:
        subset = np.arange(n_points)
    pb = replace(pb_all, x=pb_all.x[subset], seen=pb_all.seen[subset])
    scorer = _Scorer(pb)
    k_views = pb.seen.sum(axis=1)
    pool = np.flatnonzero((k_views >= 3) & scorer.ok)
    if len(pool) < 2:
        raise DegenerateError(
            f"robust estimation needs points seen in at least 3 views (pairs together in 8, e.g. "
            f"two points in 4 views); only {len(pool)} such point(s) among {n_points}. Track the "
            "points through more views."
        )

    best = {"cost": np.inf, "a": None, "err": None, "n_in": 0}
    trials = lo_steps = 0
    needed = math.inf
    batch = 16

    def consider(a: np.ndarray) -> bool:
        """Score hypotheses a (H, 9); keep the best; True if it improved."""
        err = scorer.errors(a.reshape(-1, 3, 3))
        cost = _msac_cost(err, thr)
        k = int(np.argmin(cost))
        if cost[k] < best["cost"]:
            best.update(cost=float(cost[k]), a=a[k], err=err[k], n_in=int(np.sum(err[k] < thr)))
            return True
        return False

    def local_optimisation():
        nonlocal lo_steps
        for _ in range(5):
            inl = np.flatnonzero(best["err"] < thr)
            if len(inl) < 2:
                return
            a, ok = _null_vectors(_forms_sum(pb, inl)[None])
            lo_steps += 1
            if not ok[0] or not consider(a):
                return

    while trials < min(needed, max_trials):
        B = int(min(batch, max_trials - trials, max(1, math.ceil(needed - trials)) if math.isfinite(needed) else batch))
        pairs = _draw_pairs(rng, pool, k_views, pb.seen, T, B)
        trials += B
        if len(pairs):
            M = _forms(pb, pairs.ravel()).reshape(-1, 2, 9, 9).sum(axis=1)
            a, ok = _null_vectors(M)
            if ok.any() and consider(a[ok]):
                local_optimisation()
                n_in_pool = int(np.sum(best["err"][pool] < thr))
                needed = _trials_needed(n_in_pool, len(pool), confidence)
        batch = min(2 * batch, 256)
        if progress is not None:
            progress({"trials": trials, "trials_needed": needed, "best_inliers": best["n_in"],
                      "best_cost": best["cost"]})

    if best["a"] is None or best["n_in"] < MIN_CONSENSUS:
        raise DegenerateError(
            f"no consensus: after {trials} hypotheses the best one agrees with only {best['n_in']} "
            f"point(s) within {thr:g} px (at least {MIN_CONSENSUS} needed). The tracks are mostly "
            "wrong, the threshold is too small for the pixel noise (try 3-4x the noise), or the "
            "motion was not a pure translation."
        )

    # final model: the paper's TLS on the inliers, reclassified until the inliers settle
    if len(subset) == n_points:
        inliers = best["err"] < thr
    else:
        inliers = point_errors(_to_pixels(pb, best["a"])[0], uv, T)[0] < thr
    refits = 0
    for _ in range(4):
        masked = np.where(inliers[None, :, None], uv, np.nan)
        try:
            lin = estimate_linear(masked, T)
        except MirroredError:
            raise
        except DegenerateError as exc:
            raise DegenerateError(f"the {int(inliers.sum())} inliers found do not determine the camera: {exc}") from exc
        refits += 1
        err, res = point_errors(lin.A, uv, T)
        new = err < thr
        if np.array_equal(new, inliers) or new.sum() < MIN_CONSENSUS:
            break
        inliers = new
    final_err = np.where(np.isnan(err), np.nan, err)
    cost = float(_msac_cost(final_err[None], thr)[0])
    return RobustEstimate(
        linear=lin,
        inliers=lin.used.copy(),
        error_px=final_err,
        residuals_px=res,
        trials=int(trials),
        inlier_ratio=float(lin.used.sum() / n_points),
        threshold_px=thr,
        cost=cost,
        info={"trials_needed": float(needed), "lo_steps": lo_steps, "refits": refits,
              "n_candidates": int(len(pool)), "n_scored": int(len(subset)), "time_s": time.perf_counter() - t0},
    )
