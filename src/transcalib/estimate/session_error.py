"""The robot's pose error common to a session's views: a variance component the covariance takes in.

A robot errs by how far its arm configuration is from where it was calibrated
(docs/uncertainty.md §1). Inside a session of small translations the configuration
hardly changes, so much of a view's error is its session's: with several sessions the
per-view model (:mod:`.robot_error`) takes that part for independent errors, and the
std of the hand-eye offset covers a third to a half of its scatter (§7.2: 0.1 deg / 1 mm
per session and 0.02 deg / 0.2 mm per view, three sessions). The model ::

    e_i = e'_i + b_s(i),    e'_i ~ N(0, sigma_c^2 I),   b_s ~ N(0, tau_c I)   (c = rot, pos)

``b_s`` the error of session ``s`` (three rotation and three position coordinates),
shared by its views. Only sessions of two views or more carry one (a single view's
error is its own). ``b_s`` moves the data as the sum of its views' per-view error
columns, so it is measured on them, for both components, whether or not the fit found
a component's per-view part (one it left out, ``sigma_c = 0``, has its columns added
with the data's information alone). The fit does not estimate the ``b_s``; they move
its estimate by ``G b``, ``G = S^-1 S_cb``, so ::

    cov = sigma^2 S^-1 + sum_c tau_c G D_c G^T                           (1)

as for the views' error fields (:mod:`.view_field`, whose likelihood this shares). With
``A`` the sum over each session's views of their error columns, the coefficients' data
information is ``S_bb = A^T S_d A``, ``S_cb = S_d A`` (``S_d`` the reduced information
without the per-view errors' prior), their reduced score ``g = A^T b_d - S_cb^T S^-1 b``
(``b_d = b + w^2 e`` the data's part of the right-hand side: the prior added ``-w^2
e``), ``E g g^T = sigma^2 Q + sum_c tau_c Q D_c Q``, ``Q = S_bb - S_cb^T S^-1 S_cb``.
On ``Q``'s range the likelihood-ratio test of ``tau = 0`` (two components on the
boundary) decides; where it finds them, the ``tau_c`` in (1) are the squares of the
stds' mean over the likelihood (:func:`mean_std_squared`), not its maximum. With one
orientation there is one session, whose error the camera's orientation and the points'
origin take up whole: nothing to measure, and nothing it biases beyond the camera's pose
in that session.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry.rotation import group_by_orientation
from .covariance import reduced_information
from .distributions import chi2_sf
from .robot_error import COMPONENTS
from .view_field import ABSORBED_SHARE, fit_components, log_likelihood

__all__ = ["SessionError", "session_error", "session_groups", "SESSION_ALPHA"]

#: Level of the likelihood-ratio test that takes the sessions' errors into the covariance.
SESSION_ALPHA = 0.05
#: Nodes per component of the grid :func:`mean_std_squared` averages over.
GRID_NODES = 31


@dataclass(frozen=True, eq=False)
class SessionError:
    """The robot error common to each session (module docstring).

    Attributes
    ----------
    tau : dict component -> float
        Variance of each coordinate of a session's error (rad^2, unit^2).
    tau_cov : dict component -> float
        Its variance (inverse Fisher information; 0 at 0).
    p_value : float
        Likelihood-ratio test of ``tau = 0``.
    n_sessions : int
        Sessions of two views or more.
    G : (p, 3 K n_sessions) float
        ``S^-1 S_cb``: the global parameters' response to each session error coordinate.
    """

    tau: dict
    tau_cov: dict
    p_value: float
    n_sessions: int
    G: np.ndarray

    @property
    def detected(self) -> bool:
        return bool(self.p_value < SESSION_ALPHA)

    def covariance(self) -> np.ndarray:
        """``sum_c tau_c G D_c G^T`` of eq. (1), unit px^2 like ``sigma^2 S^-1``."""
        w = np.repeat([self.tau[c] for c in self.tau], 3 * self.n_sessions)
        return (self.G * w) @ self.G.T


def session_groups(F: np.ndarray, tolerance_deg: float) -> list:
    """The index arrays of the sessions of two views or more: views whose flange
    rotations ``F (V, 3, 3)`` agree within ``tolerance_deg``, grouped as the pipeline
    groups them (:func:`~transcalib.geometry.rotation.group_by_orientation`)."""
    of = group_by_orientation(F, tolerance_deg)
    return [v for v in (np.flatnonzero(of == s) for s in range(of.max() + 1)) if len(v) >= 2]


def session_error(state, lay, data, red, Sinv: np.ndarray, sigma: float, tolerance_deg: float
                  ) -> SessionError | None:
    """The sessions' common errors at the solution ``state`` (module docstring), or None
    where they cannot be measured: one orientation or fewer than two sessions of two
    views.

    Parameters
    ----------
    red, Sinv : the reduced system at the solution (the priors in it) and ``S^-1`` (p, p).
    sigma : float
        The pixel noise per coordinate (px).
    tolerance_deg : float
        Views whose flange rotations agree within it form a session.
    """
    if state.F is None or not sigma > 0:
        return None
    groups = session_groups(state.F, tolerance_deg)
    if len(groups) < 2:
        return None
    comps = list(COMPONENTS)
    G, g, Q, scale = _session_score(*_with_every_component(state, lay, data, red), Sinv, red.rhs, groups)
    lam, vec = np.linalg.eigh(0.5 * (Q + Q.T))
    keep = lam > ABSORBED_SHARE * scale
    zero = {c: 0.0 for c in comps}
    if not keep.any():
        return SessionError(zero, dict(zero), 1.0, len(groups), G)
    P = vec[:, keep] * lam[keep]  # on Q's range: Cov(V^T g) = s2 diag(lam) + sum_c tau_c P^T D_c P
    of = np.repeat(np.arange(len(comps)), 3 * len(groups))
    parts = [P[of == c].T @ P[of == c] for c in range(len(comps))]
    z = vec[:, keep].T @ g
    tau, tau_cov, lr = fit_components(z, lam[keep], parts, sigma**2)
    p = float(chi2_sf(lr, 1) / 2 + (chi2_sf(lr, 2) / 4 if len(comps) == 2 else 0.0)) if lr > 0 else 1.0
    if p < SESSION_ALPHA:  # a few sessions' errors: the covariance averaged over the scales' likelihood
        tau = mean_std_squared(z, lam[keep], parts, sigma**2)
    return SessionError(dict(zip(comps, tau)), dict(zip(comps, np.diag(tau_cov))), p, len(groups), G)


def _with_every_component(state, lay, data, red) -> tuple:
    """``(state, layout, data, reduced system, index)`` with every robot error component's
    per-view columns (:data:`COMPONENTS`): a component the fit left out has no prior there,
    its columns the data's information alone; ``index`` (p,) places the fit's parameters
    among them. A session's error is measured whether or not its views' own errors were
    found: 0.02 deg per view is below what the data show, 0.1 deg shared by a session is
    not (with it measured only where the per-view component was in the fit, R_X's 95 %
    intervals covered 32-50 % of the trials without it, docs/uncertainty.md §7.2)."""
    if lay.robot == COMPONENTS:
        return state, lay, data, red, np.arange(lay.size)
    every = replace(lay, robot=COMPONENTS)
    index = np.arange(lay.size)
    for comp in lay.robot:
        index[lay.robot_columns(comp).ravel()] = every.robot_columns(comp).ravel()
    state = replace(state, E=np.zeros((lay.n_views, 6)) if state.E is None else state.E)
    return state, every, data, reduced_information(state, every, data), index


def _session_score(state, lay, data, red, index, Sinv, rhs, groups: list):
    """``(G, g, Q, scale)`` of the module docstring for the sessions ``groups``, from the
    reduced system ``red`` of the layout ``lay`` with every component's per-view columns
    (:func:`_with_every_component`), ``index`` placing the fit's parameters in it, and the
    fit's ``S^-1`` and right-hand side ``rhs``; ``scale`` the median information of a
    session error coordinate before the model takes its part."""
    A = np.zeros((lay.size, 3 * len(COMPONENTS) * len(groups)))  # a session's coordinate -> its views' columns
    S_d, b_d = red.S.copy(), red.rhs.copy()
    for c, comp in enumerate(COMPONENTS):
        cols = lay.robot_columns(comp)  # (V, 3)
        w2 = data.robot_weight[c] ** 2
        S_d[cols.ravel(), cols.ravel()] -= w2  # the data's information alone
        b_d[cols.ravel()] += w2 * state.E[:, 3 * c: 3 * c + 3].ravel()
        for s, views in enumerate(groups):
            for a in range(3):
                A[cols[views, a], (c * len(groups) + s) * 3 + a] = 1.0
    S_dA = S_d @ A
    S_cb = S_dA[index]  # the fit's parameters' rows
    S_bb = A.T @ S_dA
    G = Sinv @ S_cb
    g = A.T @ b_d - S_cb.T @ (Sinv @ rhs)
    return G, g, S_bb - S_cb.T @ G, max(float(np.median(np.diag(S_bb))), 1e-300)


def mean_std_squared(z: np.ndarray, lam: np.ndarray, parts: list, s2: float, n: int = GRID_NODES) -> np.ndarray:
    """``tau_k = E[s_k]^2``: the square of each std's mean over the likelihood of
    :func:`.view_field.fit_components`' model with a flat prior on each std ``s_k >= 0``,
    on a grid of ``n`` nodes per component up to three times the std each one alone
    would be fitted with. A few sessions give ``tau`` from a few numbers and the two
    components trade along a ridge. In 120 trials of the mostly-common case (docs/
    uncertainty.md §7.2, one-off) the likelihood's maximum gave R_X and t_X std ratios
    of 0.78-1.08 with 82-94 % coverage (scales 0.074 deg, 0.68 mm for 0.1, 1), the
    variance's mean ``E[s_k^2]`` 1.19-1.89 with 95-99 % (0.116 deg, 1.90 mm), this
    0.99-1.59 with 90-99 % (0.093 deg, 1.51 mm), the true scales 0.87-1.10 with 92-98 %."""
    alone = [fit_components(z, lam, [A], s2)[0][0] for A in parts]
    axes = [np.linspace(0.0, 3.0 * np.sqrt(max(a, 1e-300)), n) for a in alone]
    nodes = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    ll = np.array([log_likelihood(z, lam, parts, s2, s**2) for s in nodes])
    w = np.exp(ll - ll.max())
    return ((w[:, None] * nodes).sum(axis=0) / w.sum()) ** 2
