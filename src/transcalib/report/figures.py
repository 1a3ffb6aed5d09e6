"""The report's figures, one function each, drawn with matplotlib's Agg backend.

Every function takes the calibration (and what else it needs), returns a matplotlib
``Figure``, and draws at most a few thousand marks whatever the number of points
(points are subsampled with a fixed seed; statistics such as histograms use them all).
matplotlib is imported on first use: ``import transcalib`` stays light.
"""

from __future__ import annotations

import numpy as np

__all__ = ["residual_arrows", "residual_histogram", "reconstruction", "uncertainty_map", "truth_errors",
           "observed_pixels", "MAX_ARROWS", "MAX_POINTS"]

#: Largest number of residual arrows drawn per view, and of points in a 3-D plot.
MAX_ARROWS = 600
MAX_POINTS = 8000


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _subsample(idx: np.ndarray, k: int) -> np.ndarray:
    if idx.size <= k:
        return idx
    return np.sort(np.random.default_rng(0).choice(idx, k, replace=False))


def observed_pixels(cal, uv=None) -> np.ndarray:
    """Observed pixels ``(n_views, n_points, 2)``: ``uv`` when given, else the prediction
    plus the residual (NaN where there is no residual)."""
    if uv is not None:
        return uv
    pred = cal.camera.project(np.nan_to_num(cal.X), cal.T)
    return pred + cal.residuals_px


def _image_box(cal, obs) -> tuple[float, float]:
    if cal.image_size is not None:
        return cal.image_size
    w, h = np.nanmax(obs.reshape(-1, 2), axis=0)
    return float(w) + 1, float(h) + 1


def residual_arrows(cal, uv=None, scale: float | None = None):
    """Residual arrows of every view over the image area (observed -> predicted is the
    residual's negative; arrows show observed minus predicted, magnified by ``scale``)."""
    plt = _plt()
    obs = observed_pixels(cal, uv)
    w, h = _image_box(cal, obs)
    res = cal.residuals_px
    norm = np.sqrt(np.sum(res**2, axis=2))
    finite = norm[np.isfinite(norm)]
    typical = np.percentile(finite[_subsample(np.arange(finite.size), 100_000)], 90) if finite.size else 1.0
    scale = scale or (0.05 * max(w, h) / max(typical, 1e-12))
    n = cal.n_views
    cols = min(n, 3)
    rows = -(-n // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for i, ax in enumerate(axes.ravel()):
        if i >= n:
            ax.axis("off")
            continue
        ok = np.flatnonzero(np.isfinite(res[i, :, 0]) & np.isfinite(obs[i, :, 0]))
        big = ok[np.argpartition(norm[i, ok], -50)[-50:]] if ok.size > 50 else ok  # the largest always shown
        pick = np.union1d(_subsample(ok, MAX_ARROWS), big)
        inl = np.ones(cal.n_points, bool) if cal.inliers is None else np.asarray(cal.inliers, bool)
        for mask, color, label in ((inl[pick], "tab:blue", "inlier"), (~inl[pick], "tab:red", "outlier")):
            p = pick[mask]
            if p.size:
                ax.quiver(obs[i, p, 0], obs[i, p, 1], res[i, p, 0] * scale, -res[i, p, 1] * scale, color=color,
                          angles="xy", scale_units="xy", scale=1, width=0.004, label=label)
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        rms = np.sqrt(np.nanmean(norm[i, ok] ** 2)) if ok.size else np.nan
        ax.set_title(f"view {i}: {ok.size} points, RMS {rms:.3g} px", fontsize=9)
        ax.tick_params(labelsize=7)
    fig.suptitle(f"Reprojection residuals (arrows x{scale:.3g})", fontsize=11)
    fig.tight_layout()
    return fig


def residual_histogram(cal):
    """Histogram of the residual norms of all observations (inliers and outliers)."""
    plt = _plt()
    norm = np.sqrt(np.sum(cal.residuals_px**2, axis=2))
    fig, ax = plt.subplots(figsize=(6, 3.2))
    inl = np.ones(cal.n_points, bool) if cal.inliers is None else np.asarray(cal.inliers, bool)
    a, b = norm[:, inl], norm[:, ~inl]
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    both = np.concatenate([a, b])
    top = np.percentile(both[_subsample(np.arange(both.size), 200_000)], 99.5) if both.size else 1.0
    bins = np.linspace(0, max(top, 1e-9), 60)
    ax.stairs(np.histogram(np.minimum(a, bins[-1]), bins=bins)[0], bins, fill=True, color="tab:blue",
              label=f"inliers ({a.size} obs.)")
    if b.size:
        ax.stairs(np.histogram(np.minimum(b, bins[-1]), bins=bins)[0], bins, fill=True, color="tab:red", alpha=0.7,
                  label=f"outliers ({b.size} obs.)")
    s = cal.rms_px / np.sqrt(2)  # per coordinate; below sigma_px by the degrees of freedom fitted
    if a.size and np.isfinite(s) and s > 0:  # |r| of isotropic 2-D Gaussian residuals is Rayleigh(s)
        r = np.linspace(0, bins[-1], 200)
        pdf = r / s**2 * np.exp(-0.5 * (r / s) ** 2)
        ax.plot(r, pdf * a.size * (bins[1] - bins[0]), "k--", lw=1, label=f"Rayleigh, RMS/sqrt(2) = {s:.3g} px")
    ax.set_xlabel("residual norm [px] (clipped at the 99.5th percentile)")
    ax.set_ylabel("observations")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def reconstruction(cal, unit: str = "units"):
    """The scene points and the camera positions, from the front (as the camera looks)
    and obliquely (paper Figs. 9-10)."""
    plt = _plt()
    ok = np.flatnonzero(np.isfinite(cal.X[:, 0]))
    X = cal.X[_subsample(ok, MAX_POINTS)]
    fig = plt.figure(figsize=(11, 4.8))
    axis = cal.R[2]  # the optical axis in world coordinates
    for k, (elev, azim, title) in enumerate(((None, None, "front (along the optical axis)"),
                                            (25, -60, "oblique"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        ax.scatter(X[:, 0], X[:, 1], X[:, 2], s=2, c=X @ axis, cmap="viridis", depthshade=False)
        T = cal.T
        ax.scatter(T[:, 0], T[:, 1], T[:, 2], s=40, c="tab:red", marker="^", label="camera centres")
        span = np.ptp(np.vstack([X, T]), axis=0).max() if X.size else 1.0
        for t in T:
            end = t + 0.15 * span * axis
            ax.plot([t[0], end[0]], [t[1], end[1]], [t[2], end[2]], color="tab:red", lw=1)
        if elev is None:  # look along the optical axis: elevation/azimuth of -axis
            v = -axis
            elev, azim = np.degrees(np.arcsin(np.clip(v[2], -1, 1))), np.degrees(np.arctan2(v[1], v[0]))
        ax.view_init(elev=elev, azim=azim)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(f"x [{unit}]", fontsize=8)
        ax.set_ylabel(f"y [{unit}]", fontsize=8)
        ax.set_zlabel(f"z [{unit}]", fontsize=8)
        ax.tick_params(labelsize=6)
        if k == 0:
            ax.legend(fontsize=8, loc="upper left")
    fig.suptitle(f"Reconstruction: {ok.size} points (robot frame), {cal.n_views} camera positions", fontsize=11)
    fig.tight_layout()
    return fig


def projection_std(cal, grid=(48, 36), uv=None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Projection uncertainty over the image: the standard deviation (px, worst direction)
    of where a pixel's ray lands, propagated from the covariance of the intrinsics and
    distortion (a point on the ray at the median scene depth, kept fixed in the camera
    frame). Returns ``(u (gw,), v (gh,), std (gh, gw))`` or None without a covariance."""
    from ..geometry.camera import DIST_NAMES, project_camera_frame

    names = list(cal.param_names)
    idx = [k for k, nm in enumerate(names) if nm in ("fx", "fy", "cx", "cy", "skew") + DIST_NAMES]
    if cal.cov is None or not idx:
        return None
    w, h = cal.image_size if cal.image_size is not None else _image_box(cal, observed_pixels(cal, uv))
    u, v = np.linspace(0, w - 1, grid[0]), np.linspace(0, h - 1, grid[1])
    uu, vv = np.meshgrid(u, v)
    rays = cal.camera.pixels_to_rays(np.stack([uu, vv], axis=-1))
    ok = np.isfinite(cal.X[:, 0])
    depth = np.median((cal.X[ok] - cal.T.mean(axis=0)) @ cal.R[2]) if ok.any() else 1.0
    xc = np.moveaxis(rays * depth, -1, 0)  # (3, gh, gw)
    p = project_camera_frame(cal.camera.intrinsics, cal.camera.dist5, xc, jacobian=True)
    order = ("fx", "fy", "cx", "cy", "skew")
    J_intr = p.intrinsic_jacobian(np.eye(5))
    J = np.stack([J_intr[order.index(names[k])] if names[k] in order else p.J_dist[DIST_NAMES.index(names[k])]
                  for k in idx], axis=-1)  # (2, gh, gw, p)
    S = cal.cov[np.ix_(idx, idx)]
    C = np.einsum("a...p,pq,b...q->...ab", J, S, J)  # (gh, gw, 2, 2)
    return u, v, np.sqrt(np.linalg.eigvalsh(C)[..., -1])


def uncertainty_map(cal, uv=None):
    """Colour map of :func:`projection_std` over the image, observations overlaid."""
    plt = _plt()
    result = projection_std(cal, uv=uv)
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    if result is None:
        ax.text(0.5, 0.5, "no covariance (linear estimate only): no uncertainty map", ha="center", va="center")
        ax.axis("off")
        return fig
    u, v, std = result
    im = ax.pcolormesh(u, v, std, shading="auto", cmap="magma")
    levels = np.quantile(std, [0.1, 0.5, 0.9])
    if np.ptp(std) > 0:
        cs = ax.contour(u, v, std, levels=np.unique(levels), colors="w", linewidths=0.7)
        ax.clabel(cs, fontsize=7, fmt="%.3g")
    obs = observed_pixels(cal, uv)
    pts = obs[:, _subsample(np.arange(cal.n_points), 3000)].reshape(-1, 2)
    pts = pts[np.isfinite(pts[:, 0])]
    ax.plot(pts[:, 0], pts[:, 1], ",", color="c", alpha=0.6)
    ax.set_xlim(u[0], u[-1])
    ax.set_ylim(v[-1], v[0])
    ax.set_aspect("equal")
    fig.colorbar(im, ax=ax, label="projection std [px]")
    ax.set_title("Projection uncertainty from the intrinsics' covariance", fontsize=10)
    fig.tight_layout()
    return fig


def truth_errors(cal, truth: dict, point_ids=None, unit: str = "units"):
    """For simulated input: parameter errors in standard deviations, and the histogram of
    the point errors ``|X - X_true|``."""
    plt = _plt()
    Kt = np.asarray(truth["K"], float)
    true = {"fx": Kt[0, 0], "fy": Kt[1, 1], "cx": Kt[0, 2], "cy": Kt[1, 2], "skew": Kt[0, 1]}
    est = dict(zip(("fx", "fy", "cx", "cy", "skew"), cal.camera.intrinsics[[0, 1, 2, 3, 4]]))
    names = [n for n in true if n in cal.std and np.isfinite(cal.std[n]) and cal.std[n] > 0]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    z = [(est[n] - true[n]) / cal.std[n] for n in names]
    axes[0].bar(names, z, color=["tab:green" if abs(x) < 3 else "tab:red" for x in z])
    axes[0].axhspan(-3, 3, color="0.9", zorder=0)
    axes[0].set_ylabel("error / std")
    axes[0].set_title("Intrinsics: error against the truth, in standard deviations", fontsize=10)
    ax = axes[1]
    if "points" in truth and point_ids is not None and all(str(p).isdigit() for p in point_ids):
        Xt = np.asarray(truth["points"], float)
        idx = np.array([int(p) for p in point_ids])
        if idx.size and idx.max() < len(Xt):
            err = np.linalg.norm(cal.X - Xt[idx], axis=1)
            err = err[np.isfinite(err)]
            ax.hist(err, bins=60, color="tab:blue")
            ax.set_xlabel(f"|X - X_true| [{unit}]")
            ax.set_title(f"Point errors: median {np.median(err):.3g}, max {err.max():.3g} {unit}", fontsize=10)
    else:
        ax.text(0.5, 0.5, "point ids do not index the true points", ha="center")
        ax.axis("off")
    fig.tight_layout()
    return fig
