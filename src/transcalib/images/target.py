"""Target mode (``--target squares``): corners of dark squares on a light board.

As in the paper's experiment, each corner is the intersection of two lines fitted to the
sides of a square:

1. dark blobs (Otsu threshold) whose outline is a convex quadrilateral with a clearly
   lighter surround are candidate squares;
2. along every side, intensity profiles across the edge are sampled (bicubic, sub-pixel
   steps) and the edge point is where the profile crosses the mean of its dark and
   light levels - unbiased for a symmetric blur, whatever its width;
3. a line is fitted to each side's edge points (total least squares, outliers
   removed) - a parabola where lens distortion visibly bows the side - and adjacent
   sides are intersected;
4. squares are labelled consistently across views: in the reference view (the one with
   the most squares) by rows (top to bottom) then columns (left to right); in every
   other view by the image translation that superimposes most square centres (pure
   translation moves the board without rotating it), refined by an affine fit and an
   optimal assignment. Point id = ``4 * square + corner``; corners go around each square
   in image order starting from the top-left.

Keep the board unsaturated: clipped whites pull the corners inwards (docs/images.md).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from .frames import TrackInfo, Tracks, load_images, progress_fn
from ..types import DegenerateError, InputError

__all__ = ["track_squares"]


def _side_lines(img, quads, n_samples=24, step=0.2):
    """Refine each side of each quad to a line ``(a, b, c)``, ``a u + b v + c = 0``.

    quads : (m, 4, 2) initial corners (any order around the quad).
    Returns lines (m, 4, 3) (side k from corner k to k+1), residual rms (m, 4).
    """
    m = len(quads)
    P0 = quads
    P1 = np.roll(quads, -1, axis=1)
    L = np.linalg.norm(P1 - P0, axis=-1)  # (m, 4)
    tdir = (P1 - P0) / L[..., None]
    nrm = np.stack([-tdir[..., 1], tdir[..., 0]], axis=-1)
    half = np.clip(0.12 * L.min(axis=1), 1.5, 6.0)[:, None, None]  # profile half-length (px)
    lines = np.zeros((m, 4, 3))
    rms = np.zeros((m, 4))
    ts = np.linspace(0.15, 0.85, n_samples)
    offs = np.linspace(-1.0, 1.0, 41)  # in units of ``half``
    base = P0[:, :, None, :] + ts[None, None, :, None] * (P1 - P0)[:, :, None, :]  # (m,4,S,2)
    for _ in range(2):
        # sample profiles: (m, 4, S, O)
        pu = base[..., None, 0] + nrm[:, :, None, None, 0] * (offs[None, None, None, :] * half[..., None])
        pv = base[..., None, 1] + nrm[:, :, None, None, 1] * (offs[None, None, None, :] * half[..., None])
        prof = cv2.remap(img, pu.reshape(-1, len(offs)).astype(np.float32), pv.reshape(-1, len(offs)).astype(np.float32),
                         cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE).reshape(pu.shape).astype(float)
        k = max(2, len(offs) // 8)
        lo = prof[..., :k].mean(-1)
        hi = prof[..., -k:].mean(-1)
        mid = 0.5 * (lo + hi)
        # crossing nearest the centre: sign changes of prof - mid
        s = np.sign(prof - mid[..., None])
        change = s[..., :-1] * s[..., 1:] <= 0
        idx = np.arange(len(offs) - 1)
        centre = (len(offs) - 2) / 2.0
        dist = np.where(change, np.abs(idx - centre), np.inf)
        j = np.argmin(dist, axis=-1)
        found = np.isfinite(np.min(dist, axis=-1)) & (np.abs(hi - lo) > 10.0)
        p_a = np.take_along_axis(prof, j[..., None], -1)[..., 0]
        p_b = np.take_along_axis(prof, (j + 1)[..., None], -1)[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            frac = np.clip((mid - p_a) / (p_b - p_a), 0.0, 1.0)
        off = (offs[j] + frac * (offs[1] - offs[0])) * half
        pts = base + off[..., None] * nrm[:, :, None, :]  # (m,4,S,2)
        # TLS line per side, two passes with outlier removal
        w = found.astype(float)
        for _pass in range(2):
            ws = np.maximum(w.sum(-1, keepdims=True), 1e-9)
            c = (pts * w[..., None]).sum(-2) / ws
            d = (pts - c[..., None, :]) * np.sqrt(w)[..., None]
            cov = np.einsum("mksa,mksb->mkab", d, d)
            evals, evecs = np.linalg.eigh(cov)
            nvec = evecs[..., :, 0]  # normal: smallest eigenvalue
            r = np.einsum("mksa,mka->mks", pts - c[..., None, :], nvec)
            sig = np.sqrt((w * r**2).sum(-1) / ws[..., 0])
            w = found & (np.abs(r) <= np.maximum(3.0 * sig[..., None], 0.05))
            w = w.astype(float)
        lines = np.concatenate([nvec, -np.einsum("mka,mka->mk", nvec, c)[..., None]], axis=-1)
        rms = sig
        # re-centre the sampling on the fitted line for the next iteration
        dist_to_line = np.einsum("mksa,mka->mks", base, nvec) + lines[..., 2][..., None]
        base = base - dist_to_line[..., None] * nvec[:, :, None, :]
        nrm = nvec * np.sign(np.einsum("mka,mka->mk", nvec, nrm))[..., None]
    return lines, rms, found.sum(-1), pts, w


def _order_corners(q):
    """Order the 4 corners of each quad ``(m, 4, 2)`` by angle around its centre (image
    order, y down: top-left, top-right, bottom-right, bottom-left for an upright square)."""
    c = q.mean(1, keepdims=True)
    ang = np.arctan2(q[..., 1] - c[..., 1], q[..., 0] - c[..., 0])
    o = np.argsort(ang, axis=1)
    q = np.take_along_axis(q, o[..., None], 1)
    # start at the corner with the smallest u + v (top-left)
    start = np.argmin(q[..., 0] + q[..., 1], axis=1)
    idx = (start[:, None] + np.arange(4)[None]) % 4
    return np.take_along_axis(q, idx[..., None], 1)


def detect_squares(image, *, min_side_px: float = 8.0, max_rms_px: float = 0.5, curved: bool = True,
                   min_sagitta_px: float = 0.05) -> np.ndarray:
    """Sub-pixel corners of the dark squares in one grey image.

    Parameters
    ----------
    image : (h, w) array
        Grey image (0..255).
    min_side_px : float
        Smallest square side to accept (pixels).
    max_rms_px : float
        Largest rms distance of a side's edge points from its fitted line.
    curved : bool
        Model sides bent by lens distortion as parabolas where their bow exceeds
        ``min_sagitta_px`` (pixels); straight lines otherwise.

    Returns
    -------
    corners : (n_squares, 4, 2) float
        Corners of each square (intersections of the fitted side lines), ordered around
        the square starting from the top-left; pixel (0, 0) is the centre of the
        top-left pixel.
    """
    img = np.ascontiguousarray(np.asarray(image, np.float32))
    if img.ndim != 2:
        raise InputError(f"detect_squares: expected a grey (h, w) image, got shape {img.shape}")
    u8 = np.clip(np.rint(cv2.GaussianBlur(img, (0, 0), 1.0)), 0, 255).astype(np.uint8)
    _, dark = cv2.threshold(u8, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)
    # a local threshold as well, for uneven lighting (a global one can merge the squares
    # with a dark background); candidates of both are pooled and de-duplicated
    block = max(15, (min(img.shape) // 6) | 1)
    dark_local = cv2.adaptiveThreshold(u8, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, block, 15)
    quads = []
    for mask in (dark, dark_local):
        quads += _quads_from_mask(mask, min_side_px)
    if quads:
        c = np.array([q.mean(0) for q in quads])
        size = np.array([np.linalg.norm(q[0] - q[2]) for q in quads])
        keep = []
        for k in range(len(quads)):  # few candidates
            if all(np.linalg.norm(c[k] - c[m]) > 0.3 * size[k] for m in keep):
                keep.append(k)
        quads = [quads[k] for k in keep]
    if not quads:
        return np.zeros((0, 4, 2))
    q = _order_corners(np.array(quads))
    q = q[_isolated_dark(img, q)]
    if len(q) == 0:
        return np.zeros((0, 4, 2))
    # a slight symmetric blur makes sharp edges smooth enough for bicubic profiles (no bias)
    lines, rms, nfound, pts, w = _side_lines(cv2.GaussianBlur(img, (0, 0), 1.0), q)
    ok = np.all(rms < max_rms_px, axis=1) & np.all(nfound >= 8, axis=1)
    # corners: intersection of side k-1 and side k
    prev = np.roll(lines, 1, axis=1)
    X = np.cross(prev, lines)
    with np.errstate(divide="ignore", invalid="ignore"):
        corners = X[..., :2] / X[..., 2:3]
    if curved:
        corners = _curved_corners(corners, lines, pts, w, min_sagitta_px)
    ok &= np.all(np.isfinite(corners), axis=(1, 2)) & np.all(np.linalg.norm(corners - q, axis=-1) < 3.0, axis=1)
    return corners[ok]


def _curved_corners(corners, lines, pts, w, min_sagitta_px):
    """Corners as intersections of parabolas fitted to the sides' edge points.

    Lens distortion bends straight sides; where a side's fitted bow (sagitta) exceeds
    ``min_sagitta_px``, its edge is modelled as ``o = a + b tau + c tau^2`` in the line's
    frame (``tau`` along, ``o`` across), and the two curves of each corner are intersected
    by Newton's method from the straight-line corner. Other sides stay straight.
    """
    n = lines[..., :2]  # (m, 4, 2) unit normals
    t = np.stack([-n[..., 1], n[..., 0]], axis=-1)
    c0 = -lines[..., 2:3] * n  # a point on each line
    rel = pts - c0[:, :, None, :]
    tau = np.einsum("mksa,mka->mks", rel, t)
    off = np.einsum("mksa,mka->mks", rel, n)
    A = np.stack([np.ones_like(tau), tau, tau**2], axis=-1)
    Aw = A * w[..., None]
    H = np.einsum("mksa,mksb->mkab", Aw, A) + 1e-9 * np.eye(3)
    coef = np.linalg.solve(H, np.einsum("mksa,mks->mka", Aw, off)[..., None])[..., 0]  # (m, 4, 3)
    span = np.where(w > 0, tau, np.nan)
    half = 0.5 * (np.nanmax(span, axis=-1) - np.nanmin(span, axis=-1))
    # significant bow only: above min_sagitta_px and 4 standard errors (noise must not bend sides)
    resid = off - np.einsum("mksa,mka->mks", A, coef)
    dof = np.maximum(w.sum(-1) - 3, 1)
    sig2 = (w * resid**2).sum(-1) / dof
    var_c = sig2 * np.linalg.inv(H)[..., 2, 2]
    sag, sag_se = np.abs(coef[..., 2]) * half**2, np.sqrt(var_c) * half**2
    bowed = (sag > min_sagitta_px) & (sag > 4.0 * sag_se)
    coef = np.where(bowed[..., None], coef, np.concatenate([np.zeros_like(coef[..., :2]), np.zeros_like(coef[..., :1])],
                                                           axis=-1))
    if not bowed.any():
        return corners
    p = corners.copy()
    sides = [np.roll(np.arange(4), 1), np.arange(4)]  # corner k: sides k-1 and k
    for _ in range(6):
        G, J = [], []
        for s in sides:
            ns, ts, cs, cf = n[:, s], t[:, s], c0[:, s], coef[:, s]
            r = p - cs
            ta = np.einsum("mka,mka->mk", r, ts)
            G.append(np.einsum("mka,mka->mk", r, ns) - (cf[..., 0] + cf[..., 1] * ta + cf[..., 2] * ta**2))
            J.append(ns - (cf[..., 1] + 2 * cf[..., 2] * ta)[..., None] * ts)
        G = np.stack(G, axis=-1)  # (m, 4, 2)
        J = np.stack(J, axis=-2)  # (m, 4, 2, 2)
        with np.errstate(all="ignore"):
            step = np.linalg.solve(J + 1e-12 * np.eye(2), G[..., None])[..., 0]
        p = p - np.nan_to_num(step)
    return p


def _quads_from_mask(mask, min_side_px):
    """Convex quadrilateral blobs of a binary mask: list of (4, 2) corner arrays."""
    contours, _ = cv2.findContours(mask, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    quads = []
    for cnt in contours:  # one per blob: few, not a per-point hot path
        area = cv2.contourArea(cnt)
        if area < min_side_px**2:
            continue
        peri = cv2.arcLength(cnt, True)
        approx = cv2.approxPolyDP(cnt, 0.04 * peri, True)
        if len(approx) != 4 or not cv2.isContourConvex(approx):
            continue
        hull = cv2.contourArea(cv2.convexHull(cnt))
        if hull <= 0 or area / hull < 0.9:
            continue
        q = approx.reshape(4, 2).astype(float)
        sides = np.linalg.norm(q - np.roll(q, -1, 0), axis=1)
        if sides.min() < min_side_px or sides.min() < 0.25 * sides.max():
            continue
        quads.append(q)
    return quads


def _isolated_dark(img, q, min_contrast=30.0):
    """Quads ``(m, 4, 2)`` that are dark inside with a uniformly light ring around them
    (rejects checkerboard cells, whose diagonal neighbours are dark, and texture blobs)."""
    c = q.mean(1, keepdims=True)
    t = np.linspace(0.0, 1.0, 12, endpoint=False)

    def perimeter(scale):
        qq = c + scale * (q - c)
        a, b = qq, np.roll(qq, -1, axis=1)
        return (a[:, :, None, :] + t[None, None, :, None] * (b - a)[:, :, None, :]).reshape(len(q), -1, 2)

    ring = perimeter(1.45)
    inner = np.concatenate([perimeter(0.3), perimeter(0.6)], axis=1)
    pts = np.concatenate([ring, inner], axis=1)
    vals = cv2.remap(img, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).astype(float)
    r, i = vals[:, :ring.shape[1]], vals[:, ring.shape[1]:]
    im = np.median(i, axis=1)
    rm = np.median(r, axis=1)
    ok = (rm - im > min_contrast) & (np.min(r, axis=1) > im + 0.6 * (rm - im)) & (np.max(i, axis=1) < im + 0.4 * (rm - im))
    if ok.sum() >= 3:
        # the target's squares are alike: drop odd ones out (texture blobs) by size and contrast
        d1, d2 = q[:, 2] - q[:, 0], q[:, 3] - q[:, 1]
        size = np.sqrt(np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / 2.0)  # sqrt(area)
        ms, mc = np.median(size[ok]), np.median((rm - im)[ok])
        ok &= (size > 0.5 * ms) & (size < 2.0 * ms) & (rm - im > 0.5 * mc)
    return ok


def _row_order(centres, size):
    """Label squares by rows (top to bottom) then columns (left to right)."""
    o = np.argsort(centres[:, 1])
    rows = np.cumsum(np.r_[0, np.diff(centres[o, 1]) > 0.5 * size])
    row_of = np.empty(len(o), int)
    row_of[o] = rows
    return np.lexsort((centres[:, 0], row_of))


def track_squares(images, *, min_side_px: float = 8.0, min_squares: int = 2, progress=None) -> Tracks:
    """Corners of a board of dark squares, labelled consistently across views.

    Parameters
    ----------
    images : sequence of path or array
        The views (see :func:`transcalib.tracks.load_images`).
    min_side_px : float
        Smallest square side (pixels).
    min_squares : int
        Fewer squares found in the reference view raises :class:`DegenerateError`.
    progress : None, True or callable
        Called with a :class:`~transcalib.types.ProgressEvent` after each view; ``True``
        prints to stderr.

    Returns
    -------
    Tracks
        ``uv (n_views, 4 * n_squares, 2)``; ``ids = 4 * square + corner``.
    """
    grey, rgb, names = load_images(images)
    n = len(grey)
    step = progress_fn(progress)
    per_view = []
    for i, g in enumerate(grey):
        per_view.append(detect_squares(g, min_side_px=min_side_px))
        step("detect squares", i + 1, n)
    counts = [len(c) for c in per_view]
    r = int(np.argmax(counts))
    if counts[r] < min_squares:
        raise DegenerateError(
            f"target mode found at most {counts[r]} dark squares in one image (per view: {counts}); need >= "
            f"{min_squares}. Check that the board of black squares on white is fully visible, sharp and "
            "well lit, with squares at least ~10 px wide, or use tracking of a textured scene instead")
    ref = per_view[r]
    cref = ref.mean(1)
    size = float(np.median(np.linalg.norm(ref[:, 0] - ref[:, 2], axis=1))) / np.sqrt(2)
    order = _row_order(cref, size)
    ref, cref = ref[order], cref[order]
    n_sq = len(ref)
    uv = np.full((n, 4 * n_sq, 2), np.nan)
    uv[r] = ref.reshape(-1, 2)
    for i in range(n):
        if i == r or len(per_view[i]) == 0:
            continue
        sq = per_view[i]
        c = sq.mean(1)
        assign = _assign(cref, c, size)
        for a, b in assign:  # few squares
            mapped = sq[b]
            # cyclic order of corners nearest to the reference square shifted by the centre offset
            pred = ref[a] - cref[a] + c[b]
            best = min(range(4), key=lambda k: np.linalg.norm(np.roll(mapped, -k, 0) - pred, axis=1).sum())
            uv[i, 4 * a:4 * a + 4] = np.roll(mapped, -best, 0)
    seen = np.isfinite(uv[..., 0]).sum(0)
    keep = seen >= 2
    ids = np.arange(4 * n_sq)[keep]
    uv = uv[:, keep]
    if uv.shape[1] < 4:
        raise DegenerateError(f"target mode: squares could be matched in fewer than 2 views (per view: {counts}); "
                              "keep the board in view in every image")
    return Tracks(uv=uv, ids=ids, colors=None, view_names=names,
                  info=TrackInfo(method="squares", squares_per_view=tuple(counts)))


def _assign(cref, c, size):
    """Match square centres ``c`` of a view to reference centres ``cref``: ``[(a, b)]``."""
    best, best_t = -1, np.zeros(2)
    for a in range(len(cref)):  # hypotheses: translation taking ref square a to square b
        for b in range(len(c)):
            t = c[b] - cref[a]
            d = np.linalg.norm((cref + t)[:, None] - c[None], axis=-1)
            score = int((d.min(1) < 0.5 * size).sum())
            if score > best:
                best, best_t = score, t
    pred = cref + best_t
    match = np.linalg.norm(pred[:, None] - c[None], axis=-1)
    a, b = linear_sum_assignment(match)
    ok = match[a, b] < 0.5 * size
    a, b = a[ok], b[ok]
    if len(a) >= 3:  # affine refinement handles scale change (forward motion)
        Ah = np.column_stack([cref[a], np.ones(len(a))])
        Maff = np.linalg.lstsq(Ah, c[b], rcond=None)[0]
        pred = np.column_stack([cref, np.ones(len(cref))]) @ Maff
        match = np.linalg.norm(pred[:, None] - c[None], axis=-1)
        a, b = linear_sum_assignment(match)
        ok = match[a, b] < 0.5 * size
        a, b = a[ok], b[ok]
    return list(zip(a.tolist(), b.tolist()))
