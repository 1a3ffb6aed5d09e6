"""The report's figures: each is reduced from the calibration, then drawn.

A figure is two functions. ``*_data(cal, ...)`` reduces the calibration to what the
figure shows, with numpy, at any number of points: at most a few thousand marks
(subsampled with a fixed seed; the largest residuals always kept) and statistics such as
histograms counted from all the data. The result is a small dict of arrays (kilobytes,
whatever n), cheap to pickle to the report worker. ``draw_*(data)`` draws that dict on a
matplotlib :class:`~matplotlib.figure.Figure` with the Agg canvas: no ``pyplot``, no
``tight_layout`` (margins fixed in inches), no 3-D axes (the reconstruction is our own
orthographic projection on 2-D axes). matplotlib is imported by the ``draw_*`` functions
only: ``import transcalib`` and the ``*_data`` functions stay light.

Drawing is on the critical path of ``transcalib calibrate`` (the worker's
``report_worker_s``), and its cost is per artist rather than per mark: a figure is kept
to few artists. The marks of one colour are one ``Line2D`` (markers Agg stamps from one
drawing, or one NaN-separated polyline); ticks, the colour scale and the key are ours,
a line of markers and a text per label, not matplotlib's ticks, colorbar and legend;
several views share one axes as tiles. :func:`png` writes line art as a palette image.
"""

from __future__ import annotations

import io

import numpy as np

__all__ = ["residuals_data", "histogram_data", "reconstruction_data", "uncertainty_data", "truth_data",
           "draw_histogram", "DRAW", "png", "observed_pixels", "image_box", "residual_norms"]

#: Largest number of residual arrows drawn per view (plus the 50 largest), and of
#: points in the reconstruction.
MAX_ARROWS = 400
MAX_POINTS = 8000
#: Resolution of the PNG files (pixels per inch of the figure sizes below).
DPI = 90
_SMALL = 7  # font size of tick labels and legends (points)


# --------------------------------------------------------------------------------------
# shared helpers
# --------------------------------------------------------------------------------------


def _subsample(idx: np.ndarray, k: int) -> np.ndarray:
    """At most ``k`` of the indices ``idx``, sorted, drawn with a fixed seed."""
    if idx.size <= k:
        return idx
    return np.sort(np.random.default_rng(0).choice(idx, k, replace=False))


def _percentile(x: np.ndarray, q: float, k: int = 200_000) -> float:
    """The ``q``-th percentile of the finite values of ``x`` (any shape), estimated from
    at most ``k`` of them taken at a regular stride (NaN if there are none)."""
    some = x.ravel()[:: max(1, x.size // k)]
    some = some[np.isfinite(some)]
    return float(np.percentile(some, q)) if some.size else float("nan")


def _inliers(cal) -> np.ndarray:
    """``(n_points,)`` bool: the calibration's inliers (all points when it has none)."""
    return np.ones(cal.n_points, bool) if cal.inliers is None else np.asarray(cal.inliers, bool)


def observed_pixels(cal, uv=None) -> np.ndarray:
    """Observed pixels ``(n_views, n_points, 2)``: ``uv`` when given, else the prediction
    plus the residual (NaN where there is no residual)."""
    if uv is not None:
        return uv
    from ..geometry.camera import project

    R_cam, C = cal.camera_poses()
    return project(cal.K, R_cam, np.nan_to_num(cal.X), C, cal.dist) + cal.residuals_px


def image_box(cal, uv=None) -> tuple[int, int]:
    """``(width, height)`` px: the image size, else the extent of the observations
    (``uv``, or the prediction plus residual)."""
    from ..io.formats import image_size_or_extent

    return tuple(cal.image_size) if cal.image_size is not None else image_size_or_extent(cal, observed_pixels(cal, uv))


def residual_norms(cal) -> np.ndarray:
    """``(n_views, n_points)`` px: the length of each residual (NaN where none)."""
    r = cal.residuals_px
    return np.sqrt(r[..., 0] ** 2 + r[..., 1] ** 2)


def _figure(width_in: float, height_in: float, margins=(0.6, 0.15, 0.5, 0.45)):
    """An empty Agg figure of ``width_in x height_in`` inches whose subplots leave
    ``margins = (left, right, bottom, top)`` inches free (fixed: no layout engine)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    left, right, bottom, top = margins
    fig.subplots_adjust(left=left / width_in, right=1 - right / width_in, bottom=bottom / height_in,
                        top=1 - top / height_in)
    return fig


def _round_ticks(limits, n: int = 4) -> tuple[np.ndarray, list[str]]:
    """At most ``n + 1`` round values inside ``limits`` and their labels."""
    from matplotlib.ticker import MaxNLocator

    lo, hi = sorted(limits)
    eps = 1e-9 * (hi - lo)
    ticks = MaxNLocator(n).tick_values(lo, hi)
    ticks = ticks[(ticks >= lo - eps) & (ticks <= hi + eps)]
    return ticks, [f"{t + 0.0:g}".replace("-", "\N{MINUS SIGN}") for t in ticks]


def _ticks(ax, x=None, y=None) -> None:
    """:func:`_side_ticks` along the bottom (``x``) and the left (``y``) of ``ax``:
    ``(positions, labels)``, by default :func:`_round_ticks` of the limits, settled
    here (aspect ratio included): call this once the data are drawn."""
    ax.apply_aspect()
    _side_ticks(ax, "bottom", *(_round_ticks(ax.get_xlim()) if x is None else x))
    _side_ticks(ax, "left", *(_round_ticks(ax.get_ylim()) if y is None else y))


def _side_ticks(ax, side: str, at, labels) -> None:
    """Tick marks at ``at`` (data units) on one ``side`` of ``ax`` ("bottom", "left" or
    "right"), their ``labels``, and the axis label beyond them.

    The marks are one line of markers, each label a text. matplotlib's own ticks are
    five artists each, made when the figure is drawn, and it places the axis label by
    measuring every tick label: that was a third of the report's drawing time.
    """
    from matplotlib.lines import TICKDOWN, TICKLEFT, TICKRIGHT, Line2D
    from matplotlib.ticker import NullLocator
    from matplotlib.transforms import offset_copy

    marker, out, align, label_at = {  # the direction out of the axes; where the axis label is anchored
        "bottom": (TICKDOWN, (0, -1), {"ha": "center", "va": "top"}, (0.5, 0.0)),
        "left": (TICKLEFT, (-1, 0), {"ha": "right", "va": "center"}, (0.0, 0.5)),
        "right": (TICKRIGHT, (1, 0), {"ha": "left", "va": "center"}, (1.0, 0.5))}[side]
    at = np.asarray(at, float)
    edge = np.full_like(at, float(side == "right"))  # axes fraction across the axis
    if side == "bottom":
        axis, transform, xy = ax.xaxis, ax.get_xaxis_transform(), (at, edge)
        depth = 1.3 * _SMALL  # points: the tick labels' height
    else:
        axis, transform, xy = ax.yaxis, ax.get_yaxis_transform(), (edge, at)
        depth = 0.65 * _SMALL * max(map(len, labels), default=0)  # points: the widest label (a digit ~0.65 em)

    def away(transform, points: float):
        """``transform`` moved ``points`` out of the axes."""
        return offset_copy(transform, fig=ax.figure, x=out[0] * points, y=out[1] * points, units="points")

    axis.set_major_locator(NullLocator())
    ax.add_artist(Line2D(*xy, ls="none", marker=marker, ms=3.5, mew=0.8, color="k", transform=transform, clip_on=False))
    gap = 7.0  # points from the axes to a tick label: mark 3.5 + pad 3.5, as matplotlib
    label_transform = away(transform, gap)
    for u, v, label in zip(*xy, labels):
        ax.text(u, v, label, transform=label_transform, fontsize=_SMALL, **align)
    axis.set_label_position(side)
    axis.set_label_coords(*label_at, away(ax.transAxes, gap + depth + 4))


def _colour_scale(fig, im, rect, label: str) -> None:
    """A colour bar of the image ``im`` in ``rect`` (figure fraction): its colour map as
    an image, round values on the right (matplotlib's ``colorbar`` cost a third of the
    uncertainty figure)."""
    from matplotlib.ticker import NullLocator

    lo, hi = im.get_clim()
    pad = 0.0 if hi > lo else 1e-3 * max(abs(lo), 1e-12)  # a constant map still gets a scale
    lo, hi = lo - pad, hi + pad
    cax = fig.add_axes(rect)
    cax.imshow(np.linspace(lo, hi, 256)[:, None], cmap=im.get_cmap(), norm=im.norm, origin="lower", aspect="auto",
               extent=(0, 1, lo, hi))
    cax.xaxis.set_major_locator(NullLocator())
    _side_ticks(cax, "right", *_round_ticks((lo, hi)))
    cax.set_ylabel(label, fontsize=9)


def _title(ax, text: str, fontsize: float) -> None:
    """Title ``text`` at a fixed height above ``ax`` (matplotlib would otherwise measure
    every tick label of the axes to place it)."""
    ax.set_title(text, fontsize=fontsize, y=1.0, pad=4)


def png(fig) -> bytes:
    """The figure as PNG bytes, drawn once at :data:`DPI`, fast zlib level.

    Line art is reduced to 256 colours (its antialiased edges included): it looks the
    same, the file is a third of the size and it is written in half the time (no filter
    is searched per row). A figure with an image (a colour map: every shade is data)
    keeps all its colours. Text is rendered without hinting, which looks the same at
    this size and takes half the time.
    """
    import matplotlib
    from PIL import Image

    with matplotlib.rc_context({"text.hinting": "no_hinting"}):
        fig.canvas.draw()
    image = Image.frombuffer("RGBA", fig.canvas.get_width_height(), fig.canvas.buffer_rgba(), "raw", "RGBA", 0, 1)
    image = image.convert("RGB")
    if not any(ax.images for ax in fig.axes):
        image = image.quantize(256, method=Image.Quantize.FASTOCTREE)
    buf = io.BytesIO()
    image.save(buf, format="png", compress_level=1)
    return buf.getvalue()


# --------------------------------------------------------------------------------------
# residual arrows per view
# --------------------------------------------------------------------------------------


def residuals_data(cal, uv=None, scale: float | None = None, *, size=None, norm=None) -> dict:
    """Residual arrows of every view over the image area.

    ``size`` (:func:`image_box`) and ``norm`` (:func:`residual_norms`) are computed
    when not given. Returns ``{"size": (w, h) px, "scale": magnification, "views":
    [{"xy": (k, 2) px observed, "d": (k, 2) px residual (observed - predicted), "inlier":
    (k,) bool, "n": observations, "rms": px}, ...]}``, ``k <= MAX_ARROWS + 50`` (the 50
    largest always in).
    """
    obs = observed_pixels(cal, uv)
    w, h = size or image_box(cal, obs)
    res = cal.residuals_px
    norm = residual_norms(cal) if norm is None else norm
    typical = np.nan_to_num(_percentile(norm, 90), nan=1.0)
    scale = scale or (0.05 * max(w, h) / max(typical, 1e-12))
    inl = _inliers(cal)
    views = []
    for i in range(cal.n_views):
        ok = np.flatnonzero(np.isfinite(norm[i]) & np.isfinite(obs[i, :, 0]))
        r = norm[i, ok]
        big = ok[np.argpartition(r, -50)[-50:]] if ok.size > 50 else ok  # the largest always shown
        pick = np.union1d(_subsample(ok, MAX_ARROWS), big)
        rms = float(np.sqrt(np.mean(r**2))) if ok.size else float("nan")
        views.append({"xy": obs[i, pick], "d": res[i, pick], "inlier": inl[pick], "n": int(ok.size), "rms": rms})
    return {"size": (float(w), float(h)), "scale": float(scale), "views": views}


def _arrow_lines(xy: np.ndarray, d: np.ndarray, head: float) -> np.ndarray:
    """``(2, 6 k)`` x and y of one polyline that draws an arrow from each point ``xy (k,
    2)`` along ``d (k, 2)`` (data units of equal-aspect axes): the shaft and two barbs of
    length ``min(head, 0.4 |d|)`` at 25 degrees, each arrow ended by NaN. Drawn as one
    ``Line2D``, all arrows are a single path for Agg (``quiver`` makes a polygon each)."""
    tip = xy + d
    length = np.hypot(d[:, 0], d[:, 1])[:, None]
    back = -d * (np.minimum(0.4 * length, head) / np.maximum(length, 1e-300))  # tip -> barb end, before turning
    c, s = np.cos(np.radians(25)), np.sin(np.radians(25))
    barbs = [tip + back @ np.array([[c, s], [-s, c]]), tip + back @ np.array([[c, -s], [s, c]])]  # turned +-25 deg
    pts = np.stack([xy, tip, barbs[0], tip, barbs[1], np.full_like(xy, np.nan)], axis=1)
    return pts.reshape(-1, 2).T


def _tile_ticks(starts, size: float) -> tuple[list, list]:
    """Ticks at round values in each tile of ``size`` data units beginning at
    ``starts``: their positions and labels (the position within the tile)."""
    local, labels = _round_ticks((0.0, size), 3)
    return [s + x for s in starts for x in local], [label for _ in starts for label in labels]


def draw_residuals(d: dict):
    """Figure of :func:`residuals_data`: each view's image frame, 3 per row, with an
    arrow from each observed point along its residual (observed - predicted), magnified
    ``scale`` times, blue for inliers, red for outliers (drawn last, on top).

    The frames are tiles of one axes (an axes per view costs several times more to make
    and draw); pixel ticks run along the bottom row and the left column.
    """
    from matplotlib.patches import Rectangle

    w, h = d["size"]
    n = len(d["views"])
    cols = min(n, 3)
    rows = -(-n // cols)
    pitch = (1.08 * w, 1.2 * h)  # tile spacing: room for the titles between the rows
    extent = ((cols - 1) * pitch[0] + w, (rows - 1) * pitch[1] + h)
    width = 12.6
    fig = _figure(width, (width - 0.65) * extent[1] / extent[0] + 1.15, margins=(0.5, 0.15, 0.35, 0.8))
    ax = fig.add_subplot()
    for i, v in enumerate(d["views"]):
        row, col = divmod(i, cols)
        corner = np.array([col * pitch[0], row * pitch[1]])
        frame = ax.add_patch(Rectangle(corner, w, h, fill=False, lw=0.8, clip_on=False))  # on the axes edge
        for keep, color in ((v["inlier"], "tab:blue"), (~v["inlier"], "tab:red")):
            x, y = _arrow_lines(corner + v["xy"][keep], v["d"][keep] * d["scale"], 0.012 * max(w, h))
            ax.plot(x, y, color=color, lw=0.8)[0].set_clip_path(frame)  # after plot, which clips to the axes
        ax.text(corner[0] + w / 2, corner[1] - 0.03 * h, f"view {i}: {v['n']} points, RMS {v['rms']:.3g} px",
                fontsize=9, ha="center", va="bottom")
    ax.set(xlim=(0, extent[0]), ylim=(extent[1], 0), aspect="equal")  # image convention: y down
    ax.set_frame_on(False)
    bottom_cols = range(n - (rows - 1) * cols)  # the columns with a frame in the bottom row
    _ticks(ax, x=_tile_ticks([c * pitch[0] for c in bottom_cols], w),
           y=_tile_ticks([r * pitch[1] for r in range(rows)], h))
    fig.suptitle(f"Reprojection residuals [px] (arrows x{d['scale']:.3g}; blue inliers, red outliers)", fontsize=11)
    return fig


# --------------------------------------------------------------------------------------
# residual histogram
# --------------------------------------------------------------------------------------


def histogram_data(cal, n_bins: int = 59, *, norm=None) -> dict:
    """Histogram of the residual norms of all observations, counted from all of them.

    ``norm`` (:func:`residual_norms`) is computed when not given. Returns ``{"edges":
    (n_bins + 1,) px, "inliers": (n_bins,) counts, "outliers": (n_bins,) counts, "n_in":
    int, "n_out": int, "s": px}``; values beyond the 99.5th percentile fall in the last
    bin; ``s = RMS / sqrt(2)`` scales the Rayleigh curve.
    """
    norm = residual_norms(cal) if norm is None else norm
    ok = np.isfinite(norm)
    r, outlier = norm[ok], np.broadcast_to(~_inliers(cal), norm.shape)[ok]
    top = max(np.nan_to_num(_percentile(r, 99.5), nan=1.0), 1e-9)
    k = np.minimum((r * (n_bins / top)).astype(np.int64), n_bins - 1)  # equal bins: the index directly
    counts = np.bincount(k + n_bins * outlier, minlength=2 * n_bins).reshape(2, n_bins)
    n_out = int(counts[1].sum())
    return {"edges": np.linspace(0, top, n_bins + 1), "inliers": counts[0], "outliers": counts[1],
            "n_in": int(r.size) - n_out, "n_out": n_out,
            "s": float(cal.rms_px / np.sqrt(2))}  # per coordinate; below sigma_px by the dof fitted


def _key(ax, entries) -> None:
    """A legend as lines of coloured text at the upper right of ``ax``: ``entries =
    [(text, colour), ...]`` (matplotlib's legend, a laid-out box of handles and texts,
    cost a quarter of the histogram)."""
    from matplotlib.transforms import offset_copy

    for k, (text, color) in enumerate(entries):
        at = offset_copy(ax.transAxes, fig=ax.figure, x=-6, y=-6 - 1.5 * _SMALL * k, units="points")
        ax.text(1, 1, text, color=color, transform=at, ha="right", va="top", fontsize=_SMALL)


def draw_histogram(d: dict):
    """Figure of :func:`histogram_data`, with the Rayleigh density of isotropic 2-D
    Gaussian residuals of the same RMS."""
    fig = _figure(6, 3.2, margins=(0.75, 0.15, 0.55, 0.15))
    ax = fig.add_subplot()
    edges = d["edges"]
    ax.stairs(d["inliers"], edges, fill=True, color="tab:blue")
    key = [(f"inliers ({d['n_in']} obs.)", "tab:blue")]
    if d["n_out"]:
        ax.stairs(d["outliers"], edges, fill=True, color="tab:red", alpha=0.7)
        key.append((f"outliers ({d['n_out']} obs.)", "tab:red"))
    s = d["s"]
    if d["n_in"] and np.isfinite(s) and s > 0:  # |r| of isotropic 2-D Gaussian residuals is Rayleigh(s)
        r = np.linspace(0, edges[-1], 200)
        pdf = r / s**2 * np.exp(-0.5 * (r / s) ** 2)
        ax.plot(r, pdf * d["n_in"] * (edges[1] - edges[0]), "k--", lw=1)
        key.append((f"dashed: Rayleigh density, RMS/sqrt(2) = {s:.3g} px", "k"))
    ax.set_xlabel("residual norm [px] (clipped at the 99.5th percentile)", fontsize=8)
    ax.set_ylabel("observations", fontsize=8)
    ax.set_ylim(0, 1.2 * ax.get_ylim()[1])  # headroom: no bar under the key
    _ticks(ax)
    _key(ax, key)
    return fig


# --------------------------------------------------------------------------------------
# reconstruction: front and oblique
# --------------------------------------------------------------------------------------

#: The two views of the reconstruction: (title, azimuth deg about the camera's y axis,
#: elevation deg about its x axis) of an orthographic view of the camera frame.
VIEWS = (("front (along the optical axis)", 0.0, 0.0), ("oblique", 40.0, -25.0))


def reconstruction_data(cal, unit: str = "units") -> dict:
    """The scene points and the camera positions in the axes of the first view's camera.

    Returns ``{"X": (k, 3) camera-frame coordinates of at most MAX_POINTS points, "T":
    (n_views, 3) camera centres, "axes": (3, 3) robot x, y, z axes (rows, camera frame),
    "n": points reconstructed, "unit": str}``; lengths in ``unit``.
    """
    ok = np.flatnonzero(np.isfinite(cal.X[:, 0]))
    R_cam, C = cal.camera_poses()
    R = R_cam[0]  # world -> camera: rows of R are the camera axes in the world
    return {"X": cal.X[_subsample(ok, MAX_POINTS)] @ R.T, "T": C @ R.T, "axes": R.T.copy(), "n": int(ok.size),
            "unit": unit}


def _view_rotation(azim_deg: float, elev_deg: float) -> np.ndarray:
    """``(3, 3)``: camera frame -> view frame (x right, y down, z away from the viewer),
    turned by ``azim_deg`` about the camera's y axis, then ``elev_deg`` about x."""
    a, e = np.radians(azim_deg), np.radians(elev_deg)
    Ry = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    return Rx @ Ry


def _depth_groups(z: np.ndarray, n_colors: int = 8) -> list[tuple[np.ndarray, tuple]]:
    """The points of depths ``z (k,)`` in ``n_colors`` equal depth bins: ``[(indices,
    viridis colour), ...]``, farthest first (drawn in this order, nearer points cover
    farther ones). One ``Line2D`` of markers per bin: Agg stamps a marker drawn once,
    where ``scatter`` draws a path per point."""
    from matplotlib import colormaps

    if not z.size:
        return []
    bins = np.minimum(((z - z.min()) * (n_colors / max(np.ptp(z), 1e-300))).astype(np.int64), n_colors - 1)
    viridis = colormaps["viridis"]
    return [(np.flatnonzero(bins == b), viridis((b + 0.5) / n_colors)) for b in range(n_colors - 1, -1, -1)]


def _polyline(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """``(2, 3 k)`` x and y of segments ``starts (k, 2)`` -> ``ends (k, 2)`` as one
    NaN-separated polyline (one ``Line2D`` for all)."""
    return np.stack([starts, ends, np.full_like(starts, np.nan)], axis=1).reshape(-1, 2).T


def _draw_projection(ax, d: dict, groups: list, V: np.ndarray) -> None:
    """One orthographic view ``V (3, 3)`` of the points (``groups`` of
    :func:`_depth_groups`: colour = depth along the optical axis), the camera centres
    with their optical axes, and the robot frame's axes."""
    X, T = d["X"] @ V.T, d["T"] @ V.T
    both = np.vstack([d["X"], d["T"]])
    span = float(np.ptp(both, axis=0).max()) if both.size else 1.0
    size = 1.4 if len(X) > 2000 else 2.8  # marker diameter, points
    for idx, color in groups:
        ax.plot(X[idx, 0], X[idx, 1], ls="none", marker="o", ms=size, mew=0, color=color)
    stub = (V @ [0.0, 0.0, 0.15 * span])[:2]  # the optical axis (camera z), drawn from each centre
    ax.plot(*_polyline(T[:, :2], T[:, :2] + stub), color="tab:red", lw=1)
    ax.plot(T[:, 0], T[:, 1], "^", color="tab:red", ms=6)
    corner = np.array([X[:, 0].min(), X[:, 1].max()]) if X.size else np.zeros(2)  # bottom left (y down)
    origin = corner + 0.1 * span * np.array([1.0, -1.0])
    axes = (d["axes"] @ V.T)[:, :2]  # the robot frame, as a small triad in a corner
    ax.plot(*_polyline(np.broadcast_to(origin, axes.shape), origin + 0.12 * span * axes), color="0.3", lw=1)
    for name, axis in zip("xyz", axes):
        ax.text(*(origin + 0.17 * span * axis), name, fontsize=_SMALL, color="0.3", ha="center", va="center")
    ax.set_aspect("equal", adjustable="datalim")
    ax.invert_yaxis()  # image convention: y down
    _ticks(ax)


def draw_reconstruction(d: dict):
    """Figure of :func:`reconstruction_data`: front and oblique orthographic views
    (paper Figs. 9-10), points coloured by depth, robot axes shown as a triad."""
    fig = _figure(11, 4.8, margins=(0.6, 0.15, 0.5, 0.6))
    fig.subplots_adjust(wspace=0.2)
    unit = d["unit"]
    groups = _depth_groups(d["X"][:, 2])
    for k, (title, azim, elev) in enumerate(VIEWS):
        ax = fig.add_subplot(1, 2, k + 1)
        _draw_projection(ax, d, groups, _view_rotation(azim, elev))
        _title(ax, title, 10)
        ax.set_xlabel(f"camera x [{unit}]" if k == 0 else f"[{unit}]", fontsize=8)
        ax.set_ylabel(f"camera y [{unit}]" if k == 0 else "", fontsize=8)
    fig.suptitle(f"Reconstruction: {d['n']} points coloured by depth (dark near), the {len(d['T'])} camera centres "
                 "(red), the robot axes x y z; camera frame at T = 0", fontsize=10)
    return fig


# --------------------------------------------------------------------------------------
# projection uncertainty
# --------------------------------------------------------------------------------------


#: The frames of :func:`projection_std`: what is held fixed while the calibration varies.
PROJECTION_FRAMES = ("camera", "robot")


def projection_std(cal, grid=(48, 36), uv=None, *, size=None, frame: str = "camera"
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Projection uncertainty over the image: the standard deviation (px, worst direction)
    of where a point on a pixel's ray, at the median scene depth, projects, propagated
    from the covariance ``Sigma`` as ``J Sigma J^T`` (``J`` the pixel's derivatives), on a
    ``grid = (gw, gh)`` over the image ``size`` (default :func:`image_box`).

    ``frame="camera"``: the point is held in the camera frame, so only the intrinsics and
    distortion move it. ``frame="robot"``: it is held in the robot's frame (the scene's),
    as when a point given in robot coordinates is projected: the camera's orientation
    ``rx, ry, rz`` (``x_c <- exp([w]x) x_c``) and, where all three of its directions are
    determined, its offset in the flange ``t`` (``x_c <- x_c - R dt``) move it too, with
    their correlations with the intrinsics (mrcal's projection uncertainty, the robot
    frame as the reference). Neither includes a future view's own robot pose error.
    Returns ``(u (gw,), v (gh,), std (gh, gw))`` or None without a covariance."""
    from ..geometry.camera import DIST_NAMES, INTRINSIC_PARAMS, project_camera_frame

    if frame not in PROJECTION_FRAMES:
        raise ValueError(f"frame must be one of {PROJECTION_FRAMES}, got {frame!r}")
    names = list(cal.param_names)
    carried = set(INTRINSIC_PARAMS) | set(DIST_NAMES)
    if frame == "robot":
        carried |= {"rx", "ry", "rz"} | ({"t_x", "t_y", "t_z"} if cal.hand_eye is not None else set())
    idx = [k for k, nm in enumerate(names) if nm in carried]
    if cal.cov is None or not idx:
        return None
    w, h = size or image_box(cal, uv)
    u, v = np.linspace(0, w - 1, grid[0]), np.linspace(0, h - 1, grid[1])
    uu, vv = np.meshgrid(u, v)
    rays = cal.camera.pixels_to_rays(np.stack([uu, vv], axis=-1))
    ok = np.isfinite(cal.X[:, 0])
    some = _subsample(np.flatnonzero(ok), 100_000)  # the median depth of 10^5 points is as good
    R_cam, C = cal.camera_poses()
    depth = np.median((cal.X[some] - C[0]) @ R_cam[0, 2]) if some.size else 1.0
    xc = np.moveaxis(rays * depth, -1, 0)  # (3, gh, gw)
    p = project_camera_frame(cal.camera.intrinsics, cal.camera.dist5, xc, jacobian=True)
    J = np.stack([_projection_derivative(p, xc, names[k], cal) for k in idx], axis=-1)  # (2, gh, gw, q)
    S = cal.cov[np.ix_(idx, idx)]
    C = np.einsum("a...p,pq,b...q->...ab", J, S, J)  # (gh, gw, 2, 2)
    return u, v, np.sqrt(np.maximum(np.linalg.eigvalsh(C)[..., -1], 0.0))


def _projection_derivative(p, xc: np.ndarray, name: str, cal) -> np.ndarray:
    """``d pixel / d name`` ``(2, ...)`` of the camera-frame points ``xc (3, ...)``
    projected as ``p`` (:class:`~transcalib.geometry.camera.Projection`); rotations per
    degree, as in the covariance."""
    from ..geometry.camera import DIST_NAMES, INTRINSIC_PARAMS

    if name in INTRINSIC_PARAMS:
        basis = np.zeros((5, 1))
        basis[list(INTRINSIC_PARAMS[name])] = 1.0
        return p.intrinsic_jacobian(basis)[0]
    if name in DIST_NAMES:
        return p.J_dist[DIST_NAMES.index(name)]
    if name in ("rx", "ry", "rz"):  # d x_c = w x x_c, w along one camera axis
        axis = np.zeros(3)
        axis[("rx", "ry", "rz").index(name)] = np.radians(1.0)
        move = np.cross(axis, xc, axis=0)
    else:  # the offset t in the flange: d x_c = -R dt
        move = -cal.hand_eye.R.T[:, ("t_x", "t_y", "t_z").index(name)].reshape((3,) + (1,) * (xc.ndim - 1))
        move = np.broadcast_to(move, xc.shape)
    return np.einsum("ab...,b...->a...", p.P, move)


def uncertainty_data(cal, uv=None, n_points: int = 3000, *, size=None) -> dict | None:
    """:func:`projection_std` in both frames and the observations of at most ``n_points``
    points.

    Returns ``{"u": (gw,), "v": (gh,), "std": {frame: (gh, gw) px}, "obs": (k, 2) px}``
    (frames :data:`PROJECTION_FRAMES`; ``"robot"`` absent when the covariance has no
    orientation) or None without a covariance.
    """
    maps = {frame: projection_std(cal, uv=uv, size=size, frame=frame) for frame in PROJECTION_FRAMES}
    if maps["camera"] is None:
        return None
    if "rx" not in cal.param_names:
        del maps["robot"]
    obs = observed_pixels(cal, uv)[:, _subsample(np.arange(cal.n_points), n_points)].reshape(-1, 2)
    u, v, _ = maps["camera"]
    return {"u": u, "v": v, "std": {frame: m[2] for frame, m in maps.items()}, "obs": obs[np.isfinite(obs[:, 0])]}


#: Panel titles of :func:`draw_uncertainty`.
_FRAME_TITLES = {"camera": "A point held in the camera frame\n(intrinsics and lens)",
                 "robot": "A point held in the scene's (robot) frame\n(also the camera's orientation and offset)"}


def draw_uncertainty(d: dict | None):
    """Figure of :func:`uncertainty_data`: one panel per frame on one colour scale,
    contours at the 10th, 50th and 90th percentiles, observations overlaid (a note when
    there is no covariance)."""
    panels = [] if d is None else list(d["std"])
    width = 0.55 + 5.45 * max(len(panels), 1) + 0.95
    fig = _figure(width, 4.8, margins=(0.55, 0.95, 0.4, 0.6))
    if d is None:
        ax = fig.add_subplot()
        ax.text(0.5, 0.5, "no covariance (linear estimate only): no uncertainty map", ha="center", va="center")
        ax.axis("off")
        return fig
    u, v = d["u"], d["v"]
    du, dv = (u[-1] - u[0]) / max(len(u) - 1, 1), (v[-1] - v[0]) / max(len(v) - 1, 1)
    top = max(float(np.max(std)) for std in d["std"].values())
    fig.subplots_adjust(wspace=0.12)
    for k, frame in enumerate(panels):
        std = d["std"][frame]
        ax = fig.add_subplot(1, len(panels), k + 1)
        im = ax.imshow(std, cmap="magma", interpolation="nearest", vmin=0.0, vmax=top,  # one cell per grid point
                       extent=(u[0] - du / 2, u[-1] + du / 2, v[-1] + dv / 2, v[0] - dv / 2))
        if np.ptp(std) > 0:
            cs = ax.contour(u, v, std, levels=np.unique(np.quantile(std, [0.1, 0.5, 0.9])), colors="w", linewidths=0.7)
            ax.clabel(cs, fontsize=_SMALL, fmt="%.3g")
        ax.plot(d["obs"][:, 0], d["obs"][:, 1], ",", color="c", alpha=0.6)
        ax.set_xlim(u[0], u[-1])
        ax.set_ylim(v[-1], v[0])
        ax.set_aspect("equal")
        _ticks(ax)
        _title(ax, _FRAME_TITLES[frame], 9)
    _colour_scale(fig, im, (1 - 0.8 / width, 0.4 / 4.8, 0.15 / width, 1 - 1.0 / 4.8), "projection std [px]")
    return fig


# --------------------------------------------------------------------------------------
# errors against the truth (simulated input)
# --------------------------------------------------------------------------------------


def _point_errors(cal, truth: dict, point_ids) -> np.ndarray | None:
    """``|X - X_true|`` of the reconstructed points (finite ones), or None when the point
    ids do not index ``truth["points"]``."""
    from ..io.ids import truth_index

    if "points" not in truth:
        return None
    Xt = np.asarray(truth["points"], float)
    idx = truth_index(point_ids, len(Xt))
    if idx is None:
        return None
    err = np.linalg.norm(cal.X - Xt[idx], axis=1)
    return err[np.isfinite(err)]


def truth_data(cal, truth: dict, point_ids=None, unit: str = "units", n_bins: int = 60) -> dict:
    """Intrinsics' errors in standard deviations and the histogram of the point errors.

    Returns ``{"names": [str], "z": [error / std], "edges": (n_bins + 1,) or None,
    "counts": (n_bins,) or None, "median": float, "max": float, "unit": str}``.
    """
    Kt = np.asarray(truth["K"], float)
    true = {"fx": Kt[0, 0], "fy": Kt[1, 1], "cx": Kt[0, 2], "cy": Kt[1, 2], "skew": Kt[0, 1]}
    est = dict(zip(("fx", "fy", "cx", "cy", "skew"), cal.camera.intrinsics[[0, 1, 2, 3, 4]]))
    names = [n for n in true if n in cal.std and np.isfinite(cal.std[n]) and cal.std[n] > 0]
    out = {"names": names, "z": [float((est[n] - true[n]) / cal.std[n]) for n in names], "edges": None,
           "counts": None, "median": float("nan"), "max": float("nan"), "unit": unit}
    err = _point_errors(cal, truth, point_ids)
    if err is not None and err.size:
        counts, edges = np.histogram(err, bins=n_bins)
        out.update(edges=edges, counts=counts, median=float(np.median(err)), max=float(err.max()))
    return out


def draw_truth(d: dict):
    """Figure of :func:`truth_data`: bars of error / std (green within 3), and the
    histogram of the point errors."""
    fig = _figure(11, 3.6, margins=(0.6, 0.15, 0.5, 0.35))
    fig.subplots_adjust(wspace=0.25)
    ax = fig.add_subplot(1, 2, 1)
    ax.bar(d["names"], d["z"], color=["tab:green" if abs(x) < 3 else "tab:red" for x in d["z"]])
    ax.axhspan(-3, 3, color="0.9", zorder=0)
    ax.set_ylabel("error / std", fontsize=8)
    ax.set_title("Intrinsics: error against the truth, in standard deviations", fontsize=10)
    ax.tick_params(labelsize=_SMALL)
    ax = fig.add_subplot(1, 2, 2)
    if d["counts"] is not None:
        ax.stairs(d["counts"], d["edges"], fill=True, color="tab:blue")
        ax.set_xlabel(f"|X - X_true| [{d['unit']}]", fontsize=8)
        ax.set_title(f"Point errors: median {d['median']:.3g}, max {d['max']:.3g} {d['unit']}", fontsize=10)
        _ticks(ax)
    else:
        ax.text(0.5, 0.5, "point ids do not index the true points", ha="center")
        ax.axis("off")
    return fig


#: The drawing function of each figure file.
DRAW = {"residuals.png": draw_residuals, "residual_histogram.png": draw_histogram,
        "reconstruction.png": draw_reconstruction, "uncertainty.png": draw_uncertainty,
        "truth_errors.png": draw_truth}
