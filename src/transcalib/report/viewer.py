"""The report's interactive 3-D view: the points, a frustum per view, the robot axes, the flange.

Two steps, like the figures (:mod:`.figures`). :func:`viewer_data` reduces a calibration
with numpy to a :class:`ViewerData` (at most :data:`MAX_POINTS` points, drawn at random
with the ``rng`` seed, and every view's frustum as line segments; about 35 bytes of page
a point);
:func:`viewer_html` writes it as the page's section: the data as JSON with base64 arrays,
the vendored three.js (``vendor/three.min.js``, MIT, ``vendor/LICENSE.three.txt``) and
our ``viewer.js``, all inline. The page loads nothing: no CDN, no file next to it.

What is drawn, in the world (robot) frame of the calibration:

- the points, coloured by their image colour when known, else by their depth along
  view 0's optical axis (viridis, 2nd to 98th percentile);
- an optional extra coloured cloud (:class:`PointCloud`, e.g. a dense reconstruction);
- the frustum of every view: apex at the camera centre, the image rectangle at depth
  ``d`` (:func:`_frustum_depth`; distortion ignored) and a triangle on the image's top
  edge; the poses come from :func:`.poses.view_poses`;
- the axes of the world frame at its origin (x red, y green, z blue) and, with a hand-eye
  pose, the robot frame that moves with each view (the flange, or eye-to-hand the base).

A click on a point shows its id, position +- std (``cal.X_std``) and the views that saw it
(a finite observation in ``uv``, else a finite residual).
"""

from __future__ import annotations

import base64
import html
import json
from dataclasses import dataclass
from importlib import resources

import numpy as np

from ..errors import InputError
from .poses import ViewPoses

__all__ = ["MAX_POINTS", "PointCloud", "ViewerData", "viewer_data", "viewer_html", "depth_colours", "VIEWER_CSS"]

#: Most points the 3-D view draws of the calibration (a random subsample beyond), and of
#: the extra cloud: about 1.8 MB of page each.
MAX_POINTS = 50_000

#: viridis at 17 equal steps (matplotlib's), RGB 0-255; interpolated linearly (within 5/255).
_VIRIDIS = np.array([[68, 1, 84], [72, 24, 106], [71, 45, 123], [66, 64, 134], [59, 82, 139], [51, 99, 141],
                     [44, 114, 142], [38, 130, 142], [33, 145, 140], [31, 160, 136], [40, 174, 128],
                     [63, 188, 115], [94, 201, 98], [132, 212, 75], [173, 220, 48], [216, 226, 25],
                     [253, 231, 37]], float)
_FRUSTUM_RGB = (255, 140, 60)  # every view's frustum; view 0's is _FIRST_RGB
_FIRST_RGB = (255, 230, 80)
_AXES_RGB = ((230, 60, 60), (60, 200, 80), (80, 130, 255))  # x, y, z

VIEWER_CSS = (".tc-viewer{position:relative;border:1px solid #ccc;background:#1e1e22}"
              ".tc-viewer canvas{display:block;width:100%;cursor:crosshair}"
              ".tc-bar{position:absolute;top:6px;left:8px;color:#ddd;font-size:12px}"
              ".tc-bar label{margin-right:10px}.tc-info{color:#eee;background:#2a2a30;padding:4px 8px;"
              "font:12px monospace;min-height:1.4em;white-space:pre-wrap}.tc-nogl .tc-info{color:#fa0}")


@dataclass(frozen=True, eq=False)
class PointCloud:
    """An extra cloud for the 3-D view (e.g. the dense reconstruction).

    Attributes
    ----------
    X : (m, 3) float
        Points in the calibration's world frame and unit (rows with NaN are left out).
    colors : (m, 3) uint8, optional
        RGB of each point; default: coloured by depth like the calibration's points.
    name : str
        Its name on the page.
    """

    X: np.ndarray
    colors: np.ndarray | None = None
    name: str = "dense cloud"


@dataclass(frozen=True, eq=False)
class ViewerData:
    """What the 3-D view draws, reduced (see :func:`viewer_data`); world = robot frame
    less ``origin``, lengths in ``unit``.

    Attributes
    ----------
    unit : str
    origin : (3,) float
        Subtracted from every position (so that float32 keeps the precision).
    n_points : int
        Points the calibration reconstructed (finite ``X``).
    index : (k,) int
        The ones drawn (indices into ``cal.X``), ``k <= MAX_POINTS``.
    X : (k, 3) float32
    colors : (k, 3) uint8
    colour_by : str
        ``"image"`` or ``"depth"`` (then ``depth_range`` is its 2nd and 98th percentile).
    depth_range : (2,) float
    ids : (k,) array
        Their point ids (integers or text).
    X_std : (k, 3) float16 or None
    seen : (k, ceil(n_views / 8)) uint8
        Bit ``j`` (little-endian bit order) of row ``i``: view ``j`` observed point ``i``.
    inlier : (ceil(k / 8),) uint8 or None
        Bit ``i``: point ``i`` is an inlier.
    views : list of str (n_views)
        Labels of the views.
    frusta : (n_views * 22, 3) float32
        Segment ends: per view 4 edges from the apex, 4 of the image rectangle, 3 of the
        "up" triangle.
    axes : (6, 3) float32
        The world axes (x, y, z segments from the world origin).
    frames : (n_views * 6, 3) float32 or None
        The axes of each view's robot frame, where known (:attr:`.poses.ViewPoses.frame_R`).
    camera : dict
        The page's views (:func:`_first_views`), ``{"oblique": view, "camera": view}``,
        each ``{"eye", "up"}`` (3-lists, the target is the origin), ``"near"``, ``"far"``.
    extra : dict or None
        ``{"name", "n_points", "X" (k2, 3) float32, "colors" (k2, 3) uint8}``.
    origin_note : str
        What the world origin is (:attr:`.poses.ViewPoses.origin`).
    frames_note : str
        What ``frames`` are (:attr:`.poses.ViewPoses.frames`).
    """

    unit: str
    origin: np.ndarray
    n_points: int
    index: np.ndarray
    X: np.ndarray
    colors: np.ndarray
    colour_by: str
    depth_range: np.ndarray
    ids: np.ndarray
    X_std: np.ndarray | None
    seen: np.ndarray
    inlier: np.ndarray | None
    views: list
    frusta: np.ndarray
    axes: np.ndarray
    frames: np.ndarray | None
    camera: dict
    extra: dict | None
    origin_note: str
    frames_note: str = ""

    @property
    def n_drawn(self) -> int:
        return len(self.index)

    @property
    def n_views(self) -> int:
        return len(self.views)


def depth_colours(z: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """``(k, 3)`` uint8: viridis of ``z (k,)`` scaled from ``lo`` (dark purple) to ``hi``
    (yellow), clipped; NaN gets the middle colour."""
    t = np.clip((np.asarray(z, float) - lo) / max(hi - lo, 1e-300), 0.0, 1.0)
    t = np.where(np.isfinite(t), t, 0.5) * (len(_VIRIDIS) - 1)
    k = np.minimum(t.astype(np.int64), len(_VIRIDIS) - 2)
    f = (t - k)[:, None]
    return np.rint(_VIRIDIS[k] * (1 - f) + _VIRIDIS[k + 1] * f).astype(np.uint8)


def _finite_rows(X: np.ndarray) -> np.ndarray:
    """``(n,)`` bool: the rows of ``X (n, 3)`` without NaN or inf (column sums: ``isfinite(X)
    .all(axis=1)`` is 8 times slower; a row of finite values whose sum overflows counts
    as not finite)."""
    return np.isfinite(X[:, 0] + X[:, 1] + X[:, 2])


def _sample(idx: np.ndarray, k: int, rng) -> np.ndarray:
    """At most ``k`` of ``idx``, sorted (all of them when there are no more)."""
    if idx.size <= k:
        return idx
    return idx[np.sort(np.random.default_rng(rng).choice(idx.size, k, replace=False, shuffle=False))]


def _frusta(poses: ViewPoses, K: np.ndarray, size, depth: float) -> np.ndarray:
    """``(n_views * 22, 3)``: the frustum segments of every view (see :class:`ViewerData`)."""
    w, h = float(size[0]), float(size[1])
    px = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5],  # image corners
                   [0.35 * w, -0.5], [0.65 * w, -0.5], [0.5 * w, -0.5 - 0.2 * h]])  # the "up" triangle
    rays = np.linalg.solve(K, np.c_[px, np.ones(len(px))].T).T  # (7, 3), z = 1 in the camera frame
    ends = poses.centres[:, None] + depth * np.einsum("vji,pj->vpi", poses.R_cam_world, rays)  # R^T ray
    c = np.broadcast_to(poses.centres[:, None], (poses.n_views, 4, 3))
    segments = [c, ends[:, :4],  # apex -> corners
                ends[:, :4], ends[:, [1, 2, 3, 0]],  # rectangle
                ends[:, [4, 5, 6]], ends[:, [5, 6, 4]]]  # triangle
    a = np.concatenate(segments[0::2], axis=1)  # (V, 11, 3) segment starts
    b = np.concatenate(segments[1::2], axis=1)  # and ends
    return np.stack([a, b], axis=2).reshape(-1, 3)


def _frustum_depth(centres: np.ndarray, scale: float) -> float:
    """Depth of the drawn frusta: half the median distance between neighbouring camera
    centres (frusta apart), within 3 % and 10 % of the points' median depth ``scale``."""
    if len(centres) < 2:
        return 0.1 * scale
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)  # n_views^2: views are few
    np.fill_diagonal(d, np.inf)
    return float(np.clip(0.5 * np.median(d.min(axis=1)), 0.03 * scale, 0.1 * scale))


def _axes(origin, R, length: float) -> np.ndarray:
    """``(n * 6, 3)``: x, y, z axis segments of length ``length`` from ``origin (n, 3)``
    along the columns of ``R (n, 3, 3)``."""
    a = np.broadcast_to(origin[:, None], (len(origin), 3, 3))
    b = origin[:, None] + length * np.transpose(R, (0, 2, 1))  # row k: column k of R
    return np.stack([a, b], axis=2).reshape(-1, 3)


def _look(axes: np.ndarray, C: np.ndarray, X: np.ndarray) -> dict:
    """Eye and up for looking along ``axes[2]`` (rows: right, down, forward) at the
    origin, just far enough back that the points ``X (k, 3)`` (but 2 % of outliers) and
    every camera centre ``C (n, 3)`` are in the field of view (50 deg high, ~1.6 : 1)."""
    right, down, forward = axes
    tan_v, tan_h = 0.9 * np.tan(np.radians(25.0)), 0.9 * 1.6 * np.tan(np.radians(25.0))

    def needed(P):  # eye distance from the origin at which each of P (k, 3) is in view
        return np.maximum(np.abs(P @ down) / tan_v, np.abs(P @ right) / tan_h) - P @ forward

    spread = max(float(np.linalg.norm(C, axis=1).max()), float(np.ptp(X, axis=0).max()) if len(X) else 0.0, 1e-9)
    dist = max(float(needed(C).max()), float(np.max(-C @ forward)) + 0.05 * spread,
               float(np.percentile(needed(X), 98)) if len(X) else 0.0)
    return {"eye": (-dist * forward).tolist(), "up": (-down).tolist(), "near": 1e-3 * dist,
            "far": 10.0 * (dist + spread)}


def _first_views(poses: ViewPoses, X: np.ndarray, target: np.ndarray) -> dict:
    """The page's two views of the scene, looking at ``target`` with image-up as up:
    ``"oblique"`` (the first: view 0's direction turned 35 deg about image-up, then
    tilted 25 deg down) and ``"camera"`` (from behind view 0 along its optical axis)."""
    R0 = poses.R_cam_world[0]
    a, e = np.radians(35.0), np.radians(25.0)
    turn = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])  # about the camera's y
    tilt = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])  # about its x
    C = poses.centres - target
    return {"oblique": _look(tilt @ turn @ R0, C, X - target), "camera": _look(R0, C, X - target)}


def _rgb(name: str, a, n: int) -> np.ndarray | None:
    """``a`` as ``(n, 3)`` uint8 RGB (None stays None), or :class:`InputError`."""
    if a is None:
        return None
    a = np.asarray(a)
    if a.shape != (n, 3) or not np.issubdtype(a.dtype, np.number):
        raise InputError(f"{name} must be an array of shape ({n}, 3), got {a.dtype} {a.shape}")
    if not np.all((a >= 0) & (a <= 255) & (a == np.round(a))):  # NaN fails too
        raise InputError(f"{name} must be RGB values, integers 0-255 (uint8)")
    return a.astype(np.uint8)


def _check_lengths(uv, point_ids, view_names, n: int, V: int) -> None:
    """:class:`InputError` unless ``uv``, ``point_ids``, ``view_names`` (where given) fit
    ``n`` points in ``V`` views."""
    if uv is not None and np.shape(uv) != (V, n, 2):
        raise InputError(f"uv must have shape (n_views, n_points, 2) = ({V}, {n}, 2), got {np.shape(uv)}")
    if point_ids is not None and len(point_ids) != n:
        raise InputError(f"point_ids must hold one id per point ({n}), got {len(point_ids)}")
    if view_names is not None and len(view_names) != V:
        raise InputError(f"view_names must hold one name per view ({V}), got {len(view_names)}")


def _extra(cloud, lo: float, hi: float, R0, C0, origin, max_points: int, rng) -> dict | None:
    """The extra cloud, subsampled and coloured (see :attr:`ViewerData.extra`)."""
    if cloud is None:
        return None
    if not isinstance(cloud, PointCloud):
        raise InputError(f"extra must be a transcalib.report.PointCloud, got {type(cloud).__name__}")
    X = np.asarray(cloud.X, float)
    if X.ndim != 2 or X.shape[1] != 3:
        raise InputError(f"the extra cloud's X must have shape (m, 3), got {X.shape}")
    colors = _rgb("the extra cloud's colors", cloud.colors, len(X))
    ok = np.flatnonzero(_finite_rows(X))
    idx = _sample(ok, max_points, rng)
    rgb = depth_colours((X[idx] - C0) @ R0[2], lo, hi) if colors is None else colors[idx]
    return {"name": str(cloud.name), "n_points": int(ok.size), "X": (X[idx] - origin).astype(np.float32), "colors": rgb}


def viewer_data(cal, *, uv=None, colors=None, point_ids=None, view_names=None,
                extra: PointCloud | None = None, image_size=None, unit: str = "units",
                max_points: int = MAX_POINTS, rng=0) -> ViewerData:
    """Reduce ``cal`` to what the 3-D view draws (numpy only).

    Parameters
    ----------
    cal : Calibration
    uv : (n_views, n_points, 2) float, optional
        Observations: which views saw each point (default: where ``cal.residuals_px`` is finite).
    colors : (n_points, 3) uint8, optional
        Image colour of each point; default: colour by depth.
    point_ids : (n_points,) array, optional
        Point ids (default ``0..n-1``).
    view_names : sequence of str (n_views), optional
        Shown after the view index (image names).
    extra : PointCloud, optional
        Another cloud in the same frame (a dense reconstruction).
    image_size : (width, height), optional
        Of the frusta (default ``cal.image_size``, else twice the principal point).
    unit : str
    max_points : int
        Most points drawn of the calibration and of ``extra``.
    rng : seed or Generator
        Of the subsample.

    Returns
    -------
    ViewerData
    """
    from .poses import view_poses

    n, V = cal.n_points, cal.n_views
    poses = view_poses(cal)
    _check_lengths(uv, point_ids, view_names, n, V)
    colors = _rgb("colors", colors, n)
    ok = np.flatnonzero(_finite_rows(cal.X))
    idx = _sample(ok, max_points, rng)
    X = np.asarray(cal.X[idx], float)
    z = (X - poses.centres[0]) @ poses.R_cam_world[0, 2]
    lo, hi = (np.percentile(z, [2, 98]) if z.size else np.array([0.0, 1.0]))
    target = np.median(X, axis=0) if len(X) else poses.centres.mean(axis=0)
    scale = float(np.median(np.abs(z))) if z.size else float(np.ptp(poses.centres, axis=0).max() or 1.0)
    size = image_size if image_size is not None else cal.image_size or (2 * cal.K[0, 2] + 1, 2 * cal.K[1, 2] + 1)
    seen_all = np.isfinite(cal.residuals_px[:, idx, 0]) if uv is None else np.isfinite(np.asarray(uv)[:, idx, 0])
    ids = np.arange(n) if point_ids is None else np.asarray(point_ids)
    names = [str(v) for v in range(V)] if view_names is None else [f"{v} ({s})" for v, s in enumerate(view_names)]
    frames = None if poses.frame_T is None else _axes(poses.frame_T - target, poses.frame_R, 0.06 * scale)
    return ViewerData(
        unit=unit, origin=target, n_points=int(ok.size), index=idx, X=(X - target).astype(np.float32),
        colors=depth_colours(z, lo, hi) if colors is None else colors[idx], colour_by="depth" if colors is None else "image",
        depth_range=np.array([lo, hi], float), ids=ids[idx],
        X_std=None if cal.X_std is None else np.asarray(cal.X_std)[idx].astype(np.float16),
        seen=np.packbits(seen_all.T, axis=1, bitorder="little"),
        inlier=None if cal.inliers is None else np.packbits(np.asarray(cal.inliers, bool)[idx], bitorder="little"),
        views=names, frusta=(_frusta(poses, cal.K, size, _frustum_depth(poses.centres, scale)) - target
                             ).astype(np.float32),
        axes=_axes(-target[None], np.eye(3)[None], 0.2 * scale).astype(np.float32),
        frames=None if frames is None else frames.astype(np.float32),
        camera=_first_views(poses, X, target), origin_note=poses.origin, frames_note=poses.frames,
        extra=_extra(extra, lo, hi, poses.R_cam_world[0], poses.centres[0], target, max_points, rng))


def _b64(a: np.ndarray) -> str:
    """Base64 of the little-endian bytes of ``a`` (C order)."""
    a = np.ascontiguousarray(a)
    return base64.b64encode(a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()).decode("ascii")


def _segment_colours(n_segments: int, rgb_per_segment: np.ndarray) -> str:
    """Base64 of ``(2 n_segments, 3)`` uint8: each segment's colour at both ends."""
    return _b64(np.repeat(np.asarray(rgb_per_segment, np.uint8).reshape(n_segments, 3), 2, axis=0))


def _point_size(d: ViewerData) -> int:
    """Pixels per point: larger for sparse clouds."""
    return 4 if d.n_drawn < 2000 else 3 if d.n_drawn < 20000 else 2


def _payload(d: ViewerData) -> dict:
    """The JSON the page's ``viewer.js`` reads."""
    frustum_rgb = np.tile(np.array(_FRUSTUM_RGB, np.uint8), (d.n_views, 11, 1))
    frustum_rgb[0] = _FIRST_RGB
    points = {"xyz": _b64(d.X), "rgb": _b64(d.colors), "ids": d.ids.tolist(), "seen": _b64(d.seen),
              "seen_bytes": int(d.seen.shape[1]) if d.seen.ndim == 2 else 0,
              "inlier": None if d.inlier is None else _b64(d.inlier),
              "std": None if d.X_std is None else _b64(d.X_std.astype(np.float16))}
    out = {"unit": d.unit, "origin": d.origin.tolist(), "views": d.views, "view": d.camera, "points": points,
           "point_size": _point_size(d),
           "frusta": {"n": d.n_views, "xyz": _b64(d.frusta), "rgb": _segment_colours(11 * d.n_views, frustum_rgb)},
           "axes": {"xyz": _b64(d.axes), "rgb": _segment_colours(3, np.array(_AXES_RGB))},
           "frames": None, "extra": None}
    if d.frames is not None:
        out["frames"] = {"n": d.n_views, "xyz": _b64(d.frames),
                         "rgb": _segment_colours(3 * d.n_views, np.tile(np.array(_AXES_RGB), (d.n_views, 1)))}
    if d.extra is not None:
        out["extra"] = {"xyz": _b64(d.extra["X"]), "rgb": _b64(d.extra["colors"])}
    return out


def _legend(d: ViewerData) -> str:
    """The sentences under the view: what is drawn, how many, the colours."""
    u = html.escape(d.unit)
    drawn = (f"all {d.n_points:,} reconstructed points" if d.n_drawn == d.n_points else
             f"{d.n_drawn:,} of {d.n_points:,} reconstructed points (a random subsample)")
    colour = ("their image colour" if d.colour_by == "image" else
              f"depth along view 0's optical axis, {d.depth_range[0]:.4g} {u} (purple) to "
              f"{d.depth_range[1]:.4g} {u} (yellow)")
    text = [f"Drawn: <span id='tc-drawn'>{drawn}</span>, coloured by {colour}; the camera frustum of each of the "
            f"<span id='tc-frusta'>{d.n_views}</span> views (view 0 yellow; a triangle marks the image's top edge); "
            f"{html.escape(d.origin_note)} (x red, y green, z blue)"]
    if d.frames is not None:
        text.append(f"; the axes of {html.escape(d.frames_note)}")
    if d.extra is not None:
        e = d.extra
        text.append(f"; {html.escape(e['name'])}: " + (f"all {e['n_points']:,} points" if len(e["X"]) == e["n_points"]
                                                       else f"{len(e['X']):,} of {e['n_points']:,} points"))
    text.append(f". Lengths in {u}. Drag to orbit, right-drag or shift-drag to pan, wheel to zoom; "
                "click a point for its id, position &plusmn; std and the views that saw it.")
    return "".join(text)


def _asset(name: str) -> str:
    return resources.files(__package__).joinpath(name).read_text(encoding="utf-8")


def viewer_html(d: ViewerData) -> str:
    """The 3-D view as one HTML section: controls, data, three.js and ``viewer.js`` inline."""
    data = json.dumps(_payload(d), separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")
    layers = [("points", "points")]
    if d.extra is not None:
        layers.append(("extra", html.escape(d.extra["name"])))
    layers += [("frusta", "frusta"), ("axes", "axes")] + [("frames", "robot frames")] * (d.frames is not None)
    boxes = "".join(f"<label><input type='checkbox' data-layer='{k}' checked> {t}</label>" for k, t in layers)
    return (f"<h2>3-D view</h2>\n<div id='tc-viewer' class='tc-viewer' data-points-drawn='{d.n_drawn}' "
            f"data-points-total='{d.n_points}' data-frusta='{d.n_views}' "
            f"data-extra-drawn='{0 if d.extra is None else len(d.extra['X'])}'>"
            f"<div class='tc-bar'>{boxes}<label>point size <input type='range' min='1' max='8' value="
            f"'{_point_size(d)}' data-size></label><button type='button' data-view='oblique'>oblique</button> "
            "<button type='button' data-view='camera'>from camera 0</button>"
            "</div><div id='tc-viewer-info' class='tc-info'>Click a point: its id, position &plusmn; std and the "
            f"views that saw it.</div></div>\n<p id='tc-viewer-legend'>{_legend(d)}</p>\n"
            f"<script type='application/json' id='tc-viewer-data'>{data}</script>\n"
            f"<script>{_asset('vendor/three.min.js')}</script>\n<script>{_asset('viewer.js')}</script>")

