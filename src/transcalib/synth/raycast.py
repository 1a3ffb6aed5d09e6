"""Ray casting of textured surfaces: the supersampled intensity of one view.

Every sample of every pixel follows::

    pixel (u, v)  ->  distorted normalised (x_d, y_d) = K^-1 [u, v, 1]
                  ->  undistorted (x, y)            (camera.undistort, OpenCV model)
                  ->  world ray  C + z R^T [x, y, 1]
                  ->  nearest surface hit (s, t) in the surface's own coordinates
                  ->  texture value, box-filtered analytically over the sample footprint

so a scene point ``X`` appears exactly at ``camera.project(K, R, X, T, dist)``: the
centre of the top-left pixel is (0, 0) (OpenCV). :func:`surface_hits` and
:func:`on_surface` are the ray-rectangle intersection and :func:`nearest_hits` the
z-buffer of a few rays, also used for the ground truth of rendered pixels
(:meth:`transcalib.synth.render.Rendered.backproject`,
:meth:`transcalib.synth.robot.RobotRendered.ray_hits`). Each surface is cast only over the
pixels its rays can reach (:func:`_crop`; through a lens, :func:`_distorted_box`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..geometry.camera import distort, pad_dist, pixels_to_rays, undistort

__all__ = ["sample_rays", "camera_rays", "surface_hits", "on_surface", "nearest_hits", "render_view"]


def sample_rays(K, R, dist, image_size, S):
    """World ray directions ``R^T [x, y, 1]`` of the ``S x S`` samples of every pixel
    (:func:`camera_rays`): three arrays ``(H*S, W*S)``."""
    x, y = camera_rays(K, dist, image_size, S)
    return [x * R[0, k] + y * R[1, k] + R[2, k] for k in range(3)]


def camera_rays(K, dist, image_size, S):
    """Camera-frame rays ``[x, y, 1]`` of the ``S x S`` samples of every pixel, at offsets
    ``(k + 1/2) / S - 1/2`` around its centre: ``x, y`` each ``(H*S, W*S)``, read-only (the
    grid form of :func:`transcalib.geometry.camera.pixels_to_rays`). The last camera's are
    kept: every view of a scene, and every scene of a study, shares them."""
    K, dist = np.asarray(K, float), np.asarray(dist, float).ravel()
    return _camera_rays(tuple(K.ravel()), tuple(dist), tuple(int(n) for n in image_size), int(S))


@lru_cache(maxsize=1)
def _camera_rays(K: tuple, dist: tuple, image_size: tuple, S: int):
    w, h = image_size
    fx, sk, cx, _, fy, cy = K[:6]
    off = (np.arange(S) + 0.5) / S - 0.5
    u = (np.arange(w)[:, None] + off[None, :]).ravel()
    v = (np.arange(h)[:, None] + off[None, :]).ravel()
    y = ((v - cy) / fy)[:, None]
    x = (u[None, :] - cx - sk * y) / fx
    y = np.broadcast_to(y, x.shape)
    if any(dist):
        xy = undistort(np.stack([x, y], axis=-1), np.array(dist))
        x, y = xy[..., 0], xy[..., 1]
    x, y = np.array(x), np.array(y)  # own, contiguous copies
    x.flags.writeable = y.flags.writeable = False
    return x, y


def _crop(sf, K, R, dist, C, image_size, S):
    """Sample-grid rows/cols slice covering surface ``sf`` in the view at ``C`` (None: not
    in view)."""
    w, h = image_size
    if sf.cull_back and np.dot(sf.normal, C - sf.origin) <= 0:
        return None  # back face of a closed solid: hidden by the front faces
    full = (slice(0, h * S), slice(0, w * S))
    if hasattr(sf, "bounding_corners"):  # a solid (a sphere): its bounding cube
        P = sf.bounding_corners()
    else:
        P = sf.point(np.array([[0, 0], [sf.size[0], 0], [sf.size[0], sf.size[1]], [0, sf.size[1]]], float))
    Xc = (P - C) @ R.T
    if np.any(Xc[:, 2] <= 1e-9 * np.abs(Xc).max()):
        return full
    xy = Xc[:, :2] / Xc[:, 2:]
    if np.asarray(dist).size and np.any(np.asarray(dist) != 0):
        box = _distorted_box(xy.min(0), xy.max(0), K, dist, image_size)
        if box is None:
            return None
        uv_lo, uv_hi = box
    else:
        uv = xy @ K[:2, :2].T + K[:2, 2]
        uv_lo, uv_hi = uv.min(0), uv.max(0)
    lo = np.floor((uv_lo - 2.0 + 0.5) * S - 0.5).astype(int)
    hi = np.ceil((uv_hi + 2.0 + 0.5) * S - 0.5).astype(int) + 1
    if hi[0] <= 0 or hi[1] <= 0 or lo[0] >= w * S or lo[1] >= h * S:
        return None
    return (slice(max(lo[1], 0), min(hi[1], h * S)), slice(max(lo[0], 0), min(hi[0], w * S)))


def _distorted_box(lo, hi, K, dist, image_size, n_side: int = 64):
    """Pixel bounding box ``(uv_lo, uv_hi)`` of the rays that can meet a surface whose
    pinhole (undistorted, normalised) bounding box is ``[lo, hi]``, through the lens
    ``dist``: None when no ray of the image reaches it, the whole image when the lens
    folds.

    Only the part of ``[lo, hi]`` inside the undistorted field of view (the bounding box of
    the image border undistorted, +1 %) can be hit. There the lens is checked to be
    monotonic in the radius (``d r_d / d r > 0``, the radial terms), so the image of the
    clipped box is bounded by the image of its border, sampled ``n_side`` times a side.
    """
    w, h = image_size
    dist5 = pad_dist(dist)
    t = np.linspace(0.0, 1.0, n_side)
    border = np.concatenate([np.c_[t * w, 0 * t], np.c_[t * w, 0 * t + h], np.c_[0 * t, t * h],
                             np.c_[0 * t + w, t * h]]) - 0.5  # the samples reach half a pixel out
    field = pixels_to_rays(K, border, dist5)[:, :2]
    pad = 0.01 * (field.max(0) - field.min(0))
    lo, hi = np.maximum(lo, field.min(0) - pad), np.minimum(hi, field.max(0) + pad)
    if np.any(lo > hi):
        return None
    r2 = np.linspace(0.0, 1.0, 256) * np.max(np.maximum(lo**2, hi**2).sum())
    k1, k2, _, _, k3 = dist5
    if np.any(1.0 + r2 * (3 * k1 + r2 * (5 * k2 + r2 * 7 * k3)) <= 0.05):
        return np.array([-1.0, -1.0]), np.array([w, h], float)  # the whole image
    x = np.concatenate([lo[0] + t * (hi[0] - lo[0]), lo[0] + t * (hi[0] - lo[0]), 0 * t + lo[0], 0 * t + hi[0]])
    y = np.concatenate([0 * t + lo[1], 0 * t + hi[1], lo[1] + t * (hi[1] - lo[1]), lo[1] + t * (hi[1] - lo[1])])
    d = distort(x, y, dist5)
    uv = np.c_[d.xd, d.yd] @ K[:2, :2].T + K[:2, 2]
    return uv.min(0), uv.max(0)


def surface_hits(sf, d, C, sl=slice(None)):
    """Where the rays ``C + z d`` meet the plane of ``sf``: depth ``z`` (camera z when
    ``d`` has unit camera z) and surface coordinates ``s, t``, each ``d[k][sl].shape``.

    ``d``: the three world components of the ray directions (arrays of one shape);
    ``z = n . (origin - C) / n . d`` (inf or NaN for rays parallel to the plane). A
    surface with its own ``hits`` method (a :class:`~.surfaces.Sphere`) answers itself.
    """
    if hasattr(sf, "hits"):
        return sf.hits(d, C, sl)
    dx, dy, dz = d[0][sl], d[1][sl], d[2][sl]
    n = sf.normal
    a, b = sf.axis_s, sf.axis_t
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (n @ (sf.origin - C)) / (dx * n[0] + dy * n[1] + dz * n[2])
    s = z * (dx * a[0] + dy * a[1] + dz * a[2]) + (C - sf.origin) @ a
    t = z * (dx * b[0] + dy * b[1] + dz * b[2]) + (C - sf.origin) @ b
    return z, s, t


def on_surface(sf, z, s, t) -> np.ndarray:
    """bool mask: the hit ``(z, s, t)`` of :func:`surface_hits` lies in front of the
    camera and inside the rectangle ``[0, size[0]] x [0, size[1]]`` (or on the solid)."""
    if hasattr(sf, "on"):
        return sf.on(z, s, t)
    return (z > 0) & (s >= 0) & (s <= sf.size[0]) & (t >= 0) & (t <= sf.size[1])


def nearest_hits(surfaces, d, C) -> tuple[np.ndarray, np.ndarray]:
    """The nearest surface along each ray ``C + z d`` (the render's z-buffer, for a few rays).

    Parameters
    ----------
    surfaces : list of Surface
    d : (3, n) float
        World ray directions (unit camera z gives camera depths).
    C : (3,) float
        Ray origin (camera centre).

    Returns
    -------
    depth : (n,) float
        ``z`` of the nearest hit, ``inf`` where no surface is hit.
    which : (n,) int
        Index into ``surfaces`` of the surface hit, -1 where none.

    Back faces are skipped as in the render (``cull_back``). Any shape of ``d[0]`` works
    (a whole image of rays: the exact depth of every pixel, ``Rendered.depth_map``).
    """
    best = np.full(np.shape(d[0]), np.inf)
    which = np.full(np.shape(d[0]), -1)
    for k, sf in enumerate(surfaces):  # a loop over surfaces, vectorised over rays
        if sf.cull_back and np.dot(sf.normal, C - sf.origin) <= 0:
            continue
        z, s, t = surface_hits(sf, d, C)
        hit = on_surface(sf, z, s, t) & (z < best)
        best[hit] = z[hit]
        which[hit] = k
    return best, which


#: Pixel rows rendered at a time by :func:`render_view` (its temporaries stay in the cache).
STRIP_ROWS = 8


def render_view(surfaces, d, C, S, background, K, R, dist, image_size):
    """Supersampled intensity of one view: rays ``d`` (3 arrays ``(Hs, Ws)``), centre ``C``;
    ``(Hs / S, Ws / S)``, in strips of :data:`STRIP_ROWS` pixel rows (the same values as
    the whole image at once)."""
    Hs, Ws = d[0].shape
    crops = [_crop(sf, K, R, dist, C, image_size, S) for sf in surfaces]
    out = np.empty((Hs // S, Ws // S))
    step = STRIP_ROWS * S
    for a in range(0, Hs, step):
        b = min(a + step, Hs)
        out[a // S: b // S] = _render_rows(surfaces, crops, d, C, background, a, b).reshape(
            (b - a) // S, S, Ws // S, S).mean(axis=(1, 3))
    return out


def _render_rows(surfaces, crops, d, C, background, a: int, b: int) -> np.ndarray:
    """Sample rows ``a:b`` of :func:`render_view`: a z-buffer pass, then the texture of the
    visible samples (their footprints from the surface coordinates' differences over the
    whole crop: one row more on each side where the crop has it)."""
    Ws = d[0].shape[1]
    best = np.full((b - a, Ws), np.inf)
    owner = np.full((b - a, Ws), -1, dtype=np.int32)
    parts = []
    for k, (sf, sl) in enumerate(zip(surfaces, crops)):  # pass 1: z-buffer
        if sl is None or sl[0].stop <= a or sl[0].start >= b:
            parts.append(None)
            continue
        lo, hi = max(sl[0].start, a - 1), min(sl[0].stop, b + 1)  # the rows of the crop used here
        z, s, t = surface_hits(sf, d, C, (slice(lo, hi), sl[1]))
        inner = slice(max(sl[0].start, a) - lo, min(sl[0].stop, b) - lo)  # of those, rows a:b
        rows = slice(max(sl[0].start, a) - a, min(sl[0].stop, b) - a)
        hit = on_surface(sf, z[inner], s[inner], t[inner]) & (z[inner] < best[rows, sl[1]])
        best[rows, sl[1]][hit] = z[inner][hit]
        owner[rows, sl[1]][hit] = k
        flat = sl[0].stop - sl[0].start < 2 or sl[1].stop - sl[1].start < 2  # no differences across it
        parts.append((rows, inner, s, t, flat) if hit.any() else None)
    out = np.full((b - a, Ws), float(background))
    for k, (sf, sl, part) in enumerate(zip(surfaces, crops, parts)):  # pass 2: texture of the visible samples
        if part is None:
            continue
        rows, inner, s, t, flat = part
        m = owner[rows, sl[1]] == k
        if not m.any():
            continue
        ws, wt = (0 * s[inner][m], 0 * t[inner][m]) if flat else (_footprint(s, inner, m), _footprint(t, inner, m))
        out[rows, sl[1]][m] = sf.texture(s[inner][m], t[inner][m], ws, wt)
    return out


def _footprint(s: np.ndarray, inner: slice, m: np.ndarray) -> np.ndarray:
    """A sample's footprint along one surface axis: the bounding box of its parallelogram,
    ``|ds/dcol| + |ds/drow|`` (central differences, one-sided at the crop's edges), at the
    samples ``m`` of rows ``inner`` of ``s``; 0 where not finite."""
    with np.errstate(invalid="ignore"):
        w = np.abs(np.gradient(s[inner], axis=1)[m]) + np.abs(np.gradient(s, axis=0)[inner][m])
    return np.where(np.isfinite(w), w, 0.0)
