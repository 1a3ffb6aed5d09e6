"""The small report of a dense reconstruction: ``report.html``, self-contained.

Per reference view the depth map (turbo colours from near to far, unknown black), the
confidence (grey, 0 black to 1 white) and a table of figures; then a picture of the fused
cloud seen from beside the reference camera (a z-buffered splat of every point, no
dependence beyond OpenCV). Pictures are PNGs embedded as data URIs.
"""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path

import cv2
import numpy as np

from ..geometry.rotation import rotvec_to_matrix

__all__ = ["write_dense_report", "depth_picture", "cloud_picture"]

#: Largest side (pixels) of a picture in the report.
PICTURE_PX = 640


def _data_uri(bgr: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", bgr)
    return "data:image/png;base64," + base64.b64encode(buf.tobytes()).decode("ascii")


def _shrink(img: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    f = min(1.0, PICTURE_PX / max(h, w))
    return img if f == 1.0 else cv2.resize(img, (round(w * f), round(h * f)), interpolation=cv2.INTER_AREA)


def depth_picture(depth: np.ndarray) -> tuple[np.ndarray, float, float]:
    """BGR picture of ``depth`` (turbo, near red to far blue; unknown black) and the
    near and far depth of its colour scale (2nd and 98th percentiles)."""
    finite = depth[np.isfinite(depth)]
    if finite.size == 0:
        return np.zeros(depth.shape + (3,), np.uint8), math.nan, math.nan
    near, far = (float(v) for v in np.percentile(finite, [2.0, 98.0]))
    with np.errstate(invalid="ignore"):
        t = np.clip((far - depth) / max(far - near, 1e-12), 0.0, 1.0)
    img = cv2.applyColorMap(np.nan_to_num(t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[~np.isfinite(depth)] = 0
    return img, near, far


def cloud_picture(points: np.ndarray, colors: np.ndarray, camera, centre, size=(PICTURE_PX, 480)) -> np.ndarray:
    """BGR picture of a cloud seen from beside the reference camera: turned 25 degrees
    about the camera's vertical axis and 15 about its horizontal one, around the cloud's
    median point; nearest point wins at each pixel."""
    w, h = size
    img = np.zeros((h, w, 3), np.uint8)
    if len(points) == 0:
        return img
    stride = max(1, len(points) // 300_000)  # enough for a picture; a fixed subset
    points, colors = points[::stride], colors[::stride]
    xc = (points - centre) @ camera.R.T
    pivot = np.median(xc, axis=0)
    turn = rotvec_to_matrix(np.radians([15.0, 0.0, 0.0])) @ rotvec_to_matrix(np.radians([0.0, 25.0, 0.0]))
    q = (xc - pivot) @ turn.T + [0.0, 0.0, pivot[2]]
    front = q[:, 2] > 1e-9 * max(pivot[2], 1e-300)
    q, c = q[front], colors[front]
    uv = q[:, :2] / q[:, 2:]
    lo, hi = np.percentile(uv, [1.0, 99.0], axis=0)
    f = 0.9 * min(w / max(hi[0] - lo[0], 1e-12), h / max(hi[1] - lo[1], 1e-12))
    pix = np.rint((uv - (lo + hi) / 2) * f + [w / 2, h / 2]).astype(int)
    inside = (pix[:, 0] >= 0) & (pix[:, 0] < w) & (pix[:, 1] >= 0) & (pix[:, 1] < h)
    order = np.argsort(-q[inside, 2])  # far first: the nearest is written last
    p, col = pix[inside][order], c[inside][order]
    img[p[:, 1], p[:, 0]] = col[:, ::-1]
    return img


def _table(rows) -> str:
    return "<table>" + "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>"
                               for k, v in rows) + "</table>"


def _view_section(m, unit: str) -> str:
    depth_img, near, far = depth_picture(np.asarray(m.depth))
    conf = np.clip(np.asarray(m.confidence) * 255, 0, 255).astype(np.uint8)
    std = np.asarray(m.depth_std)
    known = np.isfinite(m.depth)
    rel = np.nanmedian(std[known] / m.depth[known]) if known.any() else math.nan
    rows = [("known pixels", f"{known.mean() * 100:.1f} %"),
            ("depth range searched", f"{m.depth_limits[0]:.4g} to {m.depth_limits[1]:.4g} {unit}"),
            ("colour scale", f"{near:.4g} (red) to {far:.4g} (blue) {unit}"),
            ("median depth std", f"{rel * 100:.3g} % of depth"),
            ("views matched", f"{', '.join(m.sources)} (best {m.best_k} at each pixel)"),
            ("image noise", f"{m.stats.noise_dn:.3g} grey levels"),
            ("time", f"{m.stats.time_s:.2f} s")]
    return (f"<h2>Reference view {html.escape(m.view)}</h2>" + _table(rows) +
            f"<figure><img alt='depth of view {html.escape(m.view)}' src='{_data_uri(_shrink(depth_img))}'>"
            "<figcaption>depth (unknown: black)</figcaption></figure>"
            f"<figure><img alt='confidence of view {html.escape(m.view)}' "
            f"src='{_data_uri(_shrink(cv2.cvtColor(conf, cv2.COLOR_GRAY2BGR)))}'>"
            "<figcaption>confidence (0 black, 1 white)</figcaption></figure>")


def write_dense_report(result, folder) -> list[str]:
    """Write ``report.html`` of ``result`` into ``folder``; returns the names written."""
    unit = result.unit or "units"
    first = result.maps[0]
    cloud = cloud_picture(np.asarray(result.points), np.asarray(result.colors), first.camera, first.centre)
    body = ["<h1>transcalib dense</h1>",
            _table([("reference views", ", ".join(m.view for m in result.maps)),
                    ("points in the cloud", f"{len(result.points):,}"),
                    ("points rejected by the consistency check", f"{result.n_rejected:,}"),
                    ("unit", unit), ("total time", f"{result.timings_s.get('total_s', math.nan):.2f} s")])]
    body += [_view_section(m, unit) for m in result.maps]
    body += ["<h2>Cloud</h2>", f"<figure><img alt='the fused cloud' src='{_data_uri(cloud)}'><figcaption>the fused "
             f"cloud from beside reference view {html.escape(first.view)} (robot frame)</figcaption></figure>"]
    style = ("body{font-family:sans-serif;max-width:60em;margin:2em auto}table{border-collapse:collapse}"
             "th,td{text-align:left;padding:2px 8px;border-bottom:1px solid #ddd}figure{display:inline-block;"
             "margin:0.5em}img{max-width:100%}")
    text = ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>transcalib dense</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    Path(folder, "report.html").write_text(text, encoding="utf-8", newline="\n")
    return ["report.html"]
