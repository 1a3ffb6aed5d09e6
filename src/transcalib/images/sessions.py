"""Tracking across sessions: several groups of views, one camera orientation per group.

Inside a **session** (views with one flange orientation) the camera only translates,
so :func:`transcalib.images.track` tracks it with the pure-translation epipolar
geometry ``F = [e]x``. Between sessions the camera also rotated (by ``R_X^T dR R_X``
with the hand-eye rotation ``R_X`` unknown), so matches need the general epipolar
geometry: :func:`track_sessions` matches SIFT descriptors between the sessions'
reference views (their first views), verifies them with a fundamental-matrix RANSAC
(``cv2.findFundamentalMat`` with ``cv2.USAC_MAGSAC``), and links the tracks whose
reference observations those verified matches hit. Linked tracks become one point,
shared by the sessions (issue 11 item 2); unlinked tracks stay points of their session.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..errors import DegenerateError, InputError
from .dispatch import track
from .features import _match_pair, _to_u8, _union_find
from .frames import Tracks, load_images

__all__ = ["track_sessions"]


def track_sessions(images, session_of_view, *, link_ratio: float = 0.8, link_threshold_px: float = 1.5,
                   snap_px: float = 1.5, min_links: int = 8, T=None, rng=0, **track_options) -> Tracks:
    """Track views taken in several sessions (orientations) and link the sessions.

    Parameters
    ----------
    images : sequence of path or array, or array (n_views, h, w[, 3])
        All views, in the order of the robot poses.
    session_of_view : (n_views,) int or str
        Session label of each view; views with one label share one orientation.
    link_ratio : float
        Lowe's ratio for the SIFT matches between sessions' reference views.
    link_threshold_px : float
        Sampson-distance threshold of the fundamental-matrix RANSAC (pixels).
    snap_px : float
        A verified match links the tracks whose reference observations lie within
        this many pixels of its two ends (the nearest ones).
    min_links : int
        A session pair with fewer verified links is not linked (its points stay apart);
        if no pair links, :class:`DegenerateError`.
    T : (n_views, 3) float, optional
        Robot translations of all views; each session's rows go to its tracker
        (``track(..., T=)``: epipoles checked against the known translations).
    rng : seed or Generator
        For the pure-translation tracker of each session.
    **track_options
        Passed to :func:`transcalib.images.track` for each session.

    Returns
    -------
    Tracks
        ``uv (n_views, n_points, 2)`` over all views; a linked point has observations in
        several sessions. ``info["sessions"]``: per session its views and track count;
        ``info["links"]``: verified links per session pair ``"a-b"``;
        ``info["n_shared_points"]``: points seen in two or more sessions.

    Raises
    ------
    InputError
        ``session_of_view`` of the wrong length, or a session with fewer than 2 views.
    DegenerateError
        A session cannot be tracked, or no two sessions share enough points.
    """
    t0 = time.perf_counter()
    grey, rgb, names = load_images(images)
    labels, groups = _sessions(session_of_view, len(grey))
    if T is not None:
        T = np.asarray(T, float)
        if T.shape != (len(grey), 3):
            raise InputError(f"track_sessions: T must be ({len(grey)}, 3), got {T.shape}")
    per = []
    for s, views in enumerate(groups):
        try:
            T_s = None if T is None else T[views]
            per.append(track([grey[v] for v in views], T=T_s, rng=rng, **track_options))
        except DegenerateError as exc:
            raise DegenerateError(f"session {labels[s]!r} (views {views}): {exc}") from exc
    feats = [_sift(grey[views[0]]) for views in groups]
    links, n_links = {}, {}
    for a in range(len(groups)):
        for b in range(a + 1, len(groups)):
            pairs = _link(feats[a], feats[b], per[a], per[b], link_ratio, link_threshold_px, snap_px)
            n_links[f"{labels[a]}-{labels[b]}"] = len(pairs)
            if len(pairs) >= min_links:
                links[(a, b)] = pairs
    if len(groups) > 1 and not links:
        raise DegenerateError(
            f"no two sessions share enough points (verified links per session pair: {n_links}, need >= {min_links}): "
            "keep part of the scene in view across orientations, turn the wrist less between sessions, or use a "
            "better-textured scene")
    uv = _merge(per, groups, links, len(grey))
    nsess = np.zeros(uv.shape[1], int)
    for views in groups:
        nsess += np.isfinite(uv[views, :, 0]).any(axis=0)
    info = {"sessions": {str(labels[s]): {"views": views, "n_tracks": per[s].n_points}
                         for s, views in enumerate(groups)},
            "links": n_links, "n_shared_points": int((nsess >= 2).sum()),
            "session_info": [t.info for t in per], "time_s": {"total": time.perf_counter() - t0}}
    return Tracks(uv=uv, ids=np.arange(uv.shape[1]), colors=None, view_names=names, info=info)


def _sessions(session_of_view, n_views):
    """Labels in order of first appearance and the views of each: ``(labels, groups)``."""
    lab = list(np.asarray(session_of_view).tolist())
    if len(lab) != n_views:
        raise InputError(f"track_sessions: session_of_view has {len(lab)} entries for {n_views} views; "
                         "give one session label per view")
    labels = list(dict.fromkeys(lab))
    groups = [[i for i, x in enumerate(lab) if x == s] for s in labels]
    small = [f"{s!r} ({len(g)} view)" for s, g in zip(labels, groups) if len(g) < 2]
    if small:
        raise InputError(f"track_sessions: every session needs >= 2 views (pure translations); got {', '.join(small)}")
    return labels, groups


def _sift(grey):
    """SIFT keypoints ``(n, 2)`` and descriptors ``(n, 128)`` of one view."""
    sift = cv2.SIFT_create(nfeatures=4000, contrastThreshold=0.02)
    kps, desc = sift.detectAndCompute(_to_u8(grey), None)
    pts = np.array([k.pt for k in kps], float).reshape(-1, 2)
    return pts, (desc if desc is not None else np.zeros((0, 128), np.float32))


def _link(fa, fb, ta, tb, ratio, threshold_px, snap_px):
    """Verified track links ``(k, 2)`` (track of session a, track of session b).

    SIFT matches between the sessions' reference views, kept when a fundamental matrix
    (USAC MAGSAC) explains them; each end is snapped to the nearest track observed in
    that reference view (within ``snap_px``); a track linked twice keeps its best link.
    """
    m = _match_pair(fa[1], fb[1], ratio)
    if len(m) < 15:
        return np.zeros((0, 2), int)
    xa, xb = fa[0][m[:, 0]], fb[0][m[:, 1]]
    F, mask = cv2.findFundamentalMat(xa, xb, cv2.USAC_MAGSAC, threshold_px, 0.9999, 5000)
    if F is None or mask is None or F.shape != (3, 3):
        return np.zeros((0, 2), int)
    ok = mask.ravel().astype(bool)
    xa, xb = xa[ok], xb[ok]
    ia, da = _snap(ta.uv[0], xa)
    ib, db = _snap(tb.uv[0], xb)
    good = (da < snap_px) & (db < snap_px)
    pairs, cost = np.column_stack([ia[good], ib[good]]), (da + db)[good]
    order = np.argsort(cost, kind="stable")  # one link per track: best first
    pairs = pairs[order]
    _, first_a = np.unique(pairs[:, 0], return_index=True)
    pairs = pairs[np.sort(first_a)]
    _, first_b = np.unique(pairs[:, 1], return_index=True)
    return pairs[np.sort(first_b)]


def _snap(ref_uv, x):
    """Nearest track (index, distance) to each point ``x`` among tracks seen at ``ref_uv``."""
    seen = np.flatnonzero(np.isfinite(ref_uv[:, 0]))
    if len(seen) == 0:
        return np.zeros(len(x), int), np.full(len(x), np.inf)
    d, k = cKDTree(ref_uv[seen]).query(x)
    return seen[k], d


def _merge(per, groups, links, n_views):
    """One ``uv (n_views, n_points, 2)``: tracks linked (union-find, at most one track
    per session in a point) into shared points; the others as they are."""
    offsets = np.cumsum([0] + [t.n_points for t in per])
    node_session = np.concatenate([np.full(t.n_points, s) for s, t in enumerate(per)])
    E = [np.column_stack([offsets[a] + p[:, 0], offsets[b] + p[:, 1]]) for (a, b), p in links.items()]
    E = np.vstack(E) if E else np.zeros((0, 2), int)
    label, _ = _union_find(E, node_session, len(node_session))
    label = np.where(label >= 0, label, np.arange(len(node_session)))  # unlinked: own point
    _, point = np.unique(label, return_inverse=True)
    uv = np.full((n_views, point.max() + 1 if len(point) else 0, 2), np.nan)
    for s, (t, views) in enumerate(zip(per, groups)):
        uv[np.asarray(views)[:, None], point[offsets[s]:offsets[s + 1]][None, :]] = t.uv
    return uv
