"""Linking across orientations: the points of each session found in the views of other orientations.

Between views of different orientations the camera (or, eye-to-hand, the object the
robot carries) also rotated, so only the general epipolar geometry holds: for a view
``a`` of a session A and a view ``b`` of another group B, SIFT matches (static ones left
out: the background behind an object carried by the robot) give a fundamental matrix
``F_ab`` (``cv2.findFundamentalMat``, USAC MAGSAC). Every point of A seen in ``a`` is then
**transferred** into ``b``: the local affine map of the verified matches around it
(:func:`~.local.local_affine`: rotation, scale and foreshortening of its patch) predicts
where and how its window appears, and Lucas-Kanade against the window in ``a``
(:func:`~.refine.lk_affine`) finds it, the warp's projective row held at the one the
resected camera and the local slope of the session's inverse depths give
(:func:`_projective_row`: an affine window alone leaves the curvature of the surface's
homography to its centre, a pull of 0.01-0.04 px alike over a view turned 15-45 deg,
which moved the hand-eye translation by about 2 of its std on renders). A transfer is
kept when it correlates with the template, converged, and lies on its epipolar line of
``F_ab``; and

- into a **session** B: when the point's observations in B's views agree with B's own
  pure-translation geometry (every pair on the epipolar lines of B's epipoles) and it is
  seen in at least 2 of them;
- into a **single view** B: when it also lies on its line of ``F_a'b`` from a second view
  ``a'`` of A that sees it.

A point of A found in B's views and a track of B that coincide in every view both see
become one point (:func:`~.checks.merge_duplicates`). Both directions are linked (A into B
and B into A), so a point seeded in either session is linked.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .checks import merge_duplicates
from .detect import match_pair, n_threads
from .epipoles import pair_epipole, residuals
from .frames import LinkInfo
from .local import local_affine, local_linear, plain_window
from .refine import SmoothedImages, lk_affine
from .resect import affine_structure, infinite_homography, interpolate_w, project_structure, resect, session_camera

__all__ = ["link_groups", "fundamental"]

#: A match moving less than this (px) between two orientations is static (the background
#: behind an object carried by the robot) and is left out of the fundamental matrix.
STATIC_LINK_PX = 1.0
#: Fewer verified matches: the view pair is not used for linking.
MIN_LINK_MATCHES = 15


def fundamental(xa: np.ndarray, xb: np.ndarray, threshold_px: float):
    """Fundamental matrix of matches ``xa -> xb`` (USAC MAGSAC): ``(F (3, 3) or None, inliers (m,))``.

    Matches moving less than :data:`STATIC_LINK_PX` are left out (never inliers)."""
    moving = np.linalg.norm(xb - xa, axis=1) >= STATIC_LINK_PX
    inl = np.zeros(len(xa), bool)
    if moving.sum() < MIN_LINK_MATCHES:
        return None, inl
    try:
        F, mask = cv2.findFundamentalMat(xa[moving].astype(np.float64), xb[moving].astype(np.float64),
                                         cv2.USAC_MAGSAC, threshold_px, 0.9999, 5000)
    except cv2.error:  # OpenCV's USAC can fail on degenerate samples
        return None, inl
    if F is None or mask is None or F.shape != (3, 3):
        return None, inl
    inl[np.flatnonzero(moving)[mask.ravel().astype(bool)]] = True
    if inl.sum() < MIN_LINK_MATCHES:
        return None, np.zeros(len(xa), bool)
    return F, inl


def _line_distance(F, xa, xb):
    """Distance (px) of ``xb`` from the epipolar line ``F xa`` of each point."""
    ha = np.column_stack([xa, np.ones(len(xa))])
    L = ha @ F.T
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs((L[:, :2] * xb).sum(1) + L[:, 2]) / np.linalg.norm(L[:, :2], axis=1)
    return np.where(np.isfinite(d), d, np.inf)


class _Pairs:
    """Verified matches and fundamental matrices of view pairs across groups, on demand."""

    def __init__(self, feats, ratio, threshold_px):
        self.feats, self.ratio, self.thr = feats, ratio, threshold_px
        self.cache = {}

    def __call__(self, a: int, b: int):
        """``(F_ab, xa (k, 2), xb (k, 2))`` verified, or None."""
        if (a, b) not in self.cache:
            fa, fb = self.feats[a], self.feats[b]
            m = match_pair(fa.descriptors, fb.descriptors, self.ratio)
            xa, xb = fa.keypoints[m[:, 0]], fb.keypoints[m[:, 1]]
            F, inl = fundamental(xa, xb, self.thr) if len(m) >= MIN_LINK_MATCHES else (None, None)
            self.cache[(a, b)] = None if F is None else (F, xa[inl], xb[inl])
        return self.cache[(a, b)]


def _lk_accept(smoothed, a, b, x, pred, J, opts, shape, max_shift_px, g=None):
    """Affine LK of the windows at ``x`` (view ``a``) into view ``b`` from ``pred`` with the
    warp ``J`` (and the projective row ``g (m, 2)`` held, when given: :func:`~.refine.lk_affine`):
    positions ``(m, 2)``, NaN where not accepted (module docstring)."""
    h, w = shape
    ref = opts.refinement
    margin = ref.window_radius + 2
    out = np.full((len(x), 2), np.nan)
    ok = (np.isfinite(pred).all(1) & np.isfinite(J).all((1, 2)) & (pred[:, 0] >= margin)
          & (pred[:, 0] <= w - 1 - margin) & (pred[:, 1] >= margin) & (pred[:, 1] <= h - 1 - margin))
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return out
    p, M, ncc, min_eig, conv = lk_affine(smoothed.plain(a), smoothed[b], x[idx], pred[idx], J[idx], ref.window_radius,
                                         2 * ref.iterations, None if g is None else g[idx])
    det = np.linalg.det(M)
    good = (conv & (ncc >= ref.min_ncc) & (min_eig > 1.0) & (np.abs(det) > 0.2) & (np.abs(det) < 5.0)
            & (np.linalg.norm(p - pred[idx], axis=1) < max_shift_px))
    out[idx[good]] = p[good]
    return out


def _transfer(smoothed, pairs, x, w, a, b, opts, shape, rng, H=None, rounds: int = 5):
    """Positions ``(m, 2)`` in view ``b`` of the session's points seen at ``x (m, 2)`` in its
    view ``a`` with inverse depths ``w (m,)``, NaN where not found (module docstring).

    ``b`` is resected against the session's affine structure (:func:`~.resect.resect`;
    with ``H``, the infinite homography the flange rotations predict, only the rest)
    from the verified descriptor matches, and each point searched where ``P_b`` puts it,
    with the local affine map of its neighbours' predictions as the starting warp. Across
    a large change of orientation the matches are few and bunched, so without ``H`` the
    camera predicts well only near them: the points go in ``rounds`` batches, nearest to
    the matches first, and ``b`` is resected again from every point found before the next
    batch (then once more for the points missed). Last, ``b`` is resected from the points
    found alone and those farther from its prediction than 4 times the robust spread of
    the others (at least 0.75 px) go: a window that slid along a repetitive texture.
    """
    out = np.full((len(x), 2), np.nan)
    got = pairs(a, b)
    ok = np.isfinite(w)
    if got is None or ok.sum() < 8:
        return out
    _, src_a, src_b = got
    h, wd = shape
    margin = opts.refinement.window_radius + 2
    ok &= (x[:, 0] >= margin) & (x[:, 0] <= wd - 1 - margin) & (x[:, 1] >= margin) & (x[:, 1] <= h - 1 - margin)
    wa = interpolate_w(x[ok], w[ok], src_a)
    P, _ = resect(src_a, wa, src_b, 2 * opts.threshold_px, rng, H=H)
    order = np.flatnonzero(ok)[np.argsort(cKDTree(src_a).query(x[ok])[0], kind="stable")]
    rounds = 1 if H is not None else rounds  # the hint predicts well everywhere: no batches
    batches = np.array_split(order, rounds) if len(order) >= 50 * rounds else [order]
    for batch in batches + [order]:
        todo = batch[~np.isfinite(out[batch, 0])]
        if P is None or len(todo) == 0:
            continue
        pred = project_structure(P, x[ok], w[ok])
        fin = np.isfinite(pred).all(1)
        _, J, res = local_affine(x[ok][fin], pred[fin], x[todo], return_residual=True)
        todo, J = todo[plain_window(J, res)], J[plain_window(J, res)]
        g = _projective_row(P, x[todo], w[todo], x[ok], w[ok])
        out[todo] = _lk_accept(smoothed, a, b, x[todo], project_structure(P, x[todo], w[todo]), J, opts, shape,
                               opts.refinement.max_shift_px, g)
        found = np.isfinite(out[:, 0])
        if found.sum() >= 12:
            P_new, _ = resect(np.vstack([src_a, x[found]]), np.r_[wa, w[found]], np.vstack([src_b, out[found]]),
                              opts.threshold_px, rng, H=H)
            P = P if P_new is None else P_new
    return _agree_with_camera(out, x, w, rng, opts.threshold_px, H)


def _projective_row(P: np.ndarray, x: np.ndarray, w: np.ndarray, xs: np.ndarray, ws: np.ndarray) -> np.ndarray:
    """``g (m, 2)``: the projective row of the homography ``a -> b`` of the surface about
    each point ``x`` (view ``a``, inverse depth ``w``): ``x_b = p + M o / (1 + g . o)``.

    About ``x`` the surface is a plane, ``w + grad w . o`` (the gradient of the session's
    inverse depths ``ws`` at their points ``xs`` around it: :func:`~.local.local_linear`),
    so ``x~_b ~ P (x + o, 1, w + grad w . o)`` and
    ``g = (P[2, :2] + P[2, 3] grad w) / P[2] . (x, 1, w)``; 0 where undefined.
    """
    _, grad = local_linear(xs, ws, x, k=10, gradient=True)
    depth = np.column_stack([x, np.ones(len(x)), w]) @ P[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        g = (P[2, :2][None] + P[2, 3] * np.nan_to_num(grad)) / depth[:, None]
    return np.where(np.isfinite(g), g, 0.0)


def _agree_with_camera(out, x, w, rng, threshold_px, H):
    """The transfers ``out`` that the camera resected from them all predicts within 4 times
    the robust spread of the residuals (at least 0.75 px); the others NaN."""
    found = np.flatnonzero(np.isfinite(out[:, 0]))
    if len(found) < 12:
        out[found] = np.nan
        return out
    P, _ = resect(x[found], w[found], out[found], threshold_px, rng, H=H)
    if P is None:
        out[found] = np.nan
        return out
    r = np.linalg.norm(project_structure(P, x[found], w[found]) - out[found], axis=1)
    limit = max(0.75, 4.0 * 1.4826 * float(np.median(r)))
    out[found[~(r <= limit)]] = np.nan
    return out


def _consistent_in_session(uvB: np.ndarray, epi: dict, thr: float) -> np.ndarray:
    """Observations ``(k, m)`` of points in a session's ``k`` views that agree with its
    pure-translation geometry: per point, the observation off the most epipolar lines of
    the others goes, until all pairs agree; points left in fewer than 2 views go."""
    k, m = uvB.shape[:2]
    keep = np.isfinite(uvB[..., 0])
    for _ in range(k):
        bad = np.zeros((k, m), int)
        for i in range(k):
            for j in range(i + 1, k):
                e = pair_epipole(epi, i, j)
                both = keep[i] & keep[j]
                if e is None or not both.any():
                    continue
                dist, rho = residuals(e, uvB[i, both], uvB[j, both])
                off = ~((dist < thr) & (rho > -1e-9))
                bad[i, np.flatnonzero(both)[off]] += 1
                bad[j, np.flatnonzero(both)[off]] += 1
        worst = np.argmax(bad, axis=0)
        drop = bad[worst, np.arange(m)] > 0
        if not drop.any():
            break
        keep[worst[drop], np.flatnonzero(drop)] = False
    keep[:, keep.sum(0) < 2] = False
    return keep


def _by_support(uv, views):
    """``views`` ordered by how many points they see, most first."""
    return sorted(views, key=lambda v: -int(np.isfinite(uv[v, :, 0]).sum()))


def link_groups(grey, feats, groups, labels, per, epis, opts, rng, report, T=None, rotations=None, derotations=None):
    """One ``uv (n_views, n_points, 2)`` over all views from the sessions' tracks, linked
    across orientations (module docstring).

    Parameters
    ----------
    grey : list of (h, w) float32
    feats : list of Features
    groups : list of list of int
        The views of each orientation group.
    labels : list of str
    per : list of (len(group), m_g, 2) float or None
        Each session's tracks (None for a single view).
    epis : list of dict or None
        Each session's epipoles ``{(i, j): e}`` (session view indices).
    opts : SessionOptions
    rng : Generator
    report : callable ``(stage, done, total)``
    T : (n_views, 3) float, optional
    rotations : (n_views, 3, 3) float, optional
        Flange positions and rotations: with both, each session's camera (its linear
        estimate) and the flange rotations predict the infinite homography to every other
        view (:func:`~.resect.infinite_homography`), a hint for the resection.
    derotations : list of Derotation or None, optional
        Each session's map from image to model pixels (:mod:`.derotate`), where its
        epipoles ``epis`` hold (None: the identity).

    Returns
    -------
    uv : (n_views, n_points, 2) float
    links : list of LinkInfo
    """
    n, shape = len(grey), grey[0].shape[:2]
    blocks, owner = [], []
    for g, (views, uvg) in enumerate(zip(groups, per)):
        if uvg is None:
            continue
        full = np.full((n, uvg.shape[1], 2), np.nan)
        full[views] = uvg
        blocks.append(full)
        owner.append(np.full(uvg.shape[1], g))
    uv = np.concatenate(blocks, axis=1) if blocks else np.zeros((n, 0, 2))
    owner = np.concatenate(owner) if owner else np.zeros(0, int)
    if len(groups) < 2 or uv.shape[1] == 0:
        return uv, []
    smoothed, pairs = SmoothedImages(grey), _Pairs(feats, opts.ratio, opts.threshold_px)
    cams = [None] * len(groups)
    if T is not None and rotations is not None:
        for g, uvg in enumerate(per):
            if uvg is not None and len(groups[g]) >= 4:
                cams[g] = session_camera(uvg, np.asarray(T)[groups[g]], rng=0)
    steps = [(A, B) for A in range(len(groups)) if per[A] is not None for B in range(len(groups)) if B != A]
    for v in range(n):  # built before the threads share them
        smoothed[v]
    with ThreadPoolExecutor(n_threads()) as pool:
        _link_steps(uv, owner, steps, groups, per, epis, cams, rotations, smoothed, pairs, opts, shape, rng, report,
                    pool, derotations or [None] * len(groups))
    uv = merge_duplicates(uv, min_shared=2)  # one common view is no evidence of one point
    return uv, _link_infos(uv, groups, labels, pairs)


def _link_steps(uv, owner, steps, groups, per, epis, cams, rotations, smoothed, pairs, opts, shape, rng, report, pool,
                derots):
    """The points of session ``A`` found in the views of group ``B``, for every step
    ``(A, B)``, written into ``uv`` (the views of ``B`` on the threads of ``pool``); the
    sessions' epipolar geometry judged in their model pixels (``derots``)."""

    def model(g, uvg):
        return uvg if derots[g] is None else derots[g].uv_to_model(uvg)

    for k, (A, B) in enumerate(steps):
        pts = np.flatnonzero(owner == A)
        a1 = _by_support(uv[:, pts], groups[A])[0]
        # points seen in 3+ views of A (when it has them): their depth is checked in several views
        need = min(3, len(groups[A]))
        in_a1 = np.flatnonzero(np.isfinite(uv[a1, pts, 0]) & (np.isfinite(uv[groups[A]][:, pts, 0]).sum(0) >= need))
        w = affine_structure(model(A, uv[groups[A]][:, pts]), epis[A] or {}, groups[A].index(a1), in_a1)
        found = np.full((len(groups[B]), len(pts), 2), np.nan)

        def into(b, seed, A=A, a1=a1, pts=pts, in_a1=in_a1, w=w):
            sel = ~np.isfinite(uv[b, pts[in_a1], 0])
            H = None if cams[A] is None else infinite_homography(cams[A], rotations[a1], rotations[b])
            return sel, _transfer(smoothed, pairs, uv[a1, pts[in_a1[sel]]], w[sel], a1, b, opts, shape,
                                  np.random.default_rng(seed), H=H)

        seeds = rng.integers(2**32, size=len(groups[B]))  # one stream per view: the same result on any thread
        for bi, (sel, got) in enumerate(pool.map(into, groups[B], seeds)):
            found[bi, in_a1[sel]] = got
        if len(groups[B]) > 1:
            keep = _consistent_in_session(model(B, found), epis[B] or {}, opts.threshold_px)
            found[~keep] = np.nan
        for bi, b in enumerate(groups[B]):
            new = np.isfinite(found[bi, :, 0])
            uv[b, pts[new]] = found[bi, new]
        report("link", k + 1, len(steps))


def _link_infos(uv, groups, labels, pairs) -> list[LinkInfo]:
    seen = np.isfinite(uv[..., 0])
    in_group = [seen[v].any(axis=0) for v in groups]
    out = []
    for A in range(len(groups)):
        for B in range(A + 1, len(groups)):
            got = [pairs.cache.get((a, b)) or pairs.cache.get((b, a)) for a in groups[A] for b in groups[B]]
            n_m = max([len(g[1]) for g in got if g is not None], default=0)
            out.append(LinkInfo(groups=(str(labels[A]), str(labels[B])), n_matches=int(n_m),
                                n_links=int((in_group[A] & in_group[B]).sum())))
    return out
