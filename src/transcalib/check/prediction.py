"""How well the calibration predicts a view it did not see: the leave-one-view-out error.

For each view ``v`` the calibration is refitted without ``v``'s observations: from the
full solution (a few standard deviations from the one without ``v``, where the cost is
nearly quadratic) :data:`LOO_STEPS` Gauss-Newton steps of every parameter and point on the
other views' observations. The points ``X_j^(-v)`` of that fit are projected through
``v``'s own (recorded) pose, and ``e_vj = uv_vj - pi(X_j^(-v); v)`` is compared with what
the covariance predicts for it::

    E |e_vj|^2 = sigma^2 (2 + tr(G_j S^-1 G_j^T) + tr(J_X V_j^-1 J_X^T)),
    G_j = J_g - J_X Y_j^T

with ``J_g`` (2, p) and ``J_X`` (2, 3) the Jacobians of the prediction with respect to the
global parameters and the point, and ``S``, ``V_j^-1``, ``Y_j = W_j V_j^-1`` the reduced
system of the fit without ``v`` (:class:`transcalib.estimate.schur.Reduced`): the
observation's own noise, the calibration's and the point's uncertainty (their
correlation included). Points seen in fewer than two other views cannot be predicted and
do not count; nor do those whose predicted error exceeds ``MAX_PREDICTED_SIGMAS`` sigmas
(``n_undetermined``). The error is reported in the definition of the calibration's ``rms_px``
(the root mean square of the observations' error norms), per view and overall, beside
the predicted value; ``benchmarks/bench_prediction.py`` checks the two against each
other over 100 scenes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import DegenerateError
from ..estimate.bundle import BundleProblem, predict_view
from ..estimate.covariance import check_identifiable, linearise, reduced_information
from ..estimate.layout import Layout, State
from ..estimate.observations import build_data
from ..estimate.solvers import gauss_newton
from ..types import Calibration
from .rotation import _refinement

__all__ = ["leave_one_view_out", "prediction_variance", "LOO_MIN_VIEWS", "LOO_STEPS"]

#: The prediction error is computed for data sets with at least this many views.
LOO_MIN_VIEWS = 5
#: Gauss-Newton steps from the full solution to the one without the view.
LOO_STEPS = 2
#: At most this many tracks (a fixed random subset of the calibration's) and views (evenly
#: spread) are used: the refits without each view cost a reduced system each, and a
#: sample shows how well the covariance predicts as well as all would (30 views x 5000
#: tracks took 22 s, three quarters of the calibration, before the cap; 0.5 s after).
LOO_MAX_POINTS = 1000
LOO_MAX_VIEWS = 12
#: Observations whose predicted error (RMS) exceeds this many pixel-noise sigmas are
#: left out (counted): points the other views barely determine (nearly parallel rays),
#: whose one error would dominate a view's mean.
MAX_PREDICTED_SIGMAS = 5.0


def leave_one_view_out(uv, T, calibration: Calibration, *, view_ids=None, steps: int = LOO_STEPS) -> dict:
    """Each view predicted by the calibration of the others (module docstring); at most
    :data:`LOO_MAX_VIEWS` views (evenly spread) on at most :data:`LOO_MAX_POINTS` tracks.

    Parameters
    ----------
    uv : (n_views, n_points, 2) float
        The observations the calibration was fitted on (outside its inliers left out).
    T : (n_views, 3) float
        Flange positions as the calibration's model uses them.
    calibration : Calibration
        The refined (maximum-likelihood) calibration.
    view_ids : sequence of str, optional
        The user's view ids (default the indices).
    steps : int
        Gauss-Newton steps of each refit.

    Returns
    -------
    dict
        ``rms_px``, ``median_px``, ``max_px`` (of the error norms), ``predicted_rms_px``,
        ``ratio`` (``rms_px / predicted_rms_px``), ``n_points`` (observations predicted),
        ``per_view`` (list of ``{view, rms_px, median_px, predicted_rms_px, n_points}``),
        ``skipped`` (views whose refit is not determined without them),
        ``n_undetermined`` (observations left out: predicted beyond ``MAX_PREDICTED_SIGMAS``).
    """
    uv, calibration = _sample(np.asarray(uv, float), calibration)
    lin = linearise(uv, T, calibration, _refinement(calibration), polish=0)
    idx = _used_points(uv, calibration)
    sigma = float(calibration.sigma_px or lin.sigma_px)
    per_view, errors, expected, skipped, n_out = [], [], [], [], 0
    names = list(range(uv.shape[0])) if view_ids is None else list(view_ids)
    for v in np.unique(np.linspace(0, uv.shape[0] - 1, min(uv.shape[0], LOO_MAX_VIEWS)).round().astype(int)):
        try:
            e2, ex2 = _predict_view(uv, T, lin.state, lin.layout, lin.data.t_weight, idx, v, steps)
        except (DegenerateError, np.linalg.LinAlgError):
            skipped.append(names[v])
            continue
        ok = ex2 <= MAX_PREDICTED_SIGMAS**2
        n_out += int(np.sum(~ok))
        if not ok.any():
            skipped.append(names[v])
            continue
        e2, ex2 = e2[ok], sigma**2 * ex2[ok]
        errors.append(e2)
        expected.append(ex2)
        per_view.append({"view": names[v], "rms_px": float(np.sqrt(e2.mean())),
                         "median_px": float(np.median(np.sqrt(e2))),
                         "predicted_rms_px": float(np.sqrt(ex2.mean())), "n_points": int(len(e2))})
    return {**_summary(errors, expected, per_view, skipped), "n_undetermined": n_out}


def _sample(uv: np.ndarray, calibration: Calibration):
    """``uv`` and ``calibration`` restricted to at most :data:`LOO_MAX_POINTS` of the
    tracks it uses (a fixed random subset: the result is repeatable)."""
    idx = _used_points(uv, calibration)
    if len(idx) <= LOO_MAX_POINTS:
        return uv, calibration
    keep = np.sort(np.random.default_rng(0).choice(idx, LOO_MAX_POINTS, replace=False))
    inliers = None if calibration.inliers is None else np.asarray(calibration.inliers)[keep]
    return uv[:, keep], replace(calibration, X=np.asarray(calibration.X)[keep], inliers=inliers,
                                residuals_px=np.asarray(calibration.residuals_px)[:, keep])


def _summary(errors, expected, per_view, skipped) -> dict:
    """The overall figures of the per-view errors ``|e|^2`` and their expectations."""
    if not errors:
        return {"rms_px": None, "median_px": None, "max_px": None, "predicted_rms_px": None, "ratio": None,
                "n_points": 0, "per_view": [], "skipped": skipped}
    e2, ex2 = np.concatenate(errors), np.concatenate(expected)
    rms, pred = float(np.sqrt(e2.mean())), float(np.sqrt(ex2.mean()))
    return {"rms_px": rms, "median_px": float(np.median(np.sqrt(e2))), "max_px": float(np.sqrt(e2.max())),
            "predicted_rms_px": pred, "ratio": rms / pred, "n_points": int(len(e2)), "per_view": per_view,
            "skipped": skipped}


def _used_points(uv, calibration: Calibration) -> np.ndarray:
    """The points the calibration's problem uses (as :func:`linearise` selects them)."""
    use = np.isfinite(np.asarray(calibration.X, float)).all(axis=1) & (np.isfinite(uv[..., 0]).sum(axis=0) >= 2)
    if calibration.inliers is not None:
        use &= np.asarray(calibration.inliers, bool)
    return np.flatnonzero(use)


def _predict_view(uv, T, state: State, lay: Layout, t_weight, idx, v: int, steps: int):
    """``(|e|^2 (m,), E|e|^2 / sigma^2 (m,))`` of view ``v``'s observations predicted by
    the fit without it."""
    seen = np.isfinite(uv[..., 0])
    others = seen.copy()
    others[v] = False
    keep = others[:, idx].sum(axis=0) >= 2
    idx_v = idx[keep]
    data = build_data(uv, others, idx_v, T, t_weight)
    start = State(state.intr.copy(), state.dist5.copy(), state.R.copy(), state.Q.copy(), state.T.copy(),
                  state.X[keep].copy(), state.F, state.t.copy())
    fit = gauss_newton(BundleProblem(lay, data), start, steps=steps).state
    red = reduced_information(fit, lay, data)
    evals, evecs = check_identifiable(red.S, lay.names(), scale=red.U_diag)
    pts = np.flatnonzero(seen[v, idx_v])
    if not len(pts):
        return np.zeros(0), np.zeros(0)
    pred, z, Jg, JX = predict_view(fit, lay, v, pts)
    e = uv[v, idx_v[pts]].T - pred
    return np.sum(e * e, axis=0), 2.0 + prediction_variance(red, (evecs / evals) @ evecs.T, lay.view_columns(v),
                                                            Jg, JX, pts)


def prediction_variance(red, Sinv: np.ndarray, cols, Jg: np.ndarray, JX: np.ndarray, pts) -> np.ndarray:
    """``tr(G_j S^-1 G_j^T) + tr(J_X V_j^-1 J_X^T)`` of each predicted observation (unit
    pixel noise; module docstring), ``(m,)``.

    Parameters
    ----------
    red : Reduced
        The reduced system of the fit that predicts (its ``Y``, ``Vinv``).
    Sinv : (p, p) float
        ``S^-1``.
    cols : (q,) int
        The global parameters the predicting view depends on.
    Jg : (q, 2, m) float
    JX : (3, 2, m) float
        Jacobians of the predictions (:func:`transcalib.estimate.bundle.predict_view`).
    pts : (m,) int
        The predicted points' indices in ``red``.
    """
    C = Sinv[np.ix_(cols, cols)]
    Y = red.Y[cols][:, :, pts]  # (q, 3, m)
    G = Jg - np.einsum("akn,can->ckn", JX, Y)  # (q, 2, m)
    var_g = np.einsum("ckn,cd,dkn->n", G, C, G)
    return var_g + np.einsum("akn,abn,bkn->n", JX, red.Vinv[:, :, pts], JX)
