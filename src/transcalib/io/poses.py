"""The one reader of robot pose files (CSV or JSON) and the ``poses.csv`` writer.

A pose is the flange's position ``T_i`` and, optionally, its orientation ``R_i``
(flange -> base: a flange vector ``v`` is ``R_i v`` in the base frame) as the controller
reports it; one pose per view, the file order is the view order. Columns (CSV header,
or the keys of the JSON objects; case-insensitive, surrounding spaces ignored):

``view``                view id; integers compare as integers (``01`` is view ``1``,
                        :func:`~transcalib.io.ids.canonical_id`, as in the tracks)
``x, y, z``             the flange position, in the file's length unit
orientation, optional   one complete set of: ``qx, qy, qz, qw`` (``"quaternion"``: ROS
                        ``tf``, Hamilton, scalar last; unit norm within
                        :data:`QUATERNION_NORM_TOL`), ``rx, ry, rz`` (``"rotvec"``: angle *
                        axis in radians, Universal Robots) or ``a, b, c`` (``"euler_zyx"``:
                        KUKA, degrees, ``R = Rz(a) Ry(b) Rx(c)``)
``session``, optional   session label (overrides the grouping by orientation)
``image``, optional     image file name of the view

The orientation format is found from the columns unless given (``rotation_format``). A
JSON file is a list of objects, or ``{"poses": [...]}``. Every error names the file, the
line and the column and says what to do.
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry.rotation import euler_zyx_to_matrix, matrix_to_quaternion, quaternion_to_matrix, rotvec_to_matrix
from ..geometry.units import length_scale
from ..types import Poses
from .files import atomic_write
from .ids import canonical_id

__all__ = ["Poses", "read_poses", "write_poses_csv"]

#: Orientation formats and their columns.
ROTATION_FORMATS = {"quaternion": ("qx", "qy", "qz", "qw"), "rotvec": ("rx", "ry", "rz"),
                    "euler_zyx": ("a", "b", "c")}
#: Other names of the formats (robot makers').
_ALIASES = {"quat": "quaternion", "ros": "quaternion", "ur": "rotvec", "rotation_vector": "rotvec",
            "kuka": "euler_zyx", "euler": "euler_zyx"}
#: Largest accepted deviation of a quaternion's norm from 1.
QUATERNION_NORM_TOL = 1e-3
_REQUIRED = ("view", "x", "y", "z")
#: Names of columns that hold an orientation in some robot's or tool's convention.
_ORIENTATION_LIKE = re.compile(r"^(roll|pitch|yaw|alpha|beta|gamma|phi|theta|psi|q[0-3wxyz]|qw|"
                               r"r[xyz]_?(deg|rad)?|rot.*|orient.*|euler.*|quat.*|angle.*|[abc]_?(deg|rad))$")


@dataclass(frozen=True)
class _Table:
    """Rows of a pose file: lower-cased column names, the file line of each row, the
    cells by column name (text from CSV, JSON values from JSON)."""

    path: Path
    header: list
    lines: list
    rows: list
    kind: str  # "column" (CSV) or "key" (JSON)

    def where(self, k: int, column: str | None = None) -> str:
        """``poses file 'p.csv', line 5, column 'qx'`` of row ``k``."""
        at = f"poses file {str(self.path)!r}, line {self.lines[k]}"
        return at if column is None else f"{at}, {self.kind} {column!r}"


def _where_header(path: Path, kind: str) -> str:
    """``poses file 'p.csv', line 1`` (CSV: the header) or ``poses file 'p.json'``."""
    return f"poses file {str(path)!r}" + (", line 1" if kind == "column" else "")


def read_poses(path, *, rotation_format: str | None = None, unit: str | None = None,
               output_unit: str | None = None) -> Poses:
    """Read a pose file: ``view, x, y, z`` [, orientation] [, session] [, image].

    CSV, or JSON (extension ``.json``): a list of objects with the same keys, or
    ``{"poses": [...]}``. See the module docstring for the columns.

    Parameters
    ----------
    path : str or Path
    rotation_format : {"quaternion", "rotvec", "euler_zyx"}, optional
        Also ``"ur"`` (rotvec) and ``"kuka"`` (euler_zyx). Default: found from the
        columns (exactly one complete set of orientation columns, or none).
    unit : {"mm", "m"}, optional
        Length unit of ``x, y, z`` in the file.
    output_unit : {"mm", "m"}, optional
        Unit of the returned ``T`` (needs ``unit``; default ``unit``).

    Returns
    -------
    Poses

    Raises
    ------
    InputError
        A missing, empty or non-UTF-8 file, invalid JSON, missing columns, a row with the
        wrong number of cells, a cell that is not a finite number, an empty or repeated
        view id, an incomplete or doubled set of orientation columns, a quaternion whose
        norm is off 1; each named with the file, line and column.
    """
    fmt = _format_name(rotation_format)
    if output_unit is not None and unit is None:
        raise InputError(f"output_unit={output_unit!r} needs the unit of the file: give unit too")
    scale = 1.0 if unit is None else length_scale(unit, output_unit or unit)
    path = Path(path)
    if not path.is_file():
        raise InputError(f"poses file {str(path)!r} does not exist")
    table = _read_json(path) if path.suffix.lower() == ".json" else _read_csv(path)
    _unused_orientation(table, fmt)
    fmt = _rotation_format(table, fmt)
    views = _views(table)
    T = _numbers(table, ("x", "y", "z")) * scale
    R = None if fmt is None else _rotations(table, fmt)
    images = _texts(table, "image")
    session = _texts(table, "session")
    return Poses(views, T, R, images, session, output_unit or unit, fmt, str(path), tuple(table.lines))


def _format_name(rotation_format) -> str | None:
    """The canonical name of a rotation format (aliases: :data:`_ALIASES`), or None."""
    if rotation_format is None:
        return None
    name = str(rotation_format).strip().lower()
    name = _ALIASES.get(name, name)
    if name not in ROTATION_FORMATS:
        raise InputError(f"rotation_format must be one of {', '.join(ROTATION_FORMATS)} (or "
                         f"{', '.join(_ALIASES)}), got {rotation_format!r}")
    return name


# ----------------------------------------------------------------------------------------
# files -> rows
# ----------------------------------------------------------------------------------------


def _read_csv(path: Path) -> _Table:
    """Header and rows of a CSV pose file; blank lines are skipped."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            records = [(reader.line_num, row) for row in reader if row and any(c.strip() for c in row)]
    except UnicodeDecodeError:
        raise InputError(f"poses file {str(path)!r} is not a UTF-8 text file; save it as UTF-8 CSV") from None
    if not records:
        raise InputError(f"poses file {str(path)!r} is empty; expected a header line {','.join(_REQUIRED)} "
                         "[,orientation columns] and one row per view")
    header = [h.strip().lower() for h in records[0][1]]
    _check_header(path, header, "column")
    if len(records) == 1:
        raise InputError(f"poses file {str(path)!r} has a header but no data rows; add one row per view")
    lines, rows = [], []
    for line, row in records[1:]:
        if len(row) != len(header):
            raise InputError(f"poses file {str(path)!r}, line {line}: {len(row)} cells, expected {len(header)} as "
                             f"in the header ({','.join(header)}); check for a missing or extra comma")
        lines.append(line)
        rows.append(dict(zip(header, row)))
    return _Table(path, header, lines, rows, "column")


def _check_header(path: Path, header: list, kind: str) -> None:
    """Required columns present, none twice."""
    twice = sorted({h for h in header if header.count(h) > 1})
    if twice:
        raise InputError(f"{_where_header(path, kind)}: {kind}(s) {', '.join(twice)} appear more than once; "
                         "give each column once")
    missing = [c for c in _REQUIRED if c not in header]
    if missing:
        raise InputError(f"{_where_header(path, kind)}: lacks {kind}(s) {', '.join(missing)}; it has "
                         f"{','.join(header)}, expected at least {','.join(_REQUIRED)} (one row per view)")


def _read_json(path: Path) -> _Table:
    """Rows of a JSON pose file: a list of objects or ``{"poses": [...]}``."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"poses file {str(path)!r} is not a UTF-8 text file; save it as UTF-8 JSON") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"poses file {str(path)!r}, line {exc.lineno}, column {exc.colno}: not valid JSON "
                         f"({exc.msg})") from None
    entries = data.get("poses") if isinstance(data, dict) else data
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise InputError(f"poses file {str(path)!r}: expected a non-empty list of objects (or {{\"poses\": [...]}}) "
                         f"with keys {', '.join(_REQUIRED)} and the orientation, one per view")
    starts = [text.count("\n", 0, m) + 1 for m in _object_starts(text)]
    lines = [starts[k] if k < len(starts) else k + 1 for k in range(len(entries))]
    rows = []
    for line, entry in zip(lines, entries):
        row = {str(key).strip().lower(): value for key, value in entry.items()}
        if len(row) != len(entry):
            raise InputError(f"poses file {str(path)!r}, line {line}: two keys differ only in case or spaces; "
                             "give each key once")
        rows.append(row)
    header = list(dict.fromkeys(key for row in rows for key in row))
    _check_header(path, header, "key")
    return _Table(path, header, lines, rows, "key")


def _object_starts(text: str) -> list[int]:
    """Offsets of the objects that are elements of the pose list (the ``{`` at depth 2
    of a top-level list, depth 3 inside ``{"poses": [...]}``)."""
    out, depth, in_str, esc = [], 0, False, False
    top_is_list = text.lstrip().startswith("[")
    for k, ch in enumerate(text):
        if in_str:
            if esc:
                esc = False
            elif ch == "\\":
                esc = True
            elif ch == '"':
                in_str = False
            continue
        if ch == '"':
            in_str = True
        elif ch in "[{":
            depth += 1
            if ch == "{" and depth == (2 if top_is_list else 3):
                out.append(k)
        elif ch in "]}":
            depth -= 1
    return out


# ----------------------------------------------------------------------------------------
# rows -> columns
# ----------------------------------------------------------------------------------------


def _rotation_format(table: _Table, given: str | None) -> str | None:
    """The orientation format: ``given`` (its columns must be present), else the one
    complete set of orientation columns (None without any)."""
    where, header = _where_header(table.path, table.kind), table.header
    if given is not None:
        missing = [c for c in ROTATION_FORMATS[given] if c not in header]
        if missing:
            raise InputError(f"{where}: lacks {table.kind}(s) {', '.join(missing)}: rotation_format={given!r} needs "
                             f"{','.join(ROTATION_FORMATS[given])}; it has {','.join(header)}. Add them, or give the "
                             "rotation_format of the orientation columns the file has (or none)")
        return given
    sets = {f: [c for c in cols if c in header] for f, cols in ROTATION_FORMATS.items()}
    partial = {f: present for f, present in sets.items() if 0 < len(present) < len(ROTATION_FORMATS[f])}
    if partial:
        f, present = next(iter(partial.items()))
        missing = [c for c in ROTATION_FORMATS[f] if c not in present]
        raise InputError(f"{where}: {table.kind}(s) {','.join(present)} of the orientation "
                         f"{','.join(ROTATION_FORMATS[f])} ({f}) without {','.join(missing)}; add the missing "
                         f"{table.kind}(s), or rename those that are not an orientation (orientations: "
                         f"{' or '.join(','.join(c) for c in ROTATION_FORMATS.values())}; see rotation_format)")
    complete = [f for f, present in sets.items() if len(present) == len(ROTATION_FORMATS[f])]
    if len(complete) > 1:
        raise InputError(f"{where}: two orientations, " + " and ".join(
            f"{','.join(ROTATION_FORMATS[f])} ({f})" for f in complete) + "; choose the one to use with "
            f"rotation_format ({' or '.join(complete)}), or remove the other {table.kind}s")
    return complete[0] if complete else None


def _unused_orientation(table: _Table, given: str | None) -> None:
    """Refuse columns that look like an orientation but no format reads (every view would
    silently be taken at one orientation); with ``rotation_format`` given, the user chose."""
    if given is not None:
        return
    read = {c for cols in ROTATION_FORMATS.values() for c in cols} | set(_REQUIRED) | {"session", "image"}
    odd = [h for h in table.header if h not in read and _ORIENTATION_LIKE.match(h)]
    if odd:
        raise InputError(f"{_where_header(table.path, table.kind)}: {table.kind}(s) {','.join(odd)} look like an "
                         "orientation, but no orientation format reads them: they would be ignored and every view "
                         "taken at one orientation. Give the orientation as qx,qy,qz,qw (rotation_format "
                         "quaternion), rx,ry,rz (rotvec: radians) or a,b,c (euler_zyx: KUKA, degrees, R = Rz(a) "
                         "Ry(b) Rx(c); roll, pitch, yaw about fixed x, y, z are c, b, a), or rename those "
                         f"{table.kind}s if they are not an orientation")


def _views(table: _Table) -> list:
    """Canonical view ids; an empty or repeated id is an error naming both lines."""
    views, first = [], {}
    for k, row in enumerate(table.rows):
        raw = row.get("view")
        text = "" if raw is None or isinstance(raw, (dict, list)) else str(raw).strip()
        if not text:
            raise InputError(f"{table.where(k, 'view')}: the view id is empty; give every view an id")
        v = canonical_id(text)
        if v in first:
            j = first[v]
            raise InputError(f"{table.where(k, 'view')}: view id {text!r} appears more than once (as view {v!r} "
                             f"on line {table.lines[j]}; integer ids compare as integers, 01 = 1); give one pose "
                             "per view")
        first[v] = k
        views.append(v)
    return views


def _numbers(table: _Table, columns) -> np.ndarray:
    """``(n_rows, len(columns))`` float; a missing, non-numeric or non-finite cell is an
    error naming its line and column."""
    out = np.empty((len(table.rows), len(columns)))
    for k, row in enumerate(table.rows):
        for m, c in enumerate(columns):
            cell = row.get(c)
            try:
                value = math.nan if isinstance(cell, bool) else float(cell)
            except (TypeError, ValueError):
                value = math.nan
            if not math.isfinite(value):
                what = "is missing" if c not in row else f"{cell!r} is not a finite number"
                raise InputError(f"{table.where(k, c)}: {what}; give a number")
            out[k, m] = value
    return out


def _rotations(table: _Table, fmt: str) -> np.ndarray:
    """Flange -> base rotations ``(n_rows, 3, 3)`` from the columns of ``fmt``."""
    values = _numbers(table, ROTATION_FORMATS[fmt])
    if fmt == "rotvec":
        return rotvec_to_matrix(values)
    if fmt == "euler_zyx":
        return euler_zyx_to_matrix(values)
    norms = np.linalg.norm(values, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOL)
    if bad.size:
        k = int(bad[0])
        raise InputError(f"{table.where(k)}: quaternion qx,qy,qz,qw has norm {norms[k]:.6g}, expected 1 (within "
                         f"{QUATERNION_NORM_TOL:g}); check the column order (ROS: qx, qy, qz, qw, scalar last) "
                         "and the digits")
    return quaternion_to_matrix(values)


def _texts(table: _Table, column: str) -> list | None:
    """A text column (stripped), or None when the file has none."""
    if column not in table.header:
        return None
    return ["" if row.get(column) is None else str(row.get(column)).strip() for row in table.rows]


# ----------------------------------------------------------------------------------------
# writer
# ----------------------------------------------------------------------------------------


def write_poses_csv(path, T: np.ndarray, view_ids=None, images=None, R: np.ndarray | None = None,
                    session=None) -> None:
    """Write ``view,x,y,z[,qx,qy,qz,qw][,session][,image]`` atomically (LF line endings);
    numbers in their shortest exact form.

    Parameters
    ----------
    T : (n_views, 3) float
    view_ids, images, session : sequences (n_views), optional
        Default view ids ``0 .. n_views - 1``.
    R : (n_views, 3, 3) float, optional
        Flange -> base rotations, written as quaternions (ROS ``tf``).
    """
    view_ids = list(range(len(T))) if view_ids is None else list(view_ids)
    q = None if R is None else matrix_to_quaternion(R)
    header = ["view", "x", "y", "z"] + (list(ROTATION_FORMATS["quaternion"]) if q is not None else [])
    header += (["session"] if session is not None else []) + (["image"] if images is not None else [])
    with atomic_write(path, newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        for i, t in enumerate(T):
            row = [view_ids[i]] + [repr(float(x)) for x in t]
            row += [] if q is None else [repr(float(x)) for x in q[i]]
            row += ([] if session is None else [session[i]]) + ([] if images is None else [images[i]])
            w.writerow(row)
