"""Ray casting of textured surfaces: the supersampled intensity of one view.

Every sample of every pixel follows::

    pixel (u, v)  ->  distorted normalised (x_d, y_d) = K^-1 [u, v, 1]
                  ->  undistorted (x, y)            (camera.undistort, OpenCV model)
                  ->  world ray  C + z R^T [x, y, 1]
                  ->  nearest surface hit (s, t) in the surface's own coordinates
                  ->  texture value, box-filtered analytically over the sample footprint

so a scene point ``X`` appears exactly at ``camera.project(K, R, X, T, dist)``: the
centre of the top-left pixel is (0, 0) (OpenCV). :func:`surface_hits` and
:func:`on_surface` are the ray-rectangle intersection, also used for the ground truth
of rendered pixels (:meth:`transcalib.synth.render.Rendered.backproject`).
"""

from __future__ import annotations

import numpy as np

from ..geometry.camera import undistort

__all__ = ["sample_rays", "surface_hits", "on_surface", "nearest_hits", "render_view"]


def sample_rays(K, R, dist, image_size, S):
    """World ray directions ``R^T [x, y, 1]`` of the ``S x S`` samples of every pixel, at
    offsets ``(k + 1/2) / S - 1/2`` around its centre: three arrays ``(H*S, W*S)`` (the
    grid form of :func:`transcalib.geometry.camera.pixels_to_rays`: ``y`` once per row)."""
    w, h = image_size
    off = (np.arange(S) + 0.5) / S - 0.5
    u = (np.arange(w)[:, None] + off[None, :]).ravel()
    v = (np.arange(h)[:, None] + off[None, :]).ravel()
    fx, sk, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    y = ((v - cy) / fy)[:, None]
    x = (u[None, :] - cx - sk * y) / fx
    y = np.broadcast_to(y, x.shape)
    if np.asarray(dist).size and np.any(np.asarray(dist) != 0):
        xy = undistort(np.stack([x, y], axis=-1), dist)
        x, y = xy[..., 0], xy[..., 1]
    # R^T [x, y, 1]: camera z = 1 at unit ray parameter
    return [x * R[0, k] + y * R[1, k] + R[2, k] for k in range(3)]


def _crop(sf, K, R, dist, C, image_size, S):
    """Sample-grid rows/cols slice covering surface ``sf`` in the view at ``C``."""
    w, h = image_size
    if sf.cull_back and np.dot(sf.normal, C - sf.origin) <= 0:
        return None  # back face of a closed solid: hidden by the front faces
    full = (slice(0, h * S), slice(0, w * S))
    if np.asarray(dist).size and np.any(np.asarray(dist) != 0):
        return full  # distortion can fold far-off points: render the whole frame
    P = sf.point(np.array([[0, 0], [sf.size[0], 0], [sf.size[0], sf.size[1]], [0, sf.size[1]]], float))
    Xc = (P - C) @ R.T
    if np.any(Xc[:, 2] <= 1e-9 * np.abs(Xc).max()):
        return full
    uv = Xc[:, :2] / Xc[:, 2:] @ K[:2, :2].T + K[:2, 2]
    lo = np.floor((uv.min(0) - 2.0 + 0.5) * S - 0.5).astype(int)
    hi = np.ceil((uv.max(0) + 2.0 + 0.5) * S - 0.5).astype(int) + 1
    if hi[0] <= 0 or hi[1] <= 0 or lo[0] >= w * S or lo[1] >= h * S:
        return None
    return (slice(max(lo[1], 0), min(hi[1], h * S)), slice(max(lo[0], 0), min(hi[0], w * S)))


def surface_hits(sf, d, C, sl=slice(None)):
    """Where the rays ``C + z d`` meet the plane of ``sf``: depth ``z`` (camera z when
    ``d`` has unit camera z) and surface coordinates ``s, t``, each ``d[k][sl].shape``.

    ``d``: the three world components of the ray directions (arrays of one shape);
    ``z = n . (origin - C) / n . d`` (inf or NaN for rays parallel to the plane).
    """
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
    camera and inside the rectangle ``[0, size[0]] x [0, size[1]]``."""
    return (z > 0) & (s >= 0) & (s <= sf.size[0]) & (t >= 0) & (t <= sf.size[1])


def nearest_hits(surfaces, d, C) -> tuple[np.ndarray, np.ndarray]:
    """The nearest surface along every ray ``C + z d``: depth ``z`` (inf where no surface
    is hit; camera z when ``d`` has unit camera z) and the index into ``surfaces`` of the
    surface hit (-1: none), each ``d[0].shape`` - the z-buffer of :func:`render_view`
    without its crops, for the exact truth of every pixel."""
    best = np.full(np.shape(d[0]), np.inf)
    owner = np.full(np.shape(d[0]), -1, dtype=np.int32)
    for k, sf in enumerate(surfaces):  # a loop over surfaces, vectorised over the rays
        if sf.cull_back and np.dot(sf.normal, C - sf.origin) <= 0:
            continue
        z, s, t = surface_hits(sf, d, C)
        hit = on_surface(sf, z, s, t) & (z < best)
        best[hit] = z[hit]
        owner[hit] = k
    return best, owner


def render_view(surfaces, d, C, S, background, K, R, dist, image_size):
    """Supersampled intensity of one view: rays ``d`` (3 arrays ``(Hs, Ws)``), centre ``C``."""
    Hs, Ws = d[0].shape
    best = np.full((Hs, Ws), np.inf)
    owner = np.full((Hs, Ws), -1, dtype=np.int32)
    crops, coords = [], []
    for k, sf in enumerate(surfaces):  # pass 1: z-buffer
        sl = _crop(sf, K, R, dist, C, image_size, S)
        crops.append(sl)
        if sl is None:
            coords.append(None)
            continue
        z, s, t = surface_hits(sf, d, C, sl)
        hit = on_surface(sf, z, s, t) & (z < best[sl])
        best[sl][hit] = z[hit]
        owner[sl][hit] = k
        coords.append((s, t) if hit.any() else None)
    out = np.full((Hs, Ws), float(background))
    for k, sf in enumerate(surfaces):  # pass 2: texture of the visible samples
        sl = crops[k]
        if sl is None or coords[k] is None:
            continue
        m = owner[sl] == k
        if not m.any():
            continue
        s, t = coords[k]
        # footprint of one sample in surface units: bounding box of its parallelogram
        with np.errstate(invalid="ignore"):
            ws = np.abs(np.gradient(s, axis=1)[m]) + np.abs(np.gradient(s, axis=0)[m]) if min(s.shape) > 1 else 0 * s[m]
            wt = np.abs(np.gradient(t, axis=1)[m]) + np.abs(np.gradient(t, axis=0)[m]) if min(t.shape) > 1 else 0 * t[m]
        ws = np.where(np.isfinite(ws), ws, 0.0)
        wt = np.where(np.isfinite(wt), wt, 0.0)
        out[sl][m] = sf.texture(s[m], t[m], ws, wt)
    return out.reshape(Hs // S, S, Ws // S, S).mean(axis=(1, 3))
