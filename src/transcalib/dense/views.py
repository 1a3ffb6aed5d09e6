"""The camera of every view, in one place: orientation, centre, session, reference view.

Dense matching needs each view's pose in the robot frame. It is made here and nowhere
else, by :func:`view_cameras`, from the calibration and the robot poses::

    one orientation (the paper's case):   R_cam_world_i = R,        C_i = T_i
    hand-eye calibration (R = R_X^T):      R_cam_world_i = R R_s^T,  C_i = T_i + R_i t_X

(``R_i`` flange -> base as read from the poses file, ``R_s`` the chordal mean of the
orientations of view i's session; ``C_i`` relative to the camera centre at ``T = 0``
with one orientation, the project's convention.) A calibration with one orientation
holds for the flange orientation it was made at, which it does not record: views whose
reported orientations differ from each other cannot all share its ``R`` and are refused.
The views with the reference view's orientation form its **session**: pure translations
of one another, whose epipolar geometry the sweep uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DegenerateError, InputError
from ..geometry.rotation import ROTATION_TOL, rotation_angle_deg, rotation_defect

__all__ = ["ViewCameras", "view_cameras", "central_view", "ORIENTATION_TOL_DEG"]

#: Largest angle (degrees) between the orientations of two views of one session.
ORIENTATION_TOL_DEG = 0.1


@dataclass(frozen=True, eq=False)
class ViewCameras:
    """Pose of every view's camera in the robot frame.

    Attributes
    ----------
    R : (n_views, 3, 3) float
        World -> camera rotation of each view.
    C : (n_views, 3) float
        Camera centres (robot units).
    session : (n_views,) int
        Session (one orientation) of each view, numbered in order of appearance.
    """

    R: np.ndarray
    C: np.ndarray
    session: np.ndarray

    @property
    def n_views(self) -> int:
        return len(self.C)

    def session_of(self, view: int) -> np.ndarray:
        """Indices of the views in ``view``'s session (itself included), ascending."""
        return np.flatnonzero(self.session == self.session[view])

    def relative_translation(self, ref: int, view: int) -> np.ndarray:
        """``t = R_ref (C_view - C_ref)`` (3,): ``view``'s centre in ``ref``'s camera
        frame (a scene point ``x`` of ``ref``'s frame is ``x - t`` in ``view``'s, same
        session)."""
        return self.R[ref] @ (self.C[view] - self.C[ref])


def _check_rotations(rotations, n_views: int) -> np.ndarray | None:
    if rotations is None:
        return None
    R = np.asarray(rotations, dtype=float)
    if R.shape != (n_views, 3, 3):
        raise InputError(f"rotations must have shape ({n_views}, 3, 3) (flange -> base, one per view); "
                         f"got {R.shape}")
    bad = np.flatnonzero(rotation_defect(R) > ROTATION_TOL)
    if bad.size:
        raise InputError(f"rotations of views {bad[:10].tolist()} are not rotation matrices")
    return R


def _sessions(R: np.ndarray) -> np.ndarray:
    """Session labels: a view joins the first session whose first view's orientation is
    within :data:`ORIENTATION_TOL_DEG`, else opens a new one."""
    firsts, labels = [], np.empty(len(R), int)
    for i, Ri in enumerate(R):  # a loop over views
        for s, f in enumerate(firsts):
            if rotation_angle_deg(R[f].T @ Ri) <= ORIENTATION_TOL_DEG:
                labels[i] = s
                break
        else:
            labels[i] = len(firsts)
            firsts.append(i)
    return labels


def _mean_rotation(R: np.ndarray) -> np.ndarray:
    """The chordal mean of rotations ``(k, 3, 3)``: one orientation per session, so that
    its views are exact translations of one another."""
    U, _, Vt = np.linalg.svd(R.sum(axis=0))
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt


def view_cameras(calibration, T, rotations=None, view_ids=None) -> ViewCameras:
    """The camera of every view (module docstring).

    Parameters
    ----------
    calibration : Calibration or Camera
        ``t_flange_camera`` set (a hand-eye calibration): ``R`` is ``R_X^T`` and the
        poses' orientations place each view.
    T : (n_views, 3) float
        Robot (flange) positions, in the calibration's unit.
    rotations : (n_views, 3, 3) float, optional
        Flange -> base orientations as read (:attr:`transcalib.io.Poses.R`).
    view_ids : sequence of str, optional
        For messages.

    Raises
    ------
    InputError
        Orientations that differ between views with a one-orientation calibration; a
        hand-eye calibration without orientations; bad shapes.
    """
    T = np.asarray(T, dtype=float)
    n = len(T)
    ids = [str(v) for v in view_ids] if view_ids is not None else [str(i) for i in range(n)]
    Rf = _check_rotations(rotations, n)
    camera = getattr(calibration, "camera", calibration)
    t_X = getattr(calibration, "t_flange_camera", None)
    if t_X is not None:
        if Rf is None:
            raise InputError("this is a hand-eye calibration (several orientations): the poses need the flange "
                             "orientation of every view (qx,qy,qz,qw, rx,ry,rz or a,b,c)")
        session = _sessions(Rf)
        Rs = np.stack([_mean_rotation(Rf[session == s]) for s in range(session.max() + 1)])[session]
        return ViewCameras(R=camera.R @ np.swapaxes(Rs, -1, -2), C=T + Rf @ np.asarray(t_X, float), session=session)
    session = np.zeros(n, int) if Rf is None else _sessions(Rf)
    if session.max() > 0:
        angle = rotation_angle_deg(Rf[0].T @ Rf)
        off = np.flatnonzero(session != 0)
        detail = ", ".join(f"view {ids[i]} at {angle[i]:.3g} deg" for i in off[:8])
        raise InputError(f"the poses hold {session.max() + 1} flange orientations but the calibration has one (its R "
                         f"holds for the orientation it was made at): {detail} from view {ids[0]}; give only views "
                         f"at the calibration's orientation (within {ORIENTATION_TOL_DEG:g} deg)")
    return ViewCameras(R=np.repeat(camera.R[None], n, axis=0), C=T.copy(), session=session)


def central_view(cams: ViewCameras) -> int:
    """The default reference view: in the largest session (the first of equal ones),
    the view with the least summed distance to the session's others (its medoid)."""
    counts = np.bincount(cams.session)
    members = np.flatnonzero(cams.session == int(np.argmax(counts)))
    C = cams.C[members]
    return int(members[np.argmin(np.linalg.norm(C[:, None] - C[None], axis=-1).sum(axis=1))])


def check_baselines(cams: ViewCameras, ref: int, sources: np.ndarray, view_ids) -> None:
    """Raise :class:`DegenerateError` when no other view of the session moved."""
    if len(sources) == 0:
        raise InputError(f"reference view {view_ids[ref]} has no other view at its orientation to match; give at "
                         "least two views of one session")
    scale = max(np.linalg.norm(cams.C[cams.session_of(ref)] - cams.C[ref], axis=1).max(), 1e-300)
    base = np.linalg.norm(cams.C[sources] - cams.C[ref], axis=1)
    if np.all(base <= 1e-9 * max(scale, np.abs(cams.C).max(), 1.0)):
        raise DegenerateError(f"the views of reference view {view_ids[ref]}'s session are all at its position: "
                              "no baseline, no depth; move the robot between the views")
