"""The calibration report: ``report.html`` (one self-contained file) and its figures as PNG.

:func:`write_report` writes ``report.html`` with the parameters and their uncertainty,
every diagnostic, an interactive 3-D view (:mod:`.viewer`: the points, the camera
frustum of every view, the robot axes, the flange (or eye-to-hand the base) where known,
an optional extra cloud),
the residuals (arrows per view and histogram), the reconstruction (front and oblique,
with the camera positions), the projection-uncertainty map and, for simulated input, the
errors against the truth. Figures are embedded as base64 PNG and also written to
``figures/``; the 3-D view's data, three.js (vendored, ``vendor/``) and its script are
inline. No external resources: the page opens offline and loads nothing.

Two steps: :func:`report_data` reduces the calibration to a :class:`ReportData` (numpy,
at any number of points: the figures' data are kilobytes, the 3-D view's at most
:data:`~transcalib.report.viewer.MAX_POINTS` points, about 1.3 MB); :func:`render_report`
draws and writes it (matplotlib). ``transcalib calibrate`` runs the second in a
:class:`~transcalib.report.worker.ReportWorker` process.
"""

from __future__ import annotations

import base64
import html
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.files import atomic_write
from .poses import ViewPoses, view_poses
from .viewer import MAX_POINTS, VIEWER_CSS, PointCloud, ViewerData, viewer_data, viewer_html

__all__ = ["write_report", "report_data", "render_report", "ReportData", "FIGURES", "PointCloud", "ViewerData",
           "ViewPoses", "view_poses", "viewer_data"]

#: Figure files, in report order.
FIGURES = ("residuals.png", "residual_histogram.png", "reconstruction.png", "uncertainty.png", "truth_errors.png")


def _row(name, value, std=None, truth=None, unit="") -> str:
    def f(x):
        return "" if x is None or not np.isfinite(x) else f"{x:.6g}"

    err = "" if truth is None else f(value - truth)
    return (f"<tr><td>{html.escape(name)}</td><td>{f(value)}</td><td>{f(std)}</td><td>{f(truth)}</td>"
            f"<td>{err}</td><td>{html.escape(unit)}</td></tr>")


def _parameters(cal, truth) -> str:
    cam = cal.camera
    K = cam.K
    Kt = None if truth is None else np.asarray(truth["K"], float)
    rows = []
    for name, (a, b) in {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2), "skew": (0, 1)}.items():
        rows.append(_row(name, K[a, b], cal.std.get(name), None if Kt is None else Kt[a, b], "px"))
    from ..geometry.camera import DIST_MODELS

    dt = None if truth is None else np.resize(np.asarray(truth.get("dist", []), float), 5)
    for k, name in enumerate(("k1", "k2", "p1", "p2", "k3")):
        if name in DIST_MODELS[cam.dist_model]:
            rows.append(_row(name, cam.dist5[k], cal.std.get(name), None if dt is None else dt[k]))
    for name in ("rx", "ry", "rz"):
        if name in cal.std:
            rows.append(_row(f"rotation {name}", None, cal.std[name], unit="deg"))
    rows.append(_row("RMS reprojection", cal.rms_px, unit="px"))
    loo = cal.info.get("leave_one_view_out")
    if loo and loo.get("rms_px") is not None:  # check/prediction.py
        rows.append(_row("RMS of each view predicted from the others", loo["rms_px"], unit="px"))
        rows.append(_row("the same, as the covariance predicts it", loo["predicted_rms_px"], unit="px"))
    if cal.sigma_px is not None:
        rows.append(_row("pixel noise sigma", cal.sigma_px, unit="px per coordinate"))
    R = "<br>".join(" ".join(f"{x:+.6f}" for x in r) for r in cam.R)
    extra = ""
    if truth is not None and "R" in truth:
        from ..geometry.rotation import rotation_angle_deg

        extra = f"<p>Angle between R and the true R: {rotation_angle_deg(cam.R @ np.asarray(truth['R']).T):.4g} deg</p>"
    head = "<tr><th>parameter</th><th>value</th><th>std</th><th>truth</th><th>error</th><th>unit</th></tr>"
    return (f"<table>{head}{''.join(rows)}</table>"
            f"<p>Distortion model: <code>{html.escape(cam.dist_model)}</code>; image size: "
            f"{'unknown' if cam.image_size is None else '%d x %d px' % cam.image_size}</p>"
            f"<p>R (robot frame &rarr; camera frame):</p><pre>{R}</pre>{extra}")


def _diagnostics(cal) -> str:
    if not cal.diagnostics:
        return "<p class='ok'>No warnings: every check passed.</p>"
    items = "".join(f"<li><code>{html.escape(getattr(d, 'code', ''))}</code> {html.escape(str(d))}</li>"
                    for d in cal.diagnostics)
    return f"<ul class='warn'>{items}</ul>"


def _figure_data(cal, uv, truth, point_ids, unit, size) -> dict:
    """``{file name: (title, data)}`` of every figure, reduced by ``figures.*_data``."""
    from . import figures as F

    norm = F.residual_norms(cal)  # once, for every figure
    out = {"residuals.png": ("Residuals per view", F.residuals_data(cal, uv, size=size, norm=norm)),
           "residual_histogram.png": ("Residual histogram", F.histogram_data(cal, norm=norm)),
           "reconstruction.png": ("Reconstruction", F.reconstruction_data(cal, unit)),
           "uncertainty.png": ("Projection uncertainty", F.uncertainty_data(cal, uv, size=size))}
    if truth is not None:
        out["truth_errors.png"] = ("Errors against the truth", F.truth_data(cal, truth, point_ids, unit))
    return out


_CSS = ("body{font-family:sans-serif;max-width:1150px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}"
        "img{max-width:100%;border:1px solid #eee}.warn li{color:#a40}.ok{color:#080}")


@dataclass(frozen=True)
class ReportData:
    """Everything the report shows, reduced: at most a megabyte or two whatever the
    number of points.

    Attributes
    ----------
    title : str
    sections : list of str
        The HTML before the figures (heading, summary, parameters, diagnostics).
    figures : dict
        ``{file name: (title, data)}`` in report order; ``data`` is what the file's
        ``figures.DRAW`` function draws.
    viewer : ViewerData or None
        The 3-D view (:func:`~transcalib.report.viewer.viewer_data`), between the
        sections and the figures; None: no 3-D view.
    """

    title: str
    sections: list
    figures: dict
    viewer: ViewerData | None = None


def report_data(cal, *, uv=None, truth=None, point_ids=None, title: str = "transcalib report", colors=None,
                view_names=None, extra: PointCloud | None = None, viewer_points: int = MAX_POINTS) -> ReportData:
    """Reduce a calibration to its :class:`ReportData` (numpy only: no matplotlib).

    Parameters as :func:`write_report`.
    """
    from ..io.files import software_version

    unit = cal.options.unit if getattr(cal, "options", None) is not None else "units"
    if not isinstance(viewer_points, (int, np.integer)) or viewer_points < 1:
        raise InputError(f"viewer_points must be a positive integer, got {viewer_points!r}")
    from .figures import image_box, observed_pixels

    uv = observed_pixels(cal, uv)  # once, for every figure
    size = image_box(cal, uv)
    viewer = viewer_data(cal, uv=uv, colors=colors, point_ids=point_ids, view_names=view_names, extra=extra,
                         image_size=size, unit=unit, max_points=int(viewer_points))
    sections = [f"<h1>{html.escape(title)}</h1>",
                f"<p>{cal.n_points} points in {cal.n_views} views; lengths in {html.escape(unit)}; "
                f"stages {html.escape(' → '.join(cal.stats.stages))}; transcalib {software_version()}; "
                f"{time.strftime('%Y-%m-%d %H:%M')}</p>",
                "<h2>Parameters</h2>", _parameters(cal, truth), "<h2>Diagnostics</h2>", _diagnostics(cal)]
    return ReportData(title=title, sections=sections, figures=_figure_data(cal, uv, truth, point_ids, unit, size),
                      viewer=viewer)


def render_report(data: ReportData, folder) -> list:
    """Draw the figures of ``data``; write ``folder/figures/*.png`` and ``folder/report.html``
    (each atomically, the page last). Returns the paths, ``report.html`` first."""
    from .figures import DRAW, png

    folder = Path(folder)
    sections, written = list(data.sections), []
    if data.viewer is not None:
        sections.append(viewer_html(data.viewer))
    for name, (fig_title, fig_data) in data.figures.items():
        image = png(DRAW[name](fig_data))
        with atomic_write(folder / "figures" / name, "wb") as fh:
            fh.write(image)
        written.append(folder / "figures" / name)
        sections.append(f"<h2>{html.escape(fig_title)}</h2><img alt='{html.escape(fig_title)}' "
                        f"src='data:image/png;base64,{base64.b64encode(image).decode('ascii')}'>")
    title = html.escape(data.title)
    page = (f"<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>{title}</title>"
            f"<style>{_CSS}{VIEWER_CSS if data.viewer is not None else ''}</style></head><body>\n" + "\n".join(sections) + "\n</body></html>\n")
    with atomic_write(folder / "report.html", encoding="utf-8", newline="\n") as fh:
        fh.write(page)
    return [folder / "report.html"] + written


def write_report(cal, folder, *, uv=None, truth=None, point_ids=None, title: str = "transcalib report", colors=None,
                 view_names=None, extra: PointCloud | None = None, viewer_points: int = MAX_POINTS) -> list:
    """Write ``folder/report.html`` and ``folder/figures/*.png`` (in this process).

    :func:`report_data` then :func:`render_report`; the CLI runs the second in a
    :class:`~transcalib.report.worker.ReportWorker` instead.

    Parameters
    ----------
    cal : Calibration
    folder : path-like
    uv : (n_views, n_points, 2) float, optional
        The observations (default: prediction + residual).
    truth : dict, optional
        ``truth.json`` of a simulated scene: adds the errors against the truth.
    point_ids : (n_points,) sequence, optional
        Ids of the points (integers or text); simulated ids index ``truth["points"]``.
    title : str
    colors : (n_points, 3) uint8, optional
        Image colour of each point (the 3-D view; default: coloured by depth).
    view_names : sequence of str (n_views), optional
        Image names, shown with the view indices in the 3-D view.
    extra : PointCloud, optional
        Another cloud for the 3-D view (a dense reconstruction), in the same frame.
    viewer_points : int
        Most points the 3-D view draws (of the calibration, and of ``extra``); a random
        subsample beyond, the number stated on the page.

    Returns
    -------
    list of Path
        ``report.html`` and the PNG files.
    """
    return render_report(report_data(cal, uv=uv, truth=truth, point_ids=point_ids, title=title, colors=colors,
                                     view_names=view_names, extra=extra, viewer_points=viewer_points), folder)
