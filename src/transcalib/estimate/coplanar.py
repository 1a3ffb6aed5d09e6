"""Linear start for coplanar translations (an XY table, a 2-axis gantry) with known parameters.

With the translations in a plane, ``T_i = T_0 + P c_i`` (``P = [p1 p2]`` an orthonormal
robot-axes basis of the plane, ``c_i = P^T (T_i - T_0)``), paper eq. 2 reads ::

    lam_ij u_ij = A (X_j - T_i) = Y'_j - A' c_i,   A' = A P = [a1 a2],  Y'_j = A (X_j - T_0)

so the data determine only ``A'`` (3 x 2, up to scale: 5 numbers). With ``B = kron(I_3, P)``
(9 x 6, ``vec(A) = B vec(A')`` for ``A = A' P^T``, row-major ``vec``) and the per-point forms
``M_j`` of :mod:`transcalib.estimate.minimal` (``lam`` and ``Y_j`` eliminated exactly),
``vec(A')`` minimises ``sum_j a'^T (B^T M_j B) a'`` over ``|a'| = 1``: the eigenvector of the
smallest eigenvalue of a 6 x 6 matrix (Hartley-normalised coordinates, undone after).

``a_k = s K R p_k`` with ``R p_1, R p_2`` orthonormal gives, with ``w = K^-T K^-1`` (as in
Zhang's planar calibration) ::

    a1^T w a2 = 0,        a1^T w a1 - a2^T w a2 = 0.

With a known principal point and zero skew, ``b_k = C^-1 a_k`` (``C`` the shift by
``(cx, cy)``) and ``w`` turns into ``diag(alpha, beta, 1)``, ``alpha = 1/fx^2``,
``beta = 1/fy^2``, so the equations are **linear** in ``(alpha, beta)`` ::

    alpha b1x b2x + beta b1y b2y = -b1z b2z
    alpha (b1x^2 - b2x^2) + beta (b1y^2 - b2y^2) = -(b1z^2 - b2z^2)

two equations for ``fx, fy`` (least squares with square pixels ``alpha = beta`` or with one
focal length known). Then ``r_k = K^-1 a_k`` (the nearest orthonormal pair, scale ``s``
dropped), ``r_3 = r_1 x r_2``, ``R = [r1 r2 r3] [p1 p2 p3]^T`` with ``p3 = p1 x p2``; the
sign of ``a'`` is the one that puts the points in front of the camera, and ``X`` is
triangulated from all views with ``A = K R`` (:func:`transcalib.geometry.triangulate`).
A fully known K skips the focal step.

Identifiability (checked with the Fisher information, ``covariance.crlb(scene, fix=...)``;
``tests/test_coplanar.py``): with zero skew, ``fx, fy, R`` and the points are determined
once ``cx, cy`` are known and singular (2 directions) with them free (so are ``cx, cy``
once ``fx, fy`` are known: start this estimator at the image centre and let the
refinement free them); with ``fx, fy`` free the system above is singular when the camera
is tilted about one of its image axes, and even ``f`` (square pixels) is lost when the
camera looks along the plane normal.
Coplanar data cannot reveal a mirrored robot frame (``r_3``'s sign is chosen for
``det R = +1``; a left-handed frame mirrors the points through the plane).

:func:`fit_coplanar_robust` runs the generic LO-RANSAC (:func:`transcalib.estimate.ransac.lo_ransac`)
on pairs of points (a point in ``k`` views gives ``2k - 3`` constraints on the 5 degrees of
freedom of ``A'``), scores ``A = A' P^T`` with :class:`transcalib.estimate.scoring.Scorer`
and refits ``A'`` on the inliers (local optimisation, judged by the unconstrained ``A'``:
imposing K and R first would reject good points when the geometry is weak), then ends
with :func:`fit_coplanar` on them.
"""

from __future__ import annotations

import time

import numpy as np

from ..errors import DegenerateError, InputError
from ..geometry.triangulate import triangulate
from ..types import LinearEstimate, RansacOptions, RansacStats
from ..validate import SPAN_RTOL, as_uv_T
from .degeneracy import explain_span, translation_basis, translation_rank
from .minimal import Problem, forms, normalise
from .noise import sigma_from_threshold, track_dof
from .ransac import lo_ransac
from .scoring import Scorer

__all__ = ["fit_coplanar", "fit_coplanar_robust"]


def _restriction(P2: np.ndarray) -> np.ndarray:
    """``B (9, 6) = kron(I_3, P2)``: ``vec(A' P2^T) = B vec(A')`` (row-major vec)."""
    return np.kron(np.eye(3), P2)


def solve_plane_affine(pb: Problem, idx: np.ndarray, P2: np.ndarray, batch: int | None = None):
    """``A'`` (normalised units) from the points ``idx``: null vectors of ``sum_j B^T M_j B``.

    Parameters
    ----------
    pb : Problem
        Hartley-normalised data (:func:`transcalib.estimate.minimal.normalise`).
    idx : (n,) int or (H, k) int
        Points (all summed), or ``H`` samples of ``k`` points each (batched).
    P2 : (3, 2) float
        Orthonormal basis of the translation plane.

    Returns
    -------
    a : (6,) or (H, 6) float
        Unit ``vec(A')`` (row-major 3 x 2), sign arbitrary.
    eig : (6,) or (H, 6) float
        Eigenvalues of the 6 x 6 form, ascending (``eig[0] = 0`` for exact data).
    """
    B = _restriction(P2)
    idx = np.asarray(idx)
    M = forms(pb, idx.ravel())  # (n, 9, 9)
    M = np.einsum("ka,nkl,lb->nab", B, M, B)
    M = M.reshape(idx.shape + (6, 6)).sum(axis=-3) if idx.ndim == 2 else np.nansum(M, axis=0)
    M = 0.5 * (M + np.swapaxes(M, -1, -2))
    w, v = np.linalg.eigh(M)
    return v[..., :, 0], w


def _pixel_affine(pb: Problem, a: np.ndarray) -> np.ndarray:
    """Normalised ``vec(A')`` (..., 6) -> pixel ``A'`` (..., 3, 2), unit Frobenius norm:
    ``A' ∝ H^-1 A'_n / t_scale`` (the translation scale only rescales)."""
    A = np.linalg.solve(pb.H, a.reshape(-1, 3, 2))
    return A / np.linalg.norm(A, axis=(1, 2))[:, None, None]


def _moving(uv: np.ndarray) -> np.ndarray:
    """(n_points,) bool: the point's pixels are not all identical (an exactly static track,
    e.g. an overlay, has parallel rays: no depth, a singular 3 x 3 block in the forms)."""
    with np.errstate(invalid="ignore"):
        spread = np.nanmax(uv, axis=0) - np.nanmin(uv, axis=0)  # (n, 2); NaN if never seen
    return np.nan_to_num(spread).max(axis=1) > 0


def _plane_to_full(a: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``A = A' P2^T`` (H, 3, 3) from ``vec(A')`` (H, 6): the hypothesis as
    :class:`Scorer` takes it (only ``A T_i`` matters, so ``A p3 = 0`` is harmless)."""
    return np.einsum("hak,bk->hab", a.reshape(-1, 3, 2), P[:, :2])


def intrinsics_from_plane(Ap: np.ndarray, fix, square_pixels: bool = False) -> np.ndarray:
    """``K`` from ``A' = s K [R p1, R p2]`` and the known parameters (module docstring).

    Parameters
    ----------
    Ap : (3, 2) float
        ``A'`` in pixels, any scale and sign.
    fix : mapping
        Must hold ``cx`` and ``cy`` (and may hold ``fx``, ``fy``, ``skew``); a fully
        known K (all of fx, fy, cx, cy) is returned as it is.
    square_pixels : bool
        ``fx = fy``.

    Returns
    -------
    K : (3, 3) float

    Raises
    ------
    DegenerateError
        The two equations do not determine the focal lengths (camera looking along the
        plane normal or tilted about an image axis) or give no positive solution.
    """
    cx, cy, skew = fix["cx"], fix["cy"], fix.get("skew", 0.0)
    if "fx" in fix and "fy" in fix:
        return np.array([[fix["fx"], skew, cx], [0.0, fix["fy"], cy], [0.0, 0.0, 1.0]])
    if skew != 0.0:
        raise InputError(f"the coplanar start solves the focal lengths for zero skew only (fix skew={skew}); "
                         "give fx and fy too, or leave the skew at 0")
    b = Ap / np.linalg.norm(Ap)
    b = b - np.outer([cx, cy, 0.0], b[2])  # C^-1 a_k
    G = np.array([[b[0, 0] * b[0, 1], b[1, 0] * b[1, 1]],
                  [b[0, 0] ** 2 - b[0, 1] ** 2, b[1, 0] ** 2 - b[1, 1] ** 2]])
    h = -np.array([b[2, 0] * b[2, 1], b[2, 0] ** 2 - b[2, 1] ** 2])
    known = {k: 1.0 / fix[nm] ** 2 for k, nm in enumerate(("fx", "fy")) if nm in fix}
    if known:  # one focal length known (it fixes the other one's square too if square_pixels)
        k_known = next(iter(known))
        h = h - G[:, k_known] * known[k_known]
        g = G[:, 1 - k_known]
        sol = np.full(2, known[k_known])
        if not square_pixels:
            sol[1 - k_known] = g @ h / max(g @ g, 1e-300)
        cond = np.linalg.norm(g) / max(np.abs(G).max(), np.abs(h).max(), 1e-300)
    elif square_pixels:
        g = G.sum(axis=1)
        sol = np.full(2, g @ h / max(g @ g, 1e-300))
        cond = np.linalg.norm(g) / max(np.abs(G).max(), np.abs(h).max(), 1e-300)
    else:
        sv = np.linalg.svd(np.column_stack([G, h]), compute_uv=False)
        cond = sv[1] / max(sv[0], 1e-300)
        sol = np.linalg.lstsq(G, h, rcond=None)[0] if cond > 1e-9 else np.full(2, np.nan)
    if not (cond > 1e-9 and np.all(sol > 0)):
        free = "f" if square_pixels else " and ".join(nm for nm in ("fx", "fy") if nm not in fix)
        raise DegenerateError(
            f"coplanar translations with a known principal point do not determine {free} here "
            f"(orthogonality equations {'degenerate' if cond <= 1e-9 else 'without a positive solution'}): the "
            "camera looks (nearly) along the normal of the translation plane"
            + ("" if square_pixels or known else " or is tilted about one of its image axes")
            + ". Assume square pixels (--square-pixels), fix a focal length, tilt the camera obliquely to the "
            "plane, or move the robot also out of the plane.")
    return np.array([[1.0 / np.sqrt(sol[0]), 0.0, cx], [0.0, 1.0 / np.sqrt(sol[1]), cy], [0.0, 0.0, 1.0]])


def _rotation(K: np.ndarray, Ap: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``R = [r1 r2 r1 x r2] P^T`` with ``[r1 r2]`` the orthonormal pair nearest to
    ``K^-1 A'`` (polar factor; the common scale drops out)."""
    Q = np.linalg.solve(K, Ap)
    U, _, Vt = np.linalg.svd(Q / np.linalg.norm(Q), full_matrices=False)
    r = U @ Vt  # (3, 2)
    Rc = np.column_stack([r, np.cross(r[:, 0], r[:, 1])])
    return Rc @ P.T


def _depths(R: np.ndarray, X: np.ndarray, T: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """Camera z of every observation ``(n_views, n_points)``, NaN where unseen."""
    z = (X[None] - T[:, None]) @ R[2]
    return np.where(seen, z, np.nan)


def _oriented(K, Ap, P, uv, T, seen):
    """``R``, ``X``, depths for the sign of ``A'`` that puts most points in front."""
    best = None
    for sign in (1.0, -1.0):
        R = _rotation(K, sign * Ap, P)
        X = triangulate(K @ R, uv, T)
        z = _depths(R, X, T, seen)
        front = np.nansum(z > 0)
        if best is None or front > best[0]:
            best = (front, R, X, z)
    return best[1:]


def fit_coplanar(uv: np.ndarray, T: np.ndarray, *, fix, square_pixels: bool = False,
                 used: np.ndarray | None = None, tol: float = SPAN_RTOL) -> LinearEstimate:
    """Linear calibration from coplanar translations and a known principal point or K.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen (validated by :func:`transcalib.validate.as_uv_T`).
    T : (n_views, 3) float
        Robot translations spanning a plane (rank 2; a small out-of-plane component, e.g.
        robot noise, is projected away).
    fix : mapping of str to float
        Known parameters; needs ``cx`` and ``cy`` (plus optionally ``fx`` and/or ``fy``;
        ``skew`` only together with both focal lengths). Other names (distortion) are
        ignored here: they matter to the refinement.
    square_pixels : bool
        ``fx = fy``.
    used : (n_points,) bool, optional
        Points to use (default: all seen in >= 2 views; exactly static tracks are always
        left out).
    tol : float
        Relative singular value of ``T_i - T_0`` below which the out-of-plane motion counts
        as zero (:func:`transcalib.estimate.degeneracy.translation_rank`); raise it (e.g.
        ``1e-3``) when measured translations jitter off the plane.

    Returns
    -------
    LinearEstimate
        ``method = "coplanar"``; ``A = K R`` (``|A[2]| = 1``); ``X`` triangulated from
        all views; ``depth`` the camera z of the observations; ``singular_values``
        ``sqrt(w_k / w_max)`` of the two smallest eigenvalues ``w_k`` of the normalised
        6 x 6 form (``[0]`` is the fit residual, ``[1]`` how well ``A'`` is determined).

    Raises
    ------
    InputError
        Malformed input, or no principal point in ``fix``.
    DegenerateError
        Translations not coplanar (rank 3: use the 3-D estimator; rank < 2), too few
        constraints (fewer than 5 from the points), or focal lengths not determined.
    """
    uv, T = as_uv_T(uv, T, min_views=3)
    fix = dict(fix or {})
    if not ("cx" in fix and "cy" in fix):
        raise InputError("fit_coplanar needs the principal point: fix={'cx': ..., 'cy': ...} (or the full K); "
                         f"got fix={fix}. With coplanar translations and a free principal point K is not "
                         "determined")
    rank = translation_rank(T, tol)
    if rank != 2:
        if rank < 2:
            explain_span(T, fix, square_pixels, tol=tol)  # raises, naming the missing directions
        s = translation_basis(T)[1]
        raise DegenerateError(f"the translations span 3-D (s3 / s1 = {s[2] / s[0]:.2g} > tol = {tol:g}): use the "
                              "paper's linear estimator (fit_linear), or raise tol if the out-of-plane motion is "
                              "only measurement jitter")
    seen = np.isfinite(uv[..., 0])
    n_seen = seen.sum(axis=0)
    usable = (n_seen >= 2) & _moving(uv)
    used = usable if used is None else (np.asarray(used, bool) & usable)
    n_constraints = int(np.sum(2 * n_seen[used] - 3))
    if n_constraints < 5:
        raise DegenerateError(f"the tracks give {n_constraints} constraints on A' = K R [p1 p2] (a point seen in k "
                              "views gives 2k - 3), at least 5 are needed: track more points")
    P = translation_basis(T)[0]
    pb = normalise(uv, T)
    a, w = solve_plane_affine(pb, np.flatnonzero(used), P[:, :2])
    if not w[1] > 1e-12 * max(w[-1], 1e-300):
        raise DegenerateError("the points do not determine A' = K R [p1 p2] (two-dimensional null space): track "
                              "more points, spread over the image and over depth")
    Ap = _pixel_affine(pb, a)[0]
    K = intrinsics_from_plane(Ap, fix, square_pixels)
    R, X, depth = _oriented(K, Ap, P, uv, T, seen)
    X[~used] = np.nan
    depth[:, ~used] = np.nan
    sv = np.sqrt(np.maximum(w[:2], 0.0) / max(w[-1], 1e-300))
    return LinearEstimate(K=K, R=R, A=K @ R, X=X, depth=depth, singular_values=sv,
                          n_used_points=int(used.sum()), used=used, method="coplanar")


class _PlaneProblem:
    """Coplanar translations as a :class:`transcalib.estimate.ransac.RansacProblem`: pairs
    of moving points seen in 3+ views as samples, normalised ``vec(A')`` (6,) as
    hypotheses, the track errors of ``A = A' P2^T`` (px^2) as errors."""

    sample_size = 2

    def __init__(self, uv: np.ndarray, T: np.ndarray, P: np.ndarray):
        k = np.isfinite(uv[..., 0]).sum(axis=0)
        self.P = P
        self.pb = normalise(uv, T)
        self.scorer = Scorer(self.pb)
        self.dof = track_dof(k)
        self.scorable = self.scorer.ok
        # a pair gives 2 (2k - 3) >= 6 > 5 constraints for k >= 3
        self.samplable = (k >= 3) & _moving(uv) & self.scorer.ok
        self.pool = np.flatnonzero(self.samplable)

    def sample(self, rng, size: int) -> np.ndarray:
        first = rng.integers(0, len(self.pool), size)
        second = (first + rng.integers(1, len(self.pool), size)) % len(self.pool)
        return self.pool[np.column_stack([first, second])]

    def _solve(self, idx):
        a, w = solve_plane_affine(self.pb, idx, self.P[:, :2])
        # the null space must be one-dimensional (as in fit_coplanar)
        return a, np.isfinite(w).all(axis=-1) & (w[..., 1] > 1e-12 * np.maximum(w[..., -1], 1e-300))

    def solve(self, pairs: np.ndarray):
        return self._solve(pairs)

    def errors(self, a: np.ndarray) -> np.ndarray:
        return self.scorer.sse(_plane_to_full(a, self.P))

    def refit(self, inliers: np.ndarray):
        a, ok = self._solve(np.flatnonzero(inliers))
        return a[None], np.atleast_1d(ok)


def fit_coplanar_robust(uv: np.ndarray, T: np.ndarray, *, fix, square_pixels: bool = False,
                        options: RansacOptions | None = None, rng=None, tol: float = SPAN_RTOL, progress=None):
    """LO-RANSAC over pairs of points for coplanar translations, then :func:`fit_coplanar`
    on the inliers, with the noise-adaptive inlier rule of :mod:`.noise`.

    Parameters
    ----------
    uv, T, fix, square_pixels, tol
        As :func:`fit_coplanar`.
    options : RansacOptions, optional
        As for :func:`transcalib.estimate.robust.estimate_robust`: ``threshold_px`` None
        (the pixel noise is estimated from the data: least median of squares, then the
        truncated chi-square estimator) or a number that fixes it; ``false_rejection``,
        the probability that the rule rejects a good track; ``confidence`` and
        ``max_trials``, the adaptive number of pairs drawn and its bound.
    rng : seed or Generator
    progress : callable, optional
        Called after every batch of pairs with a :class:`~transcalib.types.ProgressEvent`
        (stage ``"robust (coplanar)"``, ``done`` the pairs drawn so far).

    Returns
    -------
    estimate : LinearEstimate
        :func:`fit_coplanar` on the inliers (``used``).
    inliers : (n_points,) bool
        Tracks that pass the chi-square rule under the best ``A' P^T`` of the loop (the
        unconstrained plane affine, refitted on its inliers, before K and R are imposed).
    stats : RansacStats
        Pairs drawn and needed, inliers, the pixel noise of the rule (estimated, or the
        one ``threshold_px`` implies) and the time.

    Raises
    ------
    DegenerateError
        Fewer than 2 points seen in 3+ views, or no pair determines ``A'``; and as
        :func:`fit_coplanar`.
    """
    uv, T = as_uv_T(uv, T, min_views=3)
    opts = options or RansacOptions()
    problem = _PlaneProblem(uv, T, translation_basis(T)[0])
    if len(problem.pool) < 2:
        raise DegenerateError("fewer than 2 points are seen in 3 or more views: a pair cannot determine A'")
    fixed = None if opts.threshold_px is None else sigma_from_threshold(opts.threshold_px, opts.false_rejection)
    t0 = time.perf_counter()
    best = lo_ransac(problem, confidence=opts.confidence, max_trials=opts.max_trials,
                     false_rejection=opts.false_rejection, sigma=fixed, rng=rng, progress=progress,
                     stage="robust (coplanar)")
    if best.hypothesis is None:
        raise DegenerateError(f"no pair of points among {best.trials} drawn determines A' = K R [p1 p2]: track more "
                              "points, spread over the image and over depth")
    est = fit_coplanar(uv, T, fix=fix, square_pixels=square_pixels, used=best.inliers, tol=tol)
    stats = RansacStats(trials=best.trials, trials_needed=float(best.trials_needed), n_inliers=int(best.inliers.sum()),
                        sigma_px=float(best.sigma), rule_sigma_px=float(best.sigma), time_s=time.perf_counter() - t0)
    return est, best.inliers, stats
