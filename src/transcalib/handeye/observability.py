"""Which directions of the hand-eye offset ``t_X`` the data determine, and the CRLB.

Shifting ``t_X`` by ``a`` moves every camera centre by ``R_i a``; if ``R_i a = b`` is the
same for all views (``a`` is an axis of every relative rotation ``R_s^T R_u``), moving all
points by ``b`` leaves every image unchanged: ``a`` is undetermined. One session leaves all
of ``t_X`` free, two sessions the component along their relative rotation axis, three
with non-parallel relative axes none. This is not assumed but measured: the reduced Fisher
information ``S`` (points eliminated, :func:`transcalib.estimate.covariance.reduced_information`)
of the posed problem (free intrinsics, distortion, ``R_X`` and ``t_X`` with
``t_basis = I``) is reduced once more onto ``t_X``::

    I_t = S_tt - S_to S_oo^-1 S_ot

measured against ``U_tt``, the information on ``t_X`` were everything else known
(generalised eigenvalues ``I_t v = lam U_tt v`` in [0, 1]: the fraction of the information
that survives not knowing the points); eigenvectors with ``lam <= T_RTOL`` are the undetermined directions (flange
frame). **Convention**: the reported ``t_X`` has zero component along each undetermined
direction (the equally good solutions form a line or plane; the one nearest the flange
origin is reported); the base-frame points carry the same choice (shifted by ``R_i a``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from ..estimate.bundle import normal_equations
from ..estimate.covariance import bound_std, check_identifiable, reduced_information
from ..estimate.layout import Layout, State
from ..estimate.observations import build_data
from ..geometry.camera import pad_dist
from ..geometry.rotation import matrix_to_rotvec
from ..types import RefineOptions

__all__ = ["Observability", "offset_observability", "sessions_crlb"]

#: Scaled eigenvalue of the offset information below which a direction is undetermined.
T_RTOL = 1e-9
#: A determined direction whose information is below this fraction of the best one's is
#: reported as weak (its std is then >= 10 times that of the best direction).
T_WEAK = 1e-2


@dataclass(frozen=True, eq=False)
class Observability:
    """What the data determine of ``t_X``.

    Attributes
    ----------
    determined : (3, k) float
        Orthonormal directions of ``t_X`` (flange frame) the data determine.
    undetermined : (3, 3 - k) float
        Orthonormal free directions; ``t_X`` is reported with zero component along them.
    information : (3,) float
        Scaled eigenvalues of ``I_t`` (ascending; 1 = as well determined as if the other
        parameters were known, 0 = free).
    relative_axes : list of (str, str, (3,) float, float)
        Per session pair: labels, relative rotation axis (flange frame) and angle (deg).
    message : str
        What is undetermined and what extra session would fix it ("" if nothing).
    """

    determined: np.ndarray
    undetermined: np.ndarray
    information: np.ndarray
    relative_axes: list
    message: str

    @property
    def fully_determined(self) -> bool:
        return self.undetermined.shape[1] == 0


def relative_axes(rotations: np.ndarray, labels) -> list:
    """Relative rotation axis (flange frame) and angle (degrees) of each session pair."""
    out = []
    for s in range(len(rotations)):
        for u in range(s + 1, len(rotations)):
            w = matrix_to_rotvec(rotations[s].T @ rotations[u])
            ang = float(np.linalg.norm(w))
            out.append((labels[s], labels[u], w / ang if ang > 0 else np.zeros(3), float(np.degrees(ang))))
    return out


def _fisher(K, dist5, R_cam, t, X, uv, T, F, fix, estimate_skew, square_pixels, distortion, t_basis=None):
    """Reduced information ``S`` and its layout (points eliminated) at the given state."""
    seen = np.all(np.isfinite(uv), axis=2)
    used = np.flatnonzero((seen.sum(axis=0) >= 2) & np.all(np.isfinite(X), axis=1))
    lay = Layout.from_options(RefineOptions(distortion=distortion, fix=fix, estimate_skew=estimate_skew,
                                            square_pixels=square_pixels), len(T),
                              np.eye(3) if t_basis is None else t_basis)
    state = State(np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]]), pad_dist(dist5), R_cam,
                  np.tile(np.eye(3), (len(T), 1, 1)), T, X[used], F, np.asarray(t, float))
    data = build_data(uv, seen, used, T, np.zeros(len(T)))
    U = normal_equations(state, lay, data)[0]
    return reduced_information(state, lay, data).S, lay, U


def _split(free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal bases ``(3, k)`` of the span of ``free`` and ``(3, 3 - k)`` of its complement."""
    if free.shape[1] == 0:
        return np.zeros((3, 0)), np.eye(3)
    U = np.linalg.svd(free, full_matrices=True)[0]
    k = free.shape[1]
    return U[:, :k], U[:, k:]


def _suggestion(undet: np.ndarray, axes: list, frame: str) -> str:
    """What the undetermined directions ``undet (3, k)`` mean and the motion that fixes them."""
    k = undet.shape[1]
    name = f"t_{frame}_camera"
    if k == 0:
        return ""
    if k == 3:
        why = ("the views used have one flange orientation" if not axes else
               "no point is tracked across sessions")
        return (f"{name} is not determined at all ({why}); add two sessions with the wrist turned by "
                ">= 15 deg about two non-parallel axes, and track points across the sessions. Reported: t = 0.")
    if k == 2:
        return (f"only one direction of {name} is determined; add a session turned about a new axis and "
                "track points across the sessions. Reported: zero along the free directions "
                f"{np.round(undet.T, 3).tolist()} ({frame} frame).")
    a = undet[:, 0]
    e = np.eye(3)[int(np.argmin(np.abs(a)))]
    perp = np.cross(a, e)
    perp /= np.linalg.norm(perp)
    return (f"the component of {name} along {np.round(a, 3).tolist()} ({frame} frame, the common axis of "
            "the relative wrist rotations) is not determined; it is reported as 0 (t_X . a = 0) and the points "
            "carry the same convention. Add a session with the wrist turned by >= 15 deg about an axis "
            f"perpendicular to it, e.g. the {frame} axis {np.round(perp, 3).tolist()}.")


def offset_observability(K, dist5, R_cam, t, X, uv, T, F, rotations, labels, *, fix=None, estimate_skew=False,
                         square_pixels=False, distortion="none", frame="flange") -> Observability:
    """Undetermined directions of ``t_X`` from the Fisher information of the posed problem.

    Parameters
    ----------
    K : (3, 3) float
    dist5 : (5,) float
    R_cam : (3, 3) float
        ``R_X^T``.
    t : (3,) float
        ``t_X`` at which to linearise.
    X : (n_points, 3) float
        Base-frame points (NaN: not used).
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float
    F : (n_views, 3, 3) float
        ``R_i^T`` per view.
    rotations : (n_sessions, 3, 3) float
        Session orientations (for the relative axes in the message).
    labels : sequence of str
    fix, estimate_skew, square_pixels, distortion
        The posed problem (as :class:`transcalib.RefineOptions`).
    frame : {"flange", "base"}
        The frame ``t_X`` is in (``base`` eye-to-hand), named in the message.

    Raises
    ------
    DegenerateError
        Parameters other than ``t_X`` are not determined (named).
    """
    fix = dict(fix or {})
    S, lay, U_full = _fisher(K, dist5, R_cam, t, X, uv, T, F, fix, estimate_skew, square_pixels, distortion)
    it = np.arange(lay.i_t, lay.i_t + 3)
    io = np.setdiff1d(np.arange(lay.size), it)
    evals_o, evecs_o = check_identifiable(S[np.ix_(io, io)], tuple(np.array(lay.names())[io]))
    Sot = S[np.ix_(io, it)]
    It = S[np.ix_(it, it)] - Sot.T @ ((evecs_o / evals_o) @ (evecs_o.T @ Sot))
    # relative to the information on t with everything else known: eigenvalues in [0, 1]
    Utt = U_full[np.ix_(it, it)]
    evals, vecs = scipy.linalg.eigh(0.5 * (It + It.T), Utt)
    weak = evals <= T_RTOL
    undet, determined = _split(vecs[:, weak])
    axes = relative_axes(rotations, labels)
    msg = _suggestion(undet, axes, frame)
    if not weak.any() and evals[0] < T_WEAK * evals[-1]:
        v0 = np.round(vecs[:, 0] / np.linalg.norm(vecs[:, 0]), 3).tolist()
        msg = (f"t_{frame}_camera is only weakly determined along {v0} ({frame} frame; information "
               f"{evals[0] / evals[-1]:.1e} of the best direction's): the relative wrist rotations "
               "are nearly about one axis; add a session turned about a perpendicular axis.")
    return Observability(determined, undet, np.clip(evals, 0, None), axes, msg)


def sessions_crlb(scene, *, fix=None, square_pixels=False, estimate_skew=False, distortion="none",
                  t_basis=None) -> dict:
    """Cramér-Rao lower bound of a simulated :class:`~transcalib.handeye.simulate.SessionScene`.

    ``sigma_px^2 S^-1`` at the ground truth (points eliminated) for the observation
    pattern of ``scene.uv``; names as in ``Calibration.std`` (``f`` or ``fx, fy``, ``cx``,
    ``cy``, ``rx, ry, rz`` in degrees — the rotation ``R_X^T <- exp([w]x) R_X^T`` — and
    ``t_x, t_y, t_z``, or ``t_0 ..`` along ``t_basis``). Any motion: sessions, single
    views, eye-to-hand (whose poses the model inverts, as :mod:`transcalib.pipeline.motion`).
    """
    scene = scene.as_eye_in_hand()
    F = np.transpose(scene.R, (0, 2, 1))
    uv = np.where(np.isfinite(scene.uv), scene.uv_true, np.nan)
    S, lay, _ = _fisher(scene.K, pad_dist(scene.dist), scene.R_X.T, scene.t_X, scene.X, uv, scene.T, F, dict(fix or {}),
                     estimate_skew, square_pixels, distortion, t_basis)
    return bound_std(S, lay, scene.noise_px)
