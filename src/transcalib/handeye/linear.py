"""The multi-session linear start: ``M = K R_X^T`` by one exact TLS, then ``t_X`` and the points.

With ``M = K R_X^T`` the views of session ``s`` (flange rotation ``R_s``, positions
``T_i``, ``m_s`` their mean) satisfy ::

    x_ij ~ K (R_s R_X)^T (X_j - T_i - R_s t_X) = M (Y_sj - T'_i),
    T'_i = R_s^T (T_i - m_s),    Y_sj = R_s^T (X_j - m_s) - t_X

a pure-translation problem (paper eq. 2) with the same ``A = M`` for every session, the
translations ``T'_i`` in the flange frame and one point ``Y_sj`` per point and session.
So the columns of the sessions are stacked side by side (NaN elsewhere) and solved by
:func:`transcalib.estimate.linear.fit_linear`; RQ gives ``K`` and ``R_X^T``. Only the
moves inside a session enter the TLS, so ``M`` is determined when the union of the
flange-frame moves ``R_s^T (T_i - T_r)`` spans 3-D: sessions coplanar alone are fine
together when their planes differ in the flange frame. A wrist turned only about the
normal of the plane of motion (a SCARA robot) keeps the plane fixed in the flange frame:
the paper's coplanar ambiguity; :func:`check_flange_span` names it.

Then each point seen in several sessions gives ``X_j = R_s Y_sj + m_s + R_s t_X`` for each
of them; eliminating ``X_j`` (the mean over its sessions) leaves the linear least-squares
problem ::

    min_t  sum_sj | (R_s - Rbar_j) t + (b_sj - bbar_j) |^2,     b_sj = R_s Y_sj + m_s

whose normal matrix is singular along every relative rotation axis shared by all session
pairs (two sessions: the axis of ``R_1^T R_2``). The undetermined part of ``t`` is set to
zero (the minimum-norm solution), and the points follow from ``t``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import DegenerateError
from ..estimate.linear import fit_linear
from ..estimate.robust import fit_robust
from ..types import LinearEstimate, RansacOptions, RansacStats
from ..validate import SPAN_RTOL
from .sessions import SessionGrouping

__all__ = ["SessionsLinear", "sessions_linear"]

#: Relative eigenvalue of the offset's normal matrix below which a direction is free.
OFFSET_RTOL = 1e-9


@dataclass(frozen=True, eq=False)
class SessionsLinear:
    """The linear multi-session estimate.

    Attributes
    ----------
    K : (3, 3) float
    R_X : (3, 3) float
        Camera -> flange rotation (``R_flange_camera``).
    t_X : (3,) float
        Camera centre in the flange frame (robot units); zero along ``undetermined``.
    X : (n_points, 3) float
        Points in the base frame (absolute); NaN where not triangulated.
    depth : (n_views, n_points) float
        Projective depths of the TLS.
    undetermined : (3, k) float
        Orthonormal directions of ``t_X`` (flange frame) the linear problem leaves free.
    stacked : LinearEstimate
        The pure-translation TLS on the stacked sessions (its ``X`` are the ``Y_sj``).
    flange_span : (3,) float
        Singular values of the flange-frame moves (descending).
    """

    K: np.ndarray
    R_X: np.ndarray
    t_X: np.ndarray
    X: np.ndarray
    depth: np.ndarray
    undetermined: np.ndarray
    stacked: LinearEstimate
    flange_span: np.ndarray
    Y: np.ndarray  # (n_sessions, n_points, 3)
    m: np.ndarray  # (n_sessions, 3)
    rotations: np.ndarray  # (n_sessions, 3, 3)
    inliers: np.ndarray | None = None  # (n_sessions, n_points) bool with RANSAC
    ransac: RansacStats | None = None  # the robust stage, with RANSAC

    def as_linear_estimate(self) -> LinearEstimate:
        """The start of the refinement: ``K``, ``R = R_X^T``, the base-frame ``X``."""
        used = np.all(np.isfinite(self.X), axis=1)
        return LinearEstimate(K=self.K, R=self.R_X.T, A=self.K @ self.R_X.T, X=self.X, depth=self.depth,
                              singular_values=self.stacked.singular_values, n_used_points=int(used.sum()),
                              used=used, method=self.stacked.method)

    def with_offset_basis(self, basis: np.ndarray) -> "SessionsLinear":
        """Re-solve ``t_X`` restricted to ``t = basis c`` (the directions the Fisher
        information determines) and the points with it."""
        t, undet = solve_offset(self.Y, self.m, self.rotations, basis)
        return replace(self, t_X=t, X=_points(self.Y, self.m, self.rotations, t), undetermined=undet)


def _flange_moves(T: np.ndarray, grouping: SessionGrouping):
    """Session-centred flange-frame translations ``T'_i`` of the views within the tolerance
    of their session's orientation, and the means ``m_s``."""
    s_of = grouping.session_of_view
    m = np.stack([T[s_of == s].mean(axis=0) for s in range(grouping.n_sessions)])
    Tf = np.einsum("vba,vb->va", grouping.rotations[s_of], T - m[s_of])
    return Tf[grouping.angle_deg <= grouping.tolerance_deg], m


def check_flange_span(T: np.ndarray, grouping: SessionGrouping) -> np.ndarray:
    """Raise :class:`DegenerateError` unless the flange-frame moves span 3-D.

    Returns the singular values (descending) of the moves ``R_s^T (T_i - m_s)``.
    """
    Tf, _ = _flange_moves(T, grouping)
    _, s, Vt = np.linalg.svd(Tf, full_matrices=False)
    s = np.concatenate([s, np.zeros(3 - s.size)])[:3]
    if s[0] > 0 and s[2] > SPAN_RTOL * s[0]:
        return s
    n_s = grouping.n_sessions
    if s[0] == 0 or s[1] <= SPAN_RTOL * s[0]:
        raise DegenerateError("the robot moves inside the sessions are (nearly) all along one line of the flange "
                              f"frame (singular values {', '.join(f'{v:.3g}' for v in s)}): K and R_X are not "
                              "determined. Move along two or three axes in each session.")
    n_f = Vt[2]
    n_base = grouping.rotations @ n_f
    if n_s == 1:
        raise DegenerateError("the translations of the single session do not span 3-D (they lie in a plane with "
                              f"normal {np.round(n_base[0], 3).tolist()} in the base frame): K and R_X are not "
                              "determined. Move along three independent axes, or add a session with the wrist "
                              "tilted about an axis in the plane of motion.")
    raise DegenerateError(
        f"the moves of all {n_s} sessions lie in one plane of the flange frame (normal {np.round(n_f, 3).tolist()} "
        f"in the flange, {np.round(n_base[0], 3).tolist()} in the base for session {grouping.labels[0]!r}): the wrist "
        "turned only about the normal of the plane of motion (as a SCARA robot does), which leaves the paper's "
        "coplanar ambiguity (the column of M = K R_X^T along that normal is not determined). Tilt the wrist about an "
        "axis in the plane of motion for one session, or move out of the plane (e.g. along z) in one session; with "
        "a known principal point (fix cx, cy) a single 2-axis session determines fx, fy and R.")


def _stack(uv: np.ndarray, grouping: SessionGrouping) -> np.ndarray:
    """``(n_views, n_sessions * n_points, 2)``: session s's views keep the columns of block s."""
    n_views, n = uv.shape[:2]
    out = np.full((n_views, grouping.n_sessions * n, 2), np.nan)
    inside = grouping.angle_deg <= grouping.tolerance_deg  # a view off its session: refinement only
    for s in range(grouping.n_sessions):
        views = (grouping.session_of_view == s) & inside
        out[views, s * n:(s + 1) * n] = uv[views]
    return out


def solve_offset(Y: np.ndarray, m: np.ndarray, Rs: np.ndarray, basis: np.ndarray | None = None):
    """Least-squares ``t_X`` from the sessions' points (see the module docstring).

    Parameters
    ----------
    Y : (n_sessions, n_points, 3) float
        ``Y_sj``, NaN where point j is not triangulated in session s.
    m : (n_sessions, 3) float
    Rs : (n_sessions, 3, 3) float
    basis : (3, k) float, optional
        Restrict ``t = basis c``; default: the directions the normal matrix determines.

    Returns
    -------
    t : (3,) float
        Minimum-norm solution (zero along the undetermined directions).
    undetermined : (3, 3 - k) float
        Orthonormal free directions.
    """
    ok = np.all(np.isfinite(Y), axis=2)  # (S, n)
    link = ok.sum(axis=0) >= 2
    okl = ok[:, link]
    cnt = okl.sum(axis=0)
    b = np.einsum("sab,snb->sna", Rs, np.where(ok[..., None], Y, 0.0)[:, link]) + m[:, None]
    w = okl[..., None].astype(float)
    bbar = np.sum(b * w, axis=0) / cnt[:, None]
    Rbar = np.einsum("sn,sab->nab", okl.astype(float), Rs) / cnt[:, None, None]
    G = (Rs[:, None] - Rbar[None]) * okl[..., None, None]  # (S, n, 3, 3)
    h = (b - bbar[None]) * w
    N = np.einsum("snab,snac->bc", G, G)
    rhs = -np.einsum("snab,sna->b", G, h)
    if basis is None:
        evals, evecs = np.linalg.eigh(N)
        keep = evals > OFFSET_RTOL * max(evals[-1], 1e-300)
        basis = evecs[:, keep]
    basis = np.asarray(basis, float).reshape(3, -1)
    if basis.shape[1] == 0:
        return np.zeros(3), np.eye(3)
    c = np.linalg.lstsq(basis.T @ N @ basis, basis.T @ rhs, rcond=None)[0]
    U = np.linalg.svd(basis, full_matrices=True)[0]
    return basis @ c, U[:, basis.shape[1]:]


def _points(Y, m, Rs, t) -> np.ndarray:
    """Base-frame points: the mean over their sessions of ``R_s Y_sj + m_s + R_s t``."""
    ok = np.all(np.isfinite(Y), axis=2)
    b = np.einsum("sab,snb->sna", Rs, np.where(ok[..., None], Y, 0.0)) + (m + Rs @ t)[:, None]
    cnt = ok.sum(axis=0)
    X = np.sum(b * ok[..., None], axis=0) / np.maximum(cnt, 1)[:, None]
    X[cnt == 0] = np.nan
    return X


def sessions_linear(uv: np.ndarray, T: np.ndarray, grouping: SessionGrouping, method: str = "fast",
                    ransac: RansacOptions | None = None, rng=None) -> SessionsLinear:
    """Linear estimate of ``K``, ``R_X``, ``t_X`` and the points from several sessions.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Pixels, NaN where unseen; point ``j`` is the same scene point in every session.
    T : (n_views, 3) float
        Flange positions in the base frame.
    grouping : SessionGrouping
        Sessions and their flange rotations (:func:`transcalib.handeye.sessions.group_sessions`).
    method : {"fast", "dense"}
        TLS solver (:func:`transcalib.estimate.linear.fit_linear`).
    ransac : RansacOptions, optional
        Robust start: :func:`transcalib.estimate.robust.fit_robust` on the stacked
        problem (a point of one session is one sample); its outliers are NaN in ``Y``
        and ``inliers`` says which (point, session) pairs survived.
    rng : seed or Generator
        For RANSAC.

    Returns
    -------
    SessionsLinear

    Raises
    ------
    DegenerateError
        Flange-frame moves not spanning 3-D (named: one line, one plane, SCARA), too few
        points or views (from the TLS).
    MirroredError
        ``det M < 0``: a left-handed base frame or mirrored images.
    """
    span = check_flange_span(T, grouping)
    s_of = grouping.session_of_view
    m = np.stack([T[s_of == s].mean(axis=0) for s in range(grouping.n_sessions)])
    Tf = np.einsum("vba,vb->va", grouping.rotations[s_of], T - m[s_of])
    n_s, n = grouping.n_sessions, uv.shape[1]
    uv_st = _stack(uv, grouping)
    inliers = stats = None
    if ransac is None:
        stacked = fit_linear(uv_st, Tf, method)
    else:
        rob = fit_robust(uv_st, Tf, ransac, rng=rng)
        stacked, stats = rob.linear, rob.stats
        seen = np.isfinite(uv_st[..., 0]).sum(axis=0) >= 2
        inliers = (rob.inliers | ~seen).reshape(n_s, n)
    Y = stacked.X.reshape(n_s, n, 3)
    Rs = grouping.rotations
    t, undet = solve_offset(Y, m, Rs)
    depth = np.full(uv.shape[:2], np.nan)
    for s in range(n_s):
        views = grouping.session_of_view == s
        depth[views] = stacked.depth[views, s * n:(s + 1) * n]
    return SessionsLinear(stacked.K, stacked.R.T, t, _points(Y, m, Rs, t), depth, undet, stacked, span, Y, m, Rs,
                          inliers, stats)
