"""Diagnostics: warnings that name the cause of a doubtful calibration and what to do.

Every check returns a list of :class:`~transcalib.types.Diagnostic` (a ``str`` with a
stable ``code``); an empty list means nothing suspicious. :func:`diagnose` runs them all
and is silent on healthy data.

=========================  ==============================================================
code                       meaning
=========================  ==============================================================
``translations_coplanar``  the translations nearly lie in a plane (or on a line)
``translations_small``     the translations are tiny compared with the scene distance
``null_space_2d``          the linear system has a nearly two-dimensional null space
``points_behind_camera``   reconstructed points behind the camera in some view
``view_few_points``        views that see very few points
``view_residuals``         views whose residuals stand out from the others
``outliers``               gross outliers left in the residuals (mismatched tracks)
``view_rotation``          model violation: the camera rotated between views
``pose_orientation``       robot poses whose orientation differs from view 0's
=========================  ==============================================================

Model violation (``view_rotation``)
-----------------------------------
The pure-translation model is tested against a small rotation ``Q_i = exp([w_i]x)`` of
the camera in one view ``i >= 1`` (``R_i = Q_i R``, view 0 is the reference), linearised
at the pure-translation maximum-likelihood solution (:func:`view_rotation_test`). With
``J`` the Jacobian of the predicted pixels (intrinsics, distortion, ``R``, the points,
and the translations when they were refined with a prior ``sigma_T``), ``r`` the
residuals, and the points eliminated by the Schur complement::

    w_i = I_i^-1 g_i,    Cov(w_i) = s^2 I_i^-1,    t_i = g_i^T I_i^-1 g_i / s^2

``g_i`` is the gradient of ``0.5 |r|^2`` with respect to ``w_i`` and ``I_i`` the
information of ``w_i`` with every other parameter profiled out: ``w_i`` is one
Gauss-Newton step from the pure-translation solution, ``g^T I^-1 g`` the drop of the
residual sum of squares it brings, and ``t_i / 3`` follows F(3, dof - 3) under pure
translation (a score test). A forward selection names the view(s) whose rotation
explains the data, each accepted at ``alpha / (n_views - 1)`` (Bonferroni; default
``alpha = 0.01``: 0.5% of pure-translation trials flagged on the paper's scene).

When the test fires, :func:`locate_view_rotation` refits the data with the rotation of
each significant view free in turn (``refine(..., estimate_view_rotations=[i])``) and
names the view whose fit is best, with the fitted angle and its standard deviation;
views whose fit is not significantly worse are reported as alternatives.

Sensitivity (``benchmarks/bench_robust.py``, paper scene, 0.5 px): a 0.2 degree tilt or
pan of one view is always detected; a roll about the optical axis moves the points by
only ~0.5 px and is detected in ~90% of the trials, about as often as an ideal test
that knew the view and the noise. With four views a rotation of one view is largely
explained by rotating another (the three remaining pure translations do not determine
``A``), so the view named is often one of several alternatives; with five or more views
it is reliable.

Why not the Wald test of refine's ``estimate_view_rotations=True`` (all views free)?
With four views, freeing every rotation leaves ``K`` and ``R`` nearly undetermined: the
rotation estimates have standard deviations of ~0.5 degrees on the paper's scene and
their linearised covariance is unreliable. In a Monte-Carlo check the per-view Wald
tests flagged 14% of pure-translation data at a nominal 1% and detected 0.2 degree
rotations in under 10% of the trials. Testing at the well-determined null model avoids
both problems.

Errors of the robot positions shift a view's image as a whole, much like a small
rotation: when the robot is not precise compared with the image motion, pass its
precision (``sigma_T``) to the refinement; the test then accounts for it (robot noise
0.1 mm on the paper's scene: 20% of the trials flagged without ``sigma_T``, 1% with it).
"""

from __future__ import annotations

import numpy as np
from scipy import stats
from scipy.spatial.transform import Rotation

from ..geometry.camera import distort, pad_dist
from ..types import Calibration, DegenerateError, Diagnostic, InputError, LinearEstimate
from ..validate import as_uv_T

__all__ = [
    "check_translations",
    "check_null_space",
    "check_points_behind",
    "check_views",
    "check_outliers",
    "check_view_rotations",
    "view_rotation_test",
    "locate_view_rotation",
    "check_pose_orientations",
    "diagnose",
]

#: Defaults of the thresholds (see each check).
COPLANAR_RATIO = 0.2
MIN_PARALLAX_PX = 20.0
NULL_SPACE_RATIO = 0.05
MIN_VIEW_POINTS = 6
VIEW_RESIDUAL_RATIO = 2.0
ROTATION_ALPHA = 1e-2
MIN_ROTATION_SHIFT_PX = 0.1
OUTLIER_MIN_PX = 1.0


def _fmt_vec(v) -> str:
    return "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"


def _list(idx, limit: int = 10) -> str:
    idx = [int(i) for i in idx]
    s = ", ".join(map(str, idx[:limit]))
    return s + (f", ... ({len(idx)} in all)" if len(idx) > limit else "")


# ----------------------------------------------------------------------------------------
# Translations
# ----------------------------------------------------------------------------------------


def check_translations(T, *, focal_px: float | None = None, distance: float | None = None,
                       coplanar_ratio: float = COPLANAR_RATIO, min_parallax_px: float = MIN_PARALLAX_PX,
                       unit: str = "units") -> list:
    """Warn when the translations are nearly coplanar or tiny for the scene distance.

    Parameters
    ----------
    T : (n_views, 3) float
        Robot translations.
    focal_px : float, optional
        Focal length in pixels (e.g. ``(fx + fy) / 2``); with ``distance`` enables the
        parallax check.
    distance : float, optional
        Typical distance of the scene from the camera (median depth, units of ``T``).
    coplanar_ratio : float
        Warn when ``s3 / s1 < coplanar_ratio``, ``s_k`` the singular values of the
        centred translations ``T_i - mean(T)``.
    min_parallax_px : float
        Warn when the image motion produced by the translations along their weakest
        direction ``v3``, ``focal_px * extent(T . v3) / distance``, is below this.
    unit : str
        Length unit named in the messages.

    Returns
    -------
    list of Diagnostic
        ``translations_coplanar``, ``translations_small``; each suggests moving the robot
        along ``v3`` (robot axes) and by how much.
    """
    T = np.asarray(T, dtype=float)
    t = T - T.mean(axis=0)
    _, s, Vt = np.linalg.svd(t, full_matrices=True)
    s = np.concatenate([s, np.zeros(3 - s.size)])[:3]
    v3 = Vt[2]
    v3 = v3 * np.sign(v3[np.argmax(np.abs(v3))])
    extent = np.ptp(t @ v3)
    longest = np.ptp(t @ Vt[0])
    out = []
    if s[0] > 0 and s[2] < coplanar_ratio * s[0]:
        out.append(Diagnostic(
            "translations_coplanar",
            f"the robot translations nearly lie in a plane (singular values {s[0]:.3g}, {s[1]:.3g}, {s[2]:.3g} "
            f"{unit}; ratio {s[2] / s[0]:.3f} < {coplanar_ratio}), so K and R are poorly determined. Add views "
            f"displaced along the robot direction (x, y, z) = {_fmt_vec(v3)}, by about {longest:.3g} {unit} "
            f"(as far as the widest motion so far)."))
    if focal_px is not None and distance is not None and distance > 0:
        parallax = focal_px * extent / distance
        if parallax < min_parallax_px:
            need = min_parallax_px * 5 * distance / focal_px
            out.append(Diagnostic(
                "translations_small",
                f"the translations are tiny compared with the scene distance: along their weakest direction "
                f"(x, y, z) = {_fmt_vec(v3)} they span {extent:.3g} {unit} at a distance of {distance:.3g} {unit}, "
                f"i.e. only {parallax:.3g} px of image motion, so the estimate is ill-conditioned. Move the robot "
                f"along that direction by about {need:.3g} {unit} (>= {5 * min_parallax_px:.0f} px of motion), "
                f"or bring the scene closer."))
    return out


# ----------------------------------------------------------------------------------------
# Linear system
# ----------------------------------------------------------------------------------------


def check_null_space(linear: LinearEstimate, *, ratio: float = NULL_SPACE_RATIO) -> list:
    """Warn when the linear system ``C b = 0`` has a nearly two-dimensional null space.

    Parameters
    ----------
    linear : LinearEstimate
        Its ``singular_values`` ``[sigma_1, sigma_2, ...]`` (ascending): ``sigma_1`` the
        residual of the TLS solution, ``sigma_2`` that of the best solution with a
        different ``A``.
    ratio : float
        Warn when ``sigma_1 / sigma_2 > ratio``: a second, different ``A`` explains the
        data almost as well (on healthy data with 0.5-1 px noise the ratio is ~0.002).

    Returns
    -------
    list of Diagnostic
        ``null_space_2d``.
    """
    sv = np.asarray(linear.singular_values, dtype=float)
    if sv.size < 2 or not np.all(np.isfinite(sv[:2])) or sv[1] <= 0:
        return []
    r = sv[0] / sv[1]
    if r <= ratio:
        return []
    return [Diagnostic(
        "null_space_2d",
        f"the linear system has a nearly two-dimensional null space (sigma_1 / sigma_2 = {r:.3g} > {ratio}): "
        "a different camera explains the data almost as well, so K and R are not determined. Causes: "
        "translations nearly coplanar or too short, too few points, points nearly at one depth seen "
        "under tiny parallax, or mismatched tracks. Add robot motions along a third independent direction, "
        "track more points spread in depth, or use the robust estimator.")]


# ----------------------------------------------------------------------------------------
# Points and views
# ----------------------------------------------------------------------------------------


def _depths(R, X, T):
    """Camera z of every point in every view (n_views, n_points)."""
    return np.einsum("b,vnb->vn", R[2], X[None] - T[:, None])


def check_points_behind(uv, T, calibration) -> list:
    """Warn about reconstructed points behind the camera in a view that sees them.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float
    calibration : Calibration or LinearEstimate
        ``R`` and ``X`` (points with non-finite ``X`` are skipped).

    Returns
    -------
    list of Diagnostic
        ``points_behind_camera``.
    """
    uv, T = np.asarray(uv, float), np.asarray(T, float)
    X = np.asarray(calibration.X, float)
    seen = np.isfinite(uv[..., 0])
    z = _depths(np.asarray(calibration.R, float), X, T)
    with np.errstate(invalid="ignore"):
        behind = np.any(seen & np.isfinite(z) & (z <= 0), axis=0)
    if not behind.any():
        return []
    idx = np.flatnonzero(behind)
    return [Diagnostic(
        "points_behind_camera",
        f"{len(idx)} reconstructed point(s) lie behind the camera in a view that sees them (points {_list(idx)}): "
        "these tracks are almost certainly mismatches (or the robot moved the other way than the poses "
        "say). Remove them or run the robust estimator (calibrate(..., robust=True), CLI --robust); check "
        "the sign convention of the poses if there are many.")]


def check_views(uv, residuals_px, *, used=None, min_points: int = MIN_VIEW_POINTS,
                residual_ratio: float = VIEW_RESIDUAL_RATIO, alpha: float = 1e-4,
                min_excess_px: float = 0.1) -> list:
    """Warn about views with very few points and views whose residuals stand out.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Observations (NaN where unseen).
    residuals_px : (n_views, n_points, 2) float
        Residuals of the calibration (NaN where unseen or unused).
    used : (n_points,) bool, optional
        Points that count (e.g. the inliers); default: points with finite residuals.
    min_points : int
        Warn when a view sees fewer used points than this.
    residual_ratio : float
        A view's mean squared residual must exceed this many times that of the other
        views (practical significance) ...
    alpha : float
        ... the ratio must be significant at this level (F test with the numbers of
        residuals as degrees of freedom) ...
    min_excess_px : float
        ... and the view's RMS must exceed the others' by this much (very precise tracks
        make harmless differences of hundredths of a pixel significant).

    Returns
    -------
    list of Diagnostic
        ``view_few_points``, ``view_residuals``.
    """
    uv = np.asarray(uv, float)
    res = np.asarray(residuals_px, float)
    n_views = uv.shape[0]
    ok = np.isfinite(res[..., 0]) & np.isfinite(uv[..., 0])
    if used is not None:
        ok &= np.asarray(used, bool)[None, :]
    counts = ok.sum(axis=1)
    out = []
    few = np.flatnonzero(counts < min_points)
    if len(few):
        detail = ", ".join(f"view {i}: {counts[i]}" for i in few[:10])
        out.append(Diagnostic(
            "view_few_points",
            f"{len(few)} view(s) see very few usable points ({detail}; fewer than {min_points}): they constrain "
            "the calibration weakly and their errors go unnoticed. Track more points in those views (check the "
            "scene is in the field of view there) or drop those views."))
    e2 = np.where(ok, np.sum(np.where(ok[..., None], res, 0.0) ** 2, axis=2), 0.0)
    sse = e2.sum(axis=1)
    n_res = 2 * counts
    flagged = []
    for i in range(n_views):  # one F test per view (few views)
        others = np.arange(n_views) != i
        if n_res[i] < 4 or n_res[others].sum() < 4:
            continue
        ms_i = sse[i] / n_res[i]
        ms_o = sse[others].sum() / n_res[others].sum()
        if ms_o <= 0:
            continue
        f = ms_i / ms_o
        if (f > residual_ratio and np.sqrt(ms_i) - np.sqrt(ms_o) >= min_excess_px
                and stats.f.sf(f, n_res[i], n_res[others].sum()) < alpha):
            flagged.append((i, np.sqrt(ms_i), np.sqrt(ms_o)))
    if flagged:
        detail = ", ".join(f"view {i}: {a:.3g} px vs {b:.3g} px" for i, a, b in flagged)
        out.append(Diagnostic(
            "view_residuals",
            f"the residuals of {len(flagged)} view(s) stand out from the others (RMS per coordinate, {detail}): "
            "that view's image or pose is inconsistent with the rest. Check its robot pose (typo, wrong "
            "units, a move that did not finish), whether the robot also rotated there, motion blur or a "
            "tracking failure in that image; re-take it or drop it."))
    return out


def check_outliers(residuals_px, *, used=None, k_sigma: float = 5.0, min_px: float = OUTLIER_MIN_PX,
                   max_fraction: float = 0.001) -> list:
    """Warn when the residuals have gross outliers (heavy tails) the fit did not remove.

    Parameters
    ----------
    residuals_px : (n_views, n_points, 2) float
        Residuals of the calibration (NaN where unseen or unused).
    used : (n_points,) bool, optional
        Points that count (e.g. the inliers).
    k_sigma : float
        An observation is gross when its residual norm exceeds ``k_sigma`` times the
        robust noise ``sigma = 1.4826 median(|r|)`` per coordinate (Gaussian: probability
        ``exp(-k^2 / 2)``, 4e-6 for k = 5) ...
    min_px : float
        ... and ``min_px`` pixels: with very precise tracks (0.02 px) small tracking errors
        are many sigmas but harmless.
    max_fraction : float
        Warn when more than this fraction of the observations (and at least 3) are gross.

    Returns
    -------
    list of Diagnostic
        ``outliers``.
    """
    res = np.asarray(residuals_px, float)
    ok = np.isfinite(res[..., 0])
    if used is not None:
        ok &= np.asarray(used, bool)[None, :]
    r = res[ok]
    if len(r) < 10:
        return []
    sigma = 1.4826 * np.median(np.abs(r))
    if not sigma > 0:
        return []
    limit = max(k_sigma * sigma, min_px)
    e = np.hypot(r[:, 0], r[:, 1])
    gross = int(np.sum(e > limit))
    if gross < 3 or gross <= max_fraction * len(e):
        return []
    pts = np.flatnonzero(np.any(ok & (np.hypot(res[..., 0], res[..., 1]) > limit), axis=0))
    return [Diagnostic(
        "outliers",
        f"{gross} of {len(e)} observations ({100 * gross / len(e):.1f}%, in {len(pts)} points: {_list(pts)}) have "
        f"residuals beyond {limit:.3g} px ({k_sigma:g} sigma, robust sigma {sigma:.3g} px): the tracks contain "
        "mismatches, which "
        "bias the calibration. Run the robust estimator (calibrate(..., robust=True), CLI --robust) or remove "
        "those tracks.")]


# ----------------------------------------------------------------------------------------
# Model violation: a rotation in one view (score test at the pure-translation solution)
# ----------------------------------------------------------------------------------------


def _pixels(K, dist, xc):
    """Pixels of camera-frame points ``xc`` (..., 3), and distorted normalised coordinates."""
    xy = xc[..., :2] / xc[..., 2:3]
    if np.asarray(dist).size:
        d = distort(xy[..., 0], xy[..., 1], pad_dist(dist))
        xy = np.stack([d.xd, d.yd], axis=-1)
    u = K[0, 0] * xy[..., 0] + K[0, 1] * xy[..., 1] + K[0, 2]
    v = K[1, 1] * xy[..., 1] + K[1, 2]
    return np.stack([u, v], axis=-1), xy


def _skew_rows(x):
    """``-[x]_x`` for x (..., 3): the derivative of ``exp([w]x) x`` with respect to w."""
    Z = np.zeros(x.shape + (3,))
    Z[..., 0, 1], Z[..., 0, 2] = x[..., 2], -x[..., 1]
    Z[..., 1, 0], Z[..., 1, 2] = -x[..., 2], x[..., 0]
    Z[..., 2, 0], Z[..., 2, 1] = x[..., 1], -x[..., 0]
    return Z


class _RotationModel:
    """The pure-translation model plus a rotation ``Q_i`` of selected views, with the
    Gauss-Newton normal equations reduced over the points (Schur complement, O(n)).

    Predicted pixel: ``pi(K, dist, Q_i R (X_j - T_i))``. Parameters: intrinsics
    (``fx, fy, cx, cy[, skew]``), distortion, ``R`` (local ``R <- exp([w]x) R``), the
    translations of views with a prior ``sigma_T`` (weight ``sigma_px^2 / sigma_T^2``),
    the points, and ``w_i`` (``Q_i <- exp([w_i]x) Q_i``) of the selected views.
    """

    def __init__(self, uv, T, K, dist, R, X, estimate_skew, t_sigma, sigma_px):
        self.uv = uv
        self.seen = np.isfinite(uv[..., 0])
        self.uv0 = np.where(self.seen[..., None], uv, 0.0)
        self.T_meas = T
        self.skew = bool(estimate_skew)
        self.t_views = np.flatnonzero(t_sigma > 0)
        self.t_weight = (sigma_px / t_sigma[self.t_views]) ** 2 if len(self.t_views) else np.zeros(0)
        self.n_dist = dist.size
        self.n_intr = 5 if self.skew else 4
        self.n_nuis = self.n_intr + self.n_dist + 3 + 3 * len(self.t_views)
        V, n = self.seen.shape
        self.state0 = {"intr": np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]]), "dist": dist.copy(),
                       "R": R.copy(), "X": X.copy(), "T": T.copy(), "Q": np.tile(np.eye(3), (V, 1, 1))}

    @staticmethod
    def _K(intr):
        return np.array([[intr[0], intr[4], intr[2]], [0.0, intr[1], intr[3]], [0.0, 0.0, 1.0]])

    def residuals(self, st):
        y = np.einsum("ab,vnb->vna", st["R"], st["X"][None] - st["T"][:, None])
        xc = np.einsum("vab,vnb->vna", st["Q"], y)
        pred, xyd = _pixels(self._K(st["intr"]), st["dist"], xc)
        r = np.where(self.seen[..., None], self.uv0 - pred, 0.0)
        sse = float(np.sum(r**2))
        if len(self.t_views):
            dT = self.T_meas[self.t_views] - st["T"][self.t_views]
            sse += float(np.sum(self.t_weight[:, None] * dT**2))
        return r, sse, y, xc, xyd

    def normal(self, st, views):
        """Reduced normal equations for the global parameters (nuisance, then ``w_i`` of
        ``views``): ``S``, ``b`` and the pieces to back-substitute the points."""
        K = self._K(st["intr"])
        dist = st["dist"]
        r, sse, y, xc, xyd = self.residuals(st)
        shape = xc.shape[:2]
        Jc = np.empty(shape + (2, 3))  # d pixel / d camera coordinates (central differences)
        h = 1e-6 * np.linalg.norm(xc, axis=2, keepdims=True)
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1.0
            Jc[..., k] = (_pixels(K, dist, xc + h * e)[0] - _pixels(K, dist, xc - h * e)[0]) / (2 * h)
        zeros, ones = np.zeros(shape), np.ones(shape)
        cols = [np.stack([xyd[..., 0], zeros], -1), np.stack([zeros, xyd[..., 1]], -1),
                np.stack([ones, zeros], -1), np.stack([zeros, ones], -1)]
        if self.skew:
            cols.append(np.stack([xyd[..., 1], zeros], -1))
        for k in range(self.n_dist):
            d1, d2 = dist.copy(), dist.copy()
            step = 1e-6 * max(1.0, abs(dist[k]))
            d1[k] += step
            d2[k] -= step
            cols.append((_pixels(K, d1, xc)[0] - _pixels(K, d2, xc)[0]) / (2 * step))
        JcQ = np.einsum("vnij,vjk->vnik", Jc, st["Q"], optimize=True)
        JR = np.einsum("vnij,vnjk->vnik", JcQ, _skew_rows(y), optimize=True)
        cols += [JR[..., k] for k in range(3)]
        JX = np.einsum("vnij,jk->vnik", JcQ, st["R"], optimize=True)
        for i in self.t_views:
            for k in range(3):
                c = np.zeros(shape + (2,))
                c[i] = -JX[i, :, :, k]
                cols.append(c)
        Jw = np.einsum("vnij,vnjk->vnik", Jc, _skew_rows(xc), optimize=True)
        for i in views:
            for k in range(3):
                c = np.zeros(shape + (2,))
                c[i] = Jw[i, :, :, k]
                cols.append(c)
        m = self.seen.astype(float)[..., None, None]
        Jg = np.stack(cols, axis=-1) * m
        JX = JX * m
        U = np.einsum("vnip,vniq->pq", Jg, Jg, optimize=True)
        b = np.einsum("vnip,vni->p", Jg, r, optimize=True)
        Wt = np.einsum("vnip,vnik->npk", Jg, JX, optimize=True)
        Vinv = np.linalg.inv(np.einsum("vnik,vnil->nkl", JX, JX, optimize=True))
        bX = np.einsum("vnik,vni->nk", JX, r, optimize=True)
        for m_, i in enumerate(self.t_views):  # translation priors
            s0 = self.n_intr + self.n_dist + 3 + 3 * m_
            U[s0: s0 + 3, s0: s0 + 3] += self.t_weight[m_] * np.eye(3)
            b[s0: s0 + 3] += self.t_weight[m_] * (self.T_meas[i] - st["T"][i])
        WV = np.einsum("npk,nkl->npl", Wt, Vinv, optimize=True)
        S = U - np.tensordot(WV, Wt, axes=([0, 2], [0, 2]))
        bred = b - np.einsum("npl,nl->p", WV, bX, optimize=True)
        return S, bred, sse, (WV, Vinv, bX)

    def update(self, st, views, dg, dX):
        st = {k: v.copy() for k, v in st.items()}
        a = 0
        st["intr"][: self.n_intr] += dg[a: a + self.n_intr]
        a += self.n_intr
        st["dist"] += dg[a: a + self.n_dist]
        a += self.n_dist
        st["R"] = Rotation.from_rotvec(dg[a: a + 3]).as_matrix() @ st["R"]
        a += 3
        for i in self.t_views:
            st["T"][i] += dg[a: a + 3]
            a += 3
        for i in views:
            st["Q"][i] = Rotation.from_rotvec(dg[a: a + 3]).as_matrix() @ st["Q"][i]
            a += 3
        st["X"] = st["X"] + dX
        return st

    def fit(self, st, views, iterations: int = 50):
        """Levenberg-Marquardt (damping on the reduced system; the points are solved exactly
        for each global step) with the rotations of ``views`` free: (state, sse)."""
        S, b, sse, (WV, Vinv, bX) = self.normal(st, views)
        mu = 1e-4
        for _ in range(iterations):
            d = np.maximum(np.diag(S), 1e-300)
            improved = False
            for _ in range(12):
                A = S + mu * np.diag(d)
                dg = np.linalg.solve(A, b)
                dX = np.einsum("nkl,nl->nk", Vinv, bX - np.einsum("npl,p->nl", WV, dg))
                new = self.update(st, views, dg, dX)
                sse_new = self.residuals(new)[1]
                if sse_new < sse:
                    improved = True
                    mu = max(mu / 10, 1e-9)
                    break
                mu *= 10
            if not improved:
                break
            done = sse - sse_new <= 1e-9 * sse + 1e-300
            st = new
            S, b, sse, (WV, Vinv, bX) = self.normal(st, views)
            if done:
                break
        return st, sse


def _rot_cols(n_nuis, views_all, views):
    """Columns of ``views``' rotations among the parameters (nuisance, then views_all)."""
    return np.concatenate([n_nuis + 3 * views_all.index(i) + np.arange(3) for i in views]) if views else \
        np.zeros(0, int)


def view_rotation_test(uv, T, calibration: Calibration, *, alpha: float = ROTATION_ALPHA,
                       min_shift_px: float = MIN_ROTATION_SHIFT_PX, estimate_skew: bool | None = None,
                       sigma_T=None) -> dict:
    """Test each view ``i >= 1`` for a small camera rotation (module docstring).

    All quantities are linearised at the pure-translation maximum-likelihood solution
    (a few LM iterations make sure it is one), with the points eliminated by the Schur
    complement:

    1. a score test per view: the residual-sum-of-squares reduction ``d_i`` of one
       Gauss-Newton step with view ``i``'s rotation free, ``t_i = d_i / s^2`` with
       ``s^2 = (RSS - d_i) / (dof - 3)``, p-value from F(3, dof - 3);
    2. forward selection: add the view whose rotation explains most (jointly with the
       views already selected) while the extra reduction is significant at
       ``alpha / (n_views - 1)``. With four views a rotation of one view is largely
       explained by rotating another (the three remaining pure translations do not
       determine ``A``), so several single-view tests fire; the selection names the view
       that explains most, and ``also_consistent`` lists the views whose rotation alone
       would explain the data not significantly worse (RSS reduction within the 99%
       chi-square(3) quantile times ``s^2`` of the best one's).

    The rotations are one Gauss-Newton step from the pure-translation solution: accurate
    for small angles (a few hundredths of a degree), indicative for larger ones.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        Observations, NaN where unseen.
    T : (n_views, 3) float
        Measured translations.
    calibration : Calibration
        The pure-translation maximum-likelihood solution (``K``, ``dist``, ``R``, ``X``,
        and ``T`` when the translations were refined); points with non-finite ``X`` or
        outside ``calibration.inliers`` are left out.
    alpha : float
        Family-wise false-alarm level (Bonferroni over the views).
    min_shift_px : float
        Practical significance: a view is selected only if its rotation moves the image
        by at least this much (angle times the focal length). With thousands of very
        precise tracks, rotations of a few thousandths of a degree become statistically
        significant without mattering.
    estimate_skew : bool, optional
        Whether the skew is a parameter (default ``calibration.info["estimate_skew"]``).
    sigma_T : float or (n_views,) float, optional
        Robot precision when the translations are parameters with a prior (default
        ``calibration.info.get("sigma_T")``).

    Returns
    -------
    dict
        ``flagged`` (views selected as rotated, in order), ``also_consistent`` (other
        views that explain the data about as well), ``rotation_deg (n_views, 3)``
        (rotation vector in the camera frame, degrees: the joint estimate for flagged
        views, the single-view one otherwise; row 0 zero), ``std_deg (n_views, 3)``,
        ``statistic``, ``p_value`` ``(n_views,)`` (single-view tests; NaN for view 0),
        ``dof``, ``sigma_px``, ``level``.
    """
    uv, T = as_uv_T(uv, T)
    info = getattr(calibration, "info", {}) or {}
    if estimate_skew is None:
        estimate_skew = bool(info.get("estimate_skew", False))
    if sigma_T is None:
        sigma_T = info.get("sigma_T")
    n_views = uv.shape[0]
    t_sigma = np.zeros(n_views) if sigma_T is None else np.broadcast_to(np.asarray(sigma_T, float), (n_views,)).copy()
    X = np.asarray(calibration.X, float)
    seen = np.isfinite(uv[..., 0])
    use = np.isfinite(X).all(axis=1) & (seen.sum(axis=0) >= 2)
    inl = getattr(calibration, "inliers", None)
    if inl is not None:
        use &= np.asarray(inl, bool)
    idx = np.flatnonzero(use)
    T_cal = getattr(calibration, "T", None)
    T_start = np.asarray(T_cal, float) if T_cal is not None and t_sigma.any() else T
    sigma_px = float(info.get("sigma_px") or max(getattr(calibration, "rms_px", 1.0) / np.sqrt(2), 1e-6))
    model = _RotationModel(uv[:, idx], T, np.asarray(calibration.K, float), np.asarray(calibration.dist, float),
                           np.asarray(calibration.R, float), X[idx], estimate_skew, t_sigma, sigma_px)
    model.state0["T"] = T_start.copy()
    n_obs = int(seen[:, idx].sum())
    dof = 2 * n_obs - (model.n_nuis - 3 * len(model.t_views)) - 3 * len(idx)
    if dof <= 3:
        raise DegenerateError("too few observations to test for a rotation between views")
    level = alpha / max(1, n_views - 1)
    all_views = list(range(1, n_views))
    focal = 0.5 * (calibration.K[0, 0] + calibration.K[1, 1])

    st, sse = model.fit(model.state0, [], iterations=5)  # make sure it is the ML solution
    S, b, sse, _ = model.normal(st, all_views)
    eta = np.arange(model.n_nuis)

    def step(views, nuis):
        """Linearised fit of ``views``' rotations with ``nuis`` profiled out:
        (rotation, covariance / sigma^2, RSS reduction)."""
        th = _rot_cols(model.n_nuis, all_views, views)
        S_tn = S[np.ix_(th, nuis)]
        Sn_inv = np.linalg.pinv(S[np.ix_(nuis, nuis)], rcond=1e-13, hermitian=True)
        info_t = S[np.ix_(th, th)] - S_tn @ Sn_inv @ S_tn.T
        g = b[th] - S_tn @ Sn_inv @ b[nuis]
        cov = np.linalg.pinv(info_t, rcond=1e-13, hermitian=True)
        w = cov @ g
        return w, cov, float(g @ w)

    # single-view score tests (F(3, dof) with the variance of the one-view alternative)
    single = {}
    for i in all_views:
        w, cov, red = step([i], eta)
        d = dof - 3
        s2 = max((sse - red) / d, 1e-300)
        single[i] = (red / s2, float(stats.f.sf(red / s2 / 3.0, 3, d)), w, cov, s2)
    # forward selection on the linearised model: add the view that explains most while significant
    flagged: list = []
    reduction = 0.0
    while len(flagged) < n_views - 1:
        cand = [(step(flagged + [i], eta)[2], i) for i in all_views if i not in flagged]
        red, i = max(cand)
        d = dof - 3 * (len(flagged) + 1)
        if d <= 0:
            break
        f = ((red - reduction) / 3.0) / max((sse - red) / d, 1e-300)
        w_i = step(flagged + [i], eta)[0][-3:]
        if not (stats.f.sf(f, 3, d) < level and single[i][1] < level and np.linalg.norm(w_i) * focal >= min_shift_px):
            break
        flagged.append(i)
        reduction = red

    rot = np.zeros((n_views, 3))
    std = np.zeros((n_views, 3))
    stat = np.full(n_views, np.nan)
    pval = np.full(n_views, np.nan)
    for i in all_views:
        stat[i], pval[i] = single[i][0], single[i][1]
        rot[i] = np.degrees(single[i][2])
        std[i] = np.degrees(np.sqrt(np.maximum(np.diag(single[i][3]) * single[i][4], 0.0)))
    if flagged:  # the flagged views' rotations fitted together
        w, cov, red = step(flagged, eta)
        s2 = max((sse - red) / (dof - 3 * len(flagged)), 1e-300)
        for k, i in enumerate(flagged):
            rot[i] = np.degrees(w[3 * k: 3 * k + 3])
            std[i] = np.degrees(np.sqrt(np.maximum(np.diag(cov)[3 * k: 3 * k + 3] * s2, 0.0)))
    also = []
    if flagged:  # other views whose rotation alone explains the data about as well as the first's
        top, s2 = single[flagged[0]][0] * single[flagged[0]][4], single[flagged[0]][4]
        also = [i for i in all_views if i not in flagged and pval[i] < level
                and (top - single[i][0] * single[i][4]) / s2 < stats.chi2.ppf(0.99, 3)]
    return {"rotation_deg": rot, "std_deg": std, "statistic": stat, "p_value": pval, "dof": int(dof),
            "sigma_px": float(np.sqrt(sse / dof)), "flagged": flagged, "also_consistent": also, "level": level}


def _fit_rotated_views(uv, T, calibration, candidates):
    """Refit with one candidate view's rotation free (``refine(...,
    estimate_view_rotations=[i])``) and keep the best: ``(view, (rotation_deg (3,),
    std_deg (3,)), views explaining the data not significantly worse)``, or None."""
    from ..estimate.refine import refine

    cands = sorted(set(int(i) for i in candidates))
    if len(cands) < 1:
        return None
    info = getattr(calibration, "info", {}) or {}
    uv = np.asarray(uv, float)
    inl = getattr(calibration, "inliers", None)
    if inl is not None:
        uv = np.where(np.asarray(inl, bool)[None, :, None], uv, np.nan)
    fits = {}
    for i in cands:  # a few views at most
        try:
            c = refine(uv, T, calibration, distortion=getattr(calibration, "dist_model", "none"),
                       estimate_skew=bool(info.get("estimate_skew", False)), sigma_T=info.get("sigma_T"),
                       estimate_view_rotations=[i])
        except (DegenerateError, InputError, np.linalg.LinAlgError, TypeError):
            return None
        fits[i] = (2.0 * c.info["cost"], c.info["view_rotations_deg"][i], c.info["view_rotations_std_deg"][i],
                   c.info["sigma_px"])
    best = min(fits, key=lambda i: fits[i][0])
    s2 = fits[best][3] ** 2
    ambiguous = [i for i in cands if i != best and (fits[i][0] - fits[best][0]) / s2 < stats.chi2.ppf(0.99, 3)]
    return best, (np.asarray(fits[best][1]), np.asarray(fits[best][2])), ambiguous


def locate_view_rotation(uv, T, calibration: Calibration, *, alpha: float = ROTATION_ALPHA) -> dict | None:
    """Detect a rotated view and name it: None on pure-translation data.

    Detection is :func:`view_rotation_test` (linearised, calibrated false-alarm rate).
    When it fires, the data are refitted with the rotation of each significant view free
    in turn (:func:`transcalib.refine.refine` with ``estimate_view_rotations=[i]``, at
    most five views); the view whose fit has the lowest cost is named, with the fitted
    angle, and views whose fit is not significantly worse (99% chi-square(3)) are
    alternatives.

    Parameters
    ----------
    uv, T, calibration, alpha
        As :func:`check_view_rotations`.

    Returns
    -------
    dict or None
        ``views`` (named views, most likely first), ``alternatives``, ``rotation_deg
        (n_views, 3)``, ``std_deg (n_views, 3)`` (camera-frame rotation vectors, degrees),
        ``p_value (n_views,)``, and ``test`` (the :func:`view_rotation_test` result).
    """
    if getattr(calibration, "cov", None) is None:
        from ..estimate.refine import refine  # a linear calibration: take the ML solution first

        calibration = refine(uv, T, calibration, distortion=getattr(calibration, "dist_model", "none"))
    res = view_rotation_test(uv, T, calibration, alpha=alpha)
    if not res["flagged"]:
        return None
    p = res["p_value"]
    significant = [int(i) for i in np.argsort(-np.nan_to_num(res["statistic"], nan=-1.0)) if p[i] < res["level"]]
    fitted = _fit_rotated_views(uv, T, calibration, significant[:5])
    views, also = list(res["flagged"]), list(res["also_consistent"])
    rot, std = res["rotation_deg"].copy(), res["std_deg"].copy()
    if fitted is not None:  # the nonlinear fits name the view and give its angle
        best, (w, sd), also = fitted
        views = [best] + [i for i in views if i != best]
        rot[best], std[best] = w, sd
    return {"views": views, "alternatives": also, "rotation_deg": rot, "std_deg": std, "p_value": p, "test": res}


def check_view_rotations(uv, T, calibration: Calibration, *, alpha: float = ROTATION_ALPHA) -> list:
    """Warn when the camera rotated between views (the pure-translation model is broken).

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
    T : (n_views, 3) float
    calibration : Calibration
        A refined (maximum-likelihood) pure-translation calibration; a linear one is
        refined first.
    alpha : float
        Family-wise false-alarm probability on pure-translation data (Bonferroni over the
        views).

    Returns
    -------
    list of Diagnostic
        ``view_rotation`` naming the rotated view(s) with the angle (degrees) and its
        standard deviation, and the views that would explain the data as well.

    Notes
    -----
    See :func:`locate_view_rotation`.
    """
    loc = locate_view_rotation(uv, T, calibration, alpha=alpha)
    if loc is None:
        return []
    parts = []
    for i in loc["views"]:
        w, sd = loc["rotation_deg"][i], loc["std_deg"][i]
        ang = float(np.linalg.norm(w))
        ang_std = float(np.sqrt(np.sum((w / max(ang, 1e-300)) ** 2 * sd**2)))
        parts.append(f"view {i}: about {ang:.2g} deg +- {ang_std:.1g} (p = {loc['p_value'][i]:.1e})")
    if loc["alternatives"]:
        parts.append(f"the data are also consistent with a rotation of view(s) {_list(loc['alternatives'])} "
                     "instead; with few views the rotated one cannot be singled out for certain")
    return [Diagnostic(
        "view_rotation",
        "the camera seems to have rotated between views, which breaks the pure-translation model (view 0 is "
        f"the reference): {'; '.join(parts)}. The calibration is biased. Make the robot keep the tool "
        "orientation fixed (command pure Cartesian translations, check the orientation the controller "
        "reports), check the camera mount is rigid, or drop those views. Imprecise robot positions "
        "and unmodelled lens distortion can mimic this: give the robot's precision (sigma_T, CLI "
        "--robot-sigma) and try distortion='radial2'.")]


# ----------------------------------------------------------------------------------------
# Robot orientations
# ----------------------------------------------------------------------------------------


def check_pose_orientations(quaternions, tol_deg: float = 0.1) -> list:
    """Warn when the robot's reported orientation is not constant.

    Parameters
    ----------
    quaternions : (n_views, 4) float
        Tool orientation per view as ``qx, qy, qz, qw`` (any norm; ``q`` and ``-q`` are
        the same orientation).
    tol_deg : float
        Largest acceptable rotation angle from view 0's orientation (degrees).

    Returns
    -------
    list of Diagnostic
        ``pose_orientation`` listing each view beyond ``tol_deg`` with its angle.

    Raises
    ------
    InputError
        Wrong shape, non-finite or zero quaternions.
    """
    try:
        q = np.asarray(quaternions, dtype=float)
    except (TypeError, ValueError):
        raise InputError("quaternions must be numbers, one row qx, qy, qz, qw per view") from None
    if q.ndim != 2 or q.shape[1] != 4:
        raise InputError(f"quaternions must have shape (n_views, 4) as qx, qy, qz, qw; got shape {q.shape}")
    if not np.isfinite(q).all():
        raise InputError("quaternions contain NaN or inf; give the orientation of every pose (or none at all)")
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm < 1e-12):
        raise InputError(f"quaternions of views {np.flatnonzero(norm < 1e-12).tolist()} are zero; "
                         "each must be a rotation qx, qy, qz, qw")
    q = q / norm[:, None]
    c = np.clip(np.abs(q @ q[0]), 0.0, 1.0)
    s = np.linalg.norm(np.cross(q[:, :3], q[0, :3]) + q[0, 3] * q[:, :3] - q[:, 3:4] * q[0, :3], axis=1)
    angle = np.degrees(2.0 * np.arctan2(s, c))  # accurate for small angles too
    bad = np.flatnonzero(angle > tol_deg)
    if not len(bad):
        return []
    detail = ", ".join(f"view {i}: {angle[i]:.3g} deg" for i in bad[:20])
    return [Diagnostic(
        "pose_orientation",
        f"the robot's orientation is not constant: {len(bad)} pose(s) differ from view 0's by more than "
        f"{tol_deg:g} deg ({detail}). The method assumes pure translations; command the moves with a fixed "
        "tool orientation, or leave those views out.")]


# ----------------------------------------------------------------------------------------
# Entry point
# ----------------------------------------------------------------------------------------


def diagnose(uv, T, calibration, *, linear: LinearEstimate | None = None, quaternions=None,
             check_rotation: bool = True, unit: str = "units") -> list:
    """Run every check on a calibration; an empty list on healthy data.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        The observations the calibration was computed from.
    T : (n_views, 3) float
        Measured robot translations.
    calibration : Calibration (or LinearEstimate)
        The result to check; its ``inliers`` (if any) select the points that count.
    linear : LinearEstimate, optional
        The linear estimate (default ``calibration.linear``) for the null-space check.
    quaternions : (n_views, 4) float, optional
        Robot orientations ``qx, qy, qz, qw`` when the poses carry them.
    check_rotation : bool
        Run the model-violation (rotation) test; it needs a few refinement-sized passes.
    unit : str
        Length unit named in the messages.

    Returns
    -------
    list of Diagnostic
        In the order: translations, null space, points behind, views, outliers, rotation,
        poses.
    """
    uv, T = as_uv_T(uv, T)
    out = []
    K = np.asarray(calibration.K, float)
    R = np.asarray(calibration.R, float)
    X = np.asarray(calibration.X, float)
    seen = np.isfinite(uv[..., 0])
    z = _depths(R, X, T)
    with np.errstate(invalid="ignore"):
        zs = z[seen & np.isfinite(z) & (z > 0)]
    distance = float(np.median(zs)) if zs.size else None
    out += check_translations(T, focal_px=0.5 * (K[0, 0] + K[1, 1]), distance=distance, unit=unit)
    if linear is None:
        linear = calibration if isinstance(calibration, LinearEstimate) else getattr(calibration, "linear", None)
    if linear is not None:
        out += check_null_space(linear)
    behind = check_points_behind(uv, T, calibration)
    n_excluded = int((getattr(calibration, "info", None) or {}).get("n_points_behind_camera", 0) or 0)
    if not behind and n_excluded > 0:
        behind = [Diagnostic(
            "points_behind_camera",
            f"{n_excluded} point(s) were left out of the refinement because they lie behind the camera: these "
            "tracks are almost certainly mismatches. Remove them or run the robust estimator "
            "(calibrate(..., robust=True), CLI --robust).")]
    out += behind
    residuals = getattr(calibration, "residuals_px", None)
    if residuals is not None:
        out += check_views(uv, residuals, used=getattr(calibration, "inliers", None))
        out += check_outliers(residuals, used=getattr(calibration, "inliers", None))
    if check_rotation and isinstance(calibration, Calibration):
        try:
            out += check_view_rotations(uv, T, calibration)
        except (DegenerateError, np.linalg.LinAlgError):
            pass  # too little data to test; the other checks say why
    if quaternions is not None:
        out += check_pose_orientations(quaternions)
    return out
