"""Synthetic scenes with exact ground truth, for tests, benchmarks and examples.

A :class:`Scene` holds the true camera (``K``, ``dist``), orientation ``R``, translations
and points, and the observations a user would have: noisy pixels ``uv`` (NaN where a
point is not seen) and noisy robot translations ``T``.

>>> from transcalib import simulate
>>> scene = simulate.paper_scene(noise_px=0.5, rng=0)
>>> scene.uv.shape, scene.T.shape
((4, 24, 2), (4, 3))
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.camera import K_from_params, project

__all__ = ["Scene", "paper_scene", "random_scene", "random_rotation", "observe"]


@dataclass(frozen=True, eq=False)
class Scene:
    """A synthetic scene and its observations.

    Attributes
    ----------
    K : (3, 3) float            true intrinsics
    R : (3, 3) float            true rotation world -> camera
    dist : (k,) float           true OpenCV distortion coefficients (may be empty)
    T_true : (n_views, 3) float true translations
    X : (n_points, 3) float     true scene points (world, relative to camera at T = 0)
    T : (n_views, 3) float      measured translations (``T_true`` + robot noise)
    uv : (n_views, n_points, 2) float
        Observed pixels (exact projection + pixel noise), NaN where not seen.
    uv_true : (n_views, n_points, 2) float
        Exact projections (no NaN).
    image_size : (width, height)
    noise_px, robot_noise : float
        Standard deviations used (pixels per coordinate; units per coordinate).
    robot_sigma_deg : float
        Per-axis std of each view's orientation error (degrees) that the bound
        (:func:`transcalib.crlb`'s ``scene_information``) models; 0: exact orientations.
    unit : str
        Length unit of ``T`` and ``X``.
    """

    K: np.ndarray
    R: np.ndarray
    dist: np.ndarray
    T_true: np.ndarray
    X: np.ndarray
    T: np.ndarray
    uv: np.ndarray
    uv_true: np.ndarray
    image_size: tuple[int, int]
    noise_px: float = 0.0
    robot_noise: float = 0.0
    unit: str = "mm"
    robot_sigma_deg: float = 0.0
    meta: dict = field(default_factory=dict)

    @property
    def n_views(self) -> int:
        return self.uv.shape[0]

    @property
    def n_points(self) -> int:
        return self.uv.shape[1]

    def truth_dict(self) -> dict:
        """Ground truth as plain JSON-able values (``truth.json``)."""
        return {
            "K": self.K.tolist(),
            "R": self.R.tolist(),
            "dist": np.asarray(self.dist).tolist(),
            "T_true": self.T_true.tolist(),
            "points": self.X.tolist(),
            "image_size": list(self.image_size),
            "noise_px": self.noise_px,
            "robot_noise": self.robot_noise,
            "units": self.unit,
        }


def random_rotation(rng) -> np.ndarray:
    """A uniformly random rotation matrix (3, 3), det +1."""
    return Rotation.random(random_state=np.random.default_rng(rng)).as_matrix()


def observe(
    scene: Scene,
    noise_px: float = 0.0,
    robot_noise: float = 0.0,
    missing: float = 0.0,
    rng=None,
) -> Scene:
    """New observations of the same true scene: pixel noise, robot noise, dropouts.

    Parameters
    ----------
    scene : Scene
    noise_px : float
        Standard deviation of Gaussian pixel noise per coordinate.
    robot_noise : float
        Standard deviation of Gaussian noise per translation coordinate (scene units).
        View 0's measured translation is kept exact (only differences matter).
    missing : float
        Probability that an observation is dropped; every point keeps at least 2 views
        and every view keeps at least 2 points.
    rng : seed or Generator
    """
    rng = np.random.default_rng(rng)
    n_views, n_points = scene.uv_true.shape[:2]
    uv = scene.uv_true + rng.normal(0.0, noise_px, scene.uv_true.shape) if noise_px > 0 else scene.uv_true.copy()
    uv[~_inside(scene.uv_true, scene.image_size)] = np.nan
    if missing > 0:
        drop = rng.random((n_views, n_points)) < missing
        seen = np.isfinite(uv[..., 0]) & ~drop
        # restore views for points left with fewer than 2, in random order
        short = np.flatnonzero(seen.sum(axis=0) < 2)
        for j in short:  # rare; vectorising this would obscure it
            candidates = np.flatnonzero(np.isfinite(scene.uv_true[:, j, 0]) & _inside(scene.uv_true[:, j], scene.image_size))
            seen[rng.permutation(candidates)[:2], j] = True
        uv[~seen] = np.nan
    T = scene.T_true.copy()
    if robot_noise > 0:
        T[1:] += rng.normal(0.0, robot_noise, T[1:].shape)
    return replace(scene, uv=uv, T=T, noise_px=float(noise_px), robot_noise=float(robot_noise))


def _inside(uv: np.ndarray, image_size) -> np.ndarray:
    w, h = image_size
    u, v = uv[..., 0], uv[..., 1]
    return (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)


def paper_scene(
    noise_px: float = 0.0,
    robot_noise: float = 0.0,
    rng=None,
    dist=(),
) -> Scene:
    """The paper's first experiment (§3), as closely as the text describes it.

    A Sony XC-75E camera (752 x 582 px) with a ~15 mm lens: ``fx = 1744``, ``fy = 1807``
    pixels, principal point slightly off centre. 24 points - the corners of six 30 mm
    black squares (3 x 2) on a plane about 0.5 m away, tilted by ~15 degrees. Four
    views: three translations of 40 mm spanning 3-D, with the camera oriented
    arbitrarily in the robot frame. Units: mm. Robot precision in the paper: 0.1 mm.

    Parameters
    ----------
    noise_px : float
        Pixel noise standard deviation.
    robot_noise : float
        Robot translation noise standard deviation (mm); the paper's robot: 0.1.
    rng : seed or Generator
    dist : (k,) float
        Optional lens distortion of the true camera.
    """
    K = K_from_params(1744.0, 1807.0, 381.0, 286.0)
    # Camera orientation in the robot frame: robot z up, camera looking down-forward.
    R = Rotation.from_euler("xyz", [-110.0, 4.0, 25.0], degrees=True).as_matrix()
    # Six squares of side 30 mm, centres 50 mm apart (3 columns x 2 rows): board frame.
    corners = np.array([[-15, -15], [15, -15], [15, 15], [-15, 15]], dtype=float)
    centres = np.array([[cx, cy] for cy in (-25.0, 25.0) for cx in (-50.0, 0.0, 50.0)])
    board = (centres[:, None, :] + corners[None, :, :]).reshape(-1, 2)
    board3 = np.column_stack([board, np.zeros(len(board))])
    tilt = Rotation.from_euler("xy", [15.0, -10.0], degrees=True).as_matrix()
    X_cam = board3 @ tilt.T + np.array([0.0, 0.0, 520.0])
    X = X_cam @ R  # R^T X_cam: world coordinates, camera centre at the origin
    T_true = np.array([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0], [0.0, 40.0, 0.0], [0.0, 0.0, -40.0]])
    T_true = T_true @ Rotation.from_euler("z", 20.0, degrees=True).as_matrix().T - [20.0, 20.0, 0.0]
    return _make_scene(K, R, np.asarray(dist, float), T_true, X, (752, 582), noise_px, robot_noise, 0.0, rng,
                       meta={"preset": "paper"})


def random_scene(
    n_points: int = 50,
    n_views: int = 4,
    *,
    planar: bool = False,
    noise_px: float = 0.0,
    robot_noise: float = 0.0,
    missing: float = 0.0,
    image_size: tuple[int, int] = (800, 600),
    distance: float = 1000.0,
    baseline: float = 0.2,
    depth_range: float = 0.5,
    dist=(),
    skew: float = 0.0,
    rng=None,
) -> Scene:
    """A random camera looking at random points, translated to random positions.

    Parameters
    ----------
    n_points, n_views : int
        Sizes (``n_views >= 4``).
    planar : bool
        Points on a random plane through the scene centre (tilted up to 45 degrees),
        otherwise in a box of depth ``depth_range * distance``.
    noise_px, robot_noise, missing : float
        See :func:`observe`.
    image_size : (width, height)
    distance : float
        Distance of the scene centre from the camera at ``T = 0`` (scene units, "mm").
    baseline : float
        Translation length relative to ``distance``: translations are random directions
        with lengths ``baseline * distance * U(0.5, 1)``, the first three orthogonalised
        so that they span 3-D well.
    depth_range : float
        Relative depth extent of a non-planar scene.
    dist : (k,) float
        True lens distortion.
    skew : float
        True skew (pixels).
    rng : seed or Generator

    Points are drawn so that they fall inside the image in the reference view; views
    where they leave the image observe NaN.
    """
    rng = np.random.default_rng(rng)
    w, h = image_size
    fx = rng.uniform(0.6, 1.6) * w
    fy = fx * rng.uniform(0.9, 1.1)
    cx = w / 2 - 0.5 + rng.uniform(-0.08, 0.08) * w
    cy = h / 2 - 0.5 + rng.uniform(-0.08, 0.08) * h
    K = K_from_params(fx, fy, cx, cy, skew)
    R = random_rotation(rng)

    # Points: pixels in the central 80% of the reference image, at random depths.
    uv0 = np.column_stack([rng.uniform(0.1 * w, 0.9 * w, n_points), rng.uniform(0.1 * h, 0.9 * h, n_points)])
    rays = np.column_stack([uv0, np.ones(n_points)]) @ np.linalg.inv(K).T
    if planar:
        normal = Rotation.from_euler("xy", rng.uniform(-45, 45, 2), degrees=True).apply([0.0, 0.0, 1.0])
        z = distance * (normal @ [0, 0, 1]) / (rays @ normal)  # ray-plane intersection
    else:
        z = distance * (1.0 + depth_range * rng.uniform(-0.5, 0.5, n_points))
    X_cam = rays * (z / rays[:, 2])[:, None]
    X = X_cam @ R  # to world

    # Translations: first three orthogonal (well spread), the rest random.
    dirs = np.linalg.qr(rng.normal(size=(3, 3)))[0].T
    if n_views > 4:
        extra = rng.normal(size=(n_views - 4, 3))
        dirs = np.vstack([dirs, extra / np.linalg.norm(extra, axis=1, keepdims=True)])
    lengths = baseline * distance * rng.uniform(0.5, 1.0, n_views - 1)
    T_true = np.vstack([np.zeros(3), dirs * lengths[:, None]])
    T_true = T_true + rng.normal(0, 0.05 * baseline * distance, 3)  # view 0 need not be at 0
    return _make_scene(K, R, np.asarray(dist, float), T_true, X, image_size, noise_px, robot_noise, missing, rng,
                       meta={"preset": "random", "planar": planar})


def _make_scene(K, R, dist, T_true, X, image_size, noise_px, robot_noise, missing, rng, meta) -> Scene:
    uv_true = project(K, R, X, T_true, dist)
    exact = Scene(K=K, R=R, dist=dist, T_true=T_true, X=X, T=T_true.copy(), uv=uv_true.copy(),
                  uv_true=uv_true, image_size=tuple(int(s) for s in image_size), meta=meta)
    return observe(exact, noise_px, robot_noise, missing, rng)

