"""Each view's smooth image error field: a variance component the covariance takes in.

A tracker's errors hold a part alike over a view's points, a smooth field over the
image (on renders ~0.003 px RMS: docs/uncertainty.md section 6.3). It does not average
down over a view's ~1000 points, and the intrinsics and each view's pose error absorb
most of it, so the residuals (and a sandwich clustered by point) hardly show it; the
focal length, which rests on how a view's small rotation bends the image, scatters by
it. The model ::

    z_ij = pi(theta, X_j) + B(x_ij) a_i + n_ij,    a_i ~ N(0, tau I_m),  n_ij ~ N(0, sigma^2 I_2)

``B (2, m)``: per image coordinate the Legendre polynomials of degree 1 and 2 over the
image rectangle (``u, v; u^2, uv, v^2`` made orthonormal, ``u, v`` in [-1, 1]), each of
mean square 1 over the image. (A view's shift, degree 0, is left out: the robot's pose
error takes it, and on renders the tracker's per-view means are white.) The
coefficients of degree ``d`` have variance ``tau_d`` each: a view's field has RMS
``sqrt(2 tau_1 + 3 tau_2)`` px per coordinate (:attr:`ViewField.rms_px`). The fit does
not estimate the fields; they move its estimate by ``S^-1 S_cf a`` (``S_cf`` the reduced
information between the global parameters and the coefficients, the points
eliminated), so ::

    cov = sigma^2 S^-1 + sum_d tau_d G D_d G^T,      G = S^-1 S_cf            (1)

(``D_d`` selects degree ``d``'s coefficients). The ``tau_d`` come from the residuals at
the solution: the coefficients' reduced score ``g = R_f^T r`` (``R_f`` their Jacobian
rows with the points eliminated) has ``E g g^T = sigma^2 Q + sum_d tau_d Q D_d Q``, ``Q
= S_ff - S_fc S^-1 S_cf`` the fields' information with the camera, the robot errors and
the points profiled out. On ``Q``'s range ``g`` is Gaussian with that covariance: the
``tau_d >= 0`` by maximum likelihood (Fisher scoring on the active set), their
covariance from the Fisher information, and the likelihood-ratio test of ``tau = 0``
(two parameters on the boundary: ``p = P(chi2_1 > LR) / 2 + P(chi2_2 > LR) / 4``, Self &
Liang 1987).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .bundle import _view_system
from .covariance import _prior_rows
from .distributions import chi2_sf
from .schur import Reduced, one_blas_thread

__all__ = ["ViewField", "view_field", "fit_components", "log_likelihood", "legendre_basis", "N_BASIS", "DEGREES",
           "FIELD_ALPHA"]

#: Basis functions per image coordinate (degree 1 and 2 in two variables) and their degrees.
N_BASIS = 5
DEGREES = np.array([1, 1, 2, 2, 2])
_PER_DEGREE = np.array([2.0, 3.0])  # functions of degree 1 and 2
#: Level of the likelihood-ratio test that takes the fields into the covariance.
FIELD_ALPHA = 0.05
#: Directions of ``Q`` whose information is below this share of a coefficient's own
#: (the median diagonal of ``S_ff``, before the model takes its part) are left out of
#: the estimate of ``tau``: the model absorbs nearly all of such a field, and what the
#: residuals keep of it is the size of the fit's second-order terms (with 10^5 points
#: of white noise five such directions, 1e-5 of a coefficient's information, held
#: 10^5 times their noise and made ``tau`` absurd). Their share of the covariance
#: (``G``) stays.
ABSORBED_SHARE = 1e-3
#: Points the fields are measured on at most (blocks spread over the points' order): at
#: 10^5 points in 5 views all of them cost 0.4 s of a 1.2 s command; the fields' share
#: of the covariance is then the sample's coupling scaled to every point.
MAX_POINTS = 20_000


@dataclass(frozen=True, eq=False)
class ViewField:
    """The views' error fields (module docstring).

    Attributes
    ----------
    tau : (2,) float
        Variance of each coefficient of degree 1, 2 (px^2).
    tau_cov : (2, 2) float
        Their covariance (inverse Fisher information on the components not at 0; 0
        for those at 0).
    p_value : float
        Likelihood-ratio test of ``tau = 0``.
    G : (p, 10 V) float
        ``S^-1 S_cf``: the global parameters' response to each field coefficient.
    """

    tau: np.ndarray
    tau_cov: np.ndarray
    p_value: float
    G: np.ndarray

    @property
    def detected(self) -> bool:
        return bool(self.p_value < FIELD_ALPHA)

    @property
    def rms_px(self) -> float:
        """A view's field, RMS per coordinate over the basis's rectangle: ``sqrt(2 tau_1 +
        3 tau_2)`` (px)."""
        return float(np.sqrt(self.tau @ _PER_DEGREE))

    @property
    def rms_std_px(self) -> float:
        """Its std (delta method; NaN at 0)."""
        if self.rms_px <= 0:
            return float("nan")
        d = _PER_DEGREE / (2 * self.rms_px)
        return float(np.sqrt(max(d @ self.tau_cov @ d, 0.0)))

    def covariance(self) -> np.ndarray:
        """``sum_d tau_d G D_d G^T`` of eq. (1), unit px^2 like ``sigma^2 S^-1``."""
        w = np.tile(self.tau[DEGREES - 1], 2 * (self.G.shape[1] // (2 * N_BASIS)))
        return (self.G * w) @ self.G.T


def legendre_basis(uv: np.ndarray, box: np.ndarray) -> np.ndarray:
    """``(n, 5)``: the orthonormal Legendre basis of degree 1 and 2 at pixels ``uv (2,
    n)`` in the image rectangle ``box = (x0, y0, x1, y1)``: ``sqrt3 u, sqrt3 v, sqrt5 (3u^2
    - 1) / 2, 3 u v, sqrt5 (3 v^2 - 1) / 2`` with ``u, v`` the position scaled to [-1, 1]."""
    u = 2.0 * (uv[0] - box[0]) / (box[2] - box[0]) - 1.0
    v = 2.0 * (uv[1] - box[1]) / (box[3] - box[1]) - 1.0
    s3, s5 = np.sqrt(3.0), np.sqrt(5.0)
    return np.stack([s3 * u, s3 * v, 0.5 * s5 * (3 * u * u - 1), 3 * u * v, 0.5 * s5 * (3 * v * v - 1)], axis=1)


def view_field(state, lay, data, red: Reduced, Sinv: np.ndarray, sigma: float, box, ok=None,
               block: int = 2048) -> ViewField:
    """The views' fields at the least-squares solution ``state`` (module docstring).

    Parameters
    ----------
    red, Sinv : the reduced system at the solution (unit weights) and ``S^-1`` (p, p).
    sigma : float
        The pixel noise per coordinate (px).
    box : (4,) float
        The image rectangle ``(x0, y0, x1, y1)`` the basis is orthonormal over (px).
    ok : (n,) bool, optional
        Points that count (the others contribute nothing).
    """
    with one_blas_thread():  # small products: BLAS's threads would only spin
        return _view_field(state, lay, data, red, Sinv, sigma, np.asarray(box, float), ok, block)


def _view_field(state, lay, data, red, Sinv, sigma, box, ok, block) -> ViewField:
    """:func:`view_field`'s work: the fields' system on (a sample of) the points, ``Q``'s
    informative directions, ``tau`` and its test."""
    starts = _sampled_blocks(data.n_points, block)
    S_ff, S_cf, g_f, g_c, S_s, share = _field_system(state, lay, data, red, box, ok, block, starts)
    G = Sinv @ S_cf / share  # every point's coupling, estimated from the sample's
    if share < 1:  # tau from the sample alone: its own information on the global parameters
        Sinv = np.linalg.pinv(S_s, rcond=1e-14, hermitian=True)
    g = g_f - S_cf.T @ (Sinv @ g_c)  # the global parameters profiled out (a fit a few steps short of converged)
    Q = S_ff - S_cf.T @ Sinv @ S_cf
    lam, vec = np.linalg.eigh(0.5 * (Q + Q.T))
    keep = lam > ABSORBED_SHARE * max(np.median(np.diag(S_ff)), 1e-300)
    if not keep.any():  # the model absorbs every field: nothing to measure them by
        return ViewField(np.zeros(2), np.zeros((2, 2)), 1.0, G)
    P = vec[:, keep] * lam[keep]  # on Q's range: Cov(V^T g) = s2 diag(lam) + sum_d tau_d P^T D_d P
    degree = np.tile(DEGREES, 2 * lay.n_views)
    parts = [P[degree == d].T @ P[degree == d] for d in (1, 2)]
    tau, tau_cov, lr = fit_components(vec[:, keep].T @ g, lam[keep], parts, sigma**2)
    p = float(chi2_sf(lr, 1) / 2 + chi2_sf(lr, 2) / 4) if lr > 0 else 1.0
    return ViewField(tau, tau_cov, p, G)


def fit_components(z: np.ndarray, lam: np.ndarray, parts: list, s2: float, iterations: int = 100):
    """Maximum likelihood variance components ``tau_d >= 0`` of ``z ~ N(0, s2 diag(lam) +
    sum_d tau_d parts[d])`` by Fisher scoring on the active set (components at 0 whose
    score points below 0 stay there): ``(tau (K,), cov (K, K), LR)`` with ``LR`` twice the
    log-likelihood gained over ``tau = 0``."""
    K = len(parts)
    tau = np.zeros(K)
    base = _loglik(z, lam, parts, s2, tau)[0]
    for _ in range(iterations):
        _, score, F = _loglik(z, lam, parts, s2, tau)
        free = (tau > 0) | (score > 0)
        if not free.any():
            break
        step = np.zeros(K)
        step[free] = np.linalg.lstsq(F[np.ix_(free, free)], score[free], rcond=1e-12)[0]
        new = np.maximum(tau + step, 0.0)
        scale = s2 / lam.max()  # a tau that moves the most informative direction by 1e-10 of its noise
        done = np.all(np.abs(new - tau) <= 1e-10 * np.maximum(new, scale))
        tau = new
        if done:
            break
    ll, _, F = _loglik(z, lam, parts, s2, tau)
    cov = np.zeros((K, K))
    on = tau > 0
    if on.any():
        cov[np.ix_(on, on)] = np.linalg.pinv(F[np.ix_(on, on)], rcond=1e-12, hermitian=True)
    return tau, cov, max(2.0 * (ll - base), 0.0)


def log_likelihood(z, lam, parts, s2, tau) -> float:
    """The log-likelihood of :func:`fit_components`' model at ``tau`` (up to a constant)."""
    return _loglik(z, lam, parts, s2, tau)[0]


def _loglik(z, lam, parts, s2, tau):
    """Log-likelihood, score ``(K,)`` and Fisher information ``(K, K)`` at ``tau``."""
    C = np.diag(s2 * lam) + sum(t * A for t, A in zip(tau, parts))
    L = np.linalg.cholesky(C)
    Linv = np.linalg.solve(L, np.eye(len(z)))
    Cinv = Linv.T @ Linv
    y = Cinv @ z
    M = [Cinv @ A for A in parts]
    score = np.array([0.5 * (y @ A @ y - np.trace(m)) for A, m in zip(parts, M)])
    F = 0.5 * np.array([[np.sum(a * b.T) for b in M] for a in M])
    return -np.sum(np.log(np.diag(L))) - 0.5 * z @ y, score, F


def _sampled_blocks(n: int, block: int) -> np.ndarray:
    """First points of the blocks the fields are measured on: all of them up to
    :data:`MAX_POINTS` points, else that many spread evenly over the points' order."""
    starts = np.arange(0, n, block)
    if n <= MAX_POINTS:
        return starts
    return starts[np.unique(np.linspace(0, len(starts) - 1, -(-MAX_POINTS // block)).round().astype(int))]


def _field_system(state, lay, data, red: Reduced, box: np.ndarray, ok, block: int, starts: np.ndarray):
    """``S_ff (mV, mV)``, ``S_cf (p, mV)``, the fields' reduced score ``g_f (mV,)``, the
    global parameters' ``g_c (p,)`` and information ``S_s (p, p)`` (the priors' included)
    over the blocks of points ``starts``, :data:`block` points at a time (O(n) memory),
    and the share of the points they hold.

    Coefficient ``(i, c, l)`` (view, image coordinate, basis function; column ``m i +
    5 c + l``) moves observation ``(i, j)``'s coordinate ``c`` by ``phi_l(x_ij)``: its
    Jacobian rows are ``B_ij``. As for the camera's parameters
    (:mod:`transcalib.estimate.schur`), the points are eliminated ::

        S_ff = U_ff - sum_j W_f,j V_j^-1 W_f,j^T,   S_cf = U_cf - sum_j W_j V_j^-1 W_f,j^T,
        g_f = b_f - sum_j W_f,j V_j^-1 b_j,      g_c = b_c - sum_j W_j V_j^-1 b_j + b_prior

    with ``U_ff = sum B^T B`` (one 10 x 10 block per view), ``U_cf = sum J_c^T B``,
    ``W_f,j = sum_i B_ij^T J_Xij^T``, ``b_f = sum B^T r``, ``b_j = sum_i J_Xij^T r_ij``
    (``r`` the residuals, unit weights) and ``W V^-1``, ``V^-1`` those of ``red``.
    """
    V, m = lay.n_views, 2 * N_BASIS
    p, n = lay.size, data.n_points
    S_ff, S_cf, g, g_c = np.zeros((m * V, m * V)), np.zeros((p, m * V)), np.zeros(m * V), np.zeros(p)
    S_s, used, sampled = np.zeros((p, p)), 0, len(starts) < -(-n // block)
    for lo in starts:
        hi = min(lo + block, n)
        used += hi - lo
        part, sub = data.points(lo, hi), replace(state, X=state.X[lo:hi])
        W_f, b_X = np.zeros((m * V, 3, hi - lo)), np.zeros((3, hi - lo))
        W_c = np.zeros((p, 3, hi - lo)) if sampled else None
        for i in range(V):
            if len(part.pts[i]) == 0:
                continue
            r, w, Jg, JX, pts, _ = _view_system(sub, lay, part, i, "linear", 1.0, None)
            mask = np.ones(len(pts)) if w is None else np.asarray(w, float)
            if ok is not None:
                mask = mask * ok[lo:hi][pts]
            uv = part.uv[i] if part.full_seen[i] is None else part.full_uv[i]
            phi = legendre_basis(uv, box) * mask[:, None]  # (n_i, 5): zero where unseen or left out
            r = r * mask
            cols, vc = slice(m * i, m * (i + 1)), lay.view_columns(i)
            S_ff[cols, cols] += np.kron(np.eye(2), phi.T @ phi)
            S_cf[vc, cols] += (Jg @ phi).reshape(len(Jg), m)
            g[cols] += (r @ phi).reshape(m)
            g_c[vc] += (Jg * r).sum(axis=(1, 2))
            if sampled:  # the sample's own information on the global parameters
                Jm = Jg * mask
                S_s[np.ix_(vc, vc)] += Jm.reshape(len(Jg), -1) @ Jm.reshape(len(Jg), -1).T
                W_i = np.zeros((p, 3, len(pts)))
                W_i[vc] = np.einsum("pkn,dkn->pdn", Jm, JX)
                W_c[:, :, pts] += W_i
            # W_f rows of view i, [c, l, d, n] = phi_l(x_n) d x_c / d X_d
            W_f[cols, :, pts] = (phi.T[None, :, None, :] * JX.transpose(1, 0, 2)[:, None]).reshape(m, 3, -1)
            b_X[:, pts] += JX[:, 0] * r[0] + JX[:, 1] * r[1]
        Vinv = red.Vinv[:, :, lo:hi]
        Y_f = (W_f[:, 0, None] * Vinv[0] + W_f[:, 1, None] * Vinv[1] + W_f[:, 2, None] * Vinv[2]).reshape(m * V, -1)
        W2, Y_c, b2 = W_f.reshape(m * V, -1), red.Y[:, :, lo:hi].reshape(p, -1), b_X.reshape(-1)
        S_ff -= Y_f @ W2.T
        S_cf -= Y_c @ W2.T
        g -= Y_f @ b2
        g_c -= Y_c @ b2
        if sampled:
            S_s -= Y_c @ W_c.reshape(p, -1).T
    prior = _prior_rows(state, lay, data)
    if prior is not None:
        g_c += np.einsum("pkv,kv->p", prior[0], prior[1])
        R = prior[0].reshape(p, -1)
        S_s += R @ R.T
    return 0.5 * (S_ff + S_ff.T), S_cf, g, g_c, 0.5 * (S_s + S_s.T), used / n
