"""The robot's motion as the one model sees it: flange poses, sessions, the setup.

A view has a flange pose ``(R_i, T_i)`` in the robot base frame; the camera sits in the
flange at ``(R_X, t_X)``::

    x_ij ~ K (R_i R_X)^T (X_j - T_i - R_i t_X)                        (eye-in-hand)

Eye-to-hand (the camera fixed in the base at ``(R_bc, t_bc)``, the flange carrying the
scene points ``P_j``): ``x_ij ~ K R_bc^T (R_i P_j + T_i - t_bc)``, which is the same model
with the flange poses inverted, ``R_i -> R_i^T``, ``T_i -> -R_i^T T_i``, and
``(R_X, t_X) = (R_bc, t_bc)``: the camera moves around the flange-fixed scene. So the
eye-to-hand poses are inverted once here and every stage after runs the eye-in-hand model.

Views whose orientations agree within ``tolerance_deg`` form a **session** (a pure
translation among themselves); a view at an orientation of its own is a session of one
view. Without orientations every view is in one session and the flange axes are the
robot axes (the paper's case).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry.rotation import rotation_angle_deg
from ..handeye.sessions import SESSION_TOLERANCE_DEG, SessionGrouping, group_sessions
from ..types import SETUPS, Poses
from ..types.poses import check_rotations

#: Rotations of all views within this angle (degrees) of each other are one constant
#: orientation: rounding of a commanded one.
CONSTANT_ORIENTATION_DEG = 1e-6


@dataclass(frozen=True, eq=False)
class Motion:
    """The flange poses of the views in the model's terms.

    Attributes
    ----------
    T : (n_views, 3) float
        Flange positions (eye-to-hand: ``-R_i^T T_i``), robot units.
    R : (n_views, 3, 3) float or None
        Flange -> base rotations (eye-to-hand: ``R_i^T``); None without orientations.
    setup : {"eye-in-hand", "eye-to-hand"}
    grouping : SessionGrouping or None
        Views grouped into sessions by orientation; None without orientations.
    """

    T: np.ndarray
    R: np.ndarray | None
    setup: str
    grouping: SessionGrouping | None

    @property
    def n_views(self) -> int:
        return len(self.T)

    @property
    def constant(self) -> bool:
        """One orientation for every view (or none given): the paper's problem, solved
        with the flange axes as the model's world axes."""
        if self.R is None:
            return True
        return bool(np.all(rotation_angle_deg(self.R[0].T @ self.R) <= CONSTANT_ORIENTATION_DEG))

    @property
    def session_of_view(self) -> np.ndarray:
        return np.zeros(self.n_views, int) if self.grouping is None else self.grouping.session_of_view

    @property
    def labels(self) -> tuple:
        return ("0",) if self.grouping is None else self.grouping.labels

    def session_sizes(self) -> np.ndarray:
        """Views per session ``(n_sessions,)``."""
        return np.bincount(self.session_of_view, minlength=len(self.labels))


def motion_of(poses, setup: str = "eye-in-hand", tolerance_deg: float = SESSION_TOLERANCE_DEG) -> Motion:
    """The :class:`Motion` of ``poses``: a :class:`~transcalib.types.Poses` or translations
    ``(n_views, 3)`` (one orientation). Eye-to-hand without orientations is a translated
    object: ``T -> -T``.

    Raises
    ------
    InputError
        An unknown setup or tolerance; malformed poses.
    """
    if setup not in SETUPS:
        raise InputError(f"setup must be one of {', '.join(SETUPS)}, got {setup!r}")
    if not (isinstance(tolerance_deg, (int, float)) and tolerance_deg > 0):
        raise InputError(f"session tolerance must be a positive number of degrees, got {tolerance_deg!r}")
    if not isinstance(poses, Poses):
        poses = Poses.of(np.asarray(poses, dtype=float)) if np.ndim(poses) == 2 else poses
        if not isinstance(poses, Poses):
            raise InputError(f"poses must be a transcalib.Poses or translations (n_views, 3), got {type(poses).__name__}")
    T, R = poses.T, poses.R
    if R is not None:
        R = check_rotations(R, len(T), "poses: R")
    if setup == "eye-to-hand" and R is None:
        T = -T
    elif setup == "eye-to-hand":
        R = np.transpose(R, (0, 2, 1)).copy()
        T = -np.einsum("vab,vb->va", R, T)
    grouping = None if R is None else group_sessions(R, tolerance_deg, poses.session)
    return Motion(T, R, setup, grouping)
