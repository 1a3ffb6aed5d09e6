"""A calibration in every format at once: :func:`transcalib.export`.

=================  =====================================  ==================================
format             file(s) in the output folder           read back by
=================  =====================================  ==================================
``json``           ``calibration.json`` + ``arrays.npz``  :func:`transcalib.load`
``csv``            ``points.csv``                         any CSV reader
``opencv``         ``camera.yaml``                        ``cv2.FileStorage``
``ros``            ``camera_info.yaml``                   ROS ``camera_calibration_parsers``
``colmap``         ``colmap/{cameras,images,points3D}.txt`` ``pycolmap.Reconstruction``
``ply``            ``points.ply``                         ``plyfile``, MeshLab, Open3D
``report``         ``report.html`` + ``figures/*.png``    a web browser
=================  =====================================  ==================================

The writers of one format each: :mod:`.calibration_file` (JSON), :mod:`.tables` (CSV),
:mod:`.formats` (OpenCV, ROS, COLMAP, PLY) and :mod:`transcalib.report`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .calibration_file import check_calibration, save_calibration
from .formats import image_size_or_extent, write_colmap, write_opencv_yaml, write_ply, write_ros_camera_info
from .ids import point_id_array

__all__ = ["FORMATS", "ExportContext", "export_calibration"]

FORMATS = ("json", "csv", "opencv", "ros", "colmap", "ply", "report")


@dataclass(frozen=True)
class ExportContext:
    """What a calibration does not hold but some exports need.

    Attributes
    ----------
    point_ids : (n_points,) int64 or str array, optional   default ``0..n-1``
    view_names : sequence of str (n_views), optional   image file names (COLMAP)
    colors : (n_points, 3) uint8, optional             RGB of each point (PLY, COLMAP)
    uv : (n_views, n_points, 2) float, optional        observations (COLMAP tracks, report)
    inputs : dict, optional                            summary for ``calibration.json``
    truth : dict, optional                             ``truth.json`` of a simulation (report)
    camera_name : str                                  ROS ``camera_name``
    """

    point_ids: object = None
    view_names: object = None
    colors: object = None
    uv: object = None
    inputs: object = None
    truth: object = None
    camera_name: str = "camera"


def _write_json(cal, folder, ids, ctx):
    return save_calibration(cal, folder, point_ids=ids, inputs=ctx.inputs)


def _write_csv(cal, folder, ids):
    from .tables import write_points_csv

    write_points_csv(folder / "points.csv", ids, cal.X, cal.X_std, cal.inliers)
    return [folder / "points.csv"]


def _report_data(cal, ids, ctx):
    from ..report import report_data

    return report_data(cal, uv=ctx.uv, truth=ctx.truth, point_ids=ids, colors=ctx.colors, view_names=ctx.view_names)


def _write_report(cal, folder, ids, ctx):
    from ..report import render_report

    return render_report(_report_data(cal, ids, ctx), folder)


def _timed(timings: dict | None, key: str, work):
    """``work()``, its seconds added to ``timings[key]``."""
    t0 = time.perf_counter()
    out = work()
    if timings is not None:
        timings[key] = timings.get(key, 0.0) + time.perf_counter() - t0
    return out


def _formats(formats) -> tuple[str, ...]:
    """``formats`` (``"all"``, ``"opencv,ply"`` or a sequence of names) as a tuple of
    names from :data:`FORMATS`; :class:`InputError` naming any unknown one."""
    if isinstance(formats, str):
        formats = [f.strip() for f in formats.split(",")]
    formats = FORMATS if list(formats) == ["all"] else tuple(formats)
    unknown = [str(f) for f in formats if f not in FORMATS]
    if unknown:
        raise InputError(f"unknown export format(s) {', '.join(unknown)}; expected 'all' or some of {', '.join(FORMATS)}")
    return formats


def export_calibration(cal, folder, formats="all", context: ExportContext | None = None, *,
                       timings: dict | None = None, report_worker=None) -> list[Path]:
    """Write ``cal`` to ``folder`` in each of ``formats``: :func:`transcalib.export`.

    Parameters
    ----------
    cal : Calibration
    folder : path-like
        Output folder, created if missing.
    formats : str or sequence of str
        ``"all"`` (the default: every one of :data:`FORMATS`), some of them as a sequence
        or comma separated (``"opencv,ros,colmap,ply"``).
    context : ExportContext, optional
        Point ids, image names, colours, observations, truth (what the calibration does
        not hold). The COLMAP export needs ``uv``.
    timings : dict, optional
        Filled with the seconds each format took in this process (``"json_s"``, ...);
        with a worker, ``"report_s"`` is the reduction plus the wait at the end, and
        ``"report_worker_s"`` the worker's drawing and writing.
    report_worker : transcalib.report.worker.ReportWorker, optional
        Draw the report in this worker process, while the other formats are written
        (default: draw it here, in turn).

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    InputError
        ``cal`` is not a Calibration; an unknown format; OpenCV, ROS or COLMAP asked for
        without a known image size or observations; COLMAP without ``uv``.
    """
    check_calibration(cal, "export")
    formats = _formats(formats)
    ctx = context or ExportContext()
    folder = Path(folder)
    ids = point_id_array(ctx.point_ids if ctx.point_ids is not None else np.arange(cal.n_points))
    written = []
    needs_size = {"opencv", "ros", "colmap"} & set(formats)
    size = image_size_or_extent(cal, ctx.uv) if needs_size else None
    writers = {
        "json": lambda: _write_json(cal, folder, ids, ctx),
        "csv": lambda: _write_csv(cal, folder, ids),
        "opencv": lambda: [write_opencv_yaml(cal, folder / "camera.yaml", size)],
        "ros": lambda: [write_ros_camera_info(cal, folder / "camera_info.yaml", size, ctx.camera_name)],
        "colmap": lambda: write_colmap(cal, folder / "colmap", size, ctx.uv, ctx.view_names, ctx.colors),
        "ply": lambda: [write_ply(cal, folder / "points.ply", ctx.colors)],
        "report": lambda: _write_report(cal, folder, ids, ctx),
    }
    pending = None
    if "report" in formats and report_worker is not None:  # first: it draws while we write the rest
        pending = _timed(timings, "report_s", lambda: report_worker.submit(_report_data(cal, ids, ctx), folder))
    for name in FORMATS:  # a fixed order: the JSON first
        if name in formats and not (name == "report" and pending is not None):
            written += list(_timed(timings, f"{name}_s", writers[name]))
    if pending is not None:
        written += _timed(timings, "report_s", pending.result)
        if timings is not None:
            timings["report_worker_s"] = pending.worker_s
    return written
