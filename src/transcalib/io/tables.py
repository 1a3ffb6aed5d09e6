"""Readers and writers: tracks and poses CSV in, calibration JSON and points CSV out.

File formats (see ``docs/formats.md``):

``tracks.csv``  header ``view,point,u,v``; one row per observation; ``point`` is any id.
``poses.csv``   header ``view,x,y,z`` with optional ``qx,qy,qz,qw`` (robot orientation,
                checked to be constant) and ``image`` (file name of the view's image).
                The row order of ``poses.csv`` is the view order.

Outputs are written atomically: to a temporary file in the same folder, then renamed, so
an interrupted run never leaves a partial file. Inputs are never modified.
"""

from __future__ import annotations

import csv
import json
import math
import os
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..types import InputError

__all__ = [
    "Poses",
    "read_poses",
    "read_tracks",
    "tracks_to_uv",
    "write_tracks_csv",
    "write_points_csv",
    "write_json",
    "write_poses_csv",
    "atomic_write",
]


@dataclass(frozen=True, eq=False)
class Poses:
    """Contents of ``poses.csv``.

    Attributes
    ----------
    views : list of str          view ids, in file order (the view order)
    T : (n_views, 3) float       robot translations
    quaternions : (n_views, 4) float or None   ``qx, qy, qz, qw`` when given
    images : list of str or None image file names when given
    """

    views: list
    T: np.ndarray
    quaternions: np.ndarray | None = None
    images: list | None = None


def _canonical_id(text: str) -> str:
    """View ids compare as integers when they are integers ("03" == "3")."""
    text = text.strip()
    try:
        value = float(text)
    except ValueError:
        return text
    return str(int(value)) if value.is_integer() else text


def _read_table(path, required: list[str], what: str) -> tuple[list[str], list[list[str]]]:
    """Rows of a CSV file with a header containing ``required`` columns."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} file {str(path)!r} does not exist")
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = [row for row in csv.reader(fh) if row and any(cell.strip() for cell in row)]
    except UnicodeDecodeError:
        raise InputError(f"{what} file {str(path)!r} is not a UTF-8 text CSV file") from None
    if not rows:
        raise InputError(f"{what} file {str(path)!r} is empty; expected a header line {','.join(required)} and data rows")
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(
            f"{what} file {str(path)!r} lacks column(s) {', '.join(missing)}; its header is "
            f"{','.join(rows[0])!r}, expected at least {','.join(required)}"
        )
    if len(rows) == 1:
        raise InputError(f"{what} file {str(path)!r} has a header but no data rows")
    width = len(header)
    for k, row in enumerate(rows[1:], start=2):
        if len(row) != width:
            raise InputError(f"{what} file {str(path)!r}, line {k}: {len(row)} cells, expected {width} as in the header")
    return header, rows[1:]


def _numbers(path, rows, header, columns: list[str], what: str) -> np.ndarray:
    """Float columns; a non-numeric or non-finite cell is reported by line and column."""
    idx = [header.index(c) for c in columns]
    cells = [[row[i] for i in idx] for row in rows]
    try:
        values = np.array(cells, dtype=float)
    except ValueError:
        values = None
    if values is None or not np.isfinite(values).all():
        for k, row in enumerate(cells, start=2):
            for c, cell in zip(columns, row):
                try:
                    ok = math.isfinite(float(cell))
                except ValueError:
                    ok = False
                if not ok:
                    raise InputError(
                        f"{what} file {str(path)!r}, line {k}, column {c!r}: {cell!r} is not a finite number"
                    )
    return values.reshape(len(rows), len(columns))


def read_poses(path) -> Poses:
    """Read ``poses.csv``: ``view,x,y,z[,qx,qy,qz,qw][,image]``.

    Raises :class:`InputError` on a missing file, missing columns, empty file,
    non-numeric cells or duplicate view ids.
    """
    header, rows = _read_table(path, ["view", "x", "y", "z"], "poses")
    views = [_canonical_id(row[header.index("view")]) for row in rows]
    dup = sorted({v for v in views if views.count(v) > 1}) if len(set(views)) != len(views) else []
    if dup:
        raise InputError(f"poses file {str(path)!r}: view id(s) {dup} appear more than once; give one pose per view")
    T = _numbers(path, rows, header, ["x", "y", "z"], "poses")
    quat_cols = ["qx", "qy", "qz", "qw"]
    present = [c in header for c in quat_cols]
    if any(present) and not all(present):
        raise InputError(f"poses file {str(path)!r}: orientation needs all of qx,qy,qz,qw; found only some")
    quats = _numbers(path, rows, header, quat_cols, "poses") if all(present) else None
    if quats is not None:
        norms = np.linalg.norm(quats, axis=1)
        if np.any(norms < 1e-9):
            raise InputError(f"poses file {str(path)!r}: a quaternion qx,qy,qz,qw is zero; give unit quaternions")
        quats = quats / norms[:, None]
    images = [row[header.index("image")].strip() for row in rows] if "image" in header else None
    return Poses(views=views, T=T, quaternions=quats, images=images)


def read_tracks(path) -> tuple[list[str], list[str], np.ndarray, np.ndarray]:
    """Read ``tracks.csv``: ``view,point,u,v``, one row per observation.

    Returns
    -------
    view_ids : list of str (n_obs)
    point_ids : list of str (n_points), in order of first appearance
    point_index : (n_obs,) int, index into ``point_ids`` of each row
    uv : (n_obs, 2) float
    """
    header, rows = _read_table(path, ["view", "point", "u", "v"], "tracks")
    iv, ip = header.index("view"), header.index("point")
    view_ids = [_canonical_id(row[iv]) for row in rows]
    raw_points = np.array([row[ip].strip() for row in rows])
    uv = _numbers(path, rows, header, ["u", "v"], "tracks")
    ids, first, inverse = np.unique(raw_points, return_index=True, return_inverse=True)
    order = np.argsort(first)  # first-appearance order
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return view_ids, ids[order].tolist(), rank[inverse], uv


def tracks_to_uv(path_tracks, poses: Poses) -> tuple[np.ndarray, list[str]]:
    """Observations of ``tracks.csv`` as ``uv (n_views, n_points, 2)`` in the view order of
    ``poses``.

    Raises :class:`InputError` for views in the tracks that have no pose and for
    duplicate (view, point) rows.
    """
    view_ids, point_ids, point_index, obs = read_tracks(path_tracks)
    view_pos = {v: k for k, v in enumerate(poses.views)}
    unknown = sorted({v for v in view_ids if v not in view_pos})
    if unknown:
        raise InputError(
            f"tracks file {str(path_tracks)!r} has view(s) {unknown[:10]} that are not in the poses file "
            f"(which has {poses.views[:10]}{'...' if len(poses.views) > 10 else ''}); give every view a pose"
        )
    vidx = np.array([view_pos[v] for v in view_ids])
    flat = vidx * len(point_ids) + point_index
    uniq, counts = np.unique(flat, return_counts=True)
    if np.any(counts > 1):
        dup = uniq[counts > 1][:5]
        pairs = [(poses.views[d // len(point_ids)], point_ids[d % len(point_ids)]) for d in dup]
        raise InputError(
            f"tracks file {str(path_tracks)!r} has more than one row for (view, point) {pairs}; "
            "give each point at most one position per view"
        )
    uv = np.full((len(poses.views), len(point_ids), 2), np.nan)
    uv[vidx, point_index] = obs
    return uv, point_ids


@contextmanager
def atomic_write(path, mode: str = "w", **kwargs):
    """Open a temporary file beside ``path``; rename it to ``path`` only on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else None  # JSON has no NaN: null
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.bool_,)):
        return bool(value)
    return value


def write_json(path, data: dict) -> None:
    """Write ``data`` as indented JSON (NaN/inf become null), atomically."""
    with atomic_write(path, encoding="utf-8") as fh:
        json.dump(_jsonable(data), fh, indent=2)
        fh.write("\n")


def write_points_csv(path, point_ids, X: np.ndarray, X_std: np.ndarray | None = None, inliers=None) -> None:
    """Write ``point,x,y,z[,sx,sy,sz][,inlier]`` (empty cells for points not reconstructed)."""
    def fmt(x):
        return repr(float(x)) if np.isfinite(x) else ""

    with atomic_write(path, newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["point", "x", "y", "z"] + (["sx", "sy", "sz"] if X_std is not None else [])
                   + (["inlier"] if inliers is not None else []))
        for j, pid in enumerate(point_ids):
            row = [pid] + [fmt(x) for x in X[j]]
            if X_std is not None:
                row += [fmt(x) for x in X_std[j]]
            if inliers is not None:
                row.append(int(bool(inliers[j])))
            w.writerow(row)


def write_tracks_csv(path, uv: np.ndarray, point_ids=None, view_ids=None) -> None:
    """Write ``view,point,u,v`` for every finite observation of ``uv (n_views, n_points, 2)``,
    grouped by point (so that the points read back in the same order)."""
    n_views, n_points = uv.shape[:2]
    point_ids = list(range(n_points)) if point_ids is None else list(point_ids)
    view_ids = list(range(n_views)) if view_ids is None else list(view_ids)
    with atomic_write(path, newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["view", "point", "u", "v"])
        for j, i in np.argwhere(np.isfinite(uv[..., 0]).T):
            w.writerow([view_ids[i], point_ids[j], repr(float(uv[i, j, 0])), repr(float(uv[i, j, 1]))])


def write_poses_csv(path, T: np.ndarray, view_ids=None, images=None) -> None:
    """Write ``view,x,y,z[,image]``."""
    view_ids = list(range(len(T))) if view_ids is None else list(view_ids)
    with atomic_write(path, newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["view", "x", "y", "z"] + (["image"] if images is not None else []))
        for i, t in enumerate(T):
            w.writerow([view_ids[i]] + [repr(float(x)) for x in t] + ([images[i]] if images is not None else []))
