"""Robot poses with orientation, and their grouping into sessions.

A pose is the flange's position ``T_i`` and orientation ``R_i`` (flange -> base, so that a
flange vector ``v`` is ``R_i v`` in the base frame) as the controller reports it. Three
orientation formats, chosen by ``rotation_format``:

``"quaternion"``  columns ``qx, qy, qz, qw`` (ROS ``tf``: the flange frame in the base
                  frame, Hamilton convention, scalar last); must be unit (|1 - |q|| <= 1e-3).
``"rotvec"``      columns ``rx, ry, rz``: a rotation vector ``angle * axis`` in radians (as
                  Universal Robots controllers report it).
``"euler_zyx"``   columns ``a, b, c`` in degrees (KUKA): ``R = Rz(a) Ry(b) Rx(c)``.

A **session** is a set of views with one flange orientation. Views are grouped greedily in
file order: a view joins the first session whose first view's orientation is within
``tolerance_deg`` (default :data:`SESSION_TOLERANCE_DEG`), else it opens a new one; an
optional ``session`` column overrides the grouping. Each session's orientation is the
chordal mean of its views near its most central one; a view farther from it than the tolerance is reported with its
angle. This module reads files on its own (no dependency on :mod:`transcalib.io`).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["RobotPoses", "SessionGrouping", "read_robot_poses", "group_sessions", "quaternion_to_matrix",
           "matrix_to_quaternion", "rotvec_to_matrices", "euler_zyx_to_matrix", "ROTATION_FORMATS",
           "SESSION_TOLERANCE_DEG", "UNITS"]

#: Orientation formats and their columns.
ROTATION_FORMATS = {"quaternion": ("qx", "qy", "qz", "qw"), "rotvec": ("rx", "ry", "rz"),
                    "euler_zyx": ("a", "b", "c")}
_ALIASES = {"quat": "quaternion", "ros": "quaternion", "ur": "rotvec", "rotation_vector": "rotvec",
            "kuka": "euler_zyx", "euler": "euler_zyx"}
#: Length units of a poses file, in millimetres.
UNITS = {"mm": 1.0, "m": 1000.0}
#: Default largest angle (degrees) between two views of one session.
SESSION_TOLERANCE_DEG = 1.0
#: Largest accepted deviation of a quaternion's norm from 1.
QUATERNION_NORM_TOL = 1e-3


# ----------------------------------------------------------------------------------------
# Rotation formats (vectorised over poses)
# ----------------------------------------------------------------------------------------


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(n, 3, 3)`` of unit quaternions ``q (n, 4)`` = ``qx, qy, qz, qw``."""
    q = np.asarray(q, float).reshape(-1, 4)
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternion ``qx, qy, qz, qw`` (4,) of a rotation matrix (3, 3), ``qw >= 0``."""
    R = np.asarray(R, float)
    # largest of the four diagonal combinations first: numerically stable (Shepperd)
    d = np.array([1 + R[0, 0] - R[1, 1] - R[2, 2], 1 - R[0, 0] + R[1, 1] - R[2, 2],
                  1 - R[0, 0] - R[1, 1] + R[2, 2], 1 + np.trace(R)])
    k = int(np.argmax(d))
    s = 2.0 * np.sqrt(max(d[k], 1e-300))
    if k == 0:
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif k == 1:
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    elif k == 2:
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    else:
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    q = np.array(q)
    return q * (1.0 if q[3] >= 0 else -1.0) / np.linalg.norm(q)


def rotvec_to_matrices(w: np.ndarray) -> np.ndarray:
    """``exp([w]x)`` ``(n, 3, 3)`` of rotation vectors ``w (n, 3)`` (radians, Rodrigues)."""
    w = np.asarray(w, float).reshape(-1, 3)
    theta = np.linalg.norm(w, axis=1)
    axis = w / np.where(theta > 0, theta, 1.0)[:, None]
    q = np.concatenate([axis * np.sin(theta / 2)[:, None], np.cos(theta / 2)[:, None]], axis=1)
    return quaternion_to_matrix(q)


def euler_zyx_to_matrix(abc_deg: np.ndarray) -> np.ndarray:
    """KUKA ``A, B, C`` (degrees, ``(n, 3)``) to ``Rz(A) Ry(B) Rx(C)`` ``(n, 3, 3)``."""
    a, b, c = np.radians(np.asarray(abc_deg, float).reshape(-1, 3)).T
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    return np.stack([
        np.stack([ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc], -1),
        np.stack([sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc], -1),
        np.stack([-sb, cb * sc, cb * cc], -1)], -2)


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angles (degrees) of ``Ra^T Rb`` for stacks ``(n, 3, 3)`` (or one matrix each)."""
    tr = np.einsum("...ab,...ab->...", Ra, Rb)
    return np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))


def _project_so3(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


# ----------------------------------------------------------------------------------------
# Sessions
# ----------------------------------------------------------------------------------------


def _session_rotation(R: np.ndarray, tolerance_deg: float) -> np.ndarray:
    """Orientation of one session: the chordal mean of the views within the tolerance of
    its most central view (least median angle to the others), so that a stray view does
    not pull it."""
    angles = _angle_deg(R[:, None], R[None, :])  # (k, k)
    centre = int(np.argmin(np.median(angles, axis=1)))
    near = angles[centre] <= tolerance_deg
    return _project_so3(R[near].sum(axis=0))


@dataclass(frozen=True, eq=False)
class SessionGrouping:
    """Views grouped into sessions of one flange orientation.

    Attributes
    ----------
    session_of_view : (n_views,) int
        Session index ``0 .. n_sessions - 1`` of each view (in order of first appearance).
    rotations : (n_sessions, 3, 3) float
        Flange -> base rotation of each session (chordal mean of its views).
    angle_deg : (n_views,) float
        Angle between each view's orientation and its session's.
    tolerance_deg : float
        The tolerance used.
    off_views : tuple of (int, float)
        Views farther than the tolerance from their session's orientation, with the angle.
    labels : tuple of str
        Session names (the ``session`` column's values, or ``"0"``, ``"1"``, ...).
    """

    session_of_view: np.ndarray
    rotations: np.ndarray
    angle_deg: np.ndarray
    tolerance_deg: float
    off_views: tuple
    labels: tuple

    @property
    def n_sessions(self) -> int:
        return len(self.rotations)

    def messages(self, view_ids=None) -> list[str]:
        """One line per view off its session's orientation (empty if none)."""
        name = (lambda i: str(view_ids[i])) if view_ids is not None else str
        return [f"view {name(i)}: orientation {a:.3f} deg off its session {self.labels[self.session_of_view[i]]!r} "
                f"(tolerance {self.tolerance_deg:g} deg); the robot turned inside the session, or the view belongs "
                "to another session" for i, a in self.off_views]


def group_sessions(R: np.ndarray, tolerance_deg: float = SESSION_TOLERANCE_DEG, session=None) -> SessionGrouping:
    """Group views into sessions by flange orientation.

    Parameters
    ----------
    R : (n_views, 3, 3) float
        Flange -> base rotations ``R_i``.
    tolerance_deg : float
        Largest angle between a view and its session's first view (grouping) and its
        session's mean orientation (reported otherwise).
    session : (n_views,) sequence, optional
        Session labels overriding the grouping (any hashable values).

    Returns
    -------
    SessionGrouping
    """
    R = np.asarray(R, float)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or not np.all(np.isfinite(R)):
        raise InputError(f"flange rotations must be a finite (n_views, 3, 3) array, got shape {R.shape}")
    if not (isinstance(tolerance_deg, (int, float)) and tolerance_deg > 0):
        raise InputError(f"tolerance_deg must be a positive number of degrees, got {tolerance_deg!r}")
    n = len(R)
    if session is not None:
        session = [str(s) for s in session]
        if len(session) != n:
            raise InputError(f"session labels: got {len(session)}, expected one per view ({n})")
        labels = tuple(dict.fromkeys(session))
        of_view = np.array([labels.index(s) for s in session])
    else:
        firsts, of_view = [], np.empty(n, int)
        for i in range(n):
            angles = [_angle_deg(R[f], R[i]) for f in firsts]
            k = int(np.argmin(angles)) if angles else -1
            if k < 0 or angles[k] > tolerance_deg:
                firsts.append(i)
                k = len(firsts) - 1
            of_view[i] = k
        labels = tuple(str(k) for k in range(len(firsts)))
    rotations = np.stack([_session_rotation(R[of_view == s], tolerance_deg) for s in range(len(labels))])
    angle = _angle_deg(rotations[of_view], R)
    off = tuple((int(i), float(angle[i])) for i in np.flatnonzero(angle > tolerance_deg))
    return SessionGrouping(of_view, rotations, angle, float(tolerance_deg), off, labels)


# ----------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RobotPoses:
    """Robot flange poses read from a file.

    Attributes
    ----------
    views : list of str
        View ids in file order (the view order).
    T : (n_views, 3) float
        Flange positions in the base frame, in ``unit``.
    R : (n_views, 3, 3) float
        Flange -> base rotations ``R_i``.
    unit : {"mm", "m"}
    images : list of str or None
        Image file names (``image`` column).
    session : list of str or None
        The ``session`` column (overrides grouping by orientation).
    path : str
    """

    views: list
    T: np.ndarray
    R: np.ndarray
    unit: str
    images: list | None = None
    session: list | None = None
    path: str = ""

    def sessions(self, tolerance_deg: float = SESSION_TOLERANCE_DEG) -> SessionGrouping:
        """:func:`group_sessions` of these poses (the ``session`` column if present)."""
        return group_sessions(self.R, tolerance_deg, self.session)

    def varying_orientation(self, tolerance_deg: float = SESSION_TOLERANCE_DEG) -> bool:
        """True if the views fall into more than one session (use the sessions model)."""
        return self.sessions(tolerance_deg).n_sessions > 1


def _rows_csv(path: Path) -> tuple[list[str], list[tuple[int, list[str]]]]:
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = [(k, row) for k, row in enumerate(csv.reader(fh), start=1) if row and any(c.strip() for c in row)]
    except UnicodeDecodeError:
        raise InputError(f"poses file {str(path)!r} is not a UTF-8 text file") from None
    if len(rows) < 2:
        raise InputError(f"poses file {str(path)!r} has no data rows; expected a header line and one row per view")
    header = [h.strip().lower() for h in rows[0][1]]
    records = []
    for k, row in rows[1:]:
        if len(row) != len(header):
            raise InputError(f"poses file {str(path)!r}, line {k}: {len(row)} cells, expected {len(header)} as in "
                             "the header")
        records.append((k, dict(zip(header, (c.strip() for c in row)))))
    return header, records


def _rows_json(path: Path) -> tuple[list[str], list[tuple[int, dict]]]:
    try:
        text = path.read_text(encoding="utf-8-sig")
        data = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"poses file {str(path)!r} is not valid JSON: {exc}") from None
    entries = data.get("poses") if isinstance(data, dict) else data
    if not isinstance(entries, list) or not entries or not all(isinstance(e, dict) for e in entries):
        raise InputError(f"poses file {str(path)!r}: expected a list of objects (or {{\"poses\": [...]}}) with keys "
                         "view, x, y, z and the orientation")
    # line of each entry: the line of its k-th opening brace at list depth (good enough for messages)
    starts = [text.count("\n", 0, m) + 1 for m in _object_starts(text)]
    records = [(starts[k] if k < len(starts) else k + 1, {str(a).lower(): b for a, b in e.items()})
               for k, e in enumerate(entries)]
    header = sorted({h for _, r in records for h in r})
    return header, records


def _object_starts(text: str) -> list[int]:
    """Offsets of the objects that are elements of the pose list (depth-2 ``{``)."""
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


def _number(path, line, rec, col) -> float:
    cell = rec.get(col)
    try:
        value = float(cell)
    except (TypeError, ValueError):
        value = math.nan
    if not math.isfinite(value):
        raise InputError(f"poses file {str(path)!r}, line {line}, column {col!r}: {cell!r} is not a finite number")
    return value


def read_robot_poses(path, rotation_format: str = "quaternion", unit: str = "mm", *,
                     output_unit: str | None = None) -> RobotPoses:
    """Read flange poses with orientation from a CSV or JSON file.

    CSV: a header with ``view, x, y, z``, the orientation columns of ``rotation_format``
    (see the module docstring) and optionally ``image`` and ``session``; one row per view.
    JSON (``.json``): a list of objects with the same keys, or ``{"poses": [...]}``.

    Parameters
    ----------
    path : str or Path
    rotation_format : {"quaternion", "rotvec", "euler_zyx"}
        Also ``"ur"`` (rotvec) and ``"kuka"`` (euler_zyx).
    unit : {"mm", "m"}
        Unit of ``x, y, z`` in the file.
    output_unit : {"mm", "m"}, optional
        Unit of the returned ``T`` (default: ``unit``).

    Returns
    -------
    RobotPoses

    Raises
    ------
    InputError
        Missing file or columns, a cell that is not a finite number, a non-unit
        quaternion, duplicate view ids (each named with file and line).
    """
    fmt = _ALIASES.get(str(rotation_format).lower(), str(rotation_format).lower())
    if fmt not in ROTATION_FORMATS:
        raise InputError(f"rotation_format must be one of {', '.join(ROTATION_FORMATS)} (or ur, kuka), got "
                         f"{rotation_format!r}")
    out_unit = unit if output_unit is None else output_unit
    for u in (unit, out_unit):
        if u not in UNITS:
            raise InputError(f"unit must be one of {', '.join(UNITS)}, got {u!r}")
    path = Path(path)
    if not path.is_file():
        raise InputError(f"poses file {str(path)!r} does not exist")
    header, records = (_rows_json if path.suffix.lower() == ".json" else _rows_csv)(path)
    cols = ROTATION_FORMATS[fmt]
    missing = [c for c in ("view", "x", "y", "z", *cols) if c not in header]
    if missing:
        raise InputError(f"poses file {str(path)!r} lacks column(s) {', '.join(missing)} (rotation_format={fmt!r} "
                         f"needs {', '.join(cols)}); it has {', '.join(header)}")
    views = [str(rec["view"]).strip() for _, rec in records]
    seen = {}
    for (line, _), v in zip(records, views):
        if v in seen:
            raise InputError(f"poses file {str(path)!r}, line {line}: view id {v!r} already given on line {seen[v]}")
        seen[v] = line
    T = np.array([[_number(path, ln, rec, c) for c in "xyz"] for ln, rec in records]) * (UNITS[unit] / UNITS[out_unit])
    rot = np.array([[_number(path, ln, rec, c) for c in cols] for ln, rec in records])
    if fmt == "quaternion":
        norms = np.linalg.norm(rot, axis=1)
        bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOL)
        if bad.size:
            line = records[bad[0]][0]
            raise InputError(f"poses file {str(path)!r}, line {line}: quaternion qx,qy,qz,qw has norm "
                             f"{norms[bad[0]]:.6g}, expected 1 (within {QUATERNION_NORM_TOL:g}); check the column "
                             "order (ROS: qx, qy, qz, qw, scalar last) and the digits")
        R = quaternion_to_matrix(rot / norms[:, None])
    elif fmt == "rotvec":
        R = rotvec_to_matrices(rot)
    else:
        R = euler_zyx_to_matrix(rot)
    images = [str(rec["image"]).strip() for _, rec in records] if "image" in header else None
    session = [str(rec["session"]).strip() for _, rec in records] if "session" in header else None
    return RobotPoses(views, T, R, out_unit, images, session, str(path))
