"""Robot poses: what :func:`transcalib.calibrate` is given about the robot's motion.

A view's pose is the flange's position ``T_i`` (robot base frame, the user's length unit)
and, when known, its orientation ``R_i`` (flange -> base: a flange vector ``v`` is
``R_i v`` in the base frame), as the controller or ROS ``tf`` reports it. Without
orientations every view has the same one and the flange axes are the robot axes (the
paper's case). :func:`transcalib.io.read_poses` reads them from a file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry.rotation import ROTATION_TOL, rotation_defect


@dataclass(frozen=True, eq=False)
class Poses:
    """The poses of the views, in view order.

    Attributes
    ----------
    views : list of str (n_views)
        View ids (canonical: integers compare as integers, ``01`` is ``1``).
    T : (n_views, 3) float
        Flange positions in the base frame, in ``unit``.
    R : (n_views, 3, 3) float or None
        Flange -> base rotations ``R_i``; None without orientations.
    images : list of str or None
        Image file name of each view (a pose file's ``image`` column).
    session : list of str or None
        Session label of each view (a pose file's ``session`` column): overrides the
        grouping of the views by orientation.
    unit : str or None
        Length unit of ``T`` (None: not named).
    rotation_format : str or None
        The orientation columns of the file read, None without.
    path : str
        The file read (empty for poses made in code).
    lines : tuple of int (n_views)
        The file line of each view, for messages.
    """

    views: list
    T: np.ndarray
    R: np.ndarray | None = None
    images: list | None = None
    session: list | None = None
    unit: str | None = None
    rotation_format: str | None = None
    path: str = ""
    lines: tuple = ()

    def __post_init__(self):
        T = np.asarray(self.T, dtype=float)
        if T.ndim != 2 or T.shape[1] != 3 or len(T) != len(self.views) or not np.all(np.isfinite(T)):
            raise InputError(f"poses: T must be finite with one row x, y, z per view ({len(self.views)}), got shape "
                             f"{T.shape}")
        object.__setattr__(self, "T", T)
        if self.R is not None:
            object.__setattr__(self, "R", check_rotations(self.R, len(T), "poses: R"))
        for name in ("images", "session"):
            value = getattr(self, name)
            if value is not None and len(value) != len(T):
                raise InputError(f"poses: {name} must have one entry per view ({len(T)}), got {len(value)}")

    @classmethod
    def of(cls, T, R=None, *, views=None, session=None, unit: str | None = None) -> "Poses":
        """Poses made in code: translations ``T (n, 3)``, optional rotations ``R (n, 3, 3)``,
        view ids (default ``"0"``, ``"1"``, ...) and session labels."""
        T = np.asarray(T, dtype=float)
        n = len(T) if T.ndim == 2 else 0
        views = [str(v) for v in (range(n) if views is None else views)]
        return cls(views, T, R, session=None if session is None else [str(s) for s in session], unit=unit)

    @property
    def n_views(self) -> int:
        return len(self.views)


def check_rotations(R, n_views: int, what: str = "rotations") -> np.ndarray:
    """``R`` as a ``(n_views, 3, 3)`` stack of rotation matrices (orthonormal, det +1);
    :class:`InputError` naming the first views that are not."""
    try:
        R = np.asarray(R, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{what} must be an array of numbers ({exc})") from None
    if R.shape != (n_views, 3, 3):
        raise InputError(f"{what} must have shape (n_views, 3, 3) = ({n_views}, 3, 3), got {R.shape}")
    bad = np.flatnonzero(~(rotation_defect(R) <= ROTATION_TOL))
    if bad.size:
        raise InputError(f"{what} of views {bad[:10].tolist()} are not rotation matrices (orthonormal, det +1)")
    return R
