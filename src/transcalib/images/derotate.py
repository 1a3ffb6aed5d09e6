"""Small rotations inside a pure-translation session: estimated from the matches, then removed.

A robot's reported orientation errs by ~0.02-0.2 deg per axis, so the views of a session
("pure translations", orientations within the session tolerance) differ by small rotations
that physically turn the camera. View ``i`` at robot position ``T_i`` turned by the
robot-frame rotation ``Q_i = exp([w_i]x)`` images::

    x_i ~ A Q_i^T (X - T_i)                    (A = K R, the paper's matrix)

so the **derotated** points ``x~_i = H_i x_i``, ``H_i = A Q_i A^-1`` (a homography: the
infinite homography of the rotation), obey the exact pure-translation geometry: every
pair's epipole is ``e_ij ~ A (T_j - T_i)`` and ``x~_j`` lies on the line ``e_ij x~_i``.

:func:`estimate_rotations` fits ``A`` and the ``w_i`` (``w_0 = 0`` while fitting) to the
pairs' matches that a general fundamental matrix verifies (which holds whatever the
rotation): the robust start of ``A`` from the pairs' epipoles and the translations
(:func:`~.epipoles.robust_A`), then Levenberg-Marquardt on the signed epipolar distances
of the derotated matches, with a Cauchy loss whose scale is re-estimated from the
residuals at every step (``1.4826 MAD``: the data's noise, no fixed pixel constant). The
rotations are reported relative to the session's component-wise median orientation
(one rotated view cannot move it), ``A`` rotated to match, so ``H_i`` derotates to
that orientation. A position error ``d`` of the robot (mm) at scene distance ``D`` moves
the image like a rotation of ``d / D`` rad about the perpendicular axis; over a flat
scene the two are indistinguishable, so the estimate includes that part of the position
error (2 mm at 800 mm: up to 0.14 deg). The tracker then runs every stage in the
derotated geometry (:class:`Derotation` maps between image and model pixels) and returns
the original pixel positions.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..estimate.noise import mad_sigma
from ..geometry.rotation import matrix_to_rotvec, rotvec_to_matrix
from .epipoles import MIN_VERIFIED, MOVING_PX, _fit_epipole, robust_A

__all__ = ["RotationOptions", "Derotation", "estimate_rotations"]


@dataclass(frozen=True)
class RotationOptions:
    """Options of :func:`estimate_rotations`.

    Attributes
    ----------
    max_matches_per_pair : int
        Verified matches of a pair used in the fit, at most (a random subset).
    iterations : int
        Levenberg-Marquardt steps, at most.
    cauchy_c : float
        Cauchy loss ``rho(r) = c^2 / 2 log(1 + (r / (c sigma))^2)`` (2.385: 95 % efficiency
        on Gaussian residuals).
    inlier_sigmas : float
        A residual within this many sigmas counts as explained (per-view statistics).
    prior_deg : float
        Scale of the prior on the rotations: ``sum_i |w_i - mean w|^2 / prior^2`` is added
        to the cost. The data leave some rotations unseen (over a flat scene, or with 4
        views, a rotation across the optical axis moves the image like a translation that
        ``A`` absorbs); the prior keeps those at zero, where the tracker's geometry is the
        same, while rotations the matches show are estimated (half the 1 deg session
        tolerance: a rotation the data leave open is not pushed past the tolerance).
    prior_lam : float
        Scale of the prior ``lam^2 / prior^2`` on the radial term (a large ``lam`` shrinks
        every match towards the centre, a degenerate zero-residual fit; real lenses give
        ``|lam|`` below ~0.1 here).
    """

    max_matches_per_pair: int = 150
    iterations: int = 20
    cauchy_c: float = 2.385
    inlier_sigmas: float = 3.0
    prior_deg: float = 0.5
    prior_lam: float = 0.1


@dataclass(frozen=True, eq=False)
class Derotation:
    """The derotation of a session's views: image pixels <-> model pixels ``x~ = H_i x``.

    Attributes
    ----------
    H : (n_views, 3, 3) float
        ``A Q_i A^-1``; the identity for every view when nothing was estimated.
    omega : (n_views, 3) float or None
        Rotation vectors ``w_i`` (radians, robot frame) of the views relative to the
        session's median orientation; None when not estimated.
    A : (3, 3) float or None
        ``e_ij ~ A (T_j - T_i)`` at the median orientation (unit Frobenius norm).
    sigma_px : float
        Robust scale of the derotated epipolar distances (NaN when not estimated).
    view_rms_px : (n_views,) float or None
        RMS derotated epipolar distance of each view's explained matches.
    view_explained : (n_views,) float or None
        Share of each view's matches within ``inlier_sigmas`` sigmas.
    lens : Lens
        The radial term removed before the derotation (zero when not estimated).
    std_deg : (n_views,) float or None
        Standard deviation (degrees) of each view's rotation along its worst-determined
        axis (from the fit's normal matrix, noise and priors; not systematic errors).
    """

    H: np.ndarray
    omega: np.ndarray | None = None
    A: np.ndarray | None = None
    sigma_px: float = float("nan")
    view_rms_px: np.ndarray | None = None
    view_explained: np.ndarray | None = None
    lens: "Lens" = None
    std_deg: np.ndarray | None = None

    @classmethod
    def identity(cls, n_views: int) -> "Derotation":
        return cls(H=np.repeat(np.eye(3)[None], n_views, axis=0))

    @property
    def estimated(self) -> bool:
        return self.omega is not None

    def angles_deg(self) -> np.ndarray:
        """``(n_views,)`` rotation angle of each view from the median orientation, degrees."""
        return np.degrees(np.linalg.norm(self.omega, axis=1)) if self.estimated else np.zeros(len(self.H))

    def to_model(self, v: int, x: np.ndarray) -> np.ndarray:
        """Image pixels ``x (m, 2)`` of view ``v`` -> derotated (model) pixels."""
        return x if not self.estimated else _apply(self.H[v], self.lens.undistort(x))

    def to_image(self, v: int, x: np.ndarray) -> np.ndarray:
        """Model pixels ``x (m, 2)`` of view ``v`` -> image pixels."""
        return x if not self.estimated else self.lens.distort(_apply(np.linalg.inv(self.H[v]), x))

    def uv_to_model(self, uv: np.ndarray) -> np.ndarray:
        """:meth:`to_model` of tracks ``uv (n_views, m, 2)`` (NaN stays NaN)."""
        return uv if not self.estimated else np.stack([self.to_model(v, uv[v]) for v in range(len(uv))])

    def uv_to_image(self, uv: np.ndarray) -> np.ndarray:
        """:meth:`to_image` of tracks ``uv (n_views, m, 2)``."""
        return uv if not self.estimated else np.stack([self.to_image(v, uv[v]) for v in range(len(uv))])

    def pairs_to_image(self, xy: dict) -> dict:
        """Matches in model pixels -> image pixels."""
        return {p: (self.to_image(p[0], x), self.to_image(p[1], y)) for p, (x, y) in xy.items()}

    def pairs_to_model(self, xy: dict) -> dict:
        """Matches ``{(i, j): (x_i, x_j)}`` in model pixels."""
        return {p: (self.to_model(p[0], x), self.to_model(p[1], y)) for p, (x, y) in xy.items()}


@dataclass(frozen=True)
class Lens:
    """One radial term, the division model about the image centre ``c``::

        x_u = c + (x - c) / (1 + lam |x - c|^2 / s^2)

    (``s`` half the larger image side). Lens distortion bends the epipolar lines
    radially; left out, the fit turns it into rotations about the axes across the
    optical axis (measured: k1 = -0.06 at 640 x 480 gave 0.3 deg errors).

    Attributes
    ----------
    centre : (2,) float
    s : float
    lam : float
    """

    centre: tuple = (0.0, 0.0)
    s: float = 1.0
    lam: float = 0.0

    def undistort(self, x: np.ndarray) -> np.ndarray:
        """Points ``x (m, 2)`` undistorted: ``(m, 2)``, or ``(k, m, 2)`` for ``k`` values
        of ``lam`` at once (``lam (k,)``)."""
        d = np.asarray(x, float) - self.centre
        r2 = d[..., :1] * d[..., :1] + d[..., 1:2] * d[..., 1:2]
        lam = np.asarray(self.lam, float)[..., None, None] if np.ndim(self.lam) else self.lam
        return self.centre + d / (1.0 + lam * r2 / self.s**2)

    def distort(self, xu: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`undistort`: the root ``r = 2 r_u / (1 + sqrt(1 - 4 lam r_u^2))``
        of ``lam r_u r^2 - r + r_u = 0`` nearest ``r_u`` (radii in units of ``s``; the form
        without cancellation for small ``lam``)."""
        d = np.asarray(xu, float) - self.centre
        ru2 = (d * d).sum(-1, keepdims=True) / self.s**2
        return self.centre + d * (2.0 / (1.0 + np.sqrt(np.maximum(1.0 - 4.0 * self.lam * ru2, 0.0))))


def _apply(H: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``pi(H [x; 1])`` of points ``x (..., m, 2)``; ``H (3, 3)`` or one per point
    ``(..., m, 3, 3)`` (written out: ``einsum`` over the points cost about twice as much)."""
    x = np.asarray(x, float)
    u, v = x[..., 0], x[..., 1]
    h = [H[..., a, 0] * u + H[..., a, 1] * v + H[..., a, 2] for a in range(3)]
    with np.errstate(divide="ignore", invalid="ignore"):  # unseen (NaN) points stay NaN
        return np.stack([h[0] / h[2], h[1] / h[2]], axis=-1)


# --------------------------------------------------------------------------- the fit
@dataclass(frozen=True, eq=False)
class _Data:
    """The matches of the fit, all pairs concatenated: ``x, y (N, 2)``, views ``vi, vj (N,)``,
    translations ``t = T_j - T_i (N, 3)``; the lens's ``centre`` and ``s``."""

    x: np.ndarray
    y: np.ndarray
    vi: np.ndarray
    vj: np.ndarray
    t: np.ndarray
    centre: tuple
    s: float

    def subset(self, idx: np.ndarray) -> "_Data":
        """The matches ``idx``."""
        return _Data(self.x[idx], self.y[idx], self.vi[idx], self.vj[idx], self.t[idx], self.centre, self.s)

    @cached_property
    def still(self) -> np.ndarray:
        """(N,) bool: matches moving less than :data:`~.epipoles.MOVING_PX` (no direction)."""
        u, v = self.y[:, 0] - self.x[:, 0], self.y[:, 1] - self.x[:, 1]
        return np.sqrt(u * u + v * v) < MOVING_PX


def _homographies(A: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``H_v = A exp([w_v]x) A^-1``: ``A (..., 3, 3)``, ``omega (..., n, 3)`` -> ``(..., n, 3, 3)``."""
    return A[..., None, :, :] @ rotvec_to_matrix(omega) @ np.linalg.inv(A)[..., None, :, :]


def residuals(A: np.ndarray, lam, omega: np.ndarray, d: _Data) -> np.ndarray:
    """Signed distances ``(N,)`` (px) of the undistorted, derotated ``y~`` from the
    epipolar lines through ``x~`` and ``e = A t``: ``cross(e3 x~ - e_xy, y~ - x~) / |e3 x~ - e_xy|``
    (0 for matches moving less than :data:`~.epipoles.MOVING_PX`). With ``k`` parameter
    sets at once (``A (k, 3, 3)``, ``lam (k,)``, ``omega (k, n, 3)``): ``(k, N)``."""
    H = _homographies(A, omega)
    lens = Lens(d.centre, d.s, lam)
    xd, yd = _apply(H[..., d.vi, :, :], lens.undistort(d.x)), _apply(H[..., d.vj, :, :], lens.undistort(d.y))
    e = d.t @ np.swapaxes(A, -1, -2)
    dirn = e[..., 2:3] * xd - e[..., :2]
    disp = yd - xd
    with np.errstate(divide="ignore", invalid="ignore"):
        r = (dirn[..., 0] * disp[..., 1] - dirn[..., 1] * disp[..., 0]) / np.sqrt(dirn[..., 0] ** 2 + dirn[..., 1] ** 2)
    # back to image pixels: undistortion scales lengths near y by 1 / (1 + lam r^2), and a
    # large lam would otherwise shrink every residual (a degenerate fit)
    u, v = d.y[:, 0] - d.centre[0], d.y[:, 1] - d.centre[1]
    r = r * (1.0 + np.asarray(lam, float)[..., None] * (u * u + v * v) / d.s**2)
    return np.where(d.still, 0.0, np.nan_to_num(r, nan=1e6))


def _unpack(p: np.ndarray, n: int):
    """Parameters ``(..., 10 + 3 (n - 1))`` -> ``A (..., 3, 3)``, ``lam (...)``,
    ``omega (..., n, 3)`` (``w_0 = 0``)."""
    lead = p.shape[:-1]
    omega = np.concatenate([np.zeros(lead + (1, 3)), p[..., 10:].reshape(lead + (n - 1, 3))], axis=-2)
    return p[..., :9].reshape(lead + (3, 3)), p[..., 9], omega


def _jacobian(p: np.ndarray, n: int, d: _Data, mine: list) -> np.ndarray:
    """``(N, len(p))`` forward differences of :func:`residuals` at ``p`` (steps 1e-7 of
    ``|A|``, 1e-7 in ``lam`` and in radians: the truncation error, ~1e-7 of a residual's
    curvature, is far below the noise; Gauss-Newton needs no more). ``A`` and ``lam``,
    which move every match, in one batch with ``p`` itself; a view's rotation moves only
    its own matches ``mine[v]`` (:meth:`_Data.subset`), evaluated on those alone: the
    cost grows with the matches, not with matches times views."""
    step = np.r_[np.full(9, 1e-7 * np.linalg.norm(p[:9])), np.full(len(p) - 9, 1e-7)]
    shared = np.vstack([np.zeros(len(p)), np.diag(step)[:10]])
    r = residuals(*_unpack(p + shared, n), d)  # (11, N)
    J = np.zeros((len(d.x), len(p)))
    J[:, :10] = ((r[1:] - r[0]) / step[:10, None]).T
    for v in range(1, n):
        cols = slice(10 + 3 * (v - 1), 13 + 3 * (v - 1))
        own = np.zeros((4, len(p)))
        own[np.arange(1, 4), np.arange(len(p))[cols]] = step[cols]
        rv = residuals(*_unpack(p + own, n), d.subset(mine[v]))  # (4, |mine[v]|)
        J[mine[v], cols] = ((rv[1:] - rv[0]) / step[cols, None]).T
    return J


def _lm(p: np.ndarray, n: int, d: _Data, opts: RotationOptions):
    """Levenberg-Marquardt with a Cauchy loss (IRLS weights ``1 / (1 + (r / c sigma)^2)``,
    ``sigma`` the MAD scale of the current residuals) and the priors. Returns parameters,
    sigma and the covariance ``(3 (n - 1), 3 (n - 1))`` of ``w_1 .. w_{n-1}`` (the inverse
    of the last normal matrix)."""
    mine = [np.flatnonzero((d.vi == v) | (d.vj == v)) for v in range(n)]
    lam = 1e-3
    r = residuals(*_unpack(p, n), d)
    sigma = mad_sigma(r, len(p))
    P = np.zeros((len(p), len(p)))  # the prior: sum_i |w_i - mean w|^2 (w_0 = 0) / prior^2
    P[10:, 10:] = np.kron(np.eye(n - 1) - 1.0 / n, np.eye(3)) / np.radians(opts.prior_deg) ** 2
    P[9, 9] = 1.0 / opts.prior_lam**2  # lam -> infinity shrinks every match to the centre: zero residuals

    def cost(res, q, s):  # Cauchy loss of the residuals (in sigmas) + the prior, halved
        return float(0.5 * opts.cauchy_c**2 * np.sum(np.log1p((res / (opts.cauchy_c * s)) ** 2)) + 0.5 * q @ P @ q)

    for _ in range(opts.iterations):
        w = 1.0 / (1.0 + (r / (opts.cauchy_c * sigma)) ** 2)
        J = _jacobian(p, n, d, mine)
        Jw = J * w[:, None]
        N, g = Jw.T @ J / sigma**2 + P, Jw.T @ r / sigma**2 + P @ p
        c0, improved = cost(r, p, sigma), False
        for _ in range(8):
            step = -np.linalg.solve(N + lam * np.diag(np.diag(N) + 1e-12 * np.trace(N)), g)
            q = p + step
            q[:9] /= np.linalg.norm(q[:9])
            try:
                rq = residuals(*_unpack(q, n), d)
            except np.linalg.LinAlgError:  # the step made A singular: rejected, as a worse cost
                lam *= 10
                continue
            if cost(rq, q, sigma) < c0:
                p, r, lam, improved = q, rq, max(lam / 10, 1e-9), True
                break
            lam *= 10
        new_sigma = mad_sigma(r, len(p))
        done = not improved or (np.max(np.abs(step[10:]), initial=0.0) < 1e-6 and abs(new_sigma - sigma) < 1e-2 * sigma)
        sigma = new_sigma
        if done:  # rotations still by < 1e-6 rad (6e-5 deg), the noise scale settled
            break
    return p, sigma, np.linalg.pinv(N)[10:, 10:]


def _pair_data(xy: dict, general: dict, T: np.ndarray, shape, opts: RotationOptions, rng):
    """The fit's matches (each pair's general-F inliers, at most ``max_matches_per_pair``)
    and each pair's least-squares epipole of them ``{(i, j): e}`` (the start of ``A``);
    None without any verified pair."""
    parts, epi = [], {}
    for (i, j), (x, y) in xy.items():
        inl = general.get((i, j))
        if inl is None:
            continue
        sel = np.flatnonzero(inl & (np.linalg.norm(y - x, axis=1) >= MOVING_PX))
        if len(sel) < MIN_VERIFIED:
            continue
        epi[(i, j)] = _fit_epipole(x[sel], y[sel], float(max(shape)))
        if len(sel) > opts.max_matches_per_pair:
            sel = np.sort(rng.choice(sel, opts.max_matches_per_pair, replace=False))
        parts.append((x[sel], y[sel], np.full(len(sel), i), np.full(len(sel), j), np.tile(T[j] - T[i], (len(sel), 1))))
    if not parts:
        return None
    h, w = shape
    cat = [np.concatenate(c) for c in zip(*parts)]
    return _Data(*cat, centre=((w - 1) / 2.0, (h - 1) / 2.0), s=max(h, w) / 2.0), epi


def estimate_rotations(xy: dict, general: dict, T: np.ndarray, threshold_px: float, shape, rng,
                       opts: RotationOptions = RotationOptions()) -> Derotation | None:
    """The views' small rotations, ``A`` and one radial term of a session (module docstring).

    Parameters
    ----------
    xy : dict ``(i, j) -> (x_i (m, 2), x_j (m, 2))``
        Descriptor matches of every pair ``i < j``.
    general : dict ``(i, j) -> (m,) bool``
        The matches a general fundamental matrix verifies (pairs without one left out).
    T : (n_views, 3) float
        The session's robot positions.
    threshold_px : float
        Epipolar distance that ranks the hypotheses of ``A`` (twice it: the rotations are
        not removed yet; the start only).
    shape : (h, w)
        Image size.
    rng : Generator
    opts : RotationOptions

    Returns
    -------
    Derotation or None
        None when the translations do not span 3-D (``A`` would be 3 x 2: no derotation)
        or too few pairs are verified.
    """
    T = np.asarray(T, float)
    n = len(T)
    got = None if n < 4 else _pair_data(xy, general, T, shape, opts, rng)
    if got is None:
        return None
    data, epi = got
    fit = robust_A(epi, xy, T, 2.0 * threshold_px, float(max(shape)), rng,
                   {p: general.get(p, np.zeros(len(xy[p][0]), bool)) for p in xy})
    if fit is None or fit[0].shape[1] < 3:
        return None
    A0 = fit[0] @ fit[1].T
    if abs(np.linalg.det(A0 / np.linalg.norm(A0))) < 1e-9:
        return None
    p, sigma, cov = _lm(np.r_[(A0 / np.linalg.norm(A0)).ravel(), 0.0, np.zeros(3 * (n - 1))], n, data, opts)
    A, lam, omega = _unpack(p, n)
    return _centred(A, omega, Lens(data.centre, data.s, float(lam)), residuals(A, lam, omega, data), data, sigma,
                    opts, _view_std(cov, n))


def _view_std(cov: np.ndarray, n: int) -> np.ndarray:
    """``(n,)`` std (radians) of each view's rotation from the mean orientation, along its
    worst-determined axis: the covariance of ``w_i - mean w`` (``w_0 = 0``), the largest
    eigenvalue of each 3 x 3 block."""
    C = np.kron(np.eye(n) - 1.0 / n, np.eye(3))[:, 3:]
    full = C @ cov @ C.T
    blocks = np.stack([full[3 * v:3 * v + 3, 3 * v:3 * v + 3] for v in range(n)])
    return np.sqrt(np.maximum(np.linalg.eigvalsh(blocks)[:, -1], 0.0))


def _centred(A, omega, lens: Lens, r, data: _Data, sigma: float, opts: RotationOptions, std) -> Derotation:
    """The result relative to the median orientation ``Q_m``: ``Q_i Q_m^T`` and ``A Q_m^T``
    (``A Q_i^T = (A Q_m^T) (Q_i Q_m^T)^T``), with the per-view residual statistics."""
    n = len(omega)
    Q = rotvec_to_matrix(omega)
    Qm = rotvec_to_matrix(np.median(omega, axis=0))
    Ac = A @ Qm.T
    omega_c = matrix_to_rotvec(Q @ Qm.T)
    ok = np.abs(r) < opts.inlier_sigmas * sigma
    rms, share = np.full(n, np.nan), np.full(n, np.nan)
    for v in range(n):  # a loop over views, vectorised over matches
        mine = (data.vi == v) | (data.vj == v)
        if mine.any():
            share[v] = ok[mine].mean()
            rms[v] = np.sqrt(np.mean(r[mine & ok] ** 2)) if (mine & ok).any() else np.nan
    return Derotation(H=_homographies(Ac, omega_c), omega=omega_c, A=Ac / np.linalg.norm(Ac), sigma_px=float(sigma),
                      view_rms_px=rms, view_explained=share, lens=lens, std_deg=np.degrees(std))
