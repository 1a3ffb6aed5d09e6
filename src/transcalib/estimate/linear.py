"""The paper's linear estimator: total least squares on the stacked system ``C b = 0``.

For point ``j`` with reference view ``r`` (its first visible view) and every other view
``i`` where it is seen, subtracting eq. 2 of view ``i`` from view ``r`` eliminates
``X_j`` (paper eq. 4)::

    lam_rj u_rj - lam_ij u_ij - A (T_i - T_r) = 0            (3 equations)

with ``u = [u, v, 1]``. The unknowns are ``b = (all lam, vec(A))``; ``b`` is the right
singular vector of ``C`` for its smallest singular value (paper §2.2), computed after
Hartley normalisation (:mod:`.normalisation`) of the pixels and translations.

Two ways to compute it, equal to rounding error:

``method="dense"``
    Builds ``C`` (``3 sum(k_j - 1)`` rows, ``sum(k_j) + 9`` columns) and takes its SVD:
    O(n^3) time, O(n^2) memory; the reference.
``method="fast"`` (default)
    The arrowhead structure of ``C^T C`` (:mod:`.arrowhead`): O(n) time, chunked passes
    whose temporaries are O(chunk).

The depth weighting (:func:`fit_linear`) solves twice with different row weights; the
second solve starts Newton from the first one's root, and the first one's depths are
only reduced to one depth per point.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np

from ..geometry.rotation import rq_decompose
from ..geometry.triangulate import triangulate
from ..types import DegenerateError, InputError, LinearEstimate
from ..validate import as_uv_T, check_translations_span
from .arrowhead import Arrowhead, MedianSign, Points, chunks, column_median, signed_medians
from .normalisation import Normalisation, hartley
from .schur import one_blas_thread

__all__ = ["estimate_linear", "fit_linear", "reference_motion"]

#: Largest problem the dense reference accepts (its memory grows as n^2).
DENSE_MAX_POINTS = 3000


# --------------------------------------------------------------------------------------
# Dense reference
# --------------------------------------------------------------------------------------


def _tls_dense(uv: np.ndarray, used: np.ndarray, norm: Normalisation, weights=None):
    """The paper's formulation: build ``C`` and take its SVD (reference, small n); with
    ``weights`` ``s_j`` point j's rows are scaled by ``s_j`` and its depths by ``1 / s_j``
    (the unknowns are ``s_j lam_ij``).

    Returns ``(a (9,), depths (V, n_points), mu = sigma_min^2, eigenvalues of S(mu) (9,))``.
    """
    x = uv[:, used]
    seen = np.isfinite(x[..., 0])  # (V, n)
    U = np.concatenate([x, np.ones(x.shape[:2] + (1,))], axis=2) @ norm.H.T  # normalised
    V, n = seen.shape
    col = np.full((V, n), -1)
    col.T[seen.T] = np.arange(seen.sum())  # column of lam_vj, point-major
    n_lam = int(seen.sum())
    ref = np.argmax(seen, axis=0)
    pairs = np.argwhere((seen & (np.arange(V)[:, None] != ref[None, :])).T)  # (j, v)
    w = np.ones(n) if weights is None else weights[used]
    C = np.zeros((3 * len(pairs), n_lam + 9))
    for p, (j, v) in enumerate(pairs):  # reference code: clarity over speed
        r = ref[j]
        rows = slice(3 * p, 3 * p + 3)
        C[rows, col[r, j]] = U[r, j]
        C[rows, col[v, j]] = -U[v, j]
        C[rows, n_lam:] = -np.kron(np.eye(3), norm.T[v] - norm.T[r]) * w[j]
    _, s, Vt = np.linalg.svd(C, full_matrices=False)
    b = Vt[-1]
    depths = np.full(uv.shape[:2], np.nan)
    depths[:, used] = np.where(seen, b[col] / w[None, :], np.nan)
    # S(mu): the Schur complement of C^T C - mu I over the depths
    mu = s[-1] ** 2
    M = C.T @ C - mu * np.eye(C.shape[1])
    S = M[n_lam:, n_lam:] - M[n_lam:, :n_lam] @ np.linalg.solve(M[:n_lam, :n_lam], M[:n_lam, n_lam:])
    return b[n_lam:], depths, mu, np.linalg.eigvalsh(S)


# --------------------------------------------------------------------------------------
# One solve: normalised TLS, then A in pixels with its depths
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Solution:
    """A TLS solution in pixel units: ``||A[2]|| = 1`` and the median depth positive."""

    A: np.ndarray  # (3, 3)
    depth: np.ndarray  # (V, n_points) NaN where unseen or unused; or (n_points,) per point
    singular_values: np.ndarray  # (3,)
    mu: float  # sigma_min^2 of the normalised system: where the next solve may start


class _DepthSink:
    """Collects a depth pass into ``depth (V, n)`` (camera z: ``lam`` times ``scale``, the
    unit factor of the pixel ``A``) and the sign of their median."""

    def __init__(self, shape: tuple[int, int], scale: float):
        self.depth, self.scale, self.sign = np.full(shape, np.nan), scale, MedianSign()

    def __call__(self, c, head, tail):
        r = c.ref
        head *= self.scale
        tail *= self.scale
        self.depth[r, c.points] = head
        self.depth[:r, c.points] = tail[:r]
        self.depth[r + 1:, c.points] = tail[r:]
        self.sign.add(head)
        self.sign.add(tail)

    def result(self) -> np.ndarray:
        return np.negative(self.depth, out=self.depth) if self.sign.negative else self.depth


class _PointDepthSink:
    """Reduces a depth pass to each point's median positive depth (n,), for both signs of
    the solution (the sign is known at the end of the pass), instead of every depth."""

    def __init__(self, shape: tuple[int, int], scale: float):
        self.pos, self.neg = np.full(shape[1], np.nan), np.full(shape[1], np.nan)
        self.scale, self.sign = scale, MedianSign()

    def __call__(self, c, head, tail):
        lam = np.concatenate([head[None], tail]) * self.scale
        self.sign.add(lam)
        self.pos[c.points], self.neg[c.points] = signed_medians(lam)

    def result(self) -> np.ndarray:
        return self.neg if self.sign.negative else self.pos


def _solve(uv: np.ndarray, used: np.ndarray, norm: Normalisation, weights=None, points: Points | None = None,
           mu_start: float = 0.0, per_point: bool = False) -> _Solution:
    """The (row-weighted) TLS of the normalised system, O(n) through ``points`` or dense
    without; ``A`` back in pixel and translation units and the sign that makes the median
    depth positive. ``per_point``: ``depth`` is each point's median positive depth (n,)."""
    Sink = _PointDepthSink if per_point else _DepthSink
    if points is None:
        a, lam, mu, w = _tls_dense(uv, used, norm, weights)
        A_n = a.reshape(3, 3)
        sink = Sink(lam.shape, _pixel_scale(A_n, norm))
        sink(_Whole(), lam[0], lam[1:])
    else:
        mu, A_n, w, sink = Arrowhead(points, norm, weights).solve(
            lambda A_n: Sink(uv.shape[:2], _pixel_scale(A_n, norm)), mu_start)
    _check_null_space(mu, w)
    # reduced singular values sqrt(mu + eig_k(S(mu))): sigma_1, then the best residuals
    # of the second and third alternative A
    sv = np.sqrt(np.maximum(mu + np.concatenate([[0.0], w[1:3]]), 0.0))
    c = -sink.scale if sink.sign.negative else sink.scale
    # undo normalisation: lam' H u = A' (X - T) / t_scale  =>  A ∝ H^-1 A' / t_scale
    return _Solution(A=np.linalg.solve(norm.H, A_n) / norm.t_scale * c, depth=sink.result(), singular_values=sv,
                     mu=mu)


def _pixel_scale(A_n: np.ndarray, norm: Normalisation) -> float:
    """``1 / ||A[2]||`` of the pixel ``A = H^-1 A' / t_scale``: the depths' unit factor."""
    return 1.0 / np.linalg.norm(np.linalg.solve(norm.H, A_n)[2] / norm.t_scale)


class _Whole:
    """The dense reference's depths as one chunk for the sinks (view 0 as the head)."""

    ref, points = 0, slice(None)


def _check_null_space(mu: float, w: np.ndarray) -> None:
    """Raise DegenerateError if ``S(mu)`` has a (numerically) two-dimensional null space."""
    if mu + w[1] <= 1e-12 * w[-1]:
        raise DegenerateError(
            "the data do not determine the camera: the linear system has a (numerically) "
            f"two-dimensional null space (sigma_2 / sigma_max = {np.sqrt(max(mu + w[1], 0) / w[-1]):.1e}). "
            "Track more points, over more views, spread over the image and over depth."
        )


# --------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------


def solve_tls(uv: np.ndarray, T: np.ndarray, used: np.ndarray | None = None, method: str = "fast", weights=None):
    """Total-least-squares ``A`` and depths from validated data (no further checks).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen.
    T : (n_views, 3) float
        Translations spanning 3-D.
    used : (n_points,) bool, optional
        Points to use, each seen in at least 2 views (default: all).
    method : {"fast", "dense"}
    weights : (n_points,) float, optional
        Row weights ``s_j`` (default ones: the paper's TLS). Scaling point j's equations
        by ``s_j`` and its depths by ``1 / s_j`` leaves the exact solution unchanged and
        equalises the points' noise when ``s_j ~ 1 / depth_j`` (see :func:`fit_linear`).

    Returns
    -------
    A : (3, 3) float
        ``K R`` in pixel and translation units, ``||A[2]|| = 1``, depths positive.
    depth : (n_views, n_points) float
        ``lam_ij`` (camera z), NaN where unseen or not used.
    singular_values : (3,) float
        ``sigma_1`` the smallest singular value of the normalised ``C``, then the
        reduced values ``sqrt(sigma_1^2 + eig_k(S))``, k = 2, 3, of the Schur complement
        ``S`` over the depths: the residual of the best solution whose ``A`` is the k-th
        alternative. ``sigma_1 / sigma_2`` near 1 means ``A`` is not determined.
    """
    used = np.ones(uv.shape[1], bool) if used is None else used
    points = None
    if method == "fast":
        ref = np.empty(uv.shape[1], np.intp)
        for c in chunks(uv.shape[1]):
            ref[c] = np.argmax(np.isfinite(uv[:, c, 0]), axis=0)
        points = Points(uv, used, ref)
    with one_blas_thread() if method == "fast" else contextlib.nullcontext():
        sol = _solve(uv, used, hartley(uv, T, used), weights, points)
    return sol.A, sol.depth, sol.singular_values


def estimate_linear(uv, T, *, method: str = "fast", weighting: str = "depth") -> LinearEstimate:
    """Calibrate linearly from tracked points and known translations (paper §2).

    Parameters
    ----------
    uv : array_like (n_views, n_points, 2)
        Pixel coordinates (OpenCV convention: centre of the top-left pixel is (0, 0)),
        NaN where a point is not seen. Points seen in fewer than 2 views are ignored.
    T : array_like (n_views, 3)
        Robot translations of the views, in the robot frame (any length unit; every
        output length is in it). Need ``n_views >= 4`` spanning 3-D.
    method : {"fast", "dense"}
        ``"fast"``: exact O(n) solution through the block structure (default).
        ``"dense"``: SVD of the full system, O(n^3); for reference and tests
        (at most ``DENSE_MAX_POINTS`` points).
    weighting : {"depth", "none"}
        ``"depth"`` (default): rows weighted by 1 / depth so that far, low-parallax tracks
        do not dominate (:func:`fit_linear`); ``"none"``: the paper's TLS as published.
        Noise-free data give the same exact answer.

    Returns
    -------
    LinearEstimate
        ``K``, ``R``, ``A``, ``X`` (triangulated from all views), ``depth``,
        ``singular_values``, ``n_used_points``, ``used``, ``static`` (tracks left out
        because they do not move at all).

    Raises
    ------
    InputError
        Malformed input (shapes, non-finite translations, fewer than 4 views, ...).
    DegenerateError
        Translations not spanning 3-D, fewer than 2 usable points, degenerate depths.
    MirroredError
        ``det(K R) < 0``: a left-handed robot frame, swapped axes or flipped images.
    """
    if method not in ("fast", "dense"):
        raise InputError(f"method must be 'fast' or 'dense', got {method!r}")
    if weighting not in ("depth", "none"):
        raise InputError(f"weighting must be 'depth' or 'none', got {weighting!r}")
    uv, T = as_uv_T(uv, T)
    return fit_linear(uv, T, method, weighting)


def fit_linear(uv: np.ndarray, T: np.ndarray, method: str = "fast", weighting: str = "depth") -> LinearEstimate:
    """:func:`estimate_linear` on validated arrays (the pipeline's entry: no input checks,
    only the checks that the data determine the camera).

    ``weighting="depth"``: in the paper's equations a point's residual is its depth times
    its pixel error, so far points (small image motion) weigh as much as their depth
    squared and can dominate the TLS. Their rows are scaled by ``s_j ~ 1 / depth_j``
    instead: first from the image motion per unit of translation (pixels / length, which
    is proportional to ``1 / depth``), then from the TLS depths of that first pass. Noise-
    free data give the same exact solution. Tracks that do not move at all (a static
    overlay, dust on the lens) determine nothing and are left out (``LinearEstimate.static``).
    ``weighting="none"`` is the paper's TLS as published.

    The O(n) passes sum small matrix products over chunks of points: they run with BLAS
    on one thread, whose other threads would only spin (the dense reference keeps them).
    """
    with one_blas_thread() if method == "fast" else contextlib.nullcontext():
        return _fit_linear(uv, T, method, weighting)


def _fit_linear(uv: np.ndarray, T: np.ndarray, method: str, weighting: str) -> LinearEstimate:
    """:func:`fit_linear`'s work: the tracks in one pass, checks, the normalisation, one or
    two solves (the first keeps one depth per point), the triangulation."""
    tracks = _tracks(uv, T)
    used, motion = tracks.used, tracks.motion
    n_used = int(np.count_nonzero(used))
    if n_used < 2:
        raise DegenerateError(
            f"only {n_used} point(s) are seen in at least 2 views and move between views "
            f"({int(tracks.static.sum())} do not move at all); the linear estimate needs at least 2 points tracked "
            "through the views (more is better)")
    active_views = tracks.view_counts > 0
    if active_views.sum() < 4:
        raise DegenerateError(f"only {int(active_views.sum())} views observe tracked points; at least 4 are needed")
    check_translations_span(T[active_views])
    if method == "dense" and n_used > DENSE_MAX_POINTS:
        raise InputError(
            f"method='dense' is a reference for small problems (at most {DENSE_MAX_POINTS} points, "
            f"got {n_used}); use method='fast', which gives the same result in O(n)")
    norm = hartley(uv, T, used)
    points = Points(uv, used, tracks.ref) if method == "fast" else None
    if weighting == "depth":
        first = _solve(uv, used, norm, _relative(motion, used), points, per_point=True)
        weights = _relative(1.0 / _point_depth(first.depth, motion), used)
        sol = _solve(uv, used, norm, weights, points, mu_start=first.mu)
        del first, weights  # before X is allocated: the peak is the result's
    else:
        sol = _solve(uv, used, norm, None, points)
    K, R = rq_decompose(sol.A)
    X = triangulate(sol.A, uv, T, sol.depth, passes=1)  # NaN for unused points (no finite depth)
    return LinearEstimate(
        K=K, R=R, A=K @ R, X=X, depth=sol.depth, singular_values=sol.singular_values,
        n_used_points=n_used, used=used, method=method, static=tracks.static)


@dataclass(frozen=True)
class _Tracks:
    """What one chunked pass over the tracks tells the estimator."""

    used: np.ndarray  # (n,) bool: seen in >= 2 views and moving
    static: np.ndarray  # (n,) bool: seen in >= 2 views, not moving at all (left out)
    ref: np.ndarray  # (n,) int: first seen view
    motion: np.ndarray  # (n,) pixels per unit translation (_motion_per_length), NaN if seen once
    view_counts: np.ndarray  # (V,) int: observations of used points per view


def _tracks(uv: np.ndarray, T: np.ndarray) -> _Tracks:
    """Reference views, image motion per unit translation and the static tracks, in one
    chunked pass. A track is static when its motion is at most 1e-9 x the median."""
    V, n = uv.shape[:2]
    used, motion = np.empty(n, bool), np.empty(n)
    ref = np.empty(n, np.min_scalar_type(V - 1))
    view_counts = np.zeros(V, np.int64)
    dT = np.linalg.norm(T[:, None] - T[None], axis=2)  # (V, V): |T_i - T_r|
    for c in chunks(n):
        x = uv[:, c]
        seen = np.isfinite(x[..., 0])
        d, ref[c] = _motion_from_reference(x, seen)
        motion[c] = _motion_per_length(d, seen, dT[:, ref[c]], ref[c])
        used[c] = seen.sum(axis=0) >= 2
        view_counts += np.count_nonzero(seen & used[c], axis=1)
    median = float(np.nanmedian(motion[used])) if used.any() else 0.0
    static = used & ~(motion > 1e-9 * max(median, 1e-300))
    if static.any():
        view_counts -= np.count_nonzero(np.isfinite(uv[:, static, 0]), axis=1)
        used &= ~static
    return _Tracks(used=used, static=static, ref=ref, motion=motion, view_counts=view_counts)


def reference_motion(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image motion of every observation from its track's first (reference) view:
    ``(|uv_i - uv_r| (n_views, n_points) pixels, NaN where unseen; r (n_points,))``."""
    d, ref = np.empty(uv.shape[:2]), np.empty(uv.shape[1], np.intp)
    for c in chunks(uv.shape[1]):
        x = uv[:, c]
        d[:, c], ref[c] = _motion_from_reference(x, np.isfinite(x[..., 0]))
    return d, ref


def _motion_from_reference(x: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``|x_i - x_r|`` (V, m) of pixels ``x (V, m, 2)`` from the first seen view ``r (m,)``."""
    ref = np.argmax(seen, axis=0)
    x_ref = x[ref, np.arange(x.shape[1])] if ref.any() else x[0]  # (m, 2)
    du, dv = x[..., 0] - x_ref[:, 0], x[..., 1] - x_ref[:, 1]
    return np.sqrt(du * du + dv * dv), ref


def _motion_per_length(d: np.ndarray, seen: np.ndarray, t: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Median over a track's other views of ``|uv_i - uv_r| / |T_i - T_r|`` (pixels per unit
    of translation): proportional to ``1 / depth`` (m,); NaN for tracks seen once. ``d``, ``t``
    (V, m) image motions and translation lengths from the reference views ``ref``."""
    ok = seen & (t > 0)
    ok[ref, np.arange(ref.size)] = False
    return column_median(np.divide(d, t, out=np.full_like(d, np.nan), where=ok))


def _point_depth(z: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Each point's median positive TLS depth ``z``; where it has none, the depth the image
    motion implies (scaled to the TLS depths' units)."""
    good = np.isfinite(z) & (z > 0) & (motion > 0)
    scale = np.median(z[good] * motion[good]) if good.any() else 1.0
    return np.where(good, z, scale / np.where(motion > 0, motion, np.nan))


def _relative(w: np.ndarray, used: np.ndarray, cap: float = 10.0) -> np.ndarray:
    """Row weights scaled to median 1 over the used points, capped at ``cap`` (one near
    point must not dominate either); 1 where undefined."""
    m = np.nanmedian(w[used])
    out = np.where(np.isfinite(w) & (w > 0), w / m, 1.0)
    return np.minimum(out, cap)
