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
"""

from __future__ import annotations

import io

import numpy as np

__all__ = ["residuals_data", "histogram_data", "reconstruction_data", "uncertainty_data", "truth_data",
           "draw_residuals", "draw_histogram", "draw_reconstruction", "draw_uncertainty", "draw_truth",
           "DRAW", "png", "projection_std", "observed_pixels", "image_box", "residual_norms", "MAX_ARROWS", "MAX_POINTS", "DPI"]

#: Largest number of residual arrows drawn per view (plus the 50 largest), and of
#: points in the reconstruction.
MAX_ARROWS = 600
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
    pred = cal.camera.project(np.nan_to_num(cal.X), cal.T)
    return pred + cal.residuals_px


def image_box(cal, uv=None) -> tuple[int, int]:
    """``(width, height)`` px: the image size, else the extent of the observations
    (``uv``, or the prediction plus residual)."""
    from ..io.export import image_size_or_extent

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


def _few_ticks(ax, n: int = 5) -> None:
    """At most ``n`` ticks per axis, small labels (fewer text artists to lay out and draw)."""
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(n))
    ax.yaxis.set_major_locator(MaxNLocator(n))
    ax.tick_params(labelsize=_SMALL)


def png(fig) -> bytes:
    """The figure as PNG bytes (drawn once, at :data:`DPI`; fast zlib level)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, pil_kwargs={"compress_level": 1})
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


def draw_residuals(d: dict):
    """Figure of :func:`residuals_data`: one panel per view, 3 per row, arrows magnified."""
    w, h = d["size"]
    n = len(d["views"])
    cols = min(n, 3)
    rows = -(-n // cols)
    fig = _figure(4.2 * cols, 3.4 * rows, margins=(0.5, 0.15, 0.35, 0.75))
    fig.subplots_adjust(wspace=0.25, hspace=0.35)
    for i, v in enumerate(d["views"]):
        ax = fig.add_subplot(rows, cols, i + 1)
        for mask, color, label in ((v["inlier"], "tab:blue", "inlier"), (~v["inlier"], "tab:red", "outlier")):
            if mask.any():
                ax.quiver(v["xy"][mask, 0], v["xy"][mask, 1], v["d"][mask, 0] * d["scale"],
                          -v["d"][mask, 1] * d["scale"], color=color, angles="xy", scale_units="xy", scale=1,
                          width=0.004, label=label)
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(f"view {i}: {v['n']} points, RMS {v['rms']:.3g} px", fontsize=9)
        _few_ticks(ax)
    fig.suptitle(f"Reprojection residuals (arrows x{d['scale']:.3g}; blue inliers, red outliers)", fontsize=11)
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


def draw_histogram(d: dict):
    """Figure of :func:`histogram_data`, with the Rayleigh density of isotropic 2-D
    Gaussian residuals of the same RMS."""
    fig = _figure(6, 3.2, margins=(0.75, 0.15, 0.55, 0.15))
    ax = fig.add_subplot()
    edges = d["edges"]
    ax.stairs(d["inliers"], edges, fill=True, color="tab:blue", label=f"inliers ({d['n_in']} obs.)")
    if d["n_out"]:
        ax.stairs(d["outliers"], edges, fill=True, color="tab:red", alpha=0.7, label=f"outliers ({d['n_out']} obs.)")
    s = d["s"]
    if d["n_in"] and np.isfinite(s) and s > 0:  # |r| of isotropic 2-D Gaussian residuals is Rayleigh(s)
        r = np.linspace(0, edges[-1], 200)
        pdf = r / s**2 * np.exp(-0.5 * (r / s) ** 2)
        ax.plot(r, pdf * d["n_in"] * (edges[1] - edges[0]), "k--", lw=1, label=f"Rayleigh, RMS/sqrt(2) = {s:.3g} px")
    ax.set_xlabel("residual norm [px] (clipped at the 99.5th percentile)", fontsize=8)
    ax.set_ylabel("observations", fontsize=8)
    _few_ticks(ax, 6)
    ax.legend(fontsize=_SMALL)
    return fig


# --------------------------------------------------------------------------------------
# reconstruction: front and oblique
# --------------------------------------------------------------------------------------

#: The two views of the reconstruction: (title, azimuth deg about the camera's y axis,
#: elevation deg about its x axis) of an orthographic view of the camera frame.
VIEWS = (("front (along the optical axis)", 0.0, 0.0), ("oblique", 40.0, -25.0))


def reconstruction_data(cal, unit: str = "units") -> dict:
    """The scene points and the camera positions in the camera frame of ``T = 0``.

    Returns ``{"X": (k, 3) camera-frame coordinates of at most MAX_POINTS points, "T":
    (n_views, 3) camera centres, "axes": (3, 3) robot x, y, z axes (rows, camera frame),
    "n": points reconstructed, "unit": str}``; lengths in ``unit``.
    """
    ok = np.flatnonzero(np.isfinite(cal.X[:, 0]))
    R = cal.R  # world -> camera: rows of R are the camera axes in the world
    return {"X": cal.X[_subsample(ok, MAX_POINTS)] @ R.T, "T": cal.T @ R.T, "axes": R.T.copy(), "n": int(ok.size),
            "unit": unit}


def _view_rotation(azim_deg: float, elev_deg: float) -> np.ndarray:
    """``(3, 3)``: camera frame -> view frame (x right, y down, z away from the viewer),
    turned by ``azim_deg`` about the camera's y axis, then ``elev_deg`` about x."""
    a, e = np.radians(azim_deg), np.radians(elev_deg)
    Ry = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    return Rx @ Ry


def _draw_projection(ax, d: dict, V: np.ndarray, legend: bool) -> None:
    """One orthographic view ``V (3, 3)`` of the points (colour: depth along the optical
    axis), the camera centres with their optical axes, and the robot frame's axes."""
    X, T = d["X"] @ V.T, d["T"] @ V.T
    both = np.vstack([d["X"], d["T"]])
    span = float(np.ptp(both, axis=0).max()) if both.size else 1.0
    ax.scatter(X[:, 0], X[:, 1], s=2 if len(X) > 2000 else 8, c=d["X"][:, 2], cmap="viridis", linewidths=0)
    stub = (V @ [0.0, 0.0, 0.15 * span])[:2]  # the optical axis (camera z), drawn from each centre
    ax.plot(np.stack([T[:, 0], T[:, 0] + stub[0]]), np.stack([T[:, 1], T[:, 1] + stub[1]]), color="tab:red", lw=1)
    ax.plot(T[:, 0], T[:, 1], "^", color="tab:red", ms=6, label="camera centres")
    corner = np.array([X[:, 0].min(), X[:, 1].max()]) if X.size else np.zeros(2)  # bottom left (y down)
    origin = corner + 0.1 * span * np.array([1.0, -1.0])
    for name, axis in zip("xyz", d["axes"] @ V.T):  # the robot frame, as a small triad in a corner
        tip = origin + 0.12 * span * axis[:2]
        ax.plot([origin[0], tip[0]], [origin[1], tip[1]], color="0.3", lw=1)
        ax.text(*(origin + 0.17 * span * axis[:2]), name, fontsize=_SMALL, color="0.3", ha="center", va="center")
    ax.set_aspect("equal", adjustable="datalim")
    ax.invert_yaxis()  # image convention: y down
    _few_ticks(ax)
    if legend:
        ax.legend(fontsize=_SMALL, loc="upper left")


def draw_reconstruction(d: dict):
    """Figure of :func:`reconstruction_data`: front and oblique orthographic views
    (paper Figs. 9-10), points coloured by depth, robot axes shown as a triad."""
    fig = _figure(11, 4.8, margins=(0.6, 0.15, 0.5, 0.6))
    fig.subplots_adjust(wspace=0.2)
    unit = d["unit"]
    for k, (title, azim, elev) in enumerate(VIEWS):
        ax = fig.add_subplot(1, 2, k + 1)
        _draw_projection(ax, d, _view_rotation(azim, elev), legend=k == 0)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(f"camera x [{unit}]" if k == 0 else f"[{unit}]", fontsize=8)
        ax.set_ylabel(f"camera y [{unit}]" if k == 0 else "", fontsize=8)
    fig.suptitle(f"Reconstruction: {d['n']} points, {len(d['T'])} camera positions; camera frame at T = 0, "
                 "colour = depth, x y z = robot axes", fontsize=10)
    return fig


# --------------------------------------------------------------------------------------
# projection uncertainty
# --------------------------------------------------------------------------------------


def projection_std(cal, grid=(48, 36), uv=None, *, size=None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Projection uncertainty over the image: the standard deviation (px, worst direction)
    of where a pixel's ray lands, propagated from the covariance of the intrinsics and
    distortion (a point on the ray at the median scene depth, kept fixed in the camera
    frame), on a ``grid = (gw, gh)`` over the image ``size`` (default :func:`image_box`).
    Returns ``(u (gw,), v (gh,), std (gh, gw))`` or None without a covariance."""
    from ..geometry.camera import DIST_NAMES, project_camera_frame

    names = list(cal.param_names)
    idx = [k for k, nm in enumerate(names) if nm in ("fx", "fy", "cx", "cy", "skew") + DIST_NAMES]
    if cal.cov is None or not idx:
        return None
    w, h = size or image_box(cal, uv)
    u, v = np.linspace(0, w - 1, grid[0]), np.linspace(0, h - 1, grid[1])
    uu, vv = np.meshgrid(u, v)
    rays = cal.camera.pixels_to_rays(np.stack([uu, vv], axis=-1))
    ok = np.isfinite(cal.X[:, 0])
    some = _subsample(np.flatnonzero(ok), 100_000)  # the median depth of 10^5 points is as good
    depth = np.median((cal.X[some] - cal.T.mean(axis=0)) @ cal.R[2]) if some.size else 1.0
    xc = np.moveaxis(rays * depth, -1, 0)  # (3, gh, gw)
    p = project_camera_frame(cal.camera.intrinsics, cal.camera.dist5, xc, jacobian=True)
    order = ("fx", "fy", "cx", "cy", "skew")
    J_intr = p.intrinsic_jacobian(np.eye(5))
    J = np.stack([J_intr[order.index(names[k])] if names[k] in order else p.J_dist[DIST_NAMES.index(names[k])]
                  for k in idx], axis=-1)  # (2, gh, gw, p)
    S = cal.cov[np.ix_(idx, idx)]
    C = np.einsum("a...p,pq,b...q->...ab", J, S, J)  # (gh, gw, 2, 2)
    return u, v, np.sqrt(np.linalg.eigvalsh(C)[..., -1])


def uncertainty_data(cal, uv=None, n_points: int = 3000, *, size=None) -> dict | None:
    """:func:`projection_std` and the observations of at most ``n_points`` points.

    Returns ``{"u": (gw,), "v": (gh,), "std": (gh, gw) px, "obs": (k, 2) px}`` or None
    without a covariance.
    """
    result = projection_std(cal, uv=uv, size=size)
    if result is None:
        return None
    obs = observed_pixels(cal, uv)[:, _subsample(np.arange(cal.n_points), n_points)].reshape(-1, 2)
    u, v, std = result
    return {"u": u, "v": v, "std": std, "obs": obs[np.isfinite(obs[:, 0])]}


def draw_uncertainty(d: dict | None):
    """Figure of :func:`uncertainty_data`: colour map, contours at the 10th, 50th and
    90th percentiles, observations overlaid (a note when there is no covariance)."""
    fig = _figure(6.4, 4.6, margins=(0.55, 0.95, 0.4, 0.35))
    ax = fig.add_subplot()
    if d is None:
        ax.text(0.5, 0.5, "no covariance (linear estimate only): no uncertainty map", ha="center", va="center")
        ax.axis("off")
        return fig
    u, v, std = d["u"], d["v"], d["std"]
    im = ax.pcolormesh(u, v, std, shading="auto", cmap="magma")
    if np.ptp(std) > 0:
        cs = ax.contour(u, v, std, levels=np.unique(np.quantile(std, [0.1, 0.5, 0.9])), colors="w", linewidths=0.7)
        ax.clabel(cs, fontsize=_SMALL, fmt="%.3g")
    ax.plot(d["obs"][:, 0], d["obs"][:, 1], ",", color="c", alpha=0.6)
    ax.set_xlim(u[0], u[-1])
    ax.set_ylim(v[-1], v[0])
    ax.set_aspect("equal")
    _few_ticks(ax)
    cax = fig.add_axes((1 - 0.8 / 6.4, 0.4 / 4.6, 0.15 / 6.4, 1 - 0.75 / 4.6))
    fig.colorbar(im, cax=cax, label="projection std [px]")
    cax.tick_params(labelsize=_SMALL)
    ax.set_title("Projection uncertainty from the intrinsics' covariance", fontsize=10)
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
        _few_ticks(ax, 6)
    else:
        ax.text(0.5, 0.5, "point ids do not index the true points", ha="center")
        ax.axis("off")
    return fig


#: The drawing function of each figure file.
DRAW = {"residuals.png": draw_residuals, "residual_histogram.png": draw_histogram,
        "reconstruction.png": draw_reconstruction, "uncertainty.png": draw_uncertainty,
        "truth_errors.png": draw_truth}
