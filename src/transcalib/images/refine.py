"""Refinement: every observation aligned to its track's reference view, to a few hundredths of a pixel.

Lucas-Kanade with an affine warp and an affine brightness model, batched Gauss-Newton over
all observations of a view pair at once (:func:`lk_affine`): the template is a window around
the track's reference observation (Gaussian weights), the warp
``x_tgt = p + M o`` for template offsets ``o`` (across orientations a homography
``p + M o / (1 + g . o)`` with its projective row ``g`` given, :mod:`.link`),
photometric ``(a + d . o) I_tgt + b + c . o``; images are
smoothed with a Gaussian of sigma 1 and sampled bicubically (image and gradients in one
``cv2.remap`` of a three-channel image) at positions moved within their pixel so that the
interpolation is exact for linear functions (:func:`exact_for_ramps`: OpenCV's kernel
shifted them by up to 0.048 px with the fraction of a pixel, 0.04-0.05 px RMS of every
alignment; renders' median track error 0.035 -> 0.013-0.016 px). The affine part models
the change of scale and foreshortening between the views (its start ``(1 + rho e3) I`` comes from the epipole),
the gain and offset exposure changes, the ramp ``c`` a brightness gradient across the
window that differs between the views (shading, vignetting: with gain and offset alone
it pulled the alignment by a few thousandths of a pixel, alike over a view, which the
calibration's std does not see; renders of a perfect robot: fx's std / RMS error 0.56,
with the ramp 0.82, ``benchmarks/bench_render_floor.py``), and the gain's own gradient
``d`` a brightness change that multiplies the texture (vignetting; without it each
view's tracks came out scaled about the image centre by a few 1e-6 on renders, which
leaned a session's fx by about one std; with it the lean halved and the single views'
hand-eye t_z lean under every camera effect went, docs/uncertainty.md section 6). A step that reverses the previous one is halved
(steps that ring about the optimum converge). An observation is dropped when it does not
converge, correlates poorly with its template, moves too far, distorts the window
implausibly, lies on too weak a texture, or is too near the border.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from .detect import n_threads
from .epipoles import pair_epipole, residuals

__all__ = ["RefineOptions", "SmoothedImages", "exact_for_ramps", "lk_affine", "refine_to_reference"]


#: Observations per task of :func:`refine_to_reference` (a few tenths of a second of work).
TASK_SIZE = 512


@dataclass(frozen=True)
class RefineOptions:
    """Acceptance rules of :func:`refine_to_reference`.

    Attributes
    ----------
    window_radius : int
        Half-size of the window (px).
    min_ncc : float
        Smallest weighted normalised cross-correlation with the template.
    max_shift_px : float
        Largest move from the starting position.
    iterations : int
        Gauss-Newton steps, at most.
    """

    window_radius: int = 8
    min_ncc: float = 0.9
    max_shift_px: float = 4.0
    iterations: int = 12


class SmoothedImages:
    """Per view: the image smoothed with sigma 1 and its gradients, as one three-channel
    float32 image (``[I, dI/dx, dI/dy]``), and the smoothed image alone (:meth:`plain`:
    the templates' source), built on first use."""

    def __init__(self, grey: list):
        self.grey = grey
        self._cache = {}

    def _build(self, v: int) -> tuple:
        if v not in self._cache:
            sm = cv2.GaussianBlur(np.asarray(self.grey[v], np.float32), (0, 0), 1.0)
            gx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3, scale=1 / 8)
            gy = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3, scale=1 / 8)
            self._cache[v] = (cv2.merge([sm, gx, gy]), sm)
        return self._cache[v]

    def __getitem__(self, v: int) -> np.ndarray:
        return self._build(v)[0]

    def plain(self, v: int) -> np.ndarray:
        """``(h, w)`` float32: the smoothed image of view ``v``."""
        return self._build(v)[1]

    def shape(self) -> tuple[int, int]:
        return self.grey[0].shape[:2]


def _ramp_table(steps: int) -> np.ndarray:
    """``psi(t)`` at ``t = k / steps``, ``k = 0 .. steps`` (float32): where OpenCV's bicubic
    interpolation must sample within a pixel to return a linear function's value at ``t``.

    Its kernel (Keys' cubic convolution with ``a = -0.75``) interpolates a ramp
    ``f(k) = k`` at the fraction ``t`` as ``phi(t) = t - u (1/4 - u^2)``, ``u = t - 1/2``:
    up to 0.048 px off, alike for the image and its gradients. ``psi = phi^-1``:
    ``psi = 1/2 + v`` with ``v`` the real root of ``v^3 + 3/4 v = u`` (Cardano).
    """
    u = np.linspace(0.0, 1.0, steps + 1) - 0.5
    root = np.sqrt(u * u / 4 + 1 / 64)  # (p / 3)^3 = 1/64 for p = 3/4
    return (0.5 + np.cbrt(u / 2 + root) + np.cbrt(u / 2 - root)).astype(np.float32)


#: Steps of :data:`RAMP_TABLE` per pixel: positions land within 2e-5 px of ``psi``.
RAMP_STEPS = 1 << 15
RAMP_TABLE = _ramp_table(RAMP_STEPS)


def exact_for_ramps(x: np.ndarray) -> np.ndarray:
    """Sample positions ``x`` (float, any shape) moved within their pixel (float32) so
    that OpenCV's bicubic interpolation returns every linear function exactly
    (:func:`_ramp_table`). The alignment's error on an exactly shifted image falls from
    0.053 to 0.019 px RMS (Lanczos-4 interpolation: 0.015, at 12 times the cost)."""
    x = np.asarray(x, np.float32)
    base = np.floor(x)
    k = ((x - base) * RAMP_STEPS + 0.5).astype(np.int32)
    return base + RAMP_TABLE.take(k, mode="clip")


def _sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bicubic samples of ``img`` (h, w[, c]) at float arrays ``x, y`` (m, P), exact for
    linear functions (:func:`exact_for_ramps`): (m, P[, c]) float32."""
    m, P = x.shape
    x, y = exact_for_ramps(x), exact_for_ramps(y)
    out = np.empty((m, P) + img.shape[2:], np.float32)
    step = max(1, 30000 // max(P, 1))  # cv2 map sides stay below 32767
    for r0 in range(0, m, step):
        out[r0:r0 + step] = cv2.remap(img, x[r0:r0 + step], y[r0:r0 + step], cv2.INTER_CUBIC,
                                      borderMode=cv2.BORDER_REPLICATE)
    return out


def _offsets(radius: int):
    r = np.arange(-radius, radius + 1, dtype=np.float32)
    ox, oy = [a.ravel() for a in np.meshgrid(r, r)]
    sig = 0.5 * radius + 0.5
    return ox, oy, np.exp(-(ox**2 + oy**2) / (2 * sig**2)).astype(np.float32)


def lk_affine(ref_img: np.ndarray, tgt: np.ndarray, p_ref: np.ndarray, p0: np.ndarray, M0: np.ndarray, radius: int,
              iterations: int = 12, g: np.ndarray | None = None):
    """Batched Lucas-Kanade: align windows of ``tgt`` to template windows of ``ref_img``.

    Parameters
    ----------
    ref_img : (h, w) float32
        The smoothed reference view (:meth:`SmoothedImages.plain`): the templates.
    tgt : (h, w, 3) float32
        The target view's :class:`SmoothedImages` entry (image and gradients).
    p_ref : (m, 2) float
        Template centres in the reference view.
    p0 : (m, 2) float
        Starting positions in the target view.
    M0 : (m, 2, 2) float
        Starting affine parts.
    radius : int
    iterations : int
    g : (m, 2) float, optional
        The warp's projective row, held: ``x = p + M o / (1 + g . o)``, the homography of
        a plane about the window's centre (``M`` its Jacobian there). An affine warp
        leaves the homography's curvature to the centre: a pull of about
        ``-M E_w[o o^T] g``, alike over a view turned from the template's (0.008 /
        0.019 / 0.042 px at 15 / 30 / 45 deg, ``benchmarks/bench_lk_oracle.py``).

    Returns
    -------
    p : (m, 2) float
    M : (m, 2, 2) float
    ncc : (m,) float
        Weighted normalised cross-correlation with the template.
    min_eig : (m,) float
        Smallest eigenvalue of the translation block (texture strength).
    converged : (m,) bool
    """
    m = len(p_ref)
    ox, oy, wgt = _offsets(radius)
    sw = np.sqrt(wgt)  # the weights' roots in J and the residual: H = J J^T, grad = J r
    Tm = _sample(ref_img, p_ref[:, :1] + ox[None], p_ref[:, 1:2] + oy[None])
    p, M = p0.astype(float).copy(), M0.astype(float).copy()
    a, b, c = np.ones(m), np.zeros(m), np.zeros((m, 2))  # gain, offset, ramp across the window
    d = np.zeros((m, 2))  # the gain's own gradient across the window
    conv = np.zeros(m, bool)
    active = np.ones(m, bool)
    last = np.full(m, np.inf)
    eye = np.eye(12)
    last_move = np.zeros((m, 2))
    for _ in range(iterations):
        ia = np.flatnonzero(active)
        if len(ia) == 0:
            break
        wx, wy, shrink = _warp(p[ia], M[ia], None if g is None else g[ia], ox, oy)
        S = _sample(tgt, wx, wy)
        I, Gx, Gy = S[..., 0], S[..., 1], S[..., 2]
        J, res = _weighted_system(I, Gx, Gy, Tm[ia], a[ia], b[ia], c[ia], d[ia], shrink, ox, oy, sw)
        H = (J @ J.transpose(0, 2, 1)).astype(float)
        grad = (J @ res[..., None])[..., 0].astype(float)
        H += 1e-9 * np.trace(H, axis1=1, axis2=2)[:, None, None] * eye
        try:
            delta = -np.linalg.solve(H, grad[..., None])[..., 0]
        except np.linalg.LinAlgError:
            delta = -np.einsum("mab,mb->ma", np.linalg.pinv(H), grad)
        step = np.linalg.norm(delta[:, :2], axis=1)
        step = np.where(np.isfinite(step), step, np.inf)
        lim = np.minimum(1.0, 2.0 / np.maximum(step, 1e-12))  # at most 2 px per step
        delta = np.where(np.isfinite(delta), delta, 0.0) * lim[:, None]
        # a step that reverses the last overshot (the cost is not the quadratic the
        # gradients model there): halved, an oscillation converges instead of ringing
        delta[np.sum(delta[:, :2] * last_move[ia], axis=1) < 0] *= 0.5
        last_move[ia] = delta[:, :2]
        p[ia] += delta[:, :2]
        M[ia] += delta[:, 2:6].reshape(-1, 2, 2)
        a[ia] += delta[:, 6]
        b[ia] += delta[:, 7]
        c[ia] += delta[:, 8:10]
        d[ia] += delta[:, 10:]
        last[ia] = step
        done = step < 2e-3
        conv[ia[done]] = True
        active[ia[done]] = False
    conv |= last < 0.01  # still creeping by < 0.01 px: good enough
    wx, wy, _ = _warp(p, M, g, ox, oy)
    S = _sample(tgt, wx, wy)
    ncc = _wncc(S[..., 0], Tm, wgt)
    Gx, Gy = S[..., 1], S[..., 2]
    hxx, hxy, hyy = (wgt * Gx * Gx).sum(1), (wgt * Gx * Gy).sum(1), (wgt * Gy * Gy).sum(1)
    min_eig = 0.5 * (hxx + hyy - np.sqrt((hxx - hyy) ** 2 + 4 * hxy**2)) / wgt.sum()
    return p, M, ncc, min_eig.astype(float), conv


def _weighted_system(I, Gx, Gy, Tm, a, b, c, d, shrink, ox, oy, sw):
    """One Gauss-Newton system of :func:`lk_affine`, its rows weighted by ``sw`` (the
    roots of the window's weights).

    Samples ``I, Gx, Gy, Tm (m, P)`` float32 (target image, its gradients, template);
    parameters ``a, b (m,)``, ``c, d (m, 2)``; ``shrink (m, P)`` or None; ``ox, oy, sw (P,)``.
    Residual ``r = (a + d . o) I + b + c . o - T``; the 12 rows of ``J = dr / dtheta`` for
    ``theta = (p, M, a, b, c, d)``. Returns ``J (m, 12, P)`` and ``r (m, P)``, both times ``sw``.
    """
    f32 = np.float32
    basis = np.stack([np.ones_like(ox), ox, oy])  # (3, P): 1, o_x, o_y
    gain = np.column_stack([a, d]).astype(f32) @ basis
    res = gain * I
    res += np.column_stack([b, c]).astype(f32) @ basis
    res -= Tm
    res *= sw
    J = np.empty((len(I), 12, I.shape[1]), f32)
    gain *= sw
    np.multiply(gain, Gx, out=J[:, 0])
    np.multiply(gain, Gy, out=J[:, 1])
    ax, ay = (J[:, 0], J[:, 1]) if shrink is None else (J[:, 0] * shrink, J[:, 1] * shrink)
    np.multiply(ax, ox, out=J[:, 2])
    np.multiply(ax, oy, out=J[:, 3])
    np.multiply(ay, ox, out=J[:, 4])
    np.multiply(ay, oy, out=J[:, 5])
    np.multiply(I, sw, out=J[:, 6])
    J[:, 7], J[:, 8], J[:, 9] = sw, ox * sw, oy * sw
    np.multiply(J[:, 6], ox, out=J[:, 10])
    np.multiply(J[:, 6], oy, out=J[:, 11])
    return J, res


def _warp(p, M, g, ox, oy):
    """The window's samples ``x = p + M o / s``, ``s = 1 + g . o`` (affine when ``g`` is
    None) as float32 ``wx, wy (m, P)``, and ``1 / s`` (None when affine). In float32
    (rounding errors of 1e-4 px at 2000 px, against the tracks' 1e-2)."""
    f32 = np.float32
    M, p = M.astype(f32), p.astype(f32)
    o = np.stack([ox, oy])  # (2, P)
    qx, qy = M[:, 0] @ o, M[:, 1] @ o
    shrink = None
    if g is not None:
        g = g.astype(f32)
        shrink = 1 / (1 + g[:, :1] * ox + g[:, 1:] * oy)
        qx *= shrink
        qy *= shrink
    qx += p[:, :1]
    qy += p[:, 1:2]
    return qx, qy, shrink


def _wncc(I, T, w):
    w = w / w.sum()
    Ic = I - (I * w).sum(1, keepdims=True)
    Tc = T - (T * w).sum(1, keepdims=True)
    num = (w * Ic * Tc).sum(1)
    den = np.sqrt((w * Ic * Ic).sum(1) * (w * Tc * Tc).sum(1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / den, 0.0)


def _tasks(ref: np.ndarray, todo: np.ndarray) -> list:
    """``(r, j, observations)``: the observations of view ``j`` whose reference is view
    ``r``, at most :data:`TASK_SIZE` a task (the view pairs differ tenfold in size; even
    tasks keep every core busy, and each observation is aligned on its own)."""
    n, out = todo.shape[0], []
    for r in range(n):
        for j in range(n):
            if j != r:
                sel = np.flatnonzero((ref == r) & todo[j])
                out += [(r, j, sel[k:k + TASK_SIZE]) for k in range(0, max(len(sel), 1), TASK_SIZE)]
    return out


def _start_warp(epi, r, j, p_ref, p0, M0):
    """Start of the affine part: given ``M0`` (m, 2, 2), or ``(1 + rho e3) I`` from the
    pair's epipole (the scale change of a fronto-parallel patch), or ``I``."""
    if M0 is not None:
        return M0
    M = np.repeat(np.eye(2)[None], len(p_ref), axis=0)
    e = None if epi is None else pair_epipole(epi, r, j)
    if e is not None:
        _, rho = residuals(e, p_ref, p0)
        M = M * np.clip(1.0 + np.nan_to_num(rho) * e[2], 0.5, 2.0)[:, None, None]
    return M


def refine_to_reference(smoothed: SmoothedImages, uv: np.ndarray, ref: np.ndarray, epi: dict | None,
                        opts: RefineOptions, report=None, only=None, warps=None) -> np.ndarray:
    """Align every non-reference observation of ``uv`` to its track's reference observation.

    Parameters
    ----------
    smoothed : SmoothedImages
    uv : (n_views, n_tracks, 2) float
        Starting positions; NaN where unseen.
    ref : (n_tracks,) int
        Reference view of each track (its template).
    epi : dict ``(i, j) -> epipole or PairGeometry``, optional
        Epipoles for the start of the affine part.
    opts : RefineOptions
    report : callable ``(stage, done, total)``, optional
        Called once per task (every task, so a bar reaches its total).
    only : (n_views, n_tracks) bool, optional
        Refine only these observations (the others are returned as they are).
    warps : (n_views, n_tracks, 2, 2) float, optional
        Starting affine parts (NaN: from the epipole).

    Returns
    -------
    (n_views, n_tracks, 2) float
        Refined positions, NaN where dropped; a reference observation too near the border
        has no template: its track loses the observations refined against it.
    """
    n = uv.shape[0]
    h, w = smoothed.shape()
    seen = np.isfinite(uv[..., 0])
    todo = seen if only is None else (only & seen)
    out = uv.copy()
    margin = opts.window_radius + 2
    inside = (uv[..., 0] >= margin) & (uv[..., 0] <= w - 1 - margin) & (uv[..., 1] >= margin) & \
        (uv[..., 1] <= h - 1 - margin)
    tasks = _tasks(ref, todo)

    def one(task):
        r, j, sel = task
        if len(sel) == 0:
            return r, j, sel, None
        p_ref, p0 = uv[r, sel], uv[j, sel]
        M0 = None if warps is None else warps[j, sel]
        if M0 is not None and not np.all(np.isfinite(M0)):
            M0 = np.where(np.isfinite(M0), M0, _start_warp(epi, r, j, p_ref, p0, None))
        M0 = _start_warp(epi, r, j, p_ref, p0, M0)
        p, M, ncc, min_eig, conv = lk_affine(smoothed.plain(r), smoothed[j], p_ref, p0, M0, opts.window_radius,
                                             opts.iterations)
        det = np.linalg.det(M)
        good = (inside[r, sel] & inside[j, sel] & conv & (ncc >= opts.min_ncc)
                & (np.linalg.norm(p - p0, axis=1) < opts.max_shift_px) & (det > 0.25) & (det < 4.0) & (min_eig > 1.0))
        return r, j, sel, np.where(good[:, None], p, np.nan)

    for k in range(n):  # build the smoothed images before the threads share them
        smoothed[k]
    with ThreadPoolExecutor(n_threads()) as pool:
        for k, (r, j, sel, p) in enumerate(pool.map(one, tasks)):
            if p is not None:
                out[j, sel] = p
                out[r, sel[~inside[r, sel]]] = np.nan  # no template: the reference goes too
            if report is not None:
                report("refine", k + 1, len(tasks))
    return out
