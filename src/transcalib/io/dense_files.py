"""The files of a dense reconstruction (``transcalib dense --out DIR``).

For each reference view ``ID``: ``depth_<ID>.npy`` (float32, robot units, NaN unknown),
``confidence_<ID>.npy`` (float32, 0-1), ``depth_std_<ID>.npy`` (float32, robot units,
NaN unknown) and ``depth_<ID>.png`` (16-bit: ``depth = value * depth_png_scale``, 0
unknown); ``dense.ply``, the fused cloud (binary little endian: ``x, y, z`` double in
the calibration's frame (``dense.json``'s ``cloud.frame``), ``red, green, blue`` uchar,
``confidence``, ``depth_std`` float, ``view`` uchar: the index of its reference view in
``dense.json``); ``dense.json``, what
was done and how to read the files; ``report.html`` (:mod:`.dense_report`).
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from .dense_report import write_dense_report
from .files import software_version, write_json
from .formats import write_vertices_ply

__all__ = ["write_dense", "depth_png_scale", "DENSE_JSON", "dense_document"]

DENSE_JSON = "dense.json"
SCHEMA_VERSION = 1


def depth_png_scale(depth: np.ndarray) -> float:
    """Robot units per count of the 16-bit PNG: the smallest of 1, 2, 5 x 10^k that keeps
    the largest known depth below 60000 counts (1 when nothing is known)."""
    finite = depth[np.isfinite(depth)]
    top = float(finite.max()) if finite.size else 0.0
    if top <= 0:
        return 1.0
    k = math.floor(math.log10(top / 60000.0))
    for base in (1.0, 2.0, 5.0, 10.0):
        if base * 10.0**k * 60000.0 >= top:
            return base * 10.0**k
    return 10.0 ** (k + 1)


def _png(depth: np.ndarray, scale: float) -> np.ndarray:
    """16-bit counts of ``depth``: ``round(depth / scale)`` in 1..65535, 0 unknown."""
    with np.errstate(invalid="ignore"):
        counts = np.rint(depth / scale)
    return np.where(np.isfinite(counts), np.clip(counts, 1, 65535), 0).astype(np.uint16)


def _ply(result, path: Path) -> None:
    dtype = [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
             ("confidence", "<f4"), ("depth_std", "<f4"), ("view", "u1")]
    v = np.empty(len(result.points), dtype=dtype)
    v["x"], v["y"], v["z"] = np.asarray(result.points, float).T
    v["red"], v["green"], v["blue"] = np.asarray(result.colors).T
    v["confidence"], v["depth_std"], v["view"] = result.point_confidence, result.point_std, result.point_view
    write_vertices_ply(path, v, "written by transcalib dense")


def dense_document(result, files: dict, inputs: dict | None = None) -> dict:
    """The contents of ``dense.json`` (``files``: reference view id -> its file names)."""
    views = []
    for m in result.maps:
        cam = m.camera
        views.append({
            "view": m.view, "files": files[m.view], "size": list(m.shape[::-1]),
            "depth_png_scale": depth_png_scale(m.depth),
            "depth_limits": [m.depth_limits[0], None if math.isinf(m.depth_limits[1]) else m.depth_limits[1]],
            "sources": list(m.sources), "best_k": m.best_k, "K": cam.K.tolist(), "R_cam_world": cam.R.tolist(),
            "dist": cam.dist.tolist(), "dist_model": cam.dist_model, "centre": list(map(float, m.centre)),
            "known_fraction": m.stats.known_fraction, "noise_dn": m.stats.noise_dn,
            "hypothesis_step_px": m.stats.hypothesis_step_px,
            "calibration_std": m.depth_std_calibration is not None})
    opts = result.options
    return {"kind": "transcalib dense", "schema": SCHEMA_VERSION, "software": software_version(),
            "unit": result.unit, "depth": "along the optical axis (camera z) of the reference view, robot units",
            "depth_png": "depth = value * depth_png_scale; 0 = unknown",
            "options": {"n_depths": opts.n_depths, "window_px": opts.window_px, "best_k": opts.best_k,
                        "min_texture": opts.min_texture, "min_confidence": opts.min_confidence,
                        "consistency_rel": opts.consistency_rel, "max_turn_deg": opts.max_turn_deg},
            "reference_views": views,
            "cloud": {"file": "dense.ply", "points": int(len(result.points)), "rejected": int(result.n_rejected),
                      "frame": result.frame},
            "timings_s": dict(result.timings_s), "inputs": inputs or {}}


def write_dense(result, folder, *, inputs: dict | None = None, report: bool = True) -> list[str]:
    """Write ``result`` (a :class:`~transcalib.dense.DenseResult`) into ``folder``.

    The command writes into the temporary folder of :func:`transcalib.io.folders.output_folder`
    (``--out`` complete or absent); called directly, ``folder`` is made when missing and
    files of the same names are replaced.

    Parameters
    ----------
    folder : path-like
    inputs : dict, optional
        What the run read (file names), recorded in ``dense.json``.
    report : bool
        Also write ``report.html``.

    Returns
    -------
    list of str
        The names of the files written, relative to ``folder``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    names, files = [], {}
    for m in result.maps:
        f = {"depth": f"depth_{m.view}.npy", "confidence": f"confidence_{m.view}.npy",
             "depth_std": f"depth_std_{m.view}.npy", "depth_png": f"depth_{m.view}.png"}
        np.save(folder / f["depth"], np.asarray(m.depth, np.float32))
        np.save(folder / f["confidence"], np.asarray(m.confidence, np.float32))
        np.save(folder / f["depth_std"], np.asarray(m.depth_std, np.float32))
        ok, buf = cv2.imencode(".png", _png(m.depth, depth_png_scale(m.depth)))
        (folder / f["depth_png"]).write_bytes(buf.tobytes())
        files[m.view] = f
        names += list(f.values())
    _ply(result, folder / "dense.ply")
    write_json(folder / DENSE_JSON, dense_document(result, files, inputs))
    names += ["dense.ply", DENSE_JSON]
    if report:
        names += write_dense_report(result, folder)
    return names
