"""The camera model, written once: pinhole projection with OpenCV lens distortion.

Projection of scene point ``X_j`` seen from camera centre ``T_i`` (paper eq. 2 with
OpenCV's distortion model)::

    x_c = R (X_j - T_i)                        camera frame, z forward
    (x, y) = x_c[:2] / x_c[2]                  normalised image coordinates
    r^2 = x^2 + y^2,  rad = 1 + k1 r^2 + k2 r^4 + k3 r^6
    x' = x rad + 2 p1 x y + p2 (r^2 + 2 x^2)
    y' = y rad + p1 (r^2 + 2 y^2) + 2 p2 x y
    u = fx x' + s y' + cx,   v = fy y' + cy

:func:`distort` (with its Jacobian) and :func:`project_camera_frame` are the only
implementation of these formulas: the bundle adjuster, the diagnostics, the pipeline
and the renderer all call them. Coefficients follow OpenCV's order and meaning; padded to
five values (:attr:`Camera.dist5`) they go to ``cv2.undistort`` / ``cv2.projectPoints``
as they are (OpenCV has no skew: keep ``s = 0`` when mixing the two).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..errors import InputError

__all__ = ["camera_frame", "DIST_MODELS", "DIST_NAMES", "INTRINSIC_PARAMS", "pad_dist", "Camera", "undistort", "project_camera_frame",
           "project", "pixels_to_rays", "K_from_params"]

#: Distortion models: the OpenCV coefficients each one estimates (the others are 0).
DIST_MODELS = {"none": (), "radial1": ("k1",), "radial2": ("k1", "k2"), "opencv5": ("k1", "k2", "p1", "p2", "k3")}
#: OpenCV's order of the five coefficients.
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")
#: The intrinsic parameters a covariance names, as the entries of ``(fx, fy, cx, cy, skew)``
#: each one moves (``f``: one focal length for square pixels).
INTRINSIC_PARAMS = {"fx": (0,), "fy": (1,), "f": (0, 1), "cx": (2,), "cy": (3,), "skew": (4,)}


def dist_size(model: str) -> int:
    """Number of coefficients of distortion ``model`` (raises ``InputError`` if unknown)."""
    try:
        return len(DIST_MODELS[model])
    except KeyError:
        raise InputError(f"unknown distortion model {model!r}; expected one of {', '.join(DIST_MODELS)}") from None


def pad_dist(dist) -> np.ndarray:
    """Coefficients of any model (0, 1, 2, 4 or 5 values, OpenCV order) as OpenCV's five."""
    d = np.zeros(5)
    dist = np.asarray(dist, dtype=float).ravel()
    if dist.size not in (0, 1, 2, 4, 5):
        raise InputError(f"distortion must have 0, 1, 2, 4 or 5 coefficients (OpenCV order), got {dist.size}")
    d[: dist.size] = dist
    return d


class Distortion(NamedTuple):
    """Distorted normalised coordinates and, on request, their derivatives.

    ``dx``, ``dy`` are ``(d x'/dx, d x'/dy)`` and ``(d y'/dx, d y'/dy)`` (None without
    distortion: the identity); ``dk`` has one ``(d x'/dk, d y'/dk)`` pair per coefficient,
    in OpenCV order (5 pairs). All entries have the shape of the input coordinates.
    """

    xd: np.ndarray
    yd: np.ndarray
    dx: tuple | None = None
    dy: tuple | None = None
    dk: tuple | None = None


def distort(x: np.ndarray, y: np.ndarray, dist5: np.ndarray, *, jacobian: bool = False,
            coefficients=True) -> Distortion:
    """OpenCV distortion of normalised coordinates ``(x, y)`` (arrays of any one shape).

    Parameters
    ----------
    x, y : float arrays
        Undistorted normalised coordinates ``x_c / z_c``, ``y_c / z_c``.
    dist5 : (5,) float
        ``k1, k2, p1, p2, k3`` (:func:`pad_dist`).
    jacobian : bool
        Also return the derivatives with respect to ``x, y`` (None for the pinhole,
        where they are the identity) ...
    coefficients : bool or sequence of int
        ... and, with ``jacobian``, with respect to the coefficients: all five (True),
        none (False), or those listed (indices into OpenCV's five, in that order).

    Returns
    -------
    Distortion
        ``x', y'`` of the module docstring (and derivatives).
    """
    k1, k2, p1, p2, k3 = dist5
    pinhole = not np.any(dist5)
    which = () if not jacobian else range(5) if coefficients is True else tuple(coefficients or ())
    r2 = None if pinhole and not which else x * x + y * y
    tangential = bool(p1 or p2)  # terms left out when zero: no temporaries on the hot path
    xy = 2.0 * x * y if tangential or which else None
    radial = None
    if pinhole:
        xd, yd = x, y
    else:
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd, yd = x * radial, y * radial
        if tangential:
            xd = xd + p1 * xy + p2 * (r2 + 2.0 * x * x)
            yd = yd + p1 * (r2 + 2.0 * y * y) + p2 * xy
    if not jacobian:
        return Distortion(xd, yd)
    dx = dy = None
    if radial is not None:
        dR = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        a12 = xy * dR
        dx, dy = radial + 2.0 * x * x * dR, radial + 2.0 * y * y * dR
        if tangential:
            a12 = a12 + 2.0 * p1 * x + 2.0 * p2 * y
            dx, dy = dx + 2.0 * p1 * y + 6.0 * p2 * x, dy + 6.0 * p1 * y + 2.0 * p2 * x
        dx, dy = (dx, a12), (a12, dy)
    dk = tuple(_coefficient_derivative(k, x, y, r2, xy) for k in which) if which else None
    return Distortion(xd, yd, dx, dy, dk)


def _coefficient_derivative(k: int, x, y, r2, xy) -> tuple:
    """``(d x' / d c_k, d y' / d c_k)`` for OpenCV's coefficient ``k`` (0..4); ``xy = 2 x y``."""
    if k == 0:
        return x * r2, y * r2
    if k == 1:
        r4 = r2 * r2
        return x * r4, y * r4
    if k == 2:
        return xy, r2 + 2.0 * y * y
    if k == 3:
        return r2 + 2.0 * x * x, xy
    r6 = r2 * r2 * r2
    return x * r6, y * r6


def undistort(xy_d: np.ndarray, dist, iterations: int = 20) -> np.ndarray:
    """Invert :func:`distort`: for a radial model by Newton's method on the radius, else
    (and where that does not converge) by the fixed-point iteration of
    ``cv2.undistortPoints``; at most ``iterations`` steps, fewer once a step moves no
    point by more than 1e-15.

    Parameters
    ----------
    xy_d : (..., 2) float
        Distorted normalised coordinates.
    dist : (k,) float
        Distortion coefficients (any model, OpenCV order).

    Returns
    -------
    (..., 2) float
        Undistorted normalised coordinates.
    """
    d = pad_dist(dist)
    xy_d = np.asarray(xy_d, dtype=float)
    if not d.any():
        return xy_d.copy()
    k1, k2, p1, p2, k3 = d
    xd, yd = xy_d[..., 0], xy_d[..., 1]
    if not (p1 or p2):  # radial only: one equation in the radius, solved by Newton's method
        scale = _radial_undistortion(np.hypot(xd, yd), k1, k2, k3, iterations)
        if scale is not None:
            return np.stack([xd * scale, yd * scale], axis=-1)
    x, y = xd.copy(), yd.copy()
    for it in range(iterations):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        x_new, y_new = (xd - dx) / radial, (yd - dy) / radial
        converged = it % 4 == 3 and not np.any(np.abs(x_new - x) + np.abs(y_new - y) > 1e-15)  # NaN: not counted
        x, y = x_new, y_new
        if converged:
            break
    return np.stack([x, y], axis=-1)


def _radial_undistortion(rd: np.ndarray, k1: float, k2: float, k3: float, iterations: int):
    """``r / r_d`` for the radius ``r`` with ``r (1 + k1 r^2 + k2 r^4 + k3 r^6) = r_d``
    (Newton's method from ``r = r_d``; 1 where ``r_d = 0``), or None when some radius does
    not converge (beyond where the model folds back: the fixed-point iteration decides)."""
    r = rd.copy()
    for _ in range(iterations):
        s = r * r
        g = 1.0 + s * (k1 + s * (k2 + s * k3))
        slope = g + 2.0 * s * (k1 + s * (2.0 * k2 + 3.0 * k3 * s))  # d (r g) / dr
        with np.errstate(divide="ignore", invalid="ignore"):
            step = (r * g - rd) / slope
        r -= step
        if not np.any(np.abs(step) > 1e-15 * (1.0 + rd)):  # NaN inputs stay NaN and do not count
            break
    else:
        return None
    if np.any(~np.isfinite(r) & np.isfinite(rd)):
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rd > 0, r / rd, 1.0)


class Projection(NamedTuple):
    """Pixels of camera-frame points and, on request, their derivatives (points last).

    ``pred (2, ...)``; ``P (2, 3, ...)`` = d pixel / d x_c; ``xd``, ``yd`` the distorted
    normalised coordinates (d u / d fx = x', d u / d skew = y', d v / d fy = y');
    ``J_dist (k, 2, ...)`` = d pixel / d (the coefficients asked for: all five, k1, k2,
    p1, p2, k3, by default), or None when not asked for.
    """

    pred: np.ndarray
    P: np.ndarray | None = None
    xd: np.ndarray | None = None
    yd: np.ndarray | None = None
    J_dist: np.ndarray | None = None

    def intrinsic_jacobian(self, basis: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """d pixel / d (free intrinsics) ``(q, 2, ...)`` for a basis ``E (5, q)`` of
        ``(fx, fy, cx, cy, skew)`` increments (into ``out`` when given)."""
        out = np.empty((basis.shape[1], 2) + self.xd.shape) if out is None else out
        for p, (efx, efy, ecx, ecy, es) in enumerate(basis.T):
            _affine(out[p, 0], ((efx, self.xd), (es, self.yd)), ecx)
            _affine(out[p, 1], ((efy, self.yd),), ecy)
        return out


def _affine(out: np.ndarray, terms, const: float) -> None:
    """``out = sum(c * a for c, a in terms) + const`` in place, skipping zero terms (a
    basis column is mostly zeros and ones)."""
    out[...] = const
    for c, a in terms:
        if c == 1.0:
            out += a
        elif c:
            out += c * a


def project_camera_frame(intr: np.ndarray, dist5: np.ndarray, xc: np.ndarray, *, jacobian: bool = False,
                         valid: np.ndarray | None = None, dist_jacobian=True) -> Projection:
    """Pixels of points in the camera frame (module docstring), components first.

    Parameters
    ----------
    intr : (5,) float
        ``fx, fy, cx, cy, skew``.
    dist5 : (5,) float
        OpenCV coefficients.
    xc : (3, ...) float
        Camera-frame points (``z > 0`` in front of the camera).
    jacobian : bool
        Also return the derivatives (:class:`Projection`).
    valid : (...) bool, optional
        Points whose values matter; the others get depth 1 in the divisions (their
        results are finite and meaningless).
    dist_jacobian : bool or sequence of int
        With ``jacobian``: also the derivatives with respect to the coefficients (all
        five, or those listed: indices into OpenCV's five).

    Returns
    -------
    Projection
    """
    fx, fy, cx, cy, s = intr
    z = xc[2] if valid is None else np.where(valid, xc[2], 1.0)
    iz = 1.0 / z
    x, y = xc[0] * iz, xc[1] * iz
    d = distort(x, y, dist5, jacobian=jacobian, coefficients=dist_jacobian)
    pred = np.empty((2,) + np.shape(d.xd))
    np.multiply(fx, d.xd, out=pred[0])
    if s:
        pred[0] += s * d.yd
    pred[0] += cx
    np.multiply(fy, d.yd, out=pred[1])
    pred[1] += cy
    if not jacobian:
        return Projection(pred)
    # M = [[fx, s], [0, fy]] d(x', y')/d(x, y);  P = M [[1, 0, -x], [0, 1, -y]] / z
    if d.dx is None:  # pinhole: d(x', y')/d(x, y) = I
        m11, m12, m21, m22 = fx, s, 0.0, fy
    else:
        m11, m12 = fx * d.dx[0] + s * d.dy[0], fx * d.dx[1] + s * d.dy[1]
        m21, m22 = fy * d.dy[0], fy * d.dy[1]
    P = np.empty((2, 3) + x.shape)
    P[0, 0], P[0, 1], P[0, 2] = m11 * iz, m12 * iz, -(m11 * x + m12 * y) * iz
    P[1, 0], P[1, 1], P[1, 2] = m21 * iz, m22 * iz, -(m21 * x + m22 * y) * iz
    J_dist = None
    if d.dk:
        J_dist = np.stack([np.stack([fx * gx + s * gy if s else fx * gx, fy * gy]) for gx, gy in d.dk])
    return Projection(pred, P, d.xd, d.yd, J_dist)


def camera_frame(R: np.ndarray, X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Camera-frame coordinates ``R (X_j - T_i)`` of every point in every view, ``(3,
    n_views, n_points)``, as ``R X_j - R T_i`` (no (views, points, 3) temporary); ``R``
    is one rotation ``(3, 3)`` or one per view ``(n_views, 3, 3)``."""
    R = np.asarray(R)
    if R.ndim == 2:
        return (R @ X.T)[:, None, :] - (R @ T.T)[:, :, None]
    return np.einsum("vab,nb->avn", R, X) - np.einsum("vab,vb->av", R, T)[:, :, None]


def project(K: np.ndarray, R: np.ndarray, X: np.ndarray, T: np.ndarray, dist=()) -> np.ndarray:
    """Project scene points into every view: ``(n_views, n_points, 2)`` pixels.

    Parameters
    ----------
    K : (3, 3) float
    R : (3, 3) or (n_views, 3, 3) float
        Rotation world -> camera, for every view or per view.
    X : (n_points, 3) float
        Scene points, world frame.
    T : (n_views, 3) float
        Camera centres (translations).
    dist : (k,) float, optional
        OpenCV distortion coefficients.
    """
    xc = camera_frame(R, X, T)
    intr = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]])
    centre = xc[2] == 0  # a point at a camera's centre has no image: NaN
    pred = project_camera_frame(intr, pad_dist(dist), xc, valid=~centre).pred
    return np.moveaxis(np.where(centre, np.nan, pred), 0, -1)


def pixels_to_rays(K: np.ndarray, uv: np.ndarray, dist=()) -> np.ndarray:
    """Homogeneous normalised coordinates ``[x, y, 1]`` of pixels (undistorted).

    Parameters
    ----------
    K : (3, 3) float
    uv : (..., 2) float
    dist : (k,) float, optional

    Returns
    -------
    (..., 3) float
        ``K^-1 [u, v, 1]`` corrected for distortion: the camera-frame ray direction.
    """
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    y = (uv[..., 1] - cy) / fy
    x = (uv[..., 0] - cx - s * y) / fx
    xy = np.stack([x, y], axis=-1)
    if np.asarray(dist).size:
        xy = undistort(xy, dist)
    return np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)


def K_from_params(fx: float, fy: float, cx: float, cy: float, skew: float = 0.0) -> np.ndarray:
    """``[[fx, skew, cx], [0, fy, cy], [0, 0, 1]]``."""
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _frozen(a) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera: intrinsics, distortion, orientation in the robot frame.

    Attributes
    ----------
    K : (3, 3) float
        ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``, pixels; pixel (0, 0) is the centre of
        the top-left pixel (OpenCV).
    R : (3, 3) float
        Rotation world (robot) -> camera, det +1 (``R_cam_world``).
    dist : (k,) float
        Distortion coefficients of ``dist_model`` in OpenCV order.
    dist_model : {"none", "radial1", "radial2", "opencv5"}
    image_size : (width, height) or None
        Pixels, when known.

    >>> cam = Camera(K_from_params(800, 800, 320, 240), image_size=(640, 480))
    >>> cam.project([[0.0, 0.0, 1000.0]], [[0.0, 0.0, 0.0]]).round(3).tolist()
    [[[320.0, 240.0]]]
    """

    K: np.ndarray
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    dist: np.ndarray = field(default_factory=lambda: np.zeros(0))
    dist_model: str = "none"
    image_size: tuple | None = None

    def __post_init__(self):
        K, R = _frozen(self.K), _frozen(self.R)
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"Camera: K must be a finite 3x3 matrix with fx, fy > 0, got {K.tolist()}")
        if R.shape != (3, 3) or not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InputError(f"Camera: R must be a 3x3 rotation matrix (det +1), got {R.tolist()}")
        n = dist_size(self.dist_model)
        dist = _frozen(np.ravel(self.dist))
        if dist.size != n:
            raise InputError(f"Camera: distortion model {self.dist_model!r} has {n} coefficient(s) "
                             f"{DIST_MODELS[self.dist_model]}, got {dist.size}")
        size = None if self.image_size is None else tuple(int(v) for v in self.image_size)
        if size is not None and (len(size) != 2 or min(size) <= 0):
            raise InputError(f"Camera: image_size must be (width, height) > 0, got {self.image_size!r}")
        for name, value in (("K", K), ("R", R), ("dist", dist), ("image_size", size)):
            object.__setattr__(self, name, value)

    def __eq__(self, other) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (np.array_equal(self.K, other.K) and np.array_equal(self.R, other.R)
                and np.array_equal(self.dist, other.dist) and self.dist_model == other.dist_model
                and self.image_size == other.image_size)

    __hash__ = None

    @property
    def intrinsics(self) -> np.ndarray:
        """``fx, fy, cx, cy, skew`` (5,)."""
        K = self.K
        return np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]])

    @property
    def dist5(self) -> np.ndarray:
        """The five OpenCV coefficients ``k1, k2, p1, p2, k3`` (zeros beyond the model)."""
        out = np.zeros(5)
        out[[DIST_NAMES.index(k) for k in DIST_MODELS[self.dist_model]]] = self.dist
        return out

    def _camera_frame(self, X, T):
        X = np.asarray(X, dtype=float).reshape(-1, 3)
        T = np.zeros((1, 3)) if T is None else np.asarray(T, dtype=float).reshape(-1, 3)
        return camera_frame(self.R, X, T)  # (3, V, n)

    def project(self, X, T=None) -> np.ndarray:
        """Pixels ``(n_views, n_points, 2)`` of world points ``X (n_points, 3)`` seen from
        camera centres ``T (n_views, 3)`` (default: one view at the origin)."""
        xc = self._camera_frame(X, T)
        return np.moveaxis(project_camera_frame(self.intrinsics, self.dist5, xc).pred, 0, -1)

    def project_jacobian(self, X, T=None) -> tuple[np.ndarray, np.ndarray]:
        """Pixels ``(V, n, 2)`` and their derivative with respect to the points,
        ``d uv / d X`` ``(V, n, 2, 3)``."""
        xc = self._camera_frame(X, T)
        p = project_camera_frame(self.intrinsics, self.dist5, xc, jacobian=True)
        J = np.einsum("kc...,cd->...kd", p.P, self.R)
        return np.moveaxis(p.pred, 0, -1), J

    def pixels_to_rays(self, uv) -> np.ndarray:
        """Camera-frame ray directions ``[x, y, 1]`` (..., 3) of pixels ``uv (..., 2)``,
        corrected for distortion."""
        return pixels_to_rays(self.K, np.asarray(uv, dtype=float), self.dist)

    def unproject(self, uv) -> np.ndarray:
        """Unit ray directions in the **world** (robot) frame (..., 3) of pixels (..., 2):
        ``R^T [x, y, 1] / |.|``."""
        rays = self.pixels_to_rays(uv) @ self.R
        return rays / np.linalg.norm(rays, axis=-1, keepdims=True)

    def undistort_points(self, uv) -> np.ndarray:
        """Pixels (..., 2) the same camera without distortion would see: ``K [x, y, 1]``."""
        rays = self.pixels_to_rays(uv)
        return rays[..., :2] @ self.K[:2, :2].T + self.K[:2, 2]

    def undistort_image(self, image: np.ndarray) -> np.ndarray:
        """The image as the same camera without distortion would take it (``cv2.undistort``)."""
        import cv2

        return cv2.undistort(np.asarray(image), self.K, self.dist5)

    def to_opencv(self) -> tuple[np.ndarray, np.ndarray]:
        """``(camera_matrix (3, 3), dist_coeffs (5,))`` for OpenCV functions."""
        return np.array(self.K), self.dist5
