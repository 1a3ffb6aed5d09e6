"""The human-readable and the ``--json`` summary of a calibration (``calibrate``, ``show``)."""

from __future__ import annotations

import numpy as np

from ..estimate.variance_components import GATE_ALPHA
from ..io.ids import truth_index

__all__ = ["summary_text", "summary_json", "point_errors", "uncertainty_lines"]


def _fmt_param(cal, name: str, value: float) -> str:
    std = cal.std.get(name)
    pm = f" ± {std:<9.3g}" if std is not None and np.isfinite(std) else " " * 12
    return f"{name:>5} = {value:12.4f}{pm}"


def point_errors(cal, truth: dict | None, point_ids) -> np.ndarray | None:
    """``|X - X_true|`` per point when the ids of simulated tracks index the true points."""
    if truth is None or "points" not in truth:
        return None
    Xt = np.asarray(truth["points"], float)
    idx = truth_index(point_ids, len(Xt))
    return None if idx is None else np.linalg.norm(cal.X - Xt[idx], axis=1)


def _counts(cal, uv=None) -> tuple[int, int]:
    """(points seen in >= 2 views, inliers among them): a point seen once is not an outlier.
    Without the observations ``uv``, "seen" means "has a residual"."""
    seen = np.isfinite((cal.residuals_px if uv is None else uv)[..., 0]).sum(axis=0) >= 2
    inl = np.asarray(cal.inliers, bool) if cal.inliers is not None else np.isfinite(cal.X[:, 0])
    return int(seen.sum()), int(np.sum(inl & seen))


def prediction_lines(loo: dict | None) -> list[str]:
    """The leave-one-view-out prediction error beside the covariance's prediction."""
    if not loo or loo.get("rms_px") is None:
        return []
    worst = max(loo["per_view"], key=lambda p: p["rms_px"])
    return [f"Views predicted from the others: RMS {loo['rms_px']:.4f} px (the covariance predicts "
            f"{loo['predicted_rms_px']:.4f} px), median {loo['median_px']:.4f} px, max {loo['max_px']:.4g} px over "
            f"{loo['n_points']} observations; worst view {worst['view']}: {worst['rms_px']:.4g} px (predicted "
            f"{worst['predicted_rms_px']:.4g} px)"]


def summary_text(cal, unit: str, truth: dict | None = None, point_ids=None, uv=None) -> str:
    """Parameters with standard deviations, rotation, RMS, inliers, truth errors, warnings."""
    K = cal.K
    values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "skew": K[0, 1]}
    Kt = None if truth is None else np.asarray(truth["K"], float)
    true_vals = None if Kt is None else {"fx": Kt[0, 0], "fy": Kt[1, 1], "cx": Kt[0, 2], "cy": Kt[1, 2],
                                         "skew": Kt[0, 1]}
    stages = " → ".join(cal.stats.stages)
    lines = [f"transcalib: {cal.n_points} points in {cal.n_views} views ({stages})", "", "Intrinsics [px]:"]
    for name, v in values.items():
        if name == "skew" and "skew" not in cal.std and v == 0:
            continue
        line = "  " + _fmt_param(cal, name, v)
        if true_vals is not None:
            line += f" truth {true_vals[name]:12.4f}   error {v - true_vals[name]:+.4f}"
        lines.append(line)
    if cal.dist.size:
        from ..geometry.camera import DIST_MODELS

        lines.append(f"Distortion ({cal.dist_model}, OpenCV order):")
        for name, v in zip(DIST_MODELS[cal.dist_model], cal.dist):
            lines.append("  " + _fmt_param(cal, name, v))
    frame = "robot" if cal.hand_eye is None else {"eye-in-hand": "flange", "eye-to-hand": "robot base"}[cal.hand_eye.setup]
    lines.append(f"Rotation R ({frame} → camera):")
    lines += ["  [" + "  ".join(f"{x:+.6f}" for x in row) + "]" for row in cal.R]
    if "rx" in cal.std:
        lines.append("  std of rotation [deg]: " + ", ".join(f"{k} {cal.std[k]:.3g}" for k in ("rx", "ry", "rz")))
    if truth is not None and "R" in truth:
        from ..geometry.rotation import rotation_angle_deg

        lines.append(f"  angle to truth: {rotation_angle_deg(cal.R @ np.asarray(truth['R']).T):.4f} deg")
    n_rec = int(np.isfinite(cal.X[:, 0]).sum())
    lines.append(f"Reprojection RMS: {cal.rms_px:.4f} px; {n_rec} points reconstructed [{unit}]")
    lines += robot_error_lines(cal, unit)
    lines += uncertainty_lines(cal, unit)
    if cal.inliers is not None:
        tracked, inl = _counts(cal, uv)
        lines.append(f"Inliers: {inl} of {tracked} points seen in 2 or more views")
    lines += prediction_lines(cal.info.get("leave_one_view_out"))
    err = point_errors(cal, truth, point_ids)
    if err is not None and np.isfinite(err).any():
        lines.append(f"Point error vs truth: median {np.nanmedian(err):.4g} {unit}, max {np.nanmax(err):.4g} {unit}")
    if cal.diagnostics:
        lines.append("Warnings:")
        lines += [f"  - {d}" for d in cal.diagnostics]
    else:
        lines.append("No warnings.")
    return "\n".join(line.rstrip() for line in lines)


def robot_error_lines(cal, unit: str) -> list:
    """The robot's pose error in a few lines: the scales with their std (or why none), the
    views with the largest errors; [] when the calibration did not model it."""
    re = cal.robot_error
    if re is None:
        return []
    parts = []
    for what, s, sd, src, u in (("rotation", re.sigma_rot_deg, re.sigma_rot_std_deg, re.source[0], "deg"),
                                ("position", re.sigma_pos, re.sigma_pos_std, re.source[1], unit)):
        if src == "estimated":
            parts.append(f"{what} {s:.3g} ± {sd:.2g} {u}")
        elif src == "given":
            parts.append(f"{what} {s:.3g} {u} (given)")
        else:
            k = 0 if what == "rotation" else 1
            p = re.p_values[k]
            if src == "misfit":
                parts.append(f"{what} left out as a misfit (score p = {p:.2g}, "
                             f"fitted scale p = {re.consistency_p[k]:.2g})")
            elif np.isfinite(p) and p < GATE_ALPHA:  # found at zero, its scale fell back to zero in the fit
                parts.append(f"{what} none (score p = {p:.2g}, but the fitted scale fell to zero)")
            else:
                parts.append(f"{what} none" + (f" (p = {p:.2f})" if np.isfinite(p) else f" ({src})"))
    lines = ["Robot pose error per view (std per axis): " + ", ".join(parts)]
    if re.active:
        rot, pos = np.linalg.norm(re.rot_deg, axis=1), np.linalg.norm(re.pos, axis=1)
        worst = np.argsort(-(rot / max(re.sigma_rot_deg, 1e-300) + pos / max(re.sigma_pos, 1e-300)))[:3]
        lines.append("  largest: " + "; ".join(f"view {i} {rot[i]:.3g} deg, {pos[i]:.3g} {unit}" for i in worst)
                     + " (the uncertainties above include the robot error)")
    return lines


#: Parameters whose sandwich / model std ratio the summary shows.
_RATIO_NAMES = ("fx", "fy", "cx", "cy", "rx", "ry", "rz")


def uncertainty_lines(cal, unit: str = "units") -> list:
    """Which std the summary shows (model-based or sandwich per parameter) and the
    sandwich / model std ratios; [] without :attr:`Calibration.uncertainty`."""
    u = cal.uncertainty
    if u is None:
        return []
    names = [k for k in _RATIO_NAMES if k in u.std_model and u.std_model[k] > 0 and np.isfinite(u.std_robust[k])]
    if not names:  # no sandwich (a point alone determines some parameter combination)
        return ["Uncertainty: std model-based (too few points per parameter for the sandwich check of the noise "
                "model)"] + _view_field_lines(u.view_field) + _session_error_lines(u.session_error, unit)
    ratios = ", ".join(f"{k} {u.std_robust[k] / u.std_model[k]:.2f}" for k in names)
    robust = [k for k, v in u.reported.items() if v == "robust" and not k.startswith("robot")]
    which = ("model-based" if not robust else "sandwich for " + ", ".join(robust) + ", model-based for the rest")
    return [f"Uncertainty: std {which}; sandwich / model std: {ratios} (misfit ratio {u.misfit:.2f})"] \
        + _view_field_lines(u.view_field) + _session_error_lines(u.session_error, unit)


def _view_field_lines(vf) -> list:
    """One line on the views' error fields: found and in the std, or not found."""
    if vf is None:
        return []
    if not vf.included:
        return [f"Per-view error field: not found (p = {vf.p_value:.2f})"]
    return [f"Per-view error field: {vf.rms_px:.4f} ± {vf.rms_std_px:.4f} px RMS (p = {vf.p_value:.1e}), "
            "its effect included in the model-based std"]


def _session_error_lines(se, unit: str) -> list:
    """One line on the robot error common to each session: found and in the std, or not."""
    if se is None:
        return []
    if not se.included:
        return [f"Robot error common to each session: not found (p = {se.p_value:.2f}, {se.n_sessions} sessions)"]
    return [f"Robot error common to each session: rotation {se.sigma_rot_deg:.3g} deg, position {se.sigma_pos:.3g} "
            f"{unit} per axis (p = {se.p_value:.1e}, {se.n_sessions} sessions), its effect included in the "
            "std (model-based or sandwich)"]


def summary_json(cal, unit: str, truth: dict | None = None, point_ids=None, uv=None) -> dict:
    """The machine-readable summary printed by ``--json``."""
    tracked, inl = _counts(cal, uv)
    out = {
        "n_views": cal.n_views, "n_points": cal.n_points, "n_points_tracked": tracked,
        "n_inliers": None if cal.inliers is None else inl,
        "n_points_reconstructed": int(np.isfinite(cal.X[:, 0]).sum()), "unit": unit,
        "image_size": None if cal.image_size is None else list(cal.image_size),
        "K": cal.K, "dist_model": cal.dist_model, "dist": cal.dist, "dist_opencv": cal.dist_opencv,
        "R_cam_world": cal.R, "rms_px": cal.rms_px, "sigma_px": cal.sigma_px,
        "std": {k: v for k, v in cal.std.items() if not k.startswith("robot")},
        "robot_error": _robot_error_json(cal.robot_error),
        "uncertainty": _uncertainty_json(cal.uncertainty),
        "stages": list(cal.stats.stages),
        "diagnostics": [{"code": getattr(d, "code", ""), "message": str(d)} for d in cal.diagnostics],
        "timings_s": dict(cal.stats.timings_s),
        "leave_one_view_out": cal.info.get("leave_one_view_out"),
    }
    if truth is not None:
        Kt = np.asarray(truth["K"], float)
        out["truth_errors"] = {"K": cal.K - Kt}
        err = point_errors(cal, truth, point_ids)
        if err is not None and np.isfinite(err).any():
            out["truth_errors"].update(point_median=float(np.nanmedian(err)), point_max=float(np.nanmax(err)))
    return out


def _robot_error_json(re) -> dict | None:
    """The robot's pose error for ``--json``: scales, their std and source, each view's error."""
    if re is None:
        return None
    return {"sigma_rot_deg": re.sigma_rot_deg, "sigma_rot_std_deg": re.sigma_rot_std_deg, "sigma_pos": re.sigma_pos,
            "sigma_pos_std": re.sigma_pos_std, "source": {"rot": re.source[0], "pos": re.source[1]},
            "p_values": {"rot": re.p_values[0], "pos": re.p_values[1]},
            "consistency_p": {"rot": re.consistency_p[0], "pos": re.consistency_p[1]},
            "score_scales": {"rot_deg": re.score_scales[0], "pos": re.score_scales[1]}, "view_rot_deg": re.rot_deg,
            "view_pos": re.pos, "view_rot_std_deg": re.rot_std_deg, "view_pos_std": re.pos_std}


def _uncertainty_json(u) -> dict | None:
    """Both std (robot error columns left out, as in ``std``) and which one ``std`` is."""
    if u is None:
        return None
    keep = lambda m: {k: v for k, v in m.items() if not k.startswith("robot")}  # noqa: E731
    return {"std_model": keep(u.std_model), "std_robust": keep(u.std_robust), "reported": keep(u.reported),
            "p_value": keep(u.p_value), "dof": keep(u.dof), "misfit": u.misfit, "n_clusters": u.n_clusters,
            "view_field": None if u.view_field is None else {
                "rms_px": u.view_field.rms_px, "rms_std_px": u.view_field.rms_std_px,
                "tau_px2": u.view_field.tau_px2, "p_value": u.view_field.p_value, "included": u.view_field.included},
            "session_error": None if u.session_error is None else vars(u.session_error).copy()}
