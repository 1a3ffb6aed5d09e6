"""Checks of the robot's pose error (:mod:`transcalib.estimate.robot_error`): whether the
data could separate it from the camera, and whether it limits the calibration.

- ``robot_error_inseparable``: a scale estimated from the data is determined to worse
  than ``INSEPARABLE_REL_STD`` (its redundancy is below ~4.5 degrees of freedom: the
  per-view errors trade with the intrinsics, the hand-eye pose or the other component),
  or one orientation, where a flange rotation error moves the image much as a position
  error does. The message says which motion separates them and that datasheet values
  can be given instead.
- ``robot_error_misfit``: the score test found a per-view pose error, but its fitted scale
  is far above what the score showed (the per-view errors absorbed a model misfit
  together with a large move of the camera); that component was left out, so the poses
  are taken as exact for it and the uncertainty does not include it.
- ``robot_error_dominates``: the robot error, not the pixel noise, sets the uncertainty of
  fx or cx: their std with the errors marginalised is more than ``DOMINATES_FACTOR``
  times the std with the errors held at their estimates.
"""

from __future__ import annotations

import numpy as np

from ..errors import Diagnostic

__all__ = ["check_robot_error", "INSEPARABLE_REL_STD", "DOMINATES_FACTOR"]

#: Relative std of an estimated scale above which it counts as not separated (a variance
#: estimate with r degrees of freedom has relative std 1 / sqrt(2 r): r < 4.5).
INSEPARABLE_REL_STD = 1.0 / 3.0
#: Std inflation of fx or cx by the robot error above which it is said to dominate.
DOMINATES_FACTOR = 2.0

_MOTION = ("views at more flange orientations (the wrist turned >= 15 deg about two different axes, several "
           "views each) separate a rotation error from a position error and both from the camera; more views "
           "determine the scales better. Or give the robot's datasheet values (--robot-sigma-deg and "
           "--robot-sigma; RefineOptions.robot_sigma_deg / robot_sigma_pos)")


def check_robot_error(calibration, unit: str = "units") -> list:
    """The robot error checks (module docstring) of a refined calibration; [] without one."""
    re = getattr(calibration, "robot_error", None)
    if re is None:
        return []
    out = _misfit(re)
    if not re.active:
        return out
    vague = []
    for name, s, sd, src, u in (("sigma_rot", re.sigma_rot_deg, re.sigma_rot_std_deg, re.source[0], "deg"),
                                ("sigma_pos", re.sigma_pos, re.sigma_pos_std, re.source[1], unit)):
        if src == "estimated" and sd > INSEPARABLE_REL_STD * s:
            vague.append(f"{name} = {s:.3g} +- {sd:.2g} {u}")
    one_orientation = _one_orientation(calibration.flange_rotations)
    if vague:
        out.append(Diagnostic("robot_error_inseparable", "the data barely separate the robot's pose error from the "
                              f"camera: {', '.join(vague)} per view. " + _MOTION))
    elif one_orientation:
        out.append(Diagnostic("robot_error_inseparable", "one flange orientation: a rotation error of the flange "
                              "moves the image much as a position error does, so the scales found "
                              f"(sigma_rot {re.sigma_rot_deg:.3g} deg, sigma_pos {re.sigma_pos:.3g} {unit}) fold the "
                              "two together (sigma_pos is the camera centre's, the rotation's lever arm included). "
                              + _MOTION))
    inflation = _std_inflation(calibration)
    big = {k: v for k, v in inflation.items() if v > DOMINATES_FACTOR}
    if big:
        out.append(Diagnostic("robot_error_dominates", "the robot's pose error, not the pixel noise, limits "
                              + ", ".join(f"{k} (std x{v:.1f} by it)" for k, v in big.items())
                              + ": more views average it down (each view's error is its own), as does a "
                              "robot that repeats its poses better"))
    return out


def _misfit(re) -> list:
    """``robot_error_misfit`` for the components left out as a model misfit, else []."""
    names = [f"{what} (score p = {p:.2g}, its scale about {score:.2g} {unit}; fitted scale p = {c:.2g})"
             for what, src, p, c, score, unit in zip(("rotation", "position"), re.source, re.p_values,
                                                     re.consistency_p, re.score_scales, ("deg", "units"))
             if src == "misfit"]
    if not names:
        return []
    return [Diagnostic("robot_error_misfit", "the residuals show a per-view pose error (" + ", ".join(names)
                       + "), but fitting it moved the camera far beyond what that evidence supports: the per-view "
                       "errors were absorbing a model misfit (lens distortion, tracking errors), so the poses are "
                       "taken as exact for it and the uncertainty does not include it. Check the lens model and "
                       "the tracks, or give the robot's datasheet values (--robot-sigma-deg, --robot-sigma)")]


def _one_orientation(R, tolerance_deg: float = 1.0) -> bool:
    """No flange rotations, or all within ``tolerance_deg`` of the first."""
    if R is None:
        return True
    R = np.asarray(R, float)
    cos = (np.einsum("ab,vab->v", R[0], R) - 1.0) / 2.0
    return bool(np.all(cos >= np.cos(np.radians(tolerance_deg))))


def _std_inflation(calibration) -> dict:
    """``std(p) / std(p | robot errors)`` of fx and cx: the std with the per-view errors
    marginalised over the std they would have with the errors known."""
    names = list(calibration.param_names)
    robot = [k for k, n in enumerate(names) if n.startswith("robot")]
    cov = np.asarray(calibration.cov, float)
    if not robot or cov.size == 0:
        return {}
    out = {}
    C_rr = cov[np.ix_(robot, robot)]
    for p in ("fx", "f", "cx"):
        if p not in names:
            continue
        k = names.index(p)
        c = cov[k, robot]
        cond = cov[k, k] - c @ np.linalg.lstsq(C_rr, c, rcond=1e-12)[0]
        out["fx" if p == "f" else p] = float(np.sqrt(cov[k, k] / max(cond, 1e-300)))
    return out
