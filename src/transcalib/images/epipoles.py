"""Epipoles of pure translations: the geometry every view pair of a session has.

Under pure translation the fundamental matrix of a view pair is ``F = [e]_x``: the
epipole ``e ~ A (T_j - T_i)`` (``A = K R``) is the same point in both images and a match
``x -> y`` lies on the line through ``e`` and ``x``::

    y = x + rho (e3 x - e_xy) + (perpendicular residual)

with ``rho`` proportional to the inverse depth of the point in view ``j`` (it must have
the sign of the epipole: cheirality). Two matches fix ``e`` (the intersection of the lines
``x1 y1`` and ``x2 y2``), so :func:`epipole_ransac` runs the project's one robust loop
(:func:`transcalib.estimate.ransac.lo_ransac`) with a 2-match solver; a match's error is
its squared distance from its epipolar line (one degree of freedom, the noise of the rule
from the ``threshold_px`` a user gives, :func:`~transcalib.estimate.noise.sigma_from_distance_threshold`).

The epipoles of a session must also agree with each other (:func:`verify_pairs`): ``e_ik``
lies on the line ``e_ij e_jk`` (``t_ik = t_ij + t_jk``); a pair failing that in every
triplet (a repetitive texture can make a wrong epipole win) is re-estimated on that line.
With the robot translations known every epipole is ``A (T_j - T_i)`` for one ``A``
(:func:`fit_translations`), which also catches a consistent family of wrong epipoles.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..estimate.noise import chi2_inliers, sigma_from_distance_threshold, truncated_sigma
from ..estimate.ransac import least_singular_vector, lo_ransac
from ..validate import COPLANAR_RTOL
from .local import detrended

__all__ = ["epipole_ransac", "PairGeometry", "verify_pairs", "pair_epipole", "residuals", "signed_distance",
           "direction", "fit_translations", "robust_A", "MOVING_PX"]

log = logging.getLogger("transcalib.tracks")

#: A match that moves less than this (px) has no direction: it fits every epipole.
MOVING_PX = 0.5
#: False-rejection rate of the epipolar inlier rule.
FALSE_REJECTION = 0.01
#: A pair needs this many verified matches for its epipole to be kept.
MIN_VERIFIED = 8


# --------------------------------------------------------------------------- geometry
def direction(e: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``e3 x - e_xy`` ``(n, 2)``: direction of the epipolar line from ``e`` through ``x``."""
    return e[2] * x - e[:2]


def _directions(E: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`direction` of every hypothesis ``E (h, 3)`` at every point ``x (2, m)``
    (coordinates first): its components ``(h, m)`` each, written out (a reduction over a
    last axis of length 2 costs three times the arithmetic)."""
    return E[:, 2:3] * x[0] - E[:, 0:1], E[:, 2:3] * x[1] - E[:, 1:2]


def residuals(e: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (px) of ``y`` from the epipolar line through ``x`` and ``rho`` per match,
    ``y = x + rho (e3 x - e_xy) + residual``; a match moving less than :data:`MOVING_PX`
    has distance 0, an undefined one inf."""
    dx, dy = e[2] * x[..., 0] - e[0], e[2] * x[..., 1] - e[1]  # direction(e, x), by component
    vx, vy = y[..., 0] - x[..., 0], y[..., 1] - x[..., 1]
    nd = np.sqrt(dx * dx + dy * dy)
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.abs(dx * vy - dy * vx) / nd
        rho = (vx * dx + vy * dy) / nd**2
    dist = np.where(np.sqrt(vx * vx + vy * vy) < MOVING_PX, 0.0, dist)
    return np.where(np.isfinite(dist), dist, np.inf), rho


def signed_distance(e: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Signed distance (px) of ``y`` from the epipolar line through ``x`` (0 when not moving)."""
    d = direction(e, x)
    disp = y - x
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (d[:, 0] * disp[:, 1] - d[:, 1] * disp[:, 0]) / np.linalg.norm(d, axis=1)
    return np.where(np.linalg.norm(disp, axis=1) < MOVING_PX, 0.0, r)


def _lines(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Lines through ``x`` and ``y`` ``(n, 3)``, homogeneous, unit normal."""
    # [x; 1] x [y; 1], written out
    L = np.column_stack([x[:, 1] - y[:, 1], y[:, 0] - x[:, 0], x[:, 0] * y[:, 1] - x[:, 1] * y[:, 0]])
    n = np.sqrt(L[:, :1] * L[:, :1] + L[:, 1:2] * L[:, 1:2])
    return L / np.where(n > 0, n, 1.0)


def _fit_epipole(x: np.ndarray, y: np.ndarray, scale: float) -> np.ndarray:
    """Least-squares common point ``(3,)`` (unit norm) of the lines ``x_k y_k``, in units of
    ``scale`` pixels for conditioning: the smallest right singular vector of ``L diag(s, s, 1)``."""
    Ln = _lines(x, y) * np.array([scale, scale, 1.0])
    e = np.linalg.svd(Ln, full_matrices=False)[2][-1] * np.array([scale, scale, 1.0])
    return e / np.linalg.norm(e)


def _support(e, x, y, thr):
    """Matches consistent with ``e``: on its lines within ``thr`` px, ``rho > 0`` if moving."""
    dist, rho = residuals(e, x, y)
    moving = np.linalg.norm(y - x, axis=1) >= MOVING_PX
    return (dist < thr) & ((rho > 0) | ~moving)


# --------------------------------------------------------------------------- one pair
class _EpipoleProblem:
    """The epipole of one view pair as a :class:`~transcalib.estimate.ransac.RansacProblem`:
    pairs of moving matches as samples, both signs of the lines' intersection as
    hypotheses, squared epipolar distances as errors (inf when ``rho`` has the wrong sign)."""

    sample_size = 2

    def __init__(self, x: np.ndarray, y: np.ndarray):
        self.x, self.y = x, y
        self._x, self._disp = np.ascontiguousarray(x.T), np.ascontiguousarray((y - x).T)  # (2, n) each
        self.L = _lines(x, y)
        self.moving = np.linalg.norm(y - x, axis=1) >= MOVING_PX
        self.pool = np.flatnonzero(self.moving)
        self.dof = np.ones(len(x), np.intp)
        self.scorable = self.samplable = self.moving
        self.scale = max(float(np.abs(x).max()) if len(x) else 1.0, 1.0)

    def sample(self, rng, size: int) -> np.ndarray:
        s = self.pool[rng.integers(0, len(self.pool), size=(size, 2))]
        return s[s[:, 0] != s[:, 1]]

    def solve(self, samples: np.ndarray):
        E = np.cross(self.L[samples[:, 0]], self.L[samples[:, 1]])
        n = np.linalg.norm(E, axis=1)
        E = E / np.where(n > 1e-12, n, 1.0)[:, None]
        return np.concatenate([E, -E]), np.concatenate([n > 1e-12, n > 1e-12])

    def errors(self, E: np.ndarray) -> np.ndarray:
        dx, dy = _directions(E, self._x)
        vx, vy = self._disp
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = dx * vy - dy * vx
            err = cross * cross / (dx * dx + dy * dy)
        ok = vx * dx + vy * dy > 0
        return np.where(self.moving[None], np.where(ok & np.isfinite(err), err, np.inf), 0.0)

    def refit(self, inliers: np.ndarray):
        m = inliers & self.moving
        if m.sum() < 2:
            return np.zeros((0, 3)), np.zeros(0, bool)
        e = _fit_epipole(self.x[m], self.y[m], self.scale)
        _, rho = residuals(e, self.x[m], self.y[m])
        e = e if np.sum(rho > 0) >= np.sum(rho < 0) else -e
        return e[None], np.ones(1, bool)


def epipole_ransac(x, y, *, threshold_px: float = 1.5, max_trials: int = 1000, rng=None, detrend: bool = False,
                   false_rejection: float = FALSE_REJECTION):
    """Epipole of a pure translation from correspondences ``x -> y`` (2-match LO-RANSAC).

    Parameters
    ----------
    x, y : (n, 2) float
        Matched pixels in two views.
    threshold_px : float
        Inlier distance of ``y`` from the epipolar line through ``x``: the rule's noise is
        ``threshold_px / sqrt(chi2_1(1 - false_rejection))`` (MSAC ranking).
    max_trials : int
        At most this many pairs of matches (the loop stops adaptively before).
    rng : seed or Generator
    detrend : bool
        Judge each match's epipolar distance against the local trend of its neighbours'
        (smooth deviations from straight epipolar lines come from lens distortion;
        mismatches deviate alone).
    false_rejection : float
        Probability that the rule rejects a good match.

    Returns
    -------
    e : (3,) float or None
        Homogeneous epipole, unit norm, signed so that ``rho > 0`` (``e ~ A (T_j - T_i)``);
        None with fewer than 3 inliers or fewer than 2 moving matches.
    inliers : (n,) bool
    rho : (n,) float
        ``y = x + rho (e3 x - e_xy)``: proportional to the inverse depth in the second view.
    """
    x, y = np.asarray(x, float).reshape(-1, 2), np.asarray(y, float).reshape(-1, 2)
    n = len(x)
    none = (None, np.zeros(n, bool), np.full(n, np.nan))
    if n < 3:
        return none
    problem = _EpipoleProblem(x, y)
    if len(problem.pool) < 2:
        return none
    sigma = sigma_from_distance_threshold(threshold_px, false_rejection)
    best = lo_ransac(problem, max_trials=max_trials, sigma=sigma, false_rejection=false_rejection, rng=rng)
    if best.hypothesis is None or best.n_inliers < 3:
        return none
    e = best.hypothesis
    _, rho = residuals(e, x, y)
    inl = chi2_inliers(problem.errors(e[None])[0], problem.dof, sigma, false_rejection)
    if detrend and inl.sum() >= 12:
        # lens distortion bends epipolar lines smoothly: judge each match against the local
        # trend of its neighbours' signed distances, not against the straight line
        cheiral = (rho > 0) | ~problem.moving
        for _ in range(2):
            inl = (detrended(x, signed_distance(e, x, y), inl) < threshold_px) & cheiral
    return e, inl, rho


# --------------------------------------------------------------------------- all pairs
@dataclass(frozen=True, eq=False)
class PairGeometry:
    """The verified geometry of one view pair ``(i, j)``, ``i < j``, of a session.

    Attributes
    ----------
    e : (3,) float or None
        Unit epipole signed as ``A (T_j - T_i)``; None: not verified (too few matches, or
        no motion: see ``static``).
    inliers : (m,) bool
        The pair's descriptor matches consistent with ``e``.
    source : str
        ``"ransac"`` (its own matches), ``"repaired"`` (on the line of two consistent
        pairs' epipoles), ``"translations"`` (``A (T_j - T_i)`` of the robot translations),
        ``"none"``.
    static : bool
        The matches barely move (median below :data:`MOVING_PX`) and fewer than
        :data:`MIN_VERIFIED` moving ones verify ``e``: a repeated view. (A minority that
        moves consistently, an object carried by the robot before a static background,
        makes the pair a moving one.)
    sigma_px : float
        Noise of the inliers' epipolar distances (truncated estimator; NaN without ``e``).
    """

    e: np.ndarray | None
    inliers: np.ndarray
    source: str = "ransac"
    static: bool = False
    sigma_px: float = float("nan")

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def _geometry(e, inl, x, y, source, thr) -> PairGeometry:
    sigma = float("nan")
    if e is not None and inl.sum() >= 2:
        dist, _ = residuals(e, x[inl], y[inl])
        sigma = truncated_sigma(dist**2, np.ones(len(dist), np.intp), float(np.median(dist)) * 1.5 + 1e-6,
                                FALSE_REJECTION)
    disp = np.linalg.norm(y - x, axis=1)
    n_moving = int((inl & (disp >= MOVING_PX)).sum()) if e is not None else 0
    static = len(x) > 0 and bool(np.median(disp) < MOVING_PX) and n_moving < MIN_VERIFIED
    return PairGeometry(e=e, inliers=inl, source=source, static=static, sigma_px=sigma)


def pair_epipole(geo: dict, i: int, j: int) -> np.ndarray | None:
    """Epipole of ``(i, j)`` signed as ``A (T_j - T_i)`` from the ``i < j`` table ``geo``
    (of :class:`PairGeometry` or of epipoles)."""
    if (i, j) in geo:
        g = geo[(i, j)]
        return g.e if isinstance(g, PairGeometry) else g
    if (j, i) in geo:
        g = geo[(j, i)]
        e = g.e if isinstance(g, PairGeometry) else g
        return None if e is None else -e
    return None


def verify_pairs(xy: dict, n_views: int, threshold_px: float, rng, report=None) -> tuple[dict, list, list]:
    """Epipole of every pair (:func:`epipole_ransac`), then the pairs inconsistent with the
    others (``e_ik`` on the line ``e_ij e_jk``) re-estimated on that line.

    Parameters
    ----------
    xy : dict ``(i, j) -> (x (m, 2), y (m, 2))``
        Descriptor matches of every pair ``i < j``.
    n_views : int
    threshold_px : float
    rng : Generator
    report : callable ``(stage, done, total)``, optional

    Returns
    -------
    geo : dict ``(i, j) -> PairGeometry``
    inconsistent : list of (i, j)
        Pairs whose own epipole disagreed with every triplet.
    repaired : list of (i, j)
    """
    geo = {}
    for k, (p, (x, y)) in enumerate(xy.items()):
        e, inl, _ = epipole_ransac(x, y, threshold_px=threshold_px, rng=rng, detrend=True)
        keep = e is not None and inl.sum() >= MIN_VERIFIED
        geo[p] = _geometry(e if keep else None, inl if keep else np.zeros(len(x), bool), x, y,
                           "ransac" if keep else "none", threshold_px)
        if report is not None:
            report("verify", k + 1, len(xy))
    epi = {p: g.e for p, g in geo.items() if g.e is not None}
    bad = _inconsistent_pairs(epi, n_views)
    good = {p: e for p, e in epi.items() if p not in bad}
    repaired = []
    for p in bad:
        x, y = xy[p]
        e, inl = _repair_pair(*p, good, x, y, threshold_px)
        if e is not None and inl.sum() >= 4:
            geo[p] = _geometry(e, inl, x, y, "repaired", threshold_px)
            repaired.append(p)
        else:
            geo[p] = _geometry(None, np.zeros(len(x), bool), x, y, "none", threshold_px)
    if bad:
        log.info("view pairs with inconsistent epipoles: %s; repaired: %s", bad, repaired)
    return geo, bad, repaired


def _inconsistent_pairs(epi: dict, n: int, tol: float = 2e-3) -> list:
    """Pairs whose epipole disagrees with every triplet (at least 2): ``e_ik`` must lie on
    the line ``e_ij e_jk`` (``|det[e_ij, e_jk, e_ik]| <= tol``, unit epipoles)."""
    votes = {}
    for i in range(n):
        for j in range(i + 1, n):
            for k in range(j + 1, n):
                if (i, j) in epi and (j, k) in epi and (i, k) in epi:
                    d = abs(np.linalg.det(np.array([epi[(i, j)], epi[(j, k)], epi[(i, k)]])))
                    for p in [(i, j), (j, k), (i, k)]:
                        v = votes.setdefault(p, [0, 0])
                        v[0] += d > tol
                        v[1] += 1
    return sorted(p for p, (bad, tot) in votes.items() if tot >= 2 and bad == tot)


def _repair_pair(i, k, good, x, y, thr):
    """Epipole of pair ``(i, k)`` constrained by consistent pairs: for any view j with
    ``e_ij`` and ``e_jk`` known, ``e_ik = a e_ij + b e_jk``; one match fixes ``(a, b)``,
    so a 1-match search over all matches and all such j picks it (most support)."""
    if len(x) < 3:
        return None, np.zeros(len(x), bool)
    views = {a for p in good for a in p}
    L = _lines(x, y)
    moving = np.linalg.norm(y - x, axis=1) >= MOVING_PX
    best = (-1, None)
    for j in sorted(views - {i, k}):
        p, q = pair_epipole(good, i, j), pair_epipole(good, j, k)
        if p is None or q is None:
            continue
        ab = np.column_stack([L @ q, -(L @ p)])[moving]
        E = ab[:, :1] * p + ab[:, 1:] * q
        nE = np.linalg.norm(E, axis=1)
        E = E[nE > 1e-12] / nE[nE > 1e-12, None]
        if len(E) == 0:
            continue
        d = E[:, None, 2:3] * x[None] - E[:, None, :2]
        dv = (y - x)[None]
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = np.abs(d[..., 0] * dv[..., 1] - d[..., 1] * dv[..., 0]) / np.linalg.norm(d, axis=-1)
        rho = (dv * d).sum(-1)
        ok = dist < thr
        pos, neg = (ok & (rho > 0)).sum(1), (ok & (rho < 0)).sum(1)
        score = np.maximum(pos, neg)
        b = int(np.argmax(score))
        if score[b] > best[0]:
            best = (score[b], E[b] * (1.0 if pos[b] >= neg[b] else -1.0))
    if best[1] is None:
        return None, np.zeros(len(x), bool)
    return best[1], _support(best[1], x, y, thr)


# --------------------------------------------------------------------------- known translations
def _span_basis(T, tol=COPLANAR_RTOL):
    """Orthonormal basis ``(3, k)`` of the span of the relative translations ``T - T_0``."""
    D = np.asarray(T, float) - np.asarray(T, float)[0]
    if len(D) < 2 or not np.any(D):
        return np.zeros((3, 0))
    _, s, Vt = np.linalg.svd(D, full_matrices=False)
    return Vt[: int(np.sum(s > tol * s[0]))].T


def _fit_A(epi_list, t_list, scale):
    """Least-squares ``M`` (3, k) with ``e_p x (M b_p) = 0`` for normalised epipoles ``e_p``
    and translation coordinates ``b_p``: DLT, right singular vector."""
    return _fit_A_batch(np.asarray(epi_list, float)[None], np.asarray(t_list, float)[None], scale)[0]


def _fit_A_batch(E: np.ndarray, B: np.ndarray, scale: float) -> np.ndarray:
    """:func:`_fit_A` of ``h`` sets at once: epipoles ``E (h, n, 3)``, translation
    coordinates ``B (h, n, k)``; ``(h, 3, k)``. Each pair gives the rows
    ``[e_p]_x (I_3 kron b_p^T)``, i.e. ``[e_p]_x[r, a] b_p[c]`` at column ``a k + c`` of
    ``vec_row(M)``."""
    h, n, k = B.shape
    Hn = np.array([1.0 / scale, 1.0 / scale, 1.0])
    en = E * Hn
    en = en / np.linalg.norm(en, axis=-1, keepdims=True)
    ex = np.zeros((h, n, 3, 3))
    ex[..., 0, 1], ex[..., 0, 2], ex[..., 1, 2] = -en[..., 2], en[..., 1], -en[..., 0]
    ex = ex - np.swapaxes(ex, -1, -2)
    rows = np.einsum("hpra,hpc->hprac", ex, B).reshape(h, n * 3, 3 * k)
    M = least_singular_vector(rows).reshape(h, 3, k)
    return M / Hn[None, :, None]  # back to pixels: e = Hn^-1 M_n b


def _agrees(e_pred, x, y, inliers, thr, min_fraction=0.8):
    """The pair's own inliers are (mostly) explained by the predicted epipole (either sign)."""
    if inliers.sum() == 0:
        return False
    e_pred = e_pred / np.linalg.norm(e_pred)
    xi, yi = x[inliers], y[inliers]
    return max(_support(e_pred, xi, yi, thr).mean(), _support(-e_pred, xi, yi, thr).mean()) >= min_fraction


def _support_counts(E: np.ndarray, x: np.ndarray, y: np.ndarray, thr: float) -> np.ndarray:
    """Matches consistent with each hypothesis ``E (h, 3)`` of either sign (:func:`_support`
    of ``e`` and ``-e``, the larger count): ``(h,)`` int, all hypotheses at once."""
    dx, dy = _directions(E, np.ascontiguousarray(x.T))  # (h, m) each
    vx, vy = np.ascontiguousarray((y - x).T)
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.abs(dx * vy - dy * vx) / np.sqrt(dx * dx + dy * dy)
    on = dist < thr
    moving = (np.linalg.norm(y - x, axis=1) >= MOVING_PX)[None]
    on |= ~moving
    along = dx * vx + dy * vy
    return np.maximum((on & ((along > 0) | ~moving)).sum(1), (on & ((along < 0) | ~moving)).sum(1))


def robust_A(epi: dict, xy: dict, T: np.ndarray, threshold_px: float, scale: float, rng, inliers: dict,
             trials: int = 200) -> tuple[np.ndarray, np.ndarray, list] | None:
    """The robust fit of ``e_ij ~ M B^T (T_j - T_i)`` (``A = M B^T`` on the span ``B (3, k)``
    of the translations) to the pairs' epipoles ``epi {(i, j): e (3,)}``.

    Hypotheses from random minimal sets of pairs (DLT, :func:`_fit_A_batch`) are scored by
    the matches ``xy`` of **all** pairs that their predicted epipoles explain (within
    ``threshold_px``, either sign); the best is refitted on the pairs whose own inliers it
    explains (:func:`_agrees`; ``inliers {(i, j): (m,) bool}`` the pairs' own inliers).

    Returns
    -------
    (M (3, k), B (3, k), consistent pairs), or None (translations spanning less than a
    plane, or too few pairs).
    """
    B = _span_basis(T)
    k = B.shape[1]
    pairs = sorted(p for p, e in epi.items() if e is not None)
    if k < 2 or len(pairs) < k + 2:
        return None
    coords = {p: B.T @ (np.asarray(T[p[1]], float) - T[p[0]]) for p in xy}
    n_min = int(np.ceil((3 * k - 1) / 2))
    subsets = np.array([rng.choice(len(pairs), n_min, replace=False) for _ in range(trials)])
    Ms = _fit_A_batch(np.array([epi[p] for p in pairs])[subsets], np.array([coords[p] for p in pairs])[subsets],
                      scale)
    score = sum(_support_counts(np.einsum("hak,k->ha", Ms, coords[p]), x, y, threshold_px) for p, (x, y) in xy.items())
    best_M = Ms[int(np.argmax(score))]
    consistent = [p for p in pairs if _agrees(best_M @ coords[p], *xy[p], inliers[p], threshold_px)]
    if len(consistent) >= n_min:
        best_M = _fit_A([epi[p] for p in consistent], np.array([coords[p] for p in consistent]), scale)
    return best_M, B, consistent


def fit_translations(geo: dict, xy: dict, T: np.ndarray, threshold_px: float, scale: float, rng,
                     trials: int = 200) -> tuple[dict, list]:
    """Known robot translations: every epipole is ``e_ij ~ A (T_j - T_i)`` with one ``A = K R``.

    ``A`` (restricted to the span of the translations) is fitted robustly to the pairs'
    epipoles (:func:`robust_A`), a hypothesis scored by the matches of **all** pairs that
    its predicted epipoles explain; pairs whose own epipole disagrees (a repetitive
    texture can make a wrong epipole win a pair, consistently for one view, which the
    triplet test cannot see) get the predicted epipole and its inliers.

    Returns the updated ``geo`` and the pairs replaced.
    """
    fit = robust_A({p: g.e for p, g in geo.items() if g.e is not None}, xy, T, threshold_px, scale, rng,
                   {p: g.inliers for p, g in geo.items()}, trials)
    if fit is None:
        return geo, []
    best_M, B, consistent = fit
    out, replaced = dict(geo), []
    for p, (x, y) in xy.items():
        if p in consistent:
            continue
        e = best_M @ (B.T @ (np.asarray(T[p[1]], float) - T[p[0]]))
        e = e / np.linalg.norm(e)
        inl_pos, inl_neg = _support(e, x, y, threshold_px), _support(-e, x, y, threshold_px)
        e, inl = (e, inl_pos) if inl_pos.sum() >= inl_neg.sum() else (-e, inl_neg)
        if inl.sum() >= 4:
            out[p] = _geometry(e, inl, x, y, "translations", threshold_px)
            replaced.append(p)
    return out, replaced
