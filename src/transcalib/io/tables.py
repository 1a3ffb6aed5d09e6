"""Tables: tracks in, points and tracks out (CSV, and binary tracks).

File formats (see ``docs/formats.md``):

``tracks.csv``  header ``view,point,u,v``; one row per observation; ``point`` is any id.
                Read by a vectorised parser (pyarrow); a file with a bad cell is read
                again carefully to name its line and column. ``.npz`` (dense ``uv``,
                ``view_ids``, ``point_ids``) and ``.parquet`` (the CSV's columns) are the
                binary alternatives, chosen by extension.

Pose files are read by :mod:`transcalib.io.poses`; the tracks are put in the view order
of its :class:`~transcalib.io.poses.Poses` (view ids compare by
:func:`~transcalib.io.ids.canonical_id`, ``03`` = ``3``).

Outputs are written atomically: to a temporary file in the same folder, then renamed, so
an interrupted run never leaves a partial file. Inputs are never modified. Text files
have LF line endings.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from ..errors import InputError
from . import text
from .files import atomic_write
from .ids import canonical_id, integer_ids, point_id_array

__all__ = ["TrackTable", "read_tracks", "read_track_table", "tracks_to_uv", "write_tracks", "write_tracks_csv",
           "write_points_csv"]


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


@dataclass(frozen=True, eq=False)
class TrackTable:
    """Observations of a tracks file, one per row, with integer codes for the ids.

    Attributes
    ----------
    view_ids : list of str (n_distinct_views)   canonical view ids, first-appearance order
    view_index : (n_obs,) int                   index into ``view_ids`` of each row
    point_ids : (n_points,) int64 or str array  point ids, first-appearance order
                                                (:func:`~transcalib.io.ids.point_id_array`)
    point_index : (n_obs,) int                  index into ``point_ids`` of each row
    uv : (n_obs, 2) float                       pixels
    """

    view_ids: list
    view_index: np.ndarray
    point_ids: np.ndarray
    point_index: np.ndarray
    uv: np.ndarray


def _header(path, required: list[str], what: str) -> list[str]:
    """Lower-cased, stripped header cells of a CSV file; clear errors for a missing file,
    an empty file or missing columns."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} file {str(path)!r} does not exist")
    with open(path, "rb") as fh:
        first = fh.readline()
    try:
        header = [h.strip().lower() for h in first.decode("utf-8-sig").strip().split(",")]
    except UnicodeDecodeError:
        raise InputError(f"{what} file {str(path)!r} is not a UTF-8 text CSV file") from None
    if header == [""]:
        raise InputError(f"{what} file {str(path)!r} is empty; expected a header line {','.join(required)} and data rows")
    missing = [c for c in required if c not in header]
    if missing:
        raise InputError(f"{what} file {str(path)!r} lacks column(s) {', '.join(missing)}; its header is "
                         f"{first.decode('utf-8-sig', 'replace').strip()!r}, expected at least {','.join(required)}")
    return header


def _codes(values: list[str]) -> tuple[list[str], np.ndarray]:
    """Distinct values in first-appearance order and the index of each value."""
    arr = np.asarray(values)
    ids, first, inverse = np.unique(arr, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return ids[order].tolist(), rank[inverse].ravel()


def _tracks_fast(path, header: list[str]) -> TrackTable | None:
    """Vectorised reader (pyarrow's CSV parser); None when the file needs the careful
    reader to locate an error (bad cell, ragged row, non-finite value)."""
    table = _arrow_csv(path, header)
    if table is None or table.num_rows == 0:
        return None
    uv = _uv_array(table)
    if not np.isfinite(uv).all():
        return None
    view_ids, view_index = _view_codes(table["view"])
    point_ids, point_index = _point_codes(table["point"])
    return TrackTable(view_ids, view_index, point_ids, point_index, uv)


def _arrow_csv(path, header: list[str]):
    """The columns ``view``, ``point`` (text), ``u``, ``v`` (float) of a tracks CSV, or None
    if they do not parse."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    types = {"view": pa.string(), "point": pa.string(), "u": pa.float64(), "v": pa.float64()}
    names = [h if h in types and header.index(h) == k else f"_{k}" for k, h in enumerate(header)]
    try:
        return pcsv.read_csv(
            path, read_options=pcsv.ReadOptions(skip_rows=1, column_names=names),
            convert_options=pcsv.ConvertOptions(column_types=types, include_columns=list(types)))
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return None


def _uv_array(table) -> np.ndarray:
    """``(n_obs, 2)`` float from the Arrow columns ``u``, ``v`` (NaN where empty), filled
    chunk by chunk: no concatenated copies (fresh memory is slow to fault in)."""
    uv = np.empty((table.num_rows, 2))
    for k, name in enumerate(("u", "v")):
        start = 0
        for chunk in table[name].chunks:
            uv[start:start + len(chunk), k] = chunk.to_numpy(zero_copy_only=False)
            start += len(chunk)
    return uv


def _view_codes(column) -> tuple[list[str], np.ndarray]:
    """Canonical view ids in first-appearance order (``03`` is view ``3``) and the index
    of each row, from an Arrow string column."""
    import pyarrow.compute as pc

    enc = pc.dictionary_encode(column).combine_chunks()
    view_ids, remap = _codes([canonical_id(v) for v in enc.dictionary.to_pylist()])  # a few views
    return view_ids, remap[enc.indices.to_numpy()]


def _point_codes(column) -> tuple[np.ndarray, np.ndarray]:
    """Point ids in first-appearance order (:func:`point_id_array`, stripped of surrounding
    spaces) and the index of each row, from an Arrow string column."""
    import pyarrow.compute as pc

    ints = integer_ids(column)
    if ints is not None:
        return _integer_codes(ints)
    enc = pc.dictionary_encode(pc.utf8_trim_whitespace(column)).combine_chunks()
    return point_id_array(enc.dictionary), enc.indices.to_numpy().astype(np.intp)


def _integer_codes(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct values of ``(n,) int64`` in first-appearance order and the index of each.

    Rows grouped by point in increasing id order (as ``write_tracks`` writes them) take
    one pass; other orders a hash table (Arrow's dictionary encoding, in first-appearance
    order).
    """
    import pyarrow as pa
    import pyarrow.compute as pc

    if np.all(values[1:] >= values[:-1]):
        starts = np.empty(values.size, dtype=bool)
        starts[:1] = True
        np.not_equal(values[1:], values[:-1], out=starts[1:])
        codes = np.cumsum(starts)
        codes -= 1
        return values[starts], codes
    enc = pc.dictionary_encode(pa.array(values))
    return enc.dictionary.to_numpy(), enc.indices.to_numpy().astype(np.intp)


def read_track_table(path) -> TrackTable:
    """Read ``tracks.csv`` (``view,point,u,v``, one row per observation) fast.

    Raises :class:`InputError` naming the file, line and column of a bad cell.
    """
    header = _header(path, ["view", "point", "u", "v"], "tracks")
    fast = _tracks_fast(path, header)
    if fast is not None:
        return fast
    header, rows = _read_table(path, ["view", "point", "u", "v"], "tracks")  # careful: locates errors
    iv, ip = header.index("view"), header.index("point")
    uv = _numbers(path, rows, header, ["u", "v"], "tracks")
    view_ids, view_index = _codes([canonical_id(row[iv]) for row in rows])
    point_ids, point_index = _codes([row[ip].strip() for row in rows])
    return TrackTable(view_ids, view_index, point_id_array(point_ids), point_index, uv)


def read_tracks(path) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """Read ``tracks.csv``: ``view,point,u,v``, one row per observation.

    Returns
    -------
    view_ids : list of str (n_obs)
    point_ids : (n_points,) int64 or str array, in order of first appearance
    point_index : (n_obs,) int, index into ``point_ids`` of each row
    uv : (n_obs, 2) float
    """
    t = read_track_table(path)
    return np.asarray(t.view_ids, dtype=object)[t.view_index].tolist(), t.point_ids, t.point_index, t.uv


def tracks_to_uv(path_tracks, poses) -> tuple[np.ndarray, np.ndarray]:
    """Observations of a tracks file as ``uv (n_views, n_points, 2)`` in the view order of
    ``poses`` (a :class:`~transcalib.io.poses.Poses`: its canonical ``views``), and the
    point ids ``(n_points,)`` (int64 when every id is an integer, else str:
    :func:`~transcalib.io.ids.point_id_array`); the format follows the extension:
    ``.csv``, ``.npz`` or ``.parquet``.

    Raises :class:`InputError` for views in the tracks that have no pose and for
    duplicate (view, point) rows.
    """
    suffix = Path(path_tracks).suffix.lower()
    if suffix == ".npz":
        return _npz_to_uv(path_tracks, poses)
    t = read_parquet_tracks(path_tracks) if suffix == ".parquet" else read_track_table(path_tracks)
    view_pos = {v: k for k, v in enumerate(poses.views)}
    unknown = [v for v in t.view_ids if v not in view_pos]
    if unknown:
        raise InputError(
            f"tracks file {str(path_tracks)!r} has view(s) {unknown[:10]} that are not in the poses file "
            f"(which has {poses.views[:10]}{'...' if len(poses.views) > 10 else ''}); give every view a pose"
        )
    n_views, n_points = len(poses.views), len(t.point_ids)
    flat = np.array([view_pos[v] for v in t.view_ids], dtype=np.intp)[t.view_index]
    flat *= n_points
    flat += t.point_index  # index of each observation in uv (n_views * n_points, 2)
    filled = np.zeros(n_views * n_points, dtype=bool)
    filled[flat] = True
    if np.count_nonzero(filled) < flat.size:  # some (view, point) more than once
        dup = np.flatnonzero(np.bincount(flat) > 1)[:5]
        pairs = [(poses.views[d // n_points], t.point_ids[d % n_points].item()) for d in dup]
        raise InputError(
            f"tracks file {str(path_tracks)!r} has more than one row for (view, point) {pairs}; "
            "give each point at most one position per view"
        )
    uv = np.full((n_views * n_points, 2), np.nan)
    uv[flat] = t.uv
    return uv.reshape(n_views, n_points, 2), t.point_ids


# --------------------------------------------------------------------------------------
# binary tracks: .npz (dense uv) and .parquet (the CSV's columns)
# --------------------------------------------------------------------------------------


def _npz_to_uv(path, poses) -> tuple[np.ndarray, np.ndarray]:
    """``.npz`` tracks: ``uv (n_views, n_points, 2)``, ``view_ids (n_views,)``,
    ``point_ids (n_points,)`` (integers or text)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"tracks file {str(path)!r} does not exist")
    try:
        with np.load(path, allow_pickle=False) as z:
            uv, view_ids, point_ids = z["uv"], z["view_ids"], z["point_ids"]
    except (KeyError, ValueError, OSError) as exc:
        raise InputError(f"tracks file {str(path)!r} is not a transcalib .npz tracks file (arrays uv, view_ids, "
                         f"point_ids): {exc}") from None
    if uv.ndim != 3 or uv.shape[2] != 2 or uv.shape[:2] != (len(view_ids), len(point_ids)):
        raise InputError(f"tracks file {str(path)!r}: uv has shape {uv.shape}, expected (n_views, n_points, 2) = "
                         f"({len(view_ids)}, {len(point_ids)}, 2)")
    views = [canonical_id(str(v)) for v in view_ids]
    view_pos = {v: k for k, v in enumerate(poses.views)}
    unknown = [v for v in views if v not in view_pos]
    if unknown:
        raise InputError(f"tracks file {str(path)!r} has view(s) {unknown[:10]} that are not in the poses file")
    bad = ~np.isfinite(uv) & ~np.isnan(uv)
    if bad.any():
        raise InputError(f"tracks file {str(path)!r}: uv has infinite values; use NaN for unseen points")
    out = np.full((len(poses.views), len(point_ids), 2), np.nan)
    out[[view_pos[v] for v in views]] = uv
    return out, point_id_array(point_ids)


def read_parquet_tracks(path) -> TrackTable:
    """``.parquet`` tracks: the columns of ``tracks.csv`` (``view``, ``point``, ``u``, ``v``)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    if not path.is_file():
        raise InputError(f"tracks file {str(path)!r} does not exist")
    try:
        table = pq.read_table(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise InputError(f"tracks file {str(path)!r} is not a Parquet file: {exc}") from None
    names = {n.lower(): n for n in table.column_names}
    missing = [c for c in ("view", "point", "u", "v") if c not in names]
    if missing:
        raise InputError(f"tracks file {str(path)!r} lacks column(s) {', '.join(missing)}")
    uv = np.column_stack([table[names[c]].to_numpy(zero_copy_only=False) for c in ("u", "v")]).astype(float)
    if not np.isfinite(uv).all():
        raise InputError(f"tracks file {str(path)!r}: columns u, v must be finite numbers")
    view_ids, view_index = _view_codes(table[names["view"]].cast(pa.string()))
    point_ids, point_index = _point_codes(table[names["point"]].cast(pa.string()))
    return TrackTable(view_ids, view_index, point_ids, point_index, uv)


# --------------------------------------------------------------------------------------
# writers (vectorised; LF line endings)
# --------------------------------------------------------------------------------------


def _id_column(ids):
    """An Arrow column of ids: integers when every id is one (no quotes in the CSV)."""
    import pyarrow as pa

    return pa.array(point_id_array(ids))


def _ids_at(ids: np.ndarray, rows: np.ndarray):
    """An Arrow column of ``ids[rows]`` (``ids`` from :func:`point_id_array`): integers
    indexed by numpy, text by Arrow's ``take`` (no fixed-width copy of every row;
    ``take`` imports pyarrow.compute, 0.04 s)."""
    import pyarrow as pa

    return pa.array(ids[rows]) if ids.dtype.kind == "i" else pa.array(ids).take(rows)


def _write_arrow_csv(path, header: list[str], columns: list) -> None:
    """Write Arrow columns as CSV with an unquoted ``header`` line, atomically; chunks of
    rows are formatted on threads (:func:`~transcalib.io.text.write_in_order`)."""
    import pyarrow as pa
    import pyarrow.csv as pcsv

    table = pa.table({name: c for name, c in zip(header, columns)})
    needs_quotes = _needs_quotes([c for c in table.columns if pa.types.is_string(c.type) and len(c)])
    opts = pcsv.WriteOptions(include_header=False, quoting_style="needed" if needs_quotes else "none")

    def csv_text(rows: slice):
        sink = pa.BufferOutputStream()
        pcsv.write_csv(table.slice(rows.start, rows.stop - rows.start), sink, write_options=opts)
        return sink.getvalue()

    with atomic_write(path, "wb") as fh:
        fh.write((",".join(header) + "\n").encode())
        text.write_in_order(fh, (partial(csv_text, rows) for rows in text.chunks(table.num_rows)))


def _needs_quotes(text_columns: list) -> bool:
    """Whether a cell of the Arrow string columns holds a comma, quote or line break
    (pyarrow.compute, 0.04 s to import, only when there is text)."""
    if not text_columns:
        return False
    import pyarrow.compute as pc

    return any(pc.any(pc.match_substring_regex(c, '[,"\n\r]')).as_py() for c in text_columns)


def _float_column(x: np.ndarray):
    """Arrow float column with NaN as null (an empty CSV cell)."""
    import pyarrow as pa

    x = np.asarray(x, dtype=float)
    return pa.array(x, mask=~np.isfinite(x))


def write_points_csv(path, point_ids, X: np.ndarray, X_std: np.ndarray | None = None, inliers=None) -> None:
    """Write ``point,x,y,z[,sx,sy,sz][,inlier]`` (empty cells for points not reconstructed).

    Parameters
    ----------
    point_ids : sequence (n_points)
    X, X_std : (n_points, 3) float
    inliers : (n_points,) bool, optional
    """
    import pyarrow as pa

    header = ["point", "x", "y", "z"]
    cols = [_id_column(point_ids)] + [_float_column(X[:, k]) for k in range(3)]
    if X_std is not None:
        header += ["sx", "sy", "sz"]
        cols += [_float_column(X_std[:, k]) for k in range(3)]
    if inliers is not None:
        header.append("inlier")
        cols.append(pa.array(np.asarray(inliers, dtype=bool).astype(np.int8)))
    _write_arrow_csv(path, header, cols)


def write_tracks(path, uv: np.ndarray, point_ids=None, view_ids=None) -> None:
    """Write tracks in the format of the extension: ``.csv``, ``.npz`` or ``.parquet``.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        NaN where a point is not seen.
    point_ids, view_ids : sequences, optional
        Default ``0..n-1``; integers or text (:func:`~transcalib.io.ids.point_id_array`).
    """
    suffix = Path(path).suffix.lower()
    n_views, n_points = uv.shape[:2]
    point_ids = point_id_array(np.arange(n_points) if point_ids is None else point_ids)
    view_ids = point_id_array(np.arange(n_views) if view_ids is None else view_ids)
    if suffix == ".npz":  # like the CSV, points never seen are left out
        keep = np.isfinite(uv[..., 0]).any(axis=0)
        with atomic_write(path, "wb") as fh:
            np.savez(fh, uv=np.asarray(uv, float)[:, keep], view_ids=view_ids.astype(str), point_ids=point_ids[keep])
        return
    j, i = np.nonzero(np.isfinite(uv[..., 0]).T)  # grouped by point: points read back in order
    cols = [_ids_at(view_ids, i), _ids_at(point_ids, j), _float_column(uv[i, j, 0]), _float_column(uv[i, j, 1])]
    if suffix == ".parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        with atomic_write(path, "wb") as fh:
            pq.write_table(pa.table({"view": cols[0], "point": cols[1], "u": cols[2], "v": cols[3]}), fh)
        return
    _write_arrow_csv(path, ["view", "point", "u", "v"], cols)


def write_tracks_csv(path, uv: np.ndarray, point_ids=None, view_ids=None) -> None:
    """Write ``view,point,u,v`` for every finite observation of ``uv (n_views, n_points, 2)``,
    grouped by point (so that the points read back in the same order)."""
    write_tracks(Path(path), uv, point_ids, view_ids)
