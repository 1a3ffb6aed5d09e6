"""The parameters of the one bundle adjuster: which are free (the layout) and their values (the state).

The global parameters ``g`` are laid out as: the free intrinsics (``fix``, square pixels,
skew), the free distortion coefficients, the camera rotation ``R`` (local update ``R <-
exp([dw]x) R``), the free directions of the offset ``t`` (the hand-eye translation), then a
rotation ``w_i`` per view that has one (the rotation test) and a translation ``T_i`` per
view that is a measurement (robot noise). The points follow, 3 each.
:meth:`Layout.from_options` is the one place where options become a layout, and
:meth:`Layout.residual_dof` the one count of the residual degrees of freedom.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..geometry.camera import DIST_MODELS, DIST_NAMES
from ..geometry.rotation import rotvec_to_matrix
from ..types import INTRINSIC_NAMES, RefineOptions


def intrinsic_basis(fix, estimate_skew: bool, square_pixels: bool) -> tuple[np.ndarray, tuple]:
    """Free intrinsic parameters as a basis ``E (5, q)``: ``d(fx, fy, cx, cy, s) = E dp``.

    ``fix`` holds some of fx, fy, cx, cy, skew at known values; the skew is fixed unless
    ``estimate_skew``; with ``square_pixels`` one focal length ``f`` moves fx and fy
    together. Returns ``E`` and the names of the free parameters.
    """
    columns, names = [], []
    if square_pixels:
        if "fx" not in fix and "fy" not in fix:
            columns.append([1.0, 1.0, 0, 0, 0])
            names.append("f")
    else:
        for k in (0, 1):
            if INTRINSIC_NAMES[k] not in fix:
                columns.append(np.eye(5)[k])
                names.append(INTRINSIC_NAMES[k])
    for k in (2, 3):
        if INTRINSIC_NAMES[k] not in fix:
            columns.append(np.eye(5)[k])
            names.append(INTRINSIC_NAMES[k])
    if estimate_skew and "skew" not in fix:
        columns.append(np.eye(5)[4])
        names.append("skew")
    E = np.array(columns, dtype=float).T.reshape(5, len(columns))
    return E, tuple(names)


def dist_indices(model: str, fix=()) -> tuple:
    """Free coefficients of distortion ``model`` (indices into OpenCV's five), less ``fix``."""
    if model not in DIST_MODELS:
        raise InputError(f"distortion must be one of {', '.join(DIST_MODELS)}, got {model!r}")
    return tuple(DIST_NAMES.index(k) for k in DIST_MODELS[model] if k not in fix)


def rotation_views(spec, n_views: int) -> tuple:
    """Views with a rotation parameter: True -> 1..n_views-1, False -> none, or the listed
    views (at least one view must stay unrotated, as the reference)."""
    if spec is True:
        return tuple(range(1, n_views))
    if spec is False or spec is None:
        return ()
    views = tuple(sorted({int(v) for v in spec}))
    if any(v < 0 or v >= n_views for v in views) or len(views) >= n_views:
        raise InputError(f"estimate_view_rotations={spec!r}: view indices must be in 0..{n_views - 1} and at "
                         "least one view must stay unrotated (the reference)")
    return views


def robot_sigma(sigma_T, n_views: int) -> np.ndarray:
    """``sigma_T`` (None, one value or one per view) as ``(n_views,)``, 0 where exact."""
    if sigma_T is None:
        return np.zeros(n_views)
    s = np.asarray(sigma_T, dtype=float)
    if s.shape not in ((), (n_views,)):
        raise InputError(f"sigma_T must be one number or one per view ({n_views}), got {s.size} values")
    return np.broadcast_to(s, (n_views,)).copy()


@dataclass
class Layout:
    """Where each global parameter sits in the vector ``g`` solved for by the Schur step.

    Parameters
    ----------
    n_views : int
    intr_basis : (5, q) float
        Free intrinsics (:func:`intrinsic_basis`).
    intr_names : tuple of str
    dist_free : tuple of int
        Free distortion coefficients, indices into OpenCV's five.
    rot_views : tuple of int
        Views with a rotation ``Q_i``.
    T_views : tuple of int
        Views whose translation is a parameter.
    t_basis : (3, k) float or None
        Free directions of the offset ``t`` (the hand-eye translation): ``dt = B dp``;
        None (or k = 0): ``t`` is fixed. Directions the data cannot determine (a rotation
        axis shared by every session) are left out, so ``t`` keeps its value there.
    """

    n_views: int
    intr_basis: np.ndarray
    intr_names: tuple
    dist_free: tuple = ()
    rot_views: tuple = ()
    T_views: tuple = ()
    t_basis: np.ndarray | None = None
    i_vrot: dict = field(init=False)
    i_T: dict = field(init=False)

    def __post_init__(self):
        self.n_intr = self.intr_basis.shape[1]
        self.i_dist = self.n_intr
        self.n_dist = len(self.dist_free)
        self.i_rot = self.i_dist + self.n_dist
        self.i_t = self.i_rot + 3
        self.n_t = 0 if self.t_basis is None else self.t_basis.shape[1]
        self.t_free = self.n_t > 0
        self.n_common = self.i_t + self.n_t
        start = self.n_common
        self.i_vrot, self.i_T = {}, {}
        for i in self.rot_views:
            self.i_vrot[int(i)] = start
            start += 3
        for i in self.T_views:
            self.i_T[int(i)] = start
            start += 3
        self.size = start

    @classmethod
    def from_options(cls, opts: RefineOptions, n_views: int, t_basis: np.ndarray | None = None) -> "Layout":
        """The layout a refinement with ``opts`` estimates: free intrinsics from ``fix``,
        ``estimate_skew`` and ``square_pixels``, the free coefficients of
        ``opts.distortion`` (a model, not ``"auto"``), a rotation per view of
        ``estimate_view_rotations``, a translation per view with ``sigma_T > 0``, and the
        offset's free directions ``t_basis`` (several orientations)."""
        E, names = intrinsic_basis(opts.fix, opts.estimate_skew, opts.square_pixels)
        return cls(n_views, E, names, dist_indices(opts.distortion, opts.fix),
                   rotation_views(opts.estimate_view_rotations, n_views),
                   tuple(int(i) for i in np.flatnonzero(robot_sigma(opts.sigma_T, n_views) > 0)), t_basis)

    @property
    def n_global_no_T(self) -> int:
        """Parameters other than the translations (these have priors)."""
        return self.size - 3 * len(self.i_T)

    def residual_dof(self, n_obs: int, n_points: int) -> int:
        """Residual degrees of freedom of ``n_obs`` observations (2 residuals each) of
        ``n_points`` points: ``2 n_obs - (parameters without priors) - 3 n_points`` (the
        translations with priors add as many residuals as parameters)."""
        return int(2 * n_obs - self.n_global_no_T - 3 * n_points)

    def view_columns(self, i: int) -> np.ndarray:
        """Global indices of the columns of view ``i``'s local Jacobian (common first)."""
        cols = list(range(self.n_common))
        if i in self.i_vrot:
            cols += range(self.i_vrot[i], self.i_vrot[i] + 3)
        if i in self.i_T:
            cols += range(self.i_T[i], self.i_T[i] + 3)
        return np.array(cols)

    def names(self) -> tuple:
        names = list(self.intr_names) + [DIST_NAMES[k] for k in self.dist_free] + ["rx", "ry", "rz"]
        names += ["t_x", "t_y", "t_z"][: self.n_t] if self.n_t == 3 else [f"t_{k}" for k in range(self.n_t)]
        for i in self.i_vrot:
            names += [f"view{i}_rx", f"view{i}_ry", f"view{i}_rz"]
        for i in self.i_T:
            names += [f"T{i}_x", f"T{i}_y", f"T{i}_z"]
        return tuple(names)

    def rotation_mask(self) -> np.ndarray:
        """(size,) bool: parameters that are rotation angles (reported in degrees)."""
        m = np.zeros(self.size, bool)
        m[self.i_rot: self.i_rot + 3] = True
        for s in self.i_vrot.values():
            m[s: s + 3] = True
        return m


@dataclass
class State:
    """Current estimate. ``X`` holds only the used points; ``F`` None means identity."""

    intr: np.ndarray  # (5,) fx, fy, cx, cy, skew
    dist5: np.ndarray  # (5,) k1, k2, p1, p2, k3
    R: np.ndarray  # (3, 3)
    Q: np.ndarray  # (n_views, 3, 3) model-violation rotations, identity by default
    T: np.ndarray  # (n_views, 3)
    X: np.ndarray  # (n_used, 3)
    F: np.ndarray | None = None  # (n_views, 3, 3) known per-view rotations (sessions)
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) offset (hand-eye)

    def copy(self) -> "State":
        return State(self.intr.copy(), self.dist5.copy(), self.R.copy(), self.Q.copy(), self.T.copy(),
                     self.X.copy(), self.F, self.t.copy())

    def moved(self, lay: Layout, dg: np.ndarray, dX: np.ndarray) -> "State":
        """The state moved by ``dg`` (global, ``lay``'s order) and ``dX (3, n)``."""
        new = self.copy()
        new.intr += lay.intr_basis @ dg[: lay.n_intr]
        new.dist5[list(lay.dist_free)] += dg[lay.i_dist: lay.i_rot]
        new.R = rotvec_to_matrix(dg[lay.i_rot: lay.i_rot + 3]) @ self.R
        if lay.t_free:
            new.t += lay.t_basis @ dg[lay.i_t: lay.i_t + lay.n_t]
        for i, s in lay.i_vrot.items():
            new.Q[i] = rotvec_to_matrix(dg[s: s + 3]) @ self.Q[i]
        for i, s in lay.i_T.items():
            new.T[i] += dg[s: s + 3]
        new.X += dX.T
        return new


@dataclass(frozen=True, eq=False)
class FlangeModel:
    """Known flange orientations of the views (the hand-eye model).

    The camera rotation of view ``i`` becomes ``R F_i`` and its centre ``T_i + F_i^T t``
    (``F_i = R_i^T``, ``R = R_X^T``, ``t = t_X``; :mod:`transcalib.estimate.bundle`).

    Attributes
    ----------
    F : (n_views, 3, 3) float
        World -> flange rotations ``R_i^T`` of the views.
    t0 : (3,) float
        Start of the offset ``t`` (robot units).
    t_basis : (3, k) float
        Directions of ``t`` the data determine (the others keep ``t0``'s component).
    """

    F: np.ndarray
    t0: np.ndarray
    t_basis: np.ndarray

    @classmethod
    def of(cls, calibration) -> "FlangeModel | None":
        """The model of a calibration with flange orientations (its rotations, offset and
        the offset's determined directions), or None for one without."""
        R_i = getattr(calibration, "flange_rotations", None)
        if R_i is None:
            return None
        he = calibration.hand_eye
        undetermined = np.zeros((3, 0)) if he is None else np.asarray(he.undetermined).reshape(3, -1)
        t0 = np.zeros(3) if he is None else np.asarray(he.t, dtype=float)
        return cls(np.transpose(R_i, (0, 2, 1)).copy(), t0.copy(), complement(undetermined))


def complement(U: np.ndarray) -> np.ndarray:
    """Orthonormal basis ``(3, 3 - k)`` of the directions orthogonal to the orthonormal
    columns ``U (3, k)``."""
    if U.shape[1] == 0:
        return np.eye(3)
    return np.linalg.svd(U, full_matrices=True)[0][:, U.shape[1]:]
