"""The start of a calibration, for every robot motion, and what the motion determines.

- **One orientation** (no orientations in the poses, or one for every view): the paper's
  linear estimate — robust (two-point LO-RANSAC) from ``ROBUST_MIN_POINTS`` tracks —
  or, for coplanar translations with enough known parameters, the 2-axis start.
- **Several orientations**: the exact TLS on the pure-translation sessions (views of one
  orientation; the multi-session start with ``M = K R_X^T`` where there are several,
  :mod:`transcalib.handeye.linear`), then the single views at their own orientations
  join through their tracks (:mod:`transcalib.handeye.join`: each one's pose from its
  images, checked against the recorded orientation, and the offset ``t_X``). Needed: one
  session of >= 4 views whose translations span 3-D, or two sessions of >= 4 views at
  different orientations.
- **General motion** (no such session: every view at its own orientation, or sessions
  too small): the start from the view pairs' epipolar geometry and the flange rotations
  (:mod:`transcalib.handeye.general`), which refuses, naming why, when the turns cannot
  fix the camera's orientation.

:func:`explain_motion` says, before any estimation, what the motion cannot determine.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import Diagnostic
from ..estimate.coplanar import fit_coplanar, fit_coplanar_robust
from ..estimate.degeneracy import explain_span, translation_rank
from ..estimate.layout import FlangeModel
from ..estimate.linear import fit_linear
from ..estimate.noise import inlier_rule, median_sigma, track_dof
from ..estimate.robust import fit_robust
from ..geometry.camera import project
from ..handeye.general import check_turns, general_start
from ..handeye.join import join_single_views
from ..handeye.linear import check_flange_span, sessions_linear
from ..handeye.observability import offset_observability
from ..types import CalibrateOptions, LinearEstimate, RansacStats, report
from ..validate import COPLANAR_RTOL
from .motion import Motion

#: ``robust=None`` turns RANSAC on from this many points (2-point samples need spare points).
ROBUST_MIN_POINTS = 8
#: Views a session needs to start a calibration on its own (paper: 4 views).
MIN_SESSION_VIEWS = 4


@dataclass(frozen=True, eq=False)
class Start:
    """Where the refinement starts.

    Attributes
    ----------
    linear : LinearEstimate
        ``K``, the model's ``R`` (flange -> camera; world -> camera for one orientation)
        and the points.
    inliers : (n_points,) bool or None
        Tracks the robust start kept (None: no robust stage).
    stages : list of str
    ransac : RansacStats or None
    flange : FlangeModel or None
        The views' flange rotations and the offset (None: one orientation).
    off_views : tuple of (int, float)
        Single views whose recorded orientation their images contradict, with the angle
        (degrees): left out of the refinement, judged again after it
        (:func:`transcalib.pipeline.rejudge_views`).
    notes : tuple of str
        What the motion leaves undetermined, views off their session's orientation.
    """

    linear: LinearEstimate
    inliers: np.ndarray | None
    stages: list
    ransac: RansacStats | None
    flange: FlangeModel | None = None
    off_views: tuple = ()
    notes: tuple = ()


def explain_motion(motion: Motion, opts: CalibrateOptions) -> Diagnostic | None:
    """What the motion allows, before any estimation: None when it determines everything
    posed, a Diagnostic for coplanar translations of one orientation that the known
    parameters make identifiable; raises :class:`DegenerateError` naming what is missing."""
    r = opts.refinement
    if motion.constant:
        model = "none" if r.distortion == "auto" else r.distortion
        return explain_span(motion.T, r.fix, r.square_pixels, opts.unit, estimate_skew=r.estimate_skew,
                            distortion=model, tol=COPLANAR_RTOL)
    g, sizes = motion.grouping, motion.session_sizes()
    if not _session_start_possible(motion):  # the start from general motion: turns about two axes
        a, b = np.triu_indices(g.n_sessions, 1)
        check_turns(np.einsum("pba,pbc->pac", g.rotations[b], g.rotations[a]))
        return None
    in_session = sizes[g.session_of_view] >= 2
    check_flange_span(motion.T[in_session], g.restricted(in_session))
    return None


def _session_start_possible(motion: Motion) -> bool:
    """A session of >= :data:`MIN_SESSION_VIEWS` views whose translations span 3-D, or two
    such sessions (any span) at different orientations."""
    g, sizes = motion.grouping, motion.session_sizes()
    big = np.flatnonzero(sizes >= MIN_SESSION_VIEWS)
    spanning = [s for s in big if translation_rank(motion.T[g.session_of_view == s]) == 3]
    return bool(spanning) or len(big) >= 2


def initial_estimate(uv, motion: Motion, opts: CalibrateOptions, rng, progress, coplanar: bool = False,
                     image_size=None) -> Start:
    """The start for ``motion`` (module docstring)."""
    n_tracked = int((np.isfinite(uv[..., 0]).sum(axis=0) >= 2).sum())
    robust = n_tracked >= ROBUST_MIN_POINTS if opts.robust is None else bool(opts.robust)
    if motion.constant:
        return _one_orientation(uv, motion.T, opts, robust, rng, progress, coplanar, image_size)
    if not _session_start_possible(motion):
        return _from_general_motion(uv, motion, opts, robust, rng, progress)
    return _from_sessions(uv, motion, opts, robust, rng, progress)


def _coplanar_start_fix(uv, fix, image_size) -> dict:
    """Known parameters for the coplanar linear start: the user's, plus the image centre
    as principal point when only the focal lengths are known (the refinement then frees
    it again; the start needs one)."""
    fix = dict(fix)
    if "cx" not in fix or "cy" not in fix:
        if image_size is not None:
            centre = (0.5 * (image_size[0] - 1), 0.5 * (image_size[1] - 1))
        else:  # the middle of the observed pixels
            lo, hi = np.nanmin(uv, axis=(0, 1)), np.nanmax(uv, axis=(0, 1))
            centre = tuple(0.5 * (lo + hi))
        fix.setdefault("cx", float(centre[0]))
        fix.setdefault("cy", float(centre[1]))
    return fix


def _one_orientation(uv, T, opts: CalibrateOptions, robust: bool, rng, progress, coplanar: bool,
                     image_size) -> Start:
    """RANSAC (or the plain linear estimate); coplanar translations take the
    known-parameter linear start."""
    if coplanar:
        r = replace(opts.refinement, fix=_coplanar_start_fix(uv, opts.refinement.fix, image_size))
        if robust:
            linear, inliers, stats = fit_coplanar_robust(uv, T, fix=r.fix, square_pixels=r.square_pixels,
                                                         options=opts.ransac, rng=rng, tol=COPLANAR_RTOL)
            report(progress, "robust (coplanar)", inliers=stats.n_inliers, trials=stats.trials, sigma_px=stats.sigma_px)
            return Start(linear, inliers, ["robust"], stats)
        linear = fit_coplanar(uv, T, fix=r.fix, square_pixels=r.square_pixels, tol=COPLANAR_RTOL)
        report(progress, "linear (coplanar)", points=linear.n_used_points)
        return Start(linear, None, ["linear"], None)
    if robust:
        rob = fit_robust(uv, T, opts.ransac, rng=rng)
        report(progress, "robust", inliers=rob.n_inliers, trials=rob.trials, sigma_px=rob.sigma_px)
        return Start(rob.linear, rob.inliers, ["robust"], rob.stats)
    linear = fit_linear(uv, T)
    report(progress, "linear", points=linear.n_used_points)
    return Start(linear, None, ["linear"], None)


def _from_sessions(uv, motion: Motion, opts: CalibrateOptions, robust: bool, rng, progress) -> Start:
    """The multi-session TLS on the views of sessions (>= 2 views), the single views
    joined, the offset's determined directions from the Fisher information of the whole."""
    g = motion.grouping
    in_session = motion.session_sizes()[g.session_of_view] >= 2
    sub = g.restricted(in_session)
    lin = sessions_linear(uv[in_session], motion.T[in_session], sub, ransac=opts.ransac if robust else None, rng=rng)
    report(progress, "robust (sessions)" if robust else "linear (sessions)", sessions=sub.n_sessions,
           **({} if lin.ransac is None else {"inliers": lin.ransac.n_inliers, "sigma_px": lin.ransac.sigma_px}))
    inliers = None if lin.inliers is None else _track_inliers(lin.inliers, uv[in_session], sub)
    singles = np.flatnonzero(~in_session)
    X0 = lin.X if inliers is None else np.where(inliers[:, None], lin.X, np.nan)
    joined = join_single_views(uv, motion.T, motion.R, singles, lin.K, lin.R_X, lin.t_X, lin.undetermined, X0,
                               sub.rotations[0], g.tolerance_deg, rng)
    left_out = np.zeros(motion.n_views, bool)
    left_out[[i for i, _ in joined.off_views]] = True
    if inliers is not None:
        for pose in joined.poses:  # a track with an outlier in a single view is judged again later
            inliers &= pose.inliers | ~np.isfinite(uv[pose.view, :, 0])
    # what the motion determines of the offset: the sessions' orientations, not the small
    # differences of the views inside a session (within the tolerance they count as one)
    F_sessions = np.transpose(g.rotations[g.session_of_view], (0, 2, 1))
    uv_kept = np.where(left_out[:, None, None], np.nan, uv)
    kept = np.unique(g.session_of_view[~left_out])  # sessions still seen (for the message's axes)
    obs = offset_observability(lin.K, np.zeros(5), lin.R_X.T, joined.t, joined.X, uv_kept, motion.T, F_sessions,
                               g.rotations[kept], [g.labels[s] for s in kept], fix=opts.refinement.fix,
                               estimate_skew=opts.refinement.estimate_skew,
                               square_pixels=opts.refinement.square_pixels, distortion=_start_model(opts),
                               frame="flange" if motion.setup == "eye-in-hand" else "base")
    linear = _linear_estimate(lin, joined.X, in_session, motion.n_views)
    notes = tuple(m for m in [obs.message, *g.messages()] if m)
    return Start(linear, inliers, ["robust" if robust else "linear"], lin.ransac,
                 FlangeModel(np.transpose(motion.R, (0, 2, 1)), joined.t, obs.determined,
                             inverted=motion.setup == "eye-to-hand"), tuple(joined.off_views), notes)


def _start_model(opts: CalibrateOptions) -> str:
    """The distortion model whose coefficients count as unknowns when the start asks what
    the motion determines (``auto`` starts without)."""
    return "none" if opts.refinement.distortion == "auto" else opts.refinement.distortion


def _track_inliers(inliers: np.ndarray, uv: np.ndarray, grouping) -> np.ndarray:
    """Per track ``(n_points,)``: kept in every session in which it was judged (seen in
    >= 2 of its views), from the per-(session, point) verdicts ``(n_sessions, n_points)``.
    A session that kept less than half the median share of the tracks it judged does not
    judge: one wrong pose among its views makes every track there look wrong (the
    refinement and the test of the poses then find the view)."""
    seen = np.isfinite(uv[..., 0])
    judged = np.stack([seen[grouping.session_of_view == s].sum(axis=0) >= 2 for s in range(grouping.n_sessions)])
    share = np.array([inliers[s][judged[s]].mean() if judged[s].any() else 1.0 for s in range(len(judged))])
    trusted = share >= 0.5 * np.median(share)
    return np.all(inliers | ~(judged & trusted[:, None]), axis=0) & judged.any(axis=0)


def _from_general_motion(uv, motion: Motion, opts: CalibrateOptions, robust: bool, rng, progress) -> Start:
    """Views at their own orientations, no session to start from: the pairs' epipolar
    geometry against the flange rotations (:mod:`transcalib.handeye.general`); tracks far
    off the start's cameras flagged (the refinement judges them again)."""
    g = motion.grouping
    gs = general_start(uv, motion.T, motion.R, g.tolerance_deg, rng)
    left_out = np.zeros(motion.n_views, bool)
    left_out[[v for v, _ in gs.off_views]] = True
    uv = np.where(left_out[:, None, None], np.nan, uv)
    report(progress, "start (general motion)", pairs=len(gs.pairs), focal_px=float(gs.K[0, 0]))
    F = np.transpose(motion.R, (0, 2, 1))
    inliers = None
    if robust:
        seen = np.isfinite(uv[..., 0])
        R_cam, C = np.einsum("ab,vcb->vac", gs.R_X.T, motion.R), motion.T + motion.R @ gs.t_X
        res = uv - project(gs.K, R_cam, np.nan_to_num(gs.X), C)
        sse = np.where(np.isfinite(gs.X[:, 0]), np.nansum(res ** 2, axis=(0, 2)), np.inf)
        k = seen.sum(axis=0)
        sigma = median_sigma(sse, track_dof(k))
        inliers = inlier_rule(sse, k, sigma, opts.ransac.false_rejection)
    X = gs.X if inliers is None else np.where(inliers[:, None], gs.X, np.nan)
    obs = offset_observability(gs.K, np.zeros(5), gs.R_X.T, gs.t_X, X, uv, motion.T, F, g.rotations, list(g.labels),
                               fix=opts.refinement.fix, estimate_skew=opts.refinement.estimate_skew,
                               square_pixels=opts.refinement.square_pixels, distortion=_start_model(opts),
                               frame="flange" if motion.setup == "eye-in-hand" else "base")
    used = np.all(np.isfinite(X), axis=1)
    linear = LinearEstimate(K=gs.K, R=gs.R_X.T, A=gs.K @ gs.R_X.T, X=X, depth=np.full(uv.shape[:2], np.nan),
                            singular_values=np.zeros(0), n_used_points=int(used.sum()), used=used, method="general")
    notes = tuple(m for m in [obs.message, *g.messages()] if m)
    return Start(linear, inliers, ["robust" if robust else "linear"], None,
                 FlangeModel(F, gs.t_X, obs.determined, inverted=motion.setup == "eye-to-hand"), tuple(gs.off_views),
                 notes)


def _linear_estimate(lin, X: np.ndarray, in_session: np.ndarray, n_views: int) -> LinearEstimate:
    """The sessions' start as a :class:`LinearEstimate`: ``R = R_X^T``, base-frame points
    (with the joined offset), the TLS depths of the session views (NaN for single views)."""
    depth = np.full((n_views, X.shape[0]), np.nan)
    depth[in_session] = lin.depth
    used = np.all(np.isfinite(X), axis=1)
    return LinearEstimate(K=lin.K, R=lin.R_X.T, A=lin.K @ lin.R_X.T, X=X, depth=depth,
                          singular_values=lin.stacked.singular_values, n_used_points=int(used.sum()), used=used,
                          method="sessions")
