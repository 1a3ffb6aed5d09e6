"""Views grouped into sessions: sets of views with one flange orientation.

A **session** is a set of views with one flange orientation ``R_i`` (flange -> base, as
read by :func:`transcalib.io.read_poses`). Views are grouped greedily in file order: a
view joins the first session whose first view's orientation is within ``tolerance_deg``
(default :data:`SESSION_TOLERANCE_DEG`), else it opens a new one; an optional
``session`` column overrides the grouping. Each session's orientation is the chordal
mean of its views near its most central one; a view farther from it than the tolerance
is reported with its angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..types.options import SESSION_TOLERANCE_DEG
from ..geometry.rotation import central_mean_rotation, group_by_orientation, rotation_angle_deg

__all__ = ["SessionGrouping", "group_sessions", "SESSION_TOLERANCE_DEG"]



def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angles (degrees) of ``Ra^T Rb``, broadcast over stacks ``(..., 3, 3)``."""
    return rotation_angle_deg(np.swapaxes(Ra, -1, -2) @ Rb)


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

    def restricted(self, keep: np.ndarray) -> "SessionGrouping":
        """The grouping of the views ``keep`` ((n_views,) bool): sessions without a kept
        view dropped, the others renumbered in order."""
        keep = np.asarray(keep, bool)
        kept = np.unique(self.session_of_view[keep])
        number = np.full(self.n_sessions, -1)
        number[kept] = np.arange(len(kept))
        views = np.flatnonzero(keep)
        position = np.full(len(keep), -1)
        position[views] = np.arange(len(views))
        off = tuple((int(position[i]), a) for i, a in self.off_views if keep[i])
        return SessionGrouping(number[self.session_of_view[keep]], self.rotations[kept], self.angle_deg[keep],
                               self.tolerance_deg, off, tuple(self.labels[k] for k in kept))

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
        of_view = group_by_orientation(R, tolerance_deg)
        labels = tuple(str(k) for k in range(of_view.max() + 1 if n else 0))
    # each session's orientation: a mean that a stray view does not pull
    rotations = np.stack([central_mean_rotation(R[of_view == s], tolerance_deg)[0] for s in range(len(labels))])
    angle = _angle_deg(rotations[of_view], R)
    off = tuple((int(i), float(angle[i])) for i in np.flatnonzero(angle > tolerance_deg))
    return SessionGrouping(of_view, rotations, angle, float(tolerance_deg), off, labels)
