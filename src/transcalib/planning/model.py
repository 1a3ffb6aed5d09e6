"""The planner's scene model: what the options of ``transcalib plan`` say about the scene.

Before any image exists the planner needs a scene to predict from. :class:`PlanOptions`
holds the approximate camera (image size, focal length, pixel noise, distortion), the
scene (working distance ``D``, depth range ``R``, number of points ``N``), the camera's
orientation in the robot frame (``view_direction``) and the robot's precision. The scene
model (issue 12): ``N`` points spread uniformly over the image of the camera placed at the
centre of the reachable box, at depths uniform in ``[D - R/2, D + R/2]`` along its optical
axis, principal point at the image centre, ``fx = fy = F``, zero skew.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..errors import InputError
from ..geometry.camera import DIST_MODELS, K_from_params, project
from ..synth.simulate import Scene

__all__ = ["PlanOptions", "CRITERIA", "view_rotation", "scene_points", "design_scene", "check_box", "options_from"]

#: Design criteria: which predicted variances the planner minimises (their mean).
CRITERIA = {"focal": ("fx", "fy"), "intrinsics": ("fx", "fy", "cx", "cy")}

_AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class PlanOptions:
    """Approximate camera, scene and robot that a plan is made for.

    Attributes
    ----------
    image_size : (int, int)
        Image width and height (px).
    focal_px : float
        Approximate focal length ``F`` (px): ``fx = fy = F``.
    distance : float
        Working distance ``D`` to the middle of the scene, along the optical axis
        (robot units).
    depth_range : float
        Depth extent ``R`` of the scene (robot units): depths uniform in ``[D - R/2, D + R/2]``.
    n_points : int
        Number of tracked points ``N`` expected.
    noise_px : float
        Pixel noise standard deviation per coordinate.
    view_direction : str or (3,) float
        Optical axis in the robot frame: ``"-z"``, ``"+x"``, ... or a vector.
    robot_noise : float
        Robot precision: standard deviation of each measured translation coordinate (robot
        units); 0 = exact. Views ``i >= 1`` are then noisy measurements (as
        :func:`transcalib.simulate.observe` draws them and :func:`transcalib.crlb` bounds them).
    robot_sigma_deg : float
        Per-axis std of each view's orientation error (degrees); 0 = exact. Above 0 every
        view's pose error (this rotation and a position error of std ``robot_noise``) is in
        the prediction as the calibration estimates it (:mod:`transcalib.estimate.robot_error`).
    distortion : {"none", "radial1", "radial2", "opencv5"}
        Distortion model the calibration will estimate (its coefficients get a prediction).
    dist : tuple of float
        Assumed true distortion coefficients (OpenCV order), default zero.
    criterion : {"focal", "intrinsics"}
        What the planner minimises: the mean predicted variance of ``fx, fy``
        (``"focal"``, default) or of ``fx, fy, cx, cy``.
    min_visible : float
        Each planned view must see at least this fraction of the points (0..1).
    margin_px : float
        Points closer than this to the image border count as not seen.
    min_separation : float, optional
        Smallest distance between two planned views (robot units); default 5 % of the
        box's largest side.
    """

    image_size: tuple = (1280, 1024)
    focal_px: float = 1000.0
    distance: float = 1000.0
    depth_range: float = 0.0
    n_points: int = 100
    noise_px: float = 0.5
    view_direction: object = "-z"
    robot_noise: float = 0.0
    robot_sigma_deg: float = 0.0
    distortion: str = "none"
    dist: tuple = ()
    criterion: str = "focal"
    min_visible: float = 0.5
    margin_px: float = 0.0
    min_separation: float | None = None

    def __post_init__(self):
        try:
            w, h = (int(s) for s in self.image_size)
        except (TypeError, ValueError):
            raise InputError(f"image_size must be (width, height) in pixels, got {self.image_size!r}") from None
        if w < 2 or h < 2:
            raise InputError(f"image_size must be at least 2 x 2 pixels, got {self.image_size!r}")
        object.__setattr__(self, "image_size", (w, h))
        _positive("focal_px", self.focal_px)
        _positive("distance", self.distance)
        _positive("noise_px", self.noise_px)
        _nonneg("robot_noise", self.robot_noise)
        _nonneg("robot_sigma_deg", self.robot_sigma_deg)
        _nonneg("margin_px", self.margin_px)
        if self.min_separation is not None:
            _nonneg("min_separation", self.min_separation)
        if not (0.0 <= self.depth_range < 2.0 * self.distance):
            raise InputError(f"depth_range must be in [0, 2 * distance) = [0, {2 * self.distance:g}), "
                             f"got {self.depth_range!r}")
        if isinstance(self.n_points, bool) or int(self.n_points) != self.n_points or self.n_points < 2:
            raise InputError(f"n_points must be an integer >= 2, got {self.n_points!r}")
        if self.distortion not in DIST_MODELS:
            raise InputError(f"distortion must be one of {', '.join(DIST_MODELS)}, got {self.distortion!r}")
        if np.asarray(self.dist, float).size not in (0, 1, 2, 4, 5):
            raise InputError(f"dist must have 0, 1, 2, 4 or 5 coefficients (OpenCV order), got {self.dist!r}")
        object.__setattr__(self, "dist", tuple(float(d) for d in np.asarray(self.dist, float).ravel()))
        if self.criterion not in CRITERIA:
            raise InputError(f"criterion must be one of {', '.join(CRITERIA)}, got {self.criterion!r}")
        if not (0.0 <= self.min_visible <= 1.0):
            raise InputError(f"min_visible must be a fraction in [0, 1], got {self.min_visible!r}")
        view_rotation(self.view_direction)  # validates

    @property
    def K(self) -> np.ndarray:
        """(3, 3) assumed intrinsics: ``fx = fy = F``, principal point at the image centre."""
        w, h = self.image_size
        return K_from_params(self.focal_px, self.focal_px, (w - 1) / 2.0, (h - 1) / 2.0)

    @property
    def R(self) -> np.ndarray:
        """(3, 3) assumed rotation robot -> camera (:func:`view_rotation`)."""
        return view_rotation(self.view_direction)


def options_from(options: PlanOptions | None, kwargs: dict) -> PlanOptions:
    """``options`` or a :class:`PlanOptions` built from keyword arguments (a misspelt one fails)."""
    if options is not None and kwargs:
        raise InputError(f"give either options= or keyword options, not both (got {sorted(kwargs)})")
    if options is not None:
        if not isinstance(options, PlanOptions):
            raise InputError(f"options must be a PlanOptions, got {type(options).__name__}")
        return options
    known = {f.name for f in fields(PlanOptions)}
    unknown = sorted(set(kwargs) - known)
    if unknown:
        raise InputError(f"unknown plan option(s) {', '.join(unknown)}; expected some of {', '.join(sorted(known))}")
    return PlanOptions(**kwargs)


def view_rotation(view_direction) -> np.ndarray:
    """Rotation robot -> camera whose optical axis (camera z) points along ``view_direction``.

    Parameters
    ----------
    view_direction : str or (3,) float
        ``"-z"``, ``"+z"``, ``"x"``, ... or a vector in the robot frame.

    Returns
    -------
    (3, 3) float
        Rows are the camera axes in robot coordinates: ``z_c = d / |d|``; ``x_c`` is the
        robot x axis made orthogonal to ``z_c`` (the robot y axis if ``d`` is nearly
        along x); ``y_c = z_c x x_c`` (right-handed, ``det = +1``). For ``"-z"``:
        ``diag(1, -1, -1)`` (image x along robot x, image y along robot -y).
    """
    if isinstance(view_direction, str):
        s = view_direction.strip().lower()
        if len(s) in (1, 2) and s[-1] in _AXES and (len(s) == 1 or s[0] in "+-"):
            d = np.zeros(3)
            d[_AXES[s[-1]]] = -1.0 if s[0] == "-" else 1.0
        else:
            try:
                d = np.array([float(v) for v in s.split(",")])
            except ValueError:
                d = np.zeros(0)
    else:
        d = np.asarray(view_direction, dtype=float).ravel()
    if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
        raise InputError(f"view_direction must be an axis such as '-z' or '+x', or a non-zero vector 'a,b,c', "
                         f"got {view_direction!r}")
    z = d / np.linalg.norm(d)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = ref - (ref @ z) * z
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])


def check_box(box) -> np.ndarray:
    """``box`` as a (3, 2) array of ``[min, max]`` per robot axis (from 6 numbers ``xmin, xmax, ...``)."""
    b = np.asarray(box, dtype=float)
    if b.size != 6 or not np.all(np.isfinite(b)):
        raise InputError(f"box must be 6 finite numbers xmin,xmax,ymin,ymax,zmin,zmax, got {box!r}")
    b = b.reshape(3, 2)
    if np.any(b[:, 1] < b[:, 0]):
        raise InputError(f"box must have min <= max on every axis (xmin,xmax,ymin,ymax,zmin,zmax), got {box!r}")
    return b


def scene_points(options: PlanOptions, centre, rng=0) -> np.ndarray:
    """The model's scene points seen from the camera at ``centre``.

    Parameters
    ----------
    options : PlanOptions
    centre : (3,) float
        Camera centre (robot frame), normally the centre of the box.
    rng : seed or Generator
        Draws the pixels ``u ~ U(0, W-1)``, ``v ~ U(0, H-1)`` and depths ``z ~ U(D - R/2, D + R/2)``.

    Returns
    -------
    (n_points, 3) float
        ``X_j = centre + R^T z_j K^-1 [u_j, v_j, 1]^T`` (robot frame).
    """
    rng = np.random.default_rng(rng)
    w, h = options.image_size
    n = int(options.n_points)
    uv = np.column_stack([rng.uniform(0.0, w - 1.0, n), rng.uniform(0.0, h - 1.0, n)])
    z = options.distance + options.depth_range * rng.uniform(-0.5, 0.5, n)
    rays = np.column_stack([uv, np.ones(n)]) @ np.linalg.inv(options.K).T
    return np.asarray(centre, float) + (rays * z[:, None]) @ options.R


def visible(options: PlanOptions, X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(n_views, n_points) bool: in front of the camera and inside the image (less the margin)."""
    xc = (X[None, :, :] - T[:, None, :]) @ options.R.T
    uv = project(options.K, options.R, X, T, options.dist)
    w, h = options.image_size
    m = options.margin_px
    u, v = uv[..., 0], uv[..., 1]
    return ((xc[..., 2] > 0) & (u >= -0.5 + m) & (u <= w - 0.5 - m) & (v >= -0.5 + m) & (v <= h - 0.5 - m))


def design_scene(options: PlanOptions, X: np.ndarray, T, rng=None) -> Scene:
    """A :class:`~transcalib.simulate.Scene` of the model for translations ``T`` (n_views, 3).

    Observations outside the image (:func:`visible`) are NaN, as
    :func:`transcalib.simulate.observe` marks them; ``rng`` draws the pixel and position
    noise of ``options`` (None: exact observations, noise levels still recorded for the
    CRLB; the orientation error ``robot_sigma_deg`` is recorded, not drawn).
    """
    T = np.asarray(T, dtype=float)
    uv_true = project(options.K, options.R, X, T, options.dist)
    seen = visible(options, X, T)
    T_meas = T.copy()
    uv = uv_true.copy()
    if rng is not None:
        rng = np.random.default_rng(rng)
        uv = uv + rng.normal(0.0, options.noise_px, uv.shape)
        if options.robot_noise > 0:
            T_meas[1:] += rng.normal(0.0, options.robot_noise, T[1:].shape)
    uv[~seen] = np.nan
    return Scene(K=options.K, R=options.R, dist=np.asarray(options.dist, float), T_true=T, X=X, T=T_meas, uv=uv,
                 uv_true=uv_true, image_size=options.image_size, noise_px=float(options.noise_px),
                 robot_noise=float(options.robot_noise), unit="units", meta={"preset": "plan"},
                 robot_sigma_deg=float(options.robot_sigma_deg))


def _positive(name, value):
    if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value > 0):
        raise InputError(f"{name} must be a positive number, got {value!r}")


def _nonneg(name, value):
    if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value >= 0):
        raise InputError(f"{name} must be a number >= 0, got {value!r}")
