"""The paper's linear estimator: total least squares on the stacked system ``C b = 0``.

For point ``j`` with reference view ``r`` (its first visible view) and every other view
``i`` where it is seen, subtracting eq. 2 of view ``i`` from view ``r`` eliminates
``X_j`` (paper eq. 4)::

    lam_rj u_rj - lam_ij u_ij - A (T_i - T_r) = 0            (3 equations)

with ``u = [u, v, 1]``. The unknowns are ``b = (all lam, vec(A))``; ``b`` is the right
singular vector of ``C`` for its smallest singular value (paper §2.2), computed after
Hartley normalisation of the pixels and translations.

Two ways to compute it, equal to rounding error:

``method="dense"``
    Builds ``C`` (``3 sum(k_j - 1)`` rows, ``sum(k_j) + 9`` columns) and takes its SVD:
    O(n^3) time, O(n^2) memory; the reference.
``method="fast"`` (default)
    ``M = C^T C = [[D, B], [B^T, E]]`` is an arrowhead matrix: ``D`` is block diagonal
    with one small arrowhead block ``D_j`` per point (its depths), ``E`` (9 x 9) belongs
    to ``vec(A)``. Eliminating the depths, the smallest eigenvalue ``mu`` of ``M`` is the
    root in ``[0, min eig D)`` of ::

        f(mu) = lambda_min(S(mu)),   S(mu) = E - mu I - sum_j B_j^T (D_j - mu I)^-1 B_j

    (``f`` is concave and decreasing there), ``vec(A)`` is the null vector of
    ``S(mu)`` and the depths follow as ``lam_j = -(D_j - mu I)^-1 B_j vec(A)``. Each
    evaluation of ``S`` costs O(n) with closed-form arrowhead inverses; Newton's method
    needs a handful.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.rotation import rq_decompose
from ..geometry.triangulate import triangulate
from ..types import DegenerateError, InputError, LinearEstimate
from ..validate import as_uv_T, check_translations_span

__all__ = ["estimate_linear", "fit_linear", "solve_tls", "reference_motion", "DENSE_MAX_POINTS"]

#: Largest problem the dense reference accepts (its memory grows as n^2).
DENSE_MAX_POINTS = 3000


#: Points per chunk in the O(n) passes: every temporary stays small (a few MB), so that
#: memory is reused rather than freshly mapped, which costs more than the arithmetic.
_CHUNK = 16384


@dataclass(frozen=True)
class _Normalisation:
    """Hartley normalisation: ``u' = H u`` and ``T' = (T - T_mean) / t_scale``."""

    H: np.ndarray  # (3, 3) pixel similarity
    T: np.ndarray  # (V, 3) normalised translations
    t_scale: float


def _chunks(n: int):
    for lo in range(0, n, _CHUNK):
        yield slice(lo, min(lo + _CHUNK, n))


def _normalisation(uv: np.ndarray, used: np.ndarray, T: np.ndarray) -> _Normalisation:
    """Pixels of the used points to zero mean and mean distance sqrt(2) (two chunked
    passes); translations centred and scaled to unit mean norm."""
    total, count = np.zeros(2), 0
    for c in _chunks(uv.shape[1]):
        x = uv[:, c]
        ok = np.isfinite(x[..., 0]) & used[c]
        total += [np.sum(x[..., 0], where=ok), np.sum(x[..., 1], where=ok)]
        count += np.count_nonzero(ok)
    centre = total / count
    spread = 0.0
    for c in _chunks(uv.shape[1]):
        x = uv[:, c]
        ok = np.isfinite(x[..., 0]) & used[c]
        spread += np.sum(np.hypot(x[..., 0] - centre[0], x[..., 1] - centre[1]), where=ok)
    spread /= count
    scale = np.sqrt(2.0) / spread if spread > 0 else 1.0
    H = np.array([[scale, 0.0, -scale * centre[0]], [0.0, scale, -scale * centre[1]], [0.0, 0.0, 1.0]])
    T_mean = T.mean(axis=0)
    t_scale = float(np.linalg.norm(T - T_mean, axis=1).mean())
    return _Normalisation(H=H, T=(T - T_mean) / t_scale, t_scale=t_scale)


@dataclass(frozen=True)
class _Chunk:
    """Used points of one chunk that share their reference view, component-major, with
    a slot for every view (zero where the point is not seen).

    A point's first seen view is its reference ``r`` (the head), its other seen views
    the tail. With ``z_i`` the normalised homogeneous pixels in view ``i`` and ``t_k =
    T_k - T_r`` (the same for every point of the chunk), the blocks of ``M = C^T C`` are::

        D[r, r] = (V_j - 1) |z_r|^2,   D[k, k] = |z_k|^2,   D[r, k] = -z_r . z_k
        B[i] = kron(z_i, tt_i)   with tt_r = -sum_k t_k (per point), tt_k = t_k

    Which views see a point only masks the tail: every visibility pattern is handled by
    the same array operations.
    """

    points: np.ndarray  # (m,) point index
    ref: int  # the reference view r
    tail: np.ndarray  # (V, m) bool: seen, not the reference
    Z: np.ndarray  # (V, 3, m), zero where unseen
    t: np.ndarray  # (V, 3): T_k - T_r, zero in row r
    tt_head: np.ndarray  # (3, m): -sum_k t_k over the point's tail
    D00: np.ndarray  # (m,)
    D0k: np.ndarray  # (V, m), zero off the tail
    Dkk: np.ndarray  # (V, m), zero off the tail
    s: np.ndarray  # (m,) translation scale of each point (its row weight, see fit_linear)


def _kron_sum(P: np.ndarray, t: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``sum_k kron(P_k, t_k u_k^T)`` (9, 9) for ``P (V, 3, 3)``, ``t, u (V, 3)``."""
    return np.einsum("kac,kb,kd->abcd", P, t, u).reshape(9, 9)


class _Arrowhead:
    """``M = C^T C = [[D, B], [B^T, E]]`` of the normalised system, streamed in chunks.

    ``D`` is block diagonal, one small arrowhead block ``D_j`` per point; ``B_j``'s rows
    are Kronecker products ``kron(z_i, tt_i)`` whose tail ``tt`` depends only on the
    point's reference view. Sums over points of ``B_j^T W_j B_j`` are therefore
    ``sum_k kron(sum_j ... z z^T, t_k t_k^T)`` plus a 9-vector per point: per-point work
    on 3-vectors, sums as matrix products, nothing of size O(n) kept between passes.

    ``(D_j - mu I)^-1`` is applied in closed form: with ``delta_k = D_kk - mu``,
    ``q_k = D_0k / delta_k`` and the head's Schur scalar ``s = D_00 - mu - sum_k D_0k q_k``::

        y_0 = (b_0 - sum_k q_k b_k) / s,    y_k = (b_k - D_0k y_0) / delta_k
    """

    def __init__(self, uv: np.ndarray, used: np.ndarray, norm: _Normalisation, weights: np.ndarray | None = None):
        self.uv, self.norm = uv, norm
        self.weights = np.ones(uv.shape[1]) if weights is None else weights
        # the used points by reference view (their first seen view), in index order
        used = np.flatnonzero(used)
        ref = np.empty(used.size, dtype=np.intp)
        for c in _chunks(used.size):
            ref[c] = np.argmax(np.isfinite(uv[:, used[c], 0]), axis=0)
        groups = np.split(used[np.argsort(ref, kind="stable")], np.cumsum(np.bincount(ref, minlength=uv.shape[0]))[:-1])
        self.by_ref = [(r, members) for r, members in enumerate(groups) if members.size]
        self.E = None  # kron(I_3, sum t t^T), accumulated by the first taylor() pass

    def chunks(self):
        """Yield the used points as :class:`_Chunk` s (by reference view, then chunk)."""
        for r, members in self.by_ref:
            for c in _chunks(members.size):
                points = members[c]
                if points[-1] - points[0] + 1 == points.size:  # contiguous: a view of uv, no copy
                    x = self.uv[:, points[0]:points[-1] + 1]
                else:
                    x = self.uv[:, points]
                yield self._chunk(points, r, x, np.isfinite(x[..., 0]))

    def _chunk(self, points, r: int, x: np.ndarray, seen: np.ndarray) -> _Chunk:
        """The :class:`_Chunk` of ``points``, all with reference view ``r``; ``x`` their
        pixels ``(V, m, 2)``, ``seen`` ``(V, m)``."""
        H = self.norm.H
        tail = seen.copy()
        tail[r] = False
        Z = np.empty((seen.shape[0], 3, points.size))  # normalised homogeneous pixels
        np.multiply(x[..., 0], H[0, 0], out=Z[:, 0])
        np.multiply(x[..., 1], H[1, 1], out=Z[:, 1])
        Z[:, 0] += H[0, 2]
        Z[:, 1] += H[1, 2]
        Z[:, 2] = 1.0
        if not seen.all():  # unseen pixels are NaN: zero there
            np.copyto(Z, 0.0, where=~seen[:, None])
        t = self.norm.T - self.norm.T[r]
        return _Chunk(points=points, ref=r, tail=tail, Z=Z, t=t, tt_head=-(t.T @ tail), s=self.weights[points],
                      D00=(seen.sum(axis=0) - 1) * np.einsum("am,am->m", Z[r], Z[r]),
                      D0k=-np.einsum("iam,am->im", Z, Z[r]) * tail,
                      Dkk=np.einsum("iam,iam->im", Z, Z) * tail)

    @staticmethod
    def _inverse(c: _Chunk, mu: float):
        """Closed-form pieces of ``(D_j - mu I)^-1`` as ``(V, m)`` arrays, zero off the
        tail: ``(q, 1/s, 1/delta)``, or None if some ``D_j - mu I`` is not positive
        definite (``mu`` past a pole)."""
        delta = c.Dkk - mu
        if np.any((delta <= 0) & c.tail):
            return None
        delta[~c.tail] = 1.0
        inv_delta = c.tail / delta
        q = c.D0k * inv_delta
        s = c.D00 - mu - np.einsum("km,km->m", c.D0k, q)
        if np.any(s <= 0):
            return None
        return q, 1.0 / s, inv_delta

    def below_poles(self, mu: float) -> bool:
        """Is every ``D_j - mu I`` positive definite (``mu`` below the smallest pole)?"""
        return all(self._inverse(c, mu) is not None for c in self.chunks())

    def taylor(self, mu: float) -> tuple[np.ndarray, np.ndarray] | None:
        """First two Taylor coefficients of ``F(nu) = sum_j B_j^T (D_j - nu I)^-1 B_j`` at
        ``mu``: ``G_1 = sum B^T W B`` and ``G_2 = sum B^T W^2 B``, ``W_j = (D_j - mu I)^-1``.

        One O(n) pass; None if ``mu`` is past a pole. ``W = Delta + q^ q^T / s`` with
        ``Delta = diag(0, 1/delta_k)`` and ``q^ = (1, -q_k)``; with the head row
        ``w = q^T B`` (9 per point)::

            G_1 = sum_k B_k B_k^T / delta_k + w w^T / s
            G_2 = sum_k B_k B_k^T / delta_k^2 - sum_k q_k / (s delta_k) (B_k w^T + w B_k^T)
                  + (1 + |q|^2) w w^T / s^2

        and ``sum_j c_j B_jk B_jk^T = kron(sum_j c_j z_jk z_jk^T, t_k t_k^T)``.
        """
        G1, G2, E3 = np.zeros((9, 9)), np.zeros((9, 9)), np.zeros((3, 3))
        for c in self.chunks():
            parts = self._inverse(c, mu)
            if parts is None:
                return None
            q, inv_s, inv_delta = parts
            s2 = c.s * c.s
            E3 += c.t.T @ (c.t * (c.tail @ s2)[:, None])
            # w_j = s_j (kron(z_r, tt_head) - sum_k q_k kron(z_k, t_k)), as columns (9, m)
            w = np.einsum("am,bm->abm", c.Z[c.ref], c.tt_head) - np.einsum("kam,kb->abm", c.Z * q[:, None], c.t)
            w = w.reshape(9, -1) * c.s
            G1 += (w * inv_s) @ w.T
            G2 += (w * ((1.0 + np.einsum("km,km->m", q, q)) * inv_s**2)) @ w.T
            d1 = inv_delta * s2
            Zd = c.Z * d1[:, None]
            G1 += _kron_sum(np.matmul(Zd, c.Z.transpose(0, 2, 1)), c.t, c.t)
            G2 += _kron_sum(np.matmul(Zd * inv_delta[:, None], c.Z.transpose(0, 2, 1)), c.t, c.t)
            X = np.matmul(c.Z * (q * inv_delta * (inv_s * c.s))[:, None], w.T)  # (V, 3, 9)
            cross = np.einsum("kaq,kb->abq", X, c.t).reshape(9, 9)
            G2 -= cross + cross.T
        self.E = np.kron(np.eye(3), E3)
        return G1, G2

    def depths(self, mu: float, a: np.ndarray) -> np.ndarray:
        """Depths ``lam_j = -(D_j - mu I)^-1 B_j a / s_j`` (V, n_points), NaN where unseen or
        unused."""
        A = a.reshape(3, 3)
        y = np.full(self.uv.shape[:2], np.nan)
        for c in self.chunks():
            b = np.einsum("kam,ka->km", c.Z, c.t @ A.T) * c.s  # B_j a = s_j z_i^T A tt_i
            b_head = np.einsum("am,am->m", c.Z[c.ref], A @ c.tt_head) * c.s
            q, inv_s, inv_delta = self._inverse(c, mu)
            y0 = (b_head - np.einsum("km,km->m", q, b)) * inv_s
            lam = (c.D0k * y0 - b) * inv_delta  # the unknowns are s_j lam_ij: divide the weight out
            lam[c.ref] = -y0
            lam[~c.tail & (np.arange(len(lam)) != c.ref)[:, None]] = np.nan
            y[:, c.points] = lam / c.s
        return y


class _TaylorModel:
    """``S(nu) = E - nu I - G_1 - (nu - mu0) G_2`` near ``mu0``; exact at ``mu0``."""

    def __init__(self, E: np.ndarray, mu0: float, G: tuple[np.ndarray, np.ndarray]):
        self.E, self.mu0, (self.G1, self.G2) = E, mu0, G

    def S(self, nu: float) -> np.ndarray:
        return self.E - nu * np.eye(9) - self.G1 - (nu - self.mu0) * self.G2

    def truncation(self, nu: float) -> float:
        """Estimated norm of the neglected terms, ``(nu - mu0)^2 |G_3|`` with
        ``|G_3| ~ |G_2|^2 / |G_1|``."""
        g1, g2 = np.linalg.norm(self.G1, 2), np.linalg.norm(self.G2, 2)
        return (nu - self.mu0) ** 2 * g2 * g2 / g1 if g1 > 0 else 0.0

    def root(self, lo: float, hi: float) -> float:
        """Root of ``lambda_min(S(nu))`` in ``[lo, hi)`` (safeguarded Newton)."""
        nu = lo
        dS = -np.eye(9) - self.G2
        for _ in range(100):
            w, v = np.linalg.eigh(self.S(nu))
            f, vec = w[0], v[:, 0]
            if f > 0:
                lo = nu
            else:
                hi = nu
            slope = vec @ dS @ vec
            step = nu - f / slope if slope < 0 else np.nan
            if not lo <= step <= hi:
                step = 0.5 * (lo + hi) if np.isfinite(hi) else 2 * lo + 1e-300
            if abs(step - nu) <= 4 * np.finfo(float).eps * abs(nu) or step == nu:
                return step
            nu = step
        return nu


def _tls_fast(uv: np.ndarray, used: np.ndarray, norm: _Normalisation, weights=None):
    """Smallest right singular vector of ``C`` via the arrowhead structure, O(n).

    Returns ``(a (9,), depths (V, n_points), mu, eigenvalues of S(mu) (9,))``.

    Newton on a local model: one O(n) pass gives ``S`` and ``dS/dmu`` exactly at the
    current ``mu``; the root of the linear model (a 9 x 9 problem) is the next ``mu``.
    The smallest eigenvalue lies far below the poles for any sensible data, so two
    passes from ``mu = 0`` leave a truncation error below rounding (noise-free data
    need one).
    """
    arrow = _Arrowhead(uv, used, norm, weights)
    G = arrow.taylor(0.0)
    if G is None:
        raise DegenerateError(
            "some points' images do not move between views (zero disparity), so their depths "
            "are undetermined; remove points at infinity or use larger robot translations"
        )
    tol = 1e-15 * np.linalg.norm(arrow.E, 2)
    good, hi = 0.0, np.inf
    model = _TaylorModel(arrow.E, 0.0, G)
    mu = model.root(0.0, hi)
    for _ in range(60):
        G = arrow.taylor(mu)  # also checks mu is below every pole (a near-static track's)
        if G is None:  # past a pole: retreat halfway
            hi, mu = mu, 0.5 * (good + mu)
            continue
        good = mu
        converged = model.truncation(mu) <= tol
        model = _TaylorModel(arrow.E, mu, G)  # exact at mu
        mu = model.root(0.0, hi)
        if converged:  # the step from a validated mu is below the truncation tolerance
            break
    if not arrow.below_poles(mu):  # the last step crossed a pole: the last exact model it is
        mu = model.mu0
    w, v = np.linalg.eigh(model.S(mu))
    a = v[:, 0]
    return a, arrow.depths(mu, a), mu, w


# --------------------------------------------------------------------------------------
# Dense reference
# --------------------------------------------------------------------------------------


def _tls_dense(uv: np.ndarray, used: np.ndarray, norm: _Normalisation, weights=None):
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
    norm = _normalisation(uv, used, T)
    a, depths, mu, w = (_tls_fast if method == "fast" else _tls_dense)(uv, used, norm, weights)
    # reduced singular values sqrt(mu + eig_k(S(mu))): sigma_1, then the best residuals
    # of the second and third alternative A
    sv = np.sqrt(np.maximum(mu + np.concatenate([[0.0], w[1:3]]), 0.0))
    if mu + w[1] <= 1e-12 * w[-1]:
        raise DegenerateError(
            "the data do not determine the camera: the linear system has a (numerically) "
            f"two-dimensional null space (sigma_2 / sigma_max = {np.sqrt(max(mu + w[1], 0) / w[-1]):.1e}). "
            "Track more points, over more views, spread over the image and over depth."
        )
    # undo normalisation: lam' H u = A' (X - T) / t_scale  =>  A ∝ H^-1 A' / t_scale
    A = np.linalg.solve(norm.H, a.reshape(3, 3)) / norm.t_scale
    c = 1.0 / np.linalg.norm(A[2])
    if np.nanmedian(depths) < 0:
        c = -c
    return A * c, depths * c, sv


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
    """
    seen = np.isfinite(uv[..., 0])
    used = seen.sum(axis=0) >= 2
    motion = _motion_per_length(uv, T)
    static = used & ~(motion > 1e-9 * max(float(np.nanmedian(motion[used])) if used.any() else 0.0, 1e-300))
    used &= ~static
    if used.sum() < 2:
        raise DegenerateError(
            f"only {int(used.sum())} point(s) are seen in at least 2 views and move between views "
            f"({int(static.sum())} do not move at all); the linear estimate needs at least 2 points tracked "
            "through the views (more is better)")
    active_views = np.isfinite(uv[:, used, 0]).any(axis=1)
    if active_views.sum() < 4:
        raise DegenerateError(f"only {int(active_views.sum())} views observe tracked points; at least 4 are needed")
    check_translations_span(T[active_views])
    if method == "dense" and used.sum() > DENSE_MAX_POINTS:
        raise InputError(
            f"method='dense' is a reference for small problems (at most {DENSE_MAX_POINTS} points, "
            f"got {int(used.sum())}); use method='fast', which gives the same result in O(n)")
    if weighting == "depth":
        A, depth, sv = solve_tls(uv, T, used, method, _relative(motion, used))
        A, depth, sv = solve_tls(uv, T, used, method, _relative(1.0 / _point_depth(depth, motion), used))
    else:
        A, depth, sv = solve_tls(uv, T, used, method)
    K, R = rq_decompose(A)
    X = triangulate(A, uv, T, depth, passes=1)  # NaN for unused points (no finite depth)
    return LinearEstimate(
        K=K, R=R, A=K @ R, X=X, depth=depth, singular_values=sv,
        n_used_points=int(used.sum()), used=used, method=method, static=static)


def reference_motion(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image motion of every observation from its track's first (reference) view:
    ``(|uv_i - uv_r| (n_views, n_points) pixels, NaN where unseen; r (n_points,))``."""
    ref = np.argmax(np.isfinite(uv[..., 0]), axis=0)
    return np.hypot(*(uv - uv[ref, np.arange(uv.shape[1])][None]).transpose(2, 0, 1)), ref


def _motion_per_length(uv: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Median over a track's views of ``|uv_i - uv_r| / |T_i - T_r|`` (pixels per unit of
    translation, ``r`` its first view): proportional to ``1 / depth`` (n_points,); NaN for
    tracks seen once."""
    seen = np.isfinite(uv[..., 0])
    cols = np.arange(uv.shape[1])
    d, ref = reference_motion(uv)  # (V, n)
    t = np.linalg.norm(T[:, None, :] - T[ref][None], axis=2)  # (V, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(seen & (t > 0), d / t, np.nan)
    ratio[ref, cols] = np.nan
    out = np.full(uv.shape[1], np.nan)
    ok = np.isfinite(ratio).any(axis=0)
    out[ok] = np.nanmedian(ratio[:, ok], axis=0)
    return out


def _point_depth(depth: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Median TLS depth of each point; where it is not positive, the depth the image motion
    implies (scaled to the TLS depths' units)."""
    with np.errstate(invalid="ignore"):
        positive = np.where(depth > 0, depth, np.nan)
    z = np.full(depth.shape[1], np.nan)
    has = np.isfinite(positive).any(axis=0)
    z[has] = np.nanmedian(positive[:, has], axis=0)
    good = np.isfinite(z) & (z > 0) & (motion > 0)
    scale = np.median(z[good] * motion[good]) if good.any() else 1.0
    return np.where(good, z, scale / np.where(motion > 0, motion, np.nan))


def _relative(w: np.ndarray, used: np.ndarray, cap: float = 10.0) -> np.ndarray:
    """Row weights scaled to median 1 over the used points, capped at ``cap`` (one near
    point must not dominate either); 1 where undefined."""
    m = np.nanmedian(w[used])
    out = np.where(np.isfinite(w) & (w > 0), w / m, 1.0)
    return np.minimum(out, cap)
