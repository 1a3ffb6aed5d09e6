"""Degeneracy first: what the span of the robot translations allows, before any estimation.

Only translation differences ``t_i = T_i - T_0`` enter the model, so the rank of
``[t_1 ... t_m]`` decides what the data can determine (paper §2.1 needs rank 3):

* **rank 3** — everything (K, R, the points) for a generic scene;
* **rank 2** (coplanar: an XY table, a 2-axis gantry) — the data determine only
  ``A' = K R [p1 p2]`` up to scale (``p1, p2`` an orthonormal basis of the plane): 5
  numbers. The rotation takes 3 of them, so at most **2 free intrinsics** remain
  determined: with zero skew, ``fx, fy`` once ``cx, cy`` are known, or ``cx, cy`` once
  ``fx, fy`` are known, or ``f, cy`` with square pixels and known ``cx``. With the
  principal point free (4 intrinsics) the Fisher information is singular (2 directions:
  ``fx, fy, cx, cy`` with the rotation). The missing robot direction is the plane normal
  ``n = p1 x p2``. Special orientations lose more, whatever is known: a camera looking
  along ``n`` (image plane parallel to the motion plane: ``f`` trades against depth) and,
  with ``fx, fy`` both free, a camera tilted about one of its image axes (one
  constraint instead of two; the planar-calibration degeneracy of Sturm & Maybank 1999);
* **rank 1** (collinear) — never enough: even with K known the rotation about the line
  of motion is free.

:func:`explain_span` answers, for the problem posed (known parameters, square pixels,
distortion model), from the rank of the Fisher information of a *generic* configuration
with the user's translations (a camera tilted obliquely to the plane, points spread
over the image): it raises :class:`DegenerateError` naming what is undetermined, the
missing robot direction(s) and what would help, or returns a :class:`Diagnostic` saying
what can still be estimated. :func:`identifiability_hint` turns a list of undetermined
parameter names into that advice (for :func:`covariance.check_identifiable`).
"""

from __future__ import annotations

import numpy as np

from ..errors import DegenerateError, Diagnostic
from ..geometry.camera import project
from ..geometry.rotation import rotvec_to_matrix
from ..types import INTRINSIC_NAMES, RefineOptions
from ..validate import SPAN_RTOL, translation_singular_values
from .covariance import check_identifiable, reduced_information
from .layout import Layout, State
from .observations import build_data

__all__ = ["translation_rank", "translation_basis", "explain_span", "identifiability_hint"]

#: Generic camera tilt used by :func:`explain_span` (rotation vector, radians): oblique to
#: the plane and to both image axes, so that no special orientation is hit.
_GENERIC_TILT = np.array([0.45, 0.30, 0.15])
#: Fixing the principal point on the command line.
_PP_HOW = ("fix the principal point: fix={'cx': ..., 'cy': ...} (command line: --fix cx=..,cy=.. or "
           "--fix principal-point=centre)")


def translation_rank(T, tol: float = SPAN_RTOL) -> int:
    """Dimension (0-3) of the span of the relative translations ``T_i - T_0``.

    Parameters
    ----------
    T : (n_views, 3) float
        Robot translations.
    tol : float
        Singular values below ``tol * s_max`` count as zero (as
        :func:`transcalib.validate.check_translations_span`).
    """
    s = translation_singular_values(np.asarray(T, dtype=float))
    if s[0] == 0:
        return 0
    return int(np.sum(s > tol * s[0]))


def translation_basis(T) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal robot-axes basis ordered by how much the robot moved along it.

    Returns
    -------
    P : (3, 3) float
        Columns ``p1, p2, p3``: right singular vectors of ``T_i - T_mean`` (descending),
        ``p1`` signed so that its largest component is positive, ``p3 = p1 x p2`` with its
        largest component positive (``p2`` signed for that), so ``P`` is a rotation. With
        coplanar translations ``p3`` is the plane normal (+z for an XY table); with
        collinear ones ``p1`` is the line.
    s : (3,) float
        Singular values of ``T_i - T_0``, descending.
    """
    T = np.asarray(T, dtype=float)
    _, _, Vt = np.linalg.svd(T - T.mean(axis=0), full_matrices=True)
    P = Vt.T.copy()
    for k in range(2):
        P[:, k] *= np.sign(P[np.argmax(np.abs(P[:, k])), k])
    P[:, 2] = np.cross(P[:, 0], P[:, 1])
    if P[np.argmax(np.abs(P[:, 2])), 2] < 0:  # canonical normal (+z for an XY table): flip p2
        P[:, 1:] = -P[:, 1:]
    return P, translation_singular_values(T)


def format_direction(v: np.ndarray) -> str:
    """``(0, 0, 1)``-style text of a unit vector in robot axes (3 decimals)."""
    v = np.where(np.abs(v) < 5e-4, 0.0, v)
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"


def explain_span(T, fix=None, square_pixels: bool = False, unit: str = "units", *,
                 estimate_skew: bool = False, distortion: str = "none", tol: float = SPAN_RTOL) -> Diagnostic | None:
    """Say, before any estimation, what the span of the translations allows.

    Parameters
    ----------
    T : (n_views, 3) float
        Robot translations (``unit``).
    fix : mapping of str to float, optional
        Known parameters (names as :class:`transcalib.RefineOptions`); only which are
        known matters here.
    square_pixels : bool
        ``fx = fy``.
    unit : str
        Name of the length unit (messages).
    estimate_skew : bool
        The skew is a free parameter (default: fixed).
    distortion : str
        Distortion model whose free coefficients count as unknowns.
    tol : float
        Relative singular value below which a direction counts as missing
        (:func:`translation_rank`); :data:`transcalib.validate.COPLANAR_RTOL` (what
        ``calibrate`` uses) treats an XY table whose measured z jitters by robot noise as
        coplanar.

    Returns
    -------
    Diagnostic or None
        None for translations spanning 3-D. For coplanar translations with enough
        known parameters, code ``translations_coplanar_known_params``: the missing
        direction and what is estimated.

    Raises
    ------
    DegenerateError
        The posed problem is not identifiable: no motion, collinear translations
        (names the two missing directions), or coplanar translations without enough
        known parameters (names the undetermined parameters, the missing direction and
        what would determine them).
    """
    T = np.asarray(T, dtype=float)
    fix = dict(fix or {})
    rank = translation_rank(T, tol)
    P, s = translation_basis(T)
    if rank == 3:
        return None
    if rank == 0:
        raise DegenerateError("the robot did not move: all translations are equal, so nothing can be estimated. "
                              "Move the robot along three independent directions (x, y and z).")
    if rank == 1:
        raise DegenerateError(
            f"the robot translations are collinear (all along {format_direction(P[:, 0])} in robot axes): the "
            f"directions {format_direction(P[:, 1])} and {format_direction(P[:, 2])} are missing. Even with K "
            "known the rotation about the line of motion is undetermined. Move the robot also along "
            f"{format_direction(P[:, 1])} and {format_direction(P[:, 2])} (e.g. along x, y and z).")
    T_plane = T.mean(axis=0) + (T - T.mean(axis=0)) @ P[:, :2] @ P[:, :2].T  # out-of-plane jitter dropped
    red, names = _generic_information(T_plane, P, s, fix, square_pixels, estimate_skew, distortion)
    normal = format_direction(P[:, 2])
    head = (f"the robot translations are coplanar (singular values {', '.join(f'{v:.3g}' for v in s)} {unit}): "
            f"the robot direction {normal} (the plane normal, robot axes) is missing. ")
    try:
        check_identifiable(red.S, names, identifiability_hint(_without_rotation(names), T_plane), red.U_diag)
    except DegenerateError as exc:
        raise DegenerateError(head + "With the parameters posed, " + str(exc)) from None
    free = [nm for nm in names if nm in INTRINSIC_NAMES + ("f",)] + ["R"]
    focal = [nm for nm in free if nm in ("f", "fx", "fy")]
    caveat = ""
    if focal:
        caveat = (f", unless the camera looks straight along {normal}"
                  + (" or is tilted about one of its image axes" if len(focal) == 2 else "")
                  + f" (then {' and '.join(focal)} are undetermined and the refinement says so)")
    return Diagnostic(
        "translations_coplanar_known_params",
        head + f"With the known parameters ({', '.join(sorted(fix)) or 'none'}"
        f"{', square pixels' if square_pixels else ''}) the data still determine {', '.join(free)} and the "
        f"points{caveat}. A move along {normal} would make every parameter observable.")


def _without_rotation(names) -> list:
    """``names`` less the camera rotation ``rx, ry, rz`` (always free)."""
    return [nm for nm in names if nm not in ("rx", "ry", "rz")]


def _generic_information(T, P, s, fix, square_pixels, estimate_skew, distortion):
    """Reduced Fisher information (a :class:`Reduced`) and parameter names of a generic configuration
    with the translations ``T``: camera tilted by ``_GENERIC_TILT`` from the plane normal,
    25 points spread over +-0.4 f pixels at 5 times the largest translation extent."""
    f0 = float(fix.get("fx", fix.get("fy", 1000.0)))
    intr = np.array([fix.get("fx", f0), fix.get("fy", f0), fix.get("cx", 0.0), fix.get("cy", 0.0),
                     fix.get("skew", 0.0)], dtype=float)
    K = np.array([[intr[0], intr[4], intr[2]], [0.0, intr[1], intr[3]], [0.0, 0.0, 1.0]])
    R = rotvec_to_matrix(_GENERIC_TILT) @ P.T  # R p3 is tilted from the optical axis
    g = np.random.default_rng(0)
    n = 25
    half = 0.4 * min(intr[0], intr[1])  # +-22 degrees of field of view
    pix = np.column_stack([g.uniform(-half, half, n) + intr[2], g.uniform(-half, half, n) + intr[3], np.ones(n)])
    depth = 5.0 * max(s[0], 1e-12) * g.uniform(0.8, 1.2, n)
    X = (np.linalg.solve(K, pix.T) * depth).T @ R + T.mean(axis=0)
    uv = project(K, R, X, T)
    n_views = T.shape[0]
    lay = Layout.from_options(RefineOptions(distortion=distortion, fix=fix, estimate_skew=estimate_skew,
                                            square_pixels=square_pixels), n_views)
    state = State(intr, np.zeros(5), R, np.tile(np.eye(3), (n_views, 1, 1)), T.copy(), X)
    data = build_data(uv, np.ones((n_views, n), bool), np.arange(n), T, np.zeros(n_views))
    return reduced_information(state, lay, data), lay.names()


def identifiability_hint(names, T=None, unit: str = "units") -> str:
    """The motion or knowledge that would determine the parameters ``names``.

    Parameters
    ----------
    names : sequence of str
        Undetermined (or free) parameter names as in ``Calibration.param_names``
        (``fx, fy, f, cx, cy, skew, k1, ..., rx, ry, rz, view{i}_*, T{i}_*``).
    T : (n_views, 3) float, optional
        The translations: with a rank below 3 the advice names the missing robot
        direction(s).
    unit : str
        Length unit (messages).

    Returns
    -------
    str
        One or more sentences, for :func:`transcalib.estimate.covariance.check_identifiable`.
    """
    names = set(names)
    rank, P = 3, np.eye(3)
    if T is not None:
        rank = translation_rank(T)
        P = translation_basis(T)[0]
    out = []
    if rank == 2:
        normal = format_direction(P[:, 2])
        if names & {"skew"}:
            out.append(f"With coplanar translations the skew must be known: fix it at 0 (do not estimate it), "
                       f"or move the robot also along {normal}.")
        elif names & {"cx", "cy"}:
            out.append(f"With coplanar translations {_PP_HOW}, or move the robot also along {normal}.")
        elif names & {"fx", "fy", "f"}:
            out.append(f"The camera looks (nearly) along the plane normal {normal} or is tilted about an image "
                       "axis: assume square pixels (--square-pixels), fix a focal length, tilt the camera "
                       f"obliquely to the plane, or move the robot also along {normal}.")
        elif names & {"rx", "ry", "rz"}:
            out.append(f"Move the robot also along {normal}.")
    elif rank < 2:
        out.append("The translations are collinear: move the robot along three independent directions.")
    if names & {"k1", "k2", "p1", "p2", "k3"}:
        out.append("Use a simpler distortion model (e.g. radial1), fix known coefficients, or track points "
                   "nearer the image corners.")
    if names & {"skew"} and rank != 2:
        out.append("Fix the skew at 0 (modern sensors have none).")
    if any(nm.startswith("view") or (nm.startswith("T") and "_" in nm) for nm in names):
        out.append("Per-view rotations or translations need more points per view and a spread of depths.")
    if not out:
        out.append("Track more points spread over the image and over depth, use more views and longer "
                   "translations, or fix known parameters.")
    return " ".join(out)
