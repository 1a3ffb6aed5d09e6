"""The exact O(n) total-least-squares solver of the linear estimator (:mod:`.linear`).

``M = C^T C = [[D, B], [B^T, E]]`` is an arrowhead matrix: ``D`` is block diagonal with
one small arrowhead block ``D_j`` per point (its depths), ``E`` (9 x 9) belongs to
``vec(A)``. Eliminating the depths, the smallest eigenvalue ``mu`` of ``M`` is the root in
``[0, min eig D)`` of ::

    f(mu) = lambda_min(S(mu)),   S(mu) = E - mu I - sum_j B_j^T (D_j - mu I)^-1 B_j

(``f`` is concave and decreasing there), ``vec(A)`` is the null vector of ``S(mu)`` and
the depths follow as ``lam_j = -(D_j - mu I)^-1 B_j vec(A)``. One O(n) pass evaluates
``S`` and ``dS/dmu`` at a given ``mu`` with closed-form arrowhead inverses. Newton on that
local model, started from the root of a pilot problem (every ``step``-th point), lands on
the root in one pass; the depth pass then checks ``S(mu) a = 0`` with the exact ``S``
(:meth:`Arrowhead.solve`). A solve reads the data twice.

Internally ``vec(A)`` is column-major (``vec(A^T)``: index ``3 b + a`` for ``A[a, b]``), so
that a point's head row is one matrix product over its views; :meth:`Arrowhead.solve`
returns ``A`` itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..types import DegenerateError
from .normalisation import Normalisation

__all__ = ["Points", "Arrowhead", "MedianSign", "chunks", "column_median", "signed_medians"]

#: Points per chunk in the O(n) passes: every temporary stays small (a few MB), so that
#: memory is reused rather than freshly mapped, which costs more than the arithmetic.
_CHUNK = 16384


def chunks(n: int):
    """Slices of at most ``_CHUNK`` points covering ``range(n)``."""
    for lo in range(0, n, _CHUNK):
        yield slice(lo, min(lo + _CHUNK, n))


def column_median(a: np.ndarray) -> np.ndarray:
    """Median over axis 0 of the non-NaN entries of ``a`` ``(k, m)``; NaN where there are none
    (the values of ``np.nanmedian(a, axis=0)`` without its per-column cost)."""
    return _sorted_median(_sort_columns(a), 0, a.shape[0] - np.count_nonzero(np.isnan(a), axis=0))


def signed_medians(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Medians over axis 0 of the positive entries of ``a`` ``(k, m)`` and of minus its
    negative ones (NaN where there are none), from one sort."""
    s = _sort_columns(a)  # negatives, zeros, positives, then the NaN
    n_pos = np.count_nonzero(a > 0, axis=0)
    n_pos_end = a.shape[0] - np.count_nonzero(np.isnan(a), axis=0)
    return _sorted_median(s, n_pos_end - n_pos, n_pos), -_sorted_median(s, 0, np.count_nonzero(a < 0, axis=0))


def _sort_columns(a: np.ndarray) -> np.ndarray:
    """``a`` ``(k, m)`` sorted along axis 0, NaN last (as +inf): for a few rows an odd-even
    transposition network of element-wise min / max (``np.sort`` sorts each column apart)."""
    if a.shape[0] > 8:
        return np.sort(a, axis=0)
    s = np.where(np.isnan(a), np.inf, a)
    for r in range(a.shape[0]):
        for i in range(r % 2, a.shape[0] - 1, 2):
            lo = np.minimum(s[i], s[i + 1])
            np.maximum(s[i], s[i + 1], out=s[i + 1])
            s[i] = lo
    return s


def _sorted_median(s: np.ndarray, lo: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Median of ``s[lo_j : lo_j + k_j, j]`` of column-sorted ``s``; NaN where ``k_j = 0``."""
    top = s.shape[0] - 1
    a = np.take_along_axis(s, np.minimum(lo + np.maximum(k - 1, 0) // 2, top)[None], axis=0)[0]
    b = np.take_along_axis(s, np.minimum(lo + k // 2, top)[None], axis=0)[0]
    return np.where(k > 0, (a + b) / 2, np.nan)


class MedianSign:
    """Whether the median of all values seen so far is negative, from counts: with ``N``
    values of which ``n_neg`` are negative, it is iff ``2 n_neg > N``, or ``2 n_neg == N``
    and the two middle values (the largest negative, the smallest non-negative) sum below
    zero: ``np.nanmedian(values) < 0`` without keeping the values."""

    def __init__(self):
        self.n, self.n_neg, self.max_neg, self.min_pos = 0, 0, -np.inf, np.inf

    def add(self, values: np.ndarray) -> None:
        """Count the non-NaN entries of ``values``."""
        ok = ~np.isnan(values)
        neg = ok & (values < 0)
        self.n += int(np.count_nonzero(ok))
        self.n_neg += int(np.count_nonzero(neg))
        self.max_neg = max(self.max_neg, np.max(values, where=neg, initial=-np.inf))
        self.min_pos = min(self.min_pos, np.min(values, where=ok & ~neg, initial=np.inf))

    @property
    def negative(self) -> bool:
        if 2 * self.n_neg != self.n:
            return 2 * self.n_neg > self.n
        return self.n > 0 and self.max_neg + self.min_pos < 0


class Points:
    """The used points grouped by reference view (each point's first seen view), in chunks.

    The reference view most points share is read in place: chunks of ``uv`` (views, no
    copy), its other points (unused, or with another reference view) masked out. The points
    of other reference views are gathered, in chunks, after it (so a pass that writes a
    chunk's results by point writes every gathered point after its masked-out slot).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen.
    used : (n_points,) bool
        Points to use, each seen in at least 2 views.
    ref : (n_points,) int
        First seen view of every point.
    """

    def __init__(self, uv: np.ndarray, used: np.ndarray, ref: np.ndarray):
        self.uv, self.used, self.ref = uv, used, ref
        n = uv.shape[1]
        counts = np.bincount(ref[used], minlength=uv.shape[0])
        r0 = int(np.argmax(counts))
        self.in_place = None  # (r0, mask or None)
        if 2 * counts[r0] >= n:
            self.in_place = (r0, None if counts[r0] == n else used & (ref == r0))
        self.gathered = [(int(r), np.flatnonzero(used & (ref == r))) for r in np.flatnonzero(counts)
                         if self.in_place is None or r != r0]
        self.n_used = int(counts.sum())

    def chunks(self):
        """Yield ``(r, points, x, active)``: reference view, points (slice or indices), their
        pixels ``(n_views, m, 2)`` and which of them take part ``(m,)`` (None: all)."""
        if self.in_place is not None:
            r0, mask = self.in_place
            for c in chunks(self.uv.shape[1]):
                active = None if mask is None or mask[c].all() else mask[c]
                yield r0, c, self.uv[:, c], active
        for r, members in self.gathered:
            for c in chunks(members.size):
                yield r, members[c], self.uv[:, members[c]], None

    def subsample(self, step: int) -> "Points":
        """Every ``step``-th point (views, no copy): a pilot problem of the same kind."""
        return Points(self.uv[:, ::step], self.used[::step], self.ref[::step])


@dataclass(frozen=True)
class _Chunk:
    """Points of one chunk with reference view ``r``; the other views are the tail slots.

    With ``z_0`` the normalised homogeneous pixel in view ``r``, ``z_k`` in tail slot ``k``
    (zero where unseen), ``t_k = T_k - T_r`` (the same for every point of the chunk) and
    ``tt_0 = -sum_k t_k`` over the point's seen tail, the blocks of ``M = C^T C`` are::

        D[0, 0] = (V_j - 1) |z_0|^2,   D[k, k] = |z_k|^2,   D[0, k] = -z_0 . z_k
        B[0] = kron(z_0, tt_0),        B[k] = kron(z_k, t_k)

    (rows of point ``j`` scaled by its weight ``sw_j``). Which views see a point only masks
    its tail: every visibility pattern is handled by the same array operations. An unseen
    slot has ``z_k = 0`` and ``D[k, k] = inf`` (so ``(D_j - mu I)^-1`` is zero there); an
    inactive point no tail and ``D[0, 0] = inf``.
    """

    points: slice | np.ndarray  # (m,) point indices
    ref: int  # the reference view r
    active: np.ndarray | None  # (m,) bool: points taking part (None: all); the others are inert
    full: bool  # every point active and every tail slot seen
    seen: np.ndarray  # (K, m) bool, K = n_views - 1
    z0: np.ndarray  # (3, m)
    Z: np.ndarray  # (K, 3, m), zero where unseen
    t: np.ndarray  # (K, 3)
    tt_head: np.ndarray  # (3, m) or (3, 1)
    D00: np.ndarray  # (m,)
    D0k: np.ndarray  # (K, m), zero where unseen
    Dkk: np.ndarray  # (K, m), +inf where unseen
    sw: np.ndarray  # (m,) row weights

    def inverse(self, mu: float):
        """Closed-form pieces of ``(D_j - mu I)^-1``, ``(q, 1/s, 1/delta)`` with ``delta_k =
        D_kk - mu``, ``q_k = D_0k / delta_k`` and ``s = D_00 - mu - sum_k D_0k q_k`` (zero off
        the seen tail), or None if some ``D_j - mu I`` is not positive definite (``mu`` past
        a pole)."""
        delta = self.Dkk - mu
        if np.any(delta <= 0):
            return None
        inv_delta = np.divide(1.0, delta, out=delta)
        q = self.D0k * inv_delta
        s = self.D00 - mu - np.einsum("km,km->m", self.D0k, q)
        if np.any(s <= 0):
            return None
        return q, np.divide(1.0, s, out=s), inv_delta


def _kron_sum(t: np.ndarray, P: np.ndarray) -> np.ndarray:
    """``sum_k kron(t_k t_k^T, P_k)`` (9, 9) for ``t (K, 3)``, ``P (K, 3, 3)``."""
    return np.einsum("kb,kd,kac->badc", t, t, P).reshape(9, 9)


def _add_taylor_terms(G: np.ndarray, c: _Chunk, q: np.ndarray, inv_s: np.ndarray, inv_delta: np.ndarray) -> None:
    """Add a chunk's terms of :meth:`Arrowhead.taylor` to ``G`` (2, 9, 9). Every sum over
    points is a matrix product over the chunk (column-major ``vec``: ``B_k = sw kron(t_k,
    z_k)``, so a sum ``sum_k kron(t_k, y_k)`` over the tail is ``t^T y``)."""
    K, _, m = c.Z.shape
    # w = sw (kron(tt_0, z_0) - sum_k q_k kron(t_k, z_k))
    w = (c.t.T @ (q[:, None] * c.Z).reshape(K, -1)).reshape(3, 3, m)
    w -= c.tt_head[:, None] * c.z0
    w = w.reshape(9, m)
    w *= -c.sw
    # factors of w^T: the w w^T terms of G_1 and G_2, then the cross terms of G_2
    L = np.empty((18 + 3 * K, m))
    np.multiply(w, inv_s, out=L[0:9])
    np.multiply(L[0:9], (1.0 + np.einsum("km,km->m", q, q)) * inv_s, out=L[9:18])
    np.multiply(c.Z, (q * inv_delta * (inv_s * c.sw))[:, None], out=L[18:].reshape(K, 3, m))
    P = L @ w.T
    G += P[:18].reshape(2, 9, 9)
    X = np.einsum("kb,kaq->baq", c.t, P[18:].reshape(K, 3, 9)).reshape(9, 9)
    G[1] -= X + X.T
    # sum_k kron(t_k t_k^T, sum_j sw^2 / delta_k^o z_k z_k^T), o = 1, 2
    Zd = np.empty((K, 2, 3, m))
    np.multiply(c.Z, (inv_delta * (c.sw * c.sw))[:, None], out=Zd[:, 0])
    np.multiply(Zd[:, 0], inv_delta[:, None], out=Zd[:, 1])
    zz = np.matmul(Zd.reshape(K, 6, m), c.Z.transpose(0, 2, 1)).reshape(K, 2, 3, 3)
    G[0] += _kron_sum(c.t, zz[:, 0])
    G[1] += _kron_sum(c.t, zz[:, 1])


class Arrowhead:
    """``M = C^T C`` of the normalised, row-weighted system, streamed in chunks.

    Sums over points of ``B_j^T W_j B_j`` are ``sum_k kron(t_k t_k^T, sum_j ... z z^T)``
    plus a 9-vector per point: per-point work on 3-vectors, sums as matrix products,
    nothing of size O(n) kept between passes. ``(D_j - mu I)^-1`` is applied in closed
    form (:meth:`_Chunk.inverse`)::

        y_0 = (b_0 - sum_k q_k b_k) / s,    y_k = (b_k - D_0k y_0) / delta_k

    Parameters
    ----------
    points : Points
    norm : Normalisation
    weights : (n_points,) float, optional
        Row weights ``sw_j`` (default ones).
    """

    def __init__(self, points: Points, norm: Normalisation, weights: np.ndarray | None = None):
        self.points, self.norm = points, norm
        self.weights = weights
        V = points.uv.shape[0]
        self._tail = {r: (np.r_[0:r, r + 1:V], norm.T[np.r_[0:r, r + 1:V]] - norm.T[r]) for r in range(V)}
        self.E = None  # the A block of M (column-major vec), from the first complete taylor() pass

    def chunks(self):
        """Yield the used points as :class:`_Chunk` s. An inactive point has no tail and an
        infinite head block: it adds nothing to any sum and its depths are NaN."""
        H = self.norm.H
        for r, points, x, active in self.points.chunks():
            views, t = self._tail[r]
            K, m = views.size, x.shape[1]
            Z = np.empty((K, 3, m))  # normalised homogeneous pixels of the tail, zero where unseen
            for dst, src in ((slice(0, r), slice(0, r)), (slice(r, K), slice(r + 1, K + 1))):
                np.multiply(x[src, :, 0], H[0, 0], out=Z[dst, 0])
                np.multiply(x[src, :, 1], H[1, 1], out=Z[dst, 1])
            Z[:, 0] += H[0, 2]
            Z[:, 1] += H[1, 2]
            seen = ~np.isnan(Z[:, 0])
            z0 = np.empty((3, m))
            np.multiply(x[r, :, 0], H[0, 0], out=z0[0])
            np.multiply(x[r, :, 1], H[1, 1], out=z0[1])
            z0[0] += H[0, 2]
            z0[1] += H[1, 2]
            z0[2] = 1.0
            if active is not None:
                seen &= active
                np.copyto(z0, 0.0, where=~active)
            full = bool(seen.all())
            if not full:
                np.copyto(Z[:, :2], 0.0, where=~seen[:, None])
            Z[:, 2] = seen
            D00 = (K if full else Z[:, 2].sum(axis=0)) * np.einsum("am,am->m", z0, z0)
            Dkk = np.einsum("kam,kam->km", Z, Z)
            if not full:  # an unseen slot: an infinite diagonal entry, zero in the inverse
                np.copyto(Dkk, np.inf, where=~seen)
                if active is not None:
                    D00[~active] = np.inf
            yield _Chunk(points=points, ref=r, active=active, full=full, seen=seen, z0=z0, Z=Z, t=t,
                         tt_head=-t.sum(axis=0)[:, None] if full else -(t.T @ Z[:, 2]),
                         sw=np.ones(m) if self.weights is None else self.weights[points], D00=D00,
                         D0k=-np.einsum("kam,am->km", Z, z0), Dkk=Dkk)

    def taylor(self, mu: float) -> tuple[np.ndarray, np.ndarray] | None:
        """First two Taylor coefficients of ``F(nu) = sum_j B_j^T (D_j - nu I)^-1 B_j`` at
        ``mu``: ``G_1 = sum B^T W B`` and ``G_2 = sum B^T W^2 B``, ``W_j = (D_j - mu I)^-1``.

        One O(n) pass; None if ``mu`` is past a pole. ``W = Delta + q^ q^T / s`` with
        ``Delta = diag(0, 1/delta_k)`` and ``q^ = (1, -q_k)``; with the head row
        ``w = q^T B`` (9 per point)::

            G_1 = sum_k B_k B_k^T / delta_k + w w^T / s
            G_2 = sum_k B_k B_k^T / delta_k^2 - sum_k q_k / (s delta_k) (B_k w^T + w B_k^T)
                  + (1 + |q|^2) w w^T / s^2

        and ``sum_j c_j B_jk B_jk^T = kron(t_k t_k^T, sum_j c_j z_jk z_jk^T)``.
        """
        G, E3 = np.zeros((2, 9, 9)), np.zeros((3, 3))
        for c in self.chunks():
            parts = c.inverse(mu)
            if parts is None:
                return None
            if self.E is None:
                E3 += c.t.T @ (c.t * (c.seen @ (c.sw * c.sw))[:, None])
            _add_taylor_terms(G, c, *parts)
        if self.E is None:
            self.E = np.kron(E3, np.eye(3))
        return G[0], G[1]

    def lam(self, c: _Chunk, mu: float, A: np.ndarray):
        """Depths of a chunk's points, ``lam_j = y_j / sw_j`` with ``y_j = -(D_j - mu I)^-1
        B_j a``, and their share of ``B^T y`` (3, 3: column-major ``vec``), the term of
        ``S(mu) a = (E - mu I) a + B^T y`` that needs the points. Returns ``(head (m,), tail
        (K, m), B^T y)`` (the tail NaN where unseen, both NaN for inactive points), or None
        if ``mu`` is past a pole."""
        parts = c.inverse(mu)
        if parts is None:
            return None
        q, inv_s, inv_delta = parts
        b = np.einsum("kam,ka->km", c.Z, c.t @ A.T)  # B_j a / sw_j = z_k^T A t_k
        y0 = (np.einsum("am,am->m", c.z0, A @ c.tt_head) - np.einsum("km,km->m", q, b)) * inv_s
        tail = (c.D0k * y0 - b) * inv_delta  # the weights cancel: sw_j lam_j solves sw_j-scaled rows
        head = -y0
        # B^T y = sum_j sw_j^2 (kron(tt_0, lam_0 z_0) + sum_k kron(t_k, lam_k z_k)),
        # tt_0 = -sum_k t_k over the seen tail
        sw2 = c.sw * c.sw
        Bty = c.t.T @ (np.einsum("kam,km->ka", c.Z, tail * sw2) - c.Z[:, 2] @ (c.z0 * (head * sw2)).T)
        if not c.full:
            np.copyto(tail, np.nan, where=~c.seen)
            if c.active is not None:
                np.copyto(head, np.nan, where=~c.active)
        return head, tail, Bty

    def solve(self, make_sink, mu_start: float = 0.0):
        """The smallest eigenvalue ``mu`` of ``M``, its ``vec(A)`` and one depth pass.

        Newton on the local model ``S(nu) ~ S(mu0) - (nu - mu0)(I + G_2)``, exact at
        ``mu0``: one O(n) pass a step, the model's root (a 9 x 9 problem) the next ``mu``
        (it bounds the smallest root from above: ``F`` is convex below the poles). Newton
        starts from the root of a pilot problem (every ``step``-th point, about one chunk,
        one pass over them): ``mu`` is a mean over the points and hardly depends on their
        number (the pilot's within ~1e-2), so that the first model's root is the root to
        rounding, or the second's is. That root is taken once the model's truncation
        estimate there is below 5e-14 ``|E|``, and the depth pass confirms it with the
        exact ``S``: every ``D_j - mu I`` positive definite and ``|S(mu) a| <= 1e-13 |E|``
        (rounding: ~5e-16). One or two passes and the depth pass, then; should that fail
        (``mu`` near the pole of a track with almost no parallax), Newton goes on until the
        step from a validated ``mu`` is below ``1e-15 |E|`` by the truncation estimate.

        Parameters
        ----------
        make_sink : callable
            ``make_sink(A')`` returns a fresh ``sink(c, head, tail)``, called with every
            chunk and its depths (:meth:`lam`).
        mu_start : float
            A start below the smallest pole (e.g. a previous solve's root), or 0.

        Returns
        -------
        mu : float
            The smallest eigenvalue of ``M`` (``sigma_min^2``).
        A : (3, 3) float
            ``A'`` in normalised units, unit Frobenius norm, sign arbitrary.
        eig : (9,) float
            Eigenvalues of ``S(mu)``.
        sink
            The sink that saw every chunk.
        """
        model = self._model_at(self._pilot(mu_start))
        tol = 1e-15 * np.linalg.norm(self.E, 2)
        found, model = self._confirmed_steps(model, make_sink, tol)
        if found is not None:
            return found
        mu, model = self._newton(model, model.root(0.0, np.inf), tol)
        # the depth pass checks mu against the poles; if the last Newton step crossed one,
        # the last exact model's own mu it is
        for mu in (mu, model.mu0):
            found = self._depth_pass(mu, model, make_sink)
            if found is not None:
                return found
        raise AssertionError("unreachable: the model's own mu0 is below every pole")

    def _confirmed_steps(self, model: "_TaylorModel", make_sink, tol: float, steps: int = 2):
        """Newton steps, a pass each, until the model's truncation estimate at its root is
        below ``50 tol`` and the depth pass confirms the root (``|S a| <= 100 tol``; it is
        1-10 times the estimate):
        ``(found, model)``, ``found`` None if not (the last ``model`` is exact at its
        ``mu0``)."""
        for _ in range(steps):
            mu = model.root(0.0, np.inf)
            if model.truncation(mu) <= 50 * tol:
                return self._depth_pass(mu, model, make_sink, residual_tol=100 * tol), model
            G = self.taylor(mu)
            if G is None:
                break
            model = _TaylorModel(self.E, mu, G)
        return None, model

    def _depth_pass(self, mu: float, model: "_TaylorModel", make_sink, residual_tol: float = np.inf):
        """``(mu, A', eig S(mu), sink)`` after a pass of :meth:`lam` at ``mu``, or None if
        ``mu`` is past a pole or ``|S(mu) a| > residual_tol``."""
        w, v = np.linalg.eigh(model.S(mu))
        A = v[:, 0].reshape(3, 3).T  # column-major vec(A)
        sink, Bty = make_sink(A), np.zeros((3, 3))
        for c in self.chunks():
            parts = self.lam(c, mu, A)
            if parts is None:
                return None
            sink(c, *parts[:2])
            Bty += parts[2]
        if np.linalg.norm((self.E - mu * np.eye(9)) @ v[:, 0] + Bty.ravel()) > residual_tol:
            return None
        return mu, A, w, sink

    def _model_at(self, mu_start: float) -> "_TaylorModel":
        """The exact local model at ``mu_start``, or at 0 if that is past a pole."""
        G = self.taylor(mu_start) if mu_start > 0 else None
        if G is None:
            mu_start, G = 0.0, self.taylor(0.0)
        if G is None:
            raise DegenerateError(
                "some points' images do not move between views (zero disparity), so their depths "
                "are undetermined; remove points at infinity or use larger robot translations"
            )
        return _TaylorModel(self.E, mu_start, G)

    def _newton(self, model: "_TaylorModel", mu: float, tol: float) -> tuple[float, "_TaylorModel"]:
        """Newton from ``mu`` (the root of ``model``), a pass per step, until the step from
        an exact model at a validated ``mu`` is below the truncation tolerance. A pass
        that finds ``mu`` past a pole retreats halfway towards the last valid ``mu``."""
        good, hi = model.mu0, np.inf
        for _ in range(60):
            G = self.taylor(mu)  # also checks mu is below every pole
            if G is None:  # past a pole: retreat halfway
                hi, mu = mu, 0.5 * (good + mu)
                continue
            good = mu
            converged = model.truncation(mu) <= tol
            model = _TaylorModel(self.E, mu, G)
            mu = model.root(0.0, hi)
            if converged:
                break
        return mu, model

    def _pilot(self, mu_start: float) -> float:
        """The model root of every ``step``-th point's problem at ``mu_start`` (one pass over
        them), or ``mu_start`` if there are too few points."""
        step = self.points.n_used // _CHUNK
        if step < 4:
            return mu_start
        pilot = Arrowhead(self.points.subsample(step), self.norm,
                          None if self.weights is None else self.weights[::step])
        try:
            return pilot._model_at(mu_start).root(0.0, np.inf)
        except DegenerateError:
            return mu_start


class _TaylorModel:
    """``S(nu) = E - nu I - G_1 - (nu - mu0) G_2`` near ``mu0``; exact at ``mu0``. Below
    the poles ``F`` is convex, so the model bounds ``S`` from above and its root bounds
    the smallest root from above."""

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
