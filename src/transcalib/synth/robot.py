"""Renders of a robot's views at any flange pose, eye-in-hand and eye-to-hand, with exact truth.

A view has a flange pose ``(R_i, T_i)`` in the robot base frame (``R_i`` flange -> base,
``T_i`` the flange position, mm) and the hand-eye transform ``(R_X, t_X)`` places the
camera (docs/hand-eye.md, DESIGN.md section 4)::

    eye-in-hand   x_ij ~ K (R_i R_X)^T (X_j - T_i - R_i t_X)     X_j fixed in the base frame
    eye-to-hand   x_ij ~ K R_X^T (R_i P_j + T_i - t_X)            P_j carried in the flange frame

(eye-to-hand ``R_X, t_X`` are ``R_base_camera, t_base_camera``.) The **scene frame** is the
frame the scene points live in: the base eye-in-hand, the flange eye-to-hand. Eye-to-hand
the renderer moves the carried surfaces to the base frame by the flange pose
(:meth:`~transcalib.synth.surfaces.Surface.moved`), in front of ``static_surfaces`` that stay
in the base (a background, which does not move with the flange), and casts the rays of the
fixed camera there; eye-in-hand the surfaces stay and the camera moves. Each view is the
ray cast of :mod:`.raycast` (the pixel convention and the anti-aliasing of
:func:`transcalib.synth.render.render`) followed by the camera effects of :mod:`.degrade`,
so a scene point appears exactly at :meth:`RobotRendered.project`.

:func:`robot_scene` renders the preset of issue 20: one 3-D pure-translation session plus
single views tilted from it, the scene 0.5-1 m away (:mod:`.robot_layout`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..errors import InputError
from ..geometry.camera import pixels_to_rays, project
from ..types.options import SETUPS
from ..types.poses import check_rotations
from .degrade import Degradations, degrade_view, draw_view_effects, overlay_box
from .raycast import camera_rays, nearest_hits, render_view
from .render import PixelTruth, _check_render_args
from .robot_layout import (EYE_TO_HAND_R_BC, EYE_TO_HAND_T_BC, camera_poses, carried_object, check_layout,
                           flange_poses, layout_misses, preset_camera, preset_degradations, view_geometry, work_cell)

__all__ = ["RobotRendered", "render_robot", "robot_scene", "PRESET_DIST"]

#: Lens distortion of :func:`robot_scene` with ``degrade=True`` (OpenCV k1, k2, p1, p2, k3):
#: mild barrel, the corners of a 640 x 480 image 8 px from where a pinhole would put them.
PRESET_DIST = np.array([-0.06, 0.02, 0.0, 0.0, 0.0])


@dataclass(frozen=True, eq=False)
class RobotRendered(PixelTruth):
    """Rendered views of a robot at known flange poses, with their exact truth.

    Attributes
    ----------
    images : (n_views, height, width) uint8
    K : (3, 3) float
    dist : (k,) float
        OpenCV distortion coefficients (empty: none).
    image_size : (width, height)
    setup : {"eye-in-hand", "eye-to-hand"}
    R_X : (3, 3) float
        Eye-in-hand camera -> flange (``R_flange_camera``); eye-to-hand camera -> base
        (``R_base_camera``).
    t_X : (3,) float
        The camera centre in the flange frame (eye-in-hand) or the base frame
        (eye-to-hand), mm.
    R : (n_views, 3, 3) float
        Flange -> base rotations of the views.
    T : (n_views, 3) float
        Flange positions in the base frame, mm.
    session_of_view : (n_views,) int
        The pure-translation session of each view (single views: a session each).
    scene_surfaces : list of Surface
        The scene, in the scene frame (base eye-in-hand, flange eye-to-hand).
    static_surfaces : list of Surface
        Eye-to-hand: surfaces fixed in the base frame (the background); empty eye-in-hand.
    corners : (m, 3) float
        Exact feature points of the scene (box and plate corners), scene frame.
    meta : dict
        How it was rendered: degradations, exposure gains, highlight positions, overlay box.
    """

    images: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    image_size: tuple
    setup: str
    R_X: np.ndarray
    t_X: np.ndarray
    R: np.ndarray
    T: np.ndarray
    session_of_view: np.ndarray
    scene_surfaces: list
    static_surfaces: list
    corners: np.ndarray
    meta: dict = field(default_factory=dict)

    @property
    def n_views(self) -> int:
        return len(self.T)

    @property
    def frame(self) -> str:
        """``flange`` (eye-in-hand) or ``base`` (eye-to-hand): the frame of ``R_X, t_X``."""
        return "flange" if self.setup == "eye-in-hand" else "base"

    def camera_rotations(self) -> np.ndarray:
        """``(n_views, 3, 3)`` scene -> camera rotations: ``(R_i R_X)^T`` eye-in-hand,
        ``R_X^T R_i`` eye-to-hand."""
        return camera_poses(self.R, self.T, self.R_X, self.t_X, self.setup)[0]

    def camera_centres(self) -> np.ndarray:
        """``(n_views, 3)`` camera centres in the scene frame, mm: ``T_i + R_i t_X``
        eye-in-hand, ``R_i^T (t_X - T_i)`` eye-to-hand."""
        return camera_poses(self.R, self.T, self.R_X, self.t_X, self.setup)[1]

    def project(self, X: np.ndarray) -> np.ndarray:
        """Exact pixels ``(n_views, n, 2)`` of scene-frame points ``X (n, 3)`` (the model of
        the module docstring, with the lens distortion); NaN never (points behind a
        camera project too: see :meth:`visible`)."""
        Q, c = camera_poses(self.R, self.T, self.R_X, self.t_X, self.setup)
        return project(self.K, Q, np.asarray(X, float).reshape(-1, 3), c, self.dist)

    def base_camera(self, view: int) -> tuple[np.ndarray, np.ndarray]:
        """The camera of ``view`` in the base frame: base -> camera rotation ``(3, 3)`` and
        centre ``(3,)``, mm (eye-to-hand: ``R_X^T`` and ``t_X`` for every view)."""
        if self.setup == "eye-to-hand":
            return self.R_X.T, self.t_X
        return (self.R[view] @ self.R_X).T, self.T[view] + self.R[view] @ self.t_X

    def base_surfaces(self, view: int) -> list:
        """The surfaces in the base frame at ``view`` as the renderer casts them: the scene
        followed by the static ones (eye-to-hand the scene moved by the flange pose,
        ``x_base = R_i x_flange + T_i``)."""
        if self.setup == "eye-to-hand":
            return [sf.moved(self.R[view], self.T[view]) for sf in self.scene_surfaces] + list(self.static_surfaces)
        return list(self.scene_surfaces)

    def backproject(self, view: int, uv: np.ndarray, depth=None, return_surface: bool = False):
        """Scene-frame points ``(n, 3)`` seen at pixels ``uv (n, 2)`` of ``view``.

        With ``depth`` (``(n,)`` or a scalar, camera z in mm): the points at that depth on
        the pixels' rays, ``c_i + depth Q_i^T [x, y, 1]`` (:meth:`project` inverted).
        Without: the renderer's own ray cast in the base frame (nearest hit of
        :meth:`base_surfaces`), mapped to the scene frame; NaN where no surface or (eye-to-hand)
        a static surface is hit, those being no scene points. With ``return_surface`` also
        the index ``(n,)`` of the surface hit in ``scene_surfaces + static_surfaces`` (-1:
        none).
        """
        uv = np.asarray(uv, float).reshape(-1, 2)
        if depth is not None:
            rays = pixels_to_rays(self.K, uv, self.dist)  # camera frame, unit z
            Q, c = camera_poses(self.R[view:view + 1], self.T[view:view + 1], self.R_X, self.t_X, self.setup)
            return c[0] + (np.broadcast_to(np.asarray(depth, float), len(uv))[:, None] * rays) @ Q[0]
        best, which, X = self.ray_hits(view, uv)
        if self.setup == "eye-to-hand":
            X = (X - self.T[view]) @ self.R[view]  # base -> flange: R_i^T (x - T_i)
        X[~np.isfinite(best) | (which >= len(self.scene_surfaces))] = np.nan
        return (X, which) if return_surface else X

    def ray_hits(self, view: int, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The renderer's ray cast of pixels ``uv (n, 2)`` of ``view`` (the nearest hit of
        :meth:`base_surfaces` from :meth:`base_camera`): camera depth ``(n,)`` (inf: no
        hit), index ``(n,)`` into ``scene_surfaces + static_surfaces`` (-1: none) and the
        hit point ``(n, 3)`` in the base frame (NaN: none)."""
        Rc, C = self.base_camera(view)
        d = pixels_to_rays(self.K, np.asarray(uv, float).reshape(-1, 2), self.dist) @ Rc  # base, unit camera z
        best, which = nearest_hits(self.base_surfaces(view), d.T, C)
        X = C + best[:, None] * d
        X[~np.isfinite(best)] = np.nan
        return best, which, X

    def visible(self, X: np.ndarray, margin_px: float = 0.0, rtol: float = 1e-9) -> np.ndarray:
        """``(n_views, n)`` bool: scene-frame point ``X`` inside the image by ``margin_px``,
        in front of the camera, and no surface on its ray nearer than its depth (by more
        than ``rtol`` of it; a ray through a point on a face's edge may slip off that face
        by rounding and meet one behind, which leaves the point visible)."""
        X = np.asarray(X, float).reshape(-1, 3)
        uv = self.project(X)
        w, h = self.image_size
        vis = ((uv[..., 0] >= margin_px - 0.5) & (uv[..., 0] <= w - 0.5 - margin_px)
               & (uv[..., 1] >= margin_px - 0.5) & (uv[..., 1] <= h - 0.5 - margin_px))
        Q, c = camera_poses(self.R, self.T, self.R_X, self.t_X, self.setup)
        depth = np.einsum("vk,vnk->vn", Q[:, 2], X[None] - c[:, None])
        for i in range(self.n_views):  # a loop over views, vectorised over points
            vis[i] &= (depth[i] > 0) & (self.ray_hits(i, uv[i])[0] >= depth[i] * (1 - rtol))
        return vis

    def sample_points(self, n: int, rng=None, surfaces=None) -> np.ndarray:
        """``(n, 3)`` scene-frame points drawn uniformly (by area) on :attr:`scene_surfaces`
        (or those of the indices ``surfaces``): scene points to track exactly
        (:meth:`exact_tracks`)."""
        rng = np.random.default_rng(rng)
        sfs = [self.scene_surfaces[k] for k in (range(len(self.scene_surfaces)) if surfaces is None else surfaces)]
        area = np.array([sf.size[0] * sf.size[1] for sf in sfs])
        k = rng.choice(len(area), size=n, p=area / area.sum())
        st = rng.uniform(0.0, 1.0, (n, 2)) * np.array([sf.size for sf in sfs])[k]
        origin, a, b = (np.array([getattr(sf, f) for sf in sfs])[k] for f in ("origin", "axis_s", "axis_t"))
        return origin + st[:, :1] * a + st[:, 1:] * b

    def exact_tracks(self, X: np.ndarray | None = None, margin_px: float = 0.0) -> np.ndarray:
        """Pixel-exact tracks ``uv (n_views, n, 2)`` of scene points ``X`` (default
        :attr:`corners`): their projections, NaN where :meth:`visible` says no."""
        X = self.corners if X is None else np.asarray(X, float).reshape(-1, 3)
        uv = self.project(X)
        uv[~self.visible(X, margin_px)] = np.nan
        return uv

    def truth_dict(self) -> dict:
        """The truth as JSON-ready lists, named as in ``hand_eye.json`` and
        ``handeye.simulate``'s truth: ``R_<frame>_camera``, ``t_<frame>_camera`` (frame
        ``flange`` or ``base``), ``K``, ``image_size``; plus ``setup``, ``dist``,
        ``unit`` (mm), ``session_of_view`` and ``corners`` (the exact feature points, scene
        frame; not named ``points``, which ``calibrate --truth`` matches to track ids)."""
        f = self.frame
        return {f"R_{f}_camera": self.R_X.tolist(), f"t_{f}_camera": self.t_X.tolist(), "K": self.K.tolist(),
                "image_size": list(self.image_size), "setup": self.setup, "dist": self.dist.tolist(), "unit": "mm",
                "session_of_view": self.session_of_view.tolist(), "corners": self.corners.tolist()}


def render_robot(scene_surfaces, K, R, T, R_X, t_X, image_size, *, setup: str = "eye-in-hand",
                 static_surfaces=(), dist=(), session_of_view=None, corners=None, supersample: int = 2,
                 background: float = 0.5, noise_std: float = 0.0, blur_sigma: float = 0.0,
                 degrade: Degradations | None = None, images: bool = True, rng=None) -> RobotRendered:
    """Render the views of a robot at flange poses ``(R, T)``, eye-in-hand or eye-to-hand.

    Parameters
    ----------
    scene_surfaces : list of Surface
        The scene in the scene frame: fixed in the base eye-in-hand, carried in the
        flange frame eye-to-hand.
    K : (3, 3) float
    R : (n_views, 3, 3) float
        Flange -> base rotations.
    T : (n_views, 3) float
        Flange positions in the base frame (mm).
    R_X, t_X : (3, 3), (3,) float
        Camera in the flange (eye-in-hand) or in the base (eye-to-hand).
    image_size : (width, height)
    setup : {"eye-in-hand", "eye-to-hand"}
    static_surfaces : list of Surface
        Eye-to-hand only: surfaces fixed in the base frame (a background).
    dist : (k,) float
        OpenCV lens distortion, applied exactly to every ray.
    session_of_view : (n_views,) int, optional
        Default: views with equal rotations share a session, in order of appearance.
    corners : (m, 3) float, optional
        Exact feature points of the scene (scene frame), kept as truth.
    supersample, background, noise_std, blur_sigma, degrade, rng
        As in :func:`transcalib.synth.render.render`: ``S x S`` samples per pixel, the
        intensity where no surface is hit, the simple noise and blur, the camera effects.
    images : bool
        False: cast no pixel (``images`` of shape ``(n_views, 0, 0)``), the truth only:
        poses, :meth:`RobotRendered.project`, :meth:`~RobotRendered.backproject`,
        :meth:`~RobotRendered.exact_tracks` (fast, for geometry tests).

    Returns
    -------
    RobotRendered
    """
    R, T, R_X, t_X, (w, h) = _checked_poses(R, T, R_X, t_X, image_size, setup, static_surfaces)
    _check_render_args(T, w, h, supersample, degrade, "uint8")
    rng = np.random.default_rng(rng)
    opt = Degradations() if degrade is None else degrade
    effects = draw_view_effects(opt, len(T), (w, h), rng)
    out = RobotRendered(images=np.empty((len(T), h, w) if images else (len(T), 0, 0), np.uint8), K=np.asarray(K, float),
                        dist=np.asarray(dist, float).ravel(), image_size=(w, h), setup=setup, R_X=R_X, t_X=t_X, R=R,
                        T=T, session_of_view=_sessions(R) if session_of_view is None else np.asarray(session_of_view),
                        scene_surfaces=list(scene_surfaces), static_surfaces=list(static_surfaces),
                        corners=np.zeros((0, 3)) if corners is None else np.asarray(corners, float).reshape(-1, 3),
                        meta={"degrade": opt.active(), "exposure_gain": effects.gain,
                              "specular_uv": effects.specular_uv, "overlay_box": overlay_box(opt, (w, h)),
                              "noise_std": noise_std, "blur_sigma": blur_sigma, "supersample": int(supersample)})
    if images:
        _cast(out, opt, effects, int(supersample), background, noise_std, blur_sigma, rng)
    return out


def _cast(out: RobotRendered, opt, effects, S, background, noise_std, blur_sigma, rng) -> None:
    """Fill ``out.images``: per view, the ray cast of :meth:`RobotRendered.base_surfaces`
    from :meth:`RobotRendered.base_camera`, then the camera effects."""
    w, h = out.image_size
    x, y = camera_rays(out.K, out.dist, (w, h), S)
    d = (x, y, np.broadcast_to(1.0, x.shape))  # cast in the camera frame: the surfaces move, not the rays
    for i in range(out.n_views):  # a loop over views, vectorised over pixels
        Rc, C = out.base_camera(i)
        surfaces = [sf.moved(Rc, -Rc @ C) for sf in out.base_surfaces(i)]
        radiance = render_view(surfaces, d, np.zeros(3), S, background, out.K, np.eye(3), out.dist, (w, h))
        out.images[i] = degrade_view(radiance, opt, i, effects, blur_sigma=blur_sigma, noise_std=noise_std, rng=rng)


def _checked_poses(R, T, R_X, t_X, image_size, setup, static_surfaces):
    """The poses as float arrays, checked once: ``(R, T, R_X, t_X, (w, h))``."""
    if setup not in SETUPS:
        raise InputError(f"render_robot: setup must be one of {SETUPS}, got {setup!r}")
    if setup == "eye-in-hand" and len(static_surfaces):
        raise InputError("render_robot: eye-in-hand the whole scene is fixed in the base; give every surface as "
                         "scene_surfaces (static_surfaces are the eye-to-hand background)")
    T = np.asarray(T, float)
    if T.ndim != 2 or T.shape[1] != 3 or not np.all(np.isfinite(T)):
        raise InputError(f"render_robot: T must be finite (n_views, 3), got shape {T.shape}")
    R = check_rotations(R, len(T), "render_robot: R")
    R_X = check_rotations(np.asarray(R_X, float)[None], 1, "render_robot: R_X")[0]
    t_X = np.asarray(t_X, float)
    if t_X.shape != (3,) or not np.all(np.isfinite(t_X)):
        raise InputError(f"render_robot: t_X must be 3 finite numbers, got shape {t_X.shape}")
    return R, T, R_X, t_X, (int(image_size[0]), int(image_size[1]))


def _sessions(R: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """``(n,)`` int: views with equal rotations (within ``tol``) share a session, numbered
    in order of first appearance."""
    labels = np.full(len(R), -1)
    for i in range(len(R)):  # a loop over views
        if labels[i] < 0:
            same = (labels < 0) & (np.abs(R - R[i]).reshape(len(R), -1).max(1) <= tol)
            labels[same] = labels.max() + 1
    return labels


def robot_scene(setup: str = "eye-in-hand", session_views: int = 6, single_views: int = 6, tilt_deg=(15.0, 45.0),
                distance_mm=(500.0, 1000.0), image_size=(640, 480), degrade: bool | Degradations = True, rng=0,
                supersample: int = 2, images: bool = True, pose_error=None, blur_sigma: float = 0.0) -> RobotRendered:
    """The issue-20 preset: one 3-D pure-translation session plus single views tilted from it.

    Eye-in-hand, the camera on the flange looks down at a work cell (a textured table top,
    a fine-textured mat and four textured boxes, fenced by textured walls; base frame, z
    up). Eye-to-hand, a camera fixed beside the robot (:data:`EYE_TO_HAND_R_BC`,
    :data:`EYE_TO_HAND_T_BC`) sees a textured plate and box carried by the flange in front
    of a static textured wall. The session's ``session_views`` views share one orientation
    and translate by 13-22 % of the distance in 3-D; each of the ``single_views`` is turned
    by ``U(tilt_deg)`` from the session's orientation and aimed at the scene from
    ``U(distance_mm)``; layouts where a view would miss part of the scene are drawn again.

    Parameters
    ----------
    setup : {"eye-in-hand", "eye-to-hand"}
    session_views, single_views : int
    tilt_deg : (2,) float
        Range of the single views' turn from the session's orientation (deg).
    distance_mm : (2,) float
        Range of the camera's distance from the scene's centre (mm).
    image_size : (width, height)
    degrade : bool or Degradations
        True: the camera effects of :func:`.robot_layout.preset_degradations` and the lens
        :data:`PRESET_DIST`; a :class:`Degradations`: those effects and the lens; False: an
        ideal pinhole camera, no noise.
    rng : seed or Generator
    supersample : int
    images : bool
        False: the layout and the truth only, no pixel cast (see :func:`render_robot`).
    pose_error : (n_views, 6) float, optional
        The robot's pose error per view (:mod:`transcalib.estimate.robot_error`:
        ``delta_i`` rad in the flange frame, ``eps_i`` mm in the base frame, e.g. from
        :func:`~transcalib.estimate.robot_error.sample_errors`): the views are rendered at
        the true poses ``R_i exp([delta_i]x)``, ``T_i + eps_i`` while ``R``, ``T`` of the
        result stay the reported ones (what a controller records); the true poses are in
        ``meta["true_R"]``, ``meta["true_T"]``, the errors in ``meta["pose_error"]``.
        (The result's truth methods use ``R``, ``T``: the reported poses.)
    blur_sigma : float
        Optics blur (Gaussian std, pixels) before the sensor noise: a softer lens or a
        slight defocus.

    Returns
    -------
    RobotRendered
    """
    if setup not in SETUPS:
        raise InputError(f"robot_scene: setup must be one of {SETUPS}, got {setup!r}")
    if session_views < 4 and single_views < 1:
        raise InputError("robot_scene: need a session of >= 4 views or single views")
    rng = np.random.default_rng(rng)
    K = preset_camera(image_size)
    R_X, t_X, scene = _preset_scene(setup, int(rng.integers(2**31)), distance_mm)
    Q, c = _layout(rng, K, scene, session_views, single_views, tilt_deg, distance_mm, image_size)
    R, T = flange_poses(Q, c, R_X, t_X, setup)
    sess = np.r_[np.zeros(session_views, int), 1 + np.arange(single_views)] - (session_views == 0)
    effects = preset_degradations(image_size) if degrade is True else (None if degrade is False else degrade)
    R_true, T_true = _true_poses(R, T, pose_error)
    out = render_robot(scene.scene_surfaces, K, R_true, T_true, R_X, t_X, image_size, setup=setup,
                       static_surfaces=scene.static_surfaces, dist=PRESET_DIST if degrade is not False else (),
                       session_of_view=sess, corners=scene.corners, supersample=supersample, degrade=effects,
                       blur_sigma=blur_sigma, images=images, rng=rng)
    if pose_error is None:
        return out
    return replace(out, R=R, T=T, meta={**out.meta, "true_R": R_true, "true_T": T_true,
                                        "pose_error": np.array(pose_error, float)})


def _true_poses(R: np.ndarray, T: np.ndarray, pose_error):
    """The poses rendered: ``(R, T)`` themselves, or perturbed by ``pose_error (n_views, 6)``."""
    if pose_error is None:
        return R, T
    from ..estimate.robot_error import perturb_poses

    e = np.asarray(pose_error, float)
    if e.shape != (len(T), 6) or not np.all(np.isfinite(e)):
        raise InputError(f"robot_scene: pose_error must be finite with shape ({len(T)}, 6), got {e.shape}")
    return perturb_poses(R, T, e)


def _preset_scene(setup, seed, distance_mm):
    """``(R_X, t_X, PresetScene)`` of a setup."""
    from ..handeye.simulate import DEFAULT_R_X, DEFAULT_T_X

    if setup == "eye-in-hand":
        return DEFAULT_R_X, DEFAULT_T_X, work_cell(seed)
    return EYE_TO_HAND_R_BC, EYE_TO_HAND_T_BC, carried_object(seed, EYE_TO_HAND_R_BC, EYE_TO_HAND_T_BC,
                                                              1.6 * distance_mm[1])


def _layout(rng, K, scene, session_views, single_views, tilt_deg, distance_mm, image_size, tries: int = 200):
    """Camera rotations and centres (scene frame) from :func:`view_geometry`, drawn again
    while :func:`layout_misses` names a view (at most ``tries`` draws, then
    :func:`check_layout` raises)."""
    for _ in range(tries):
        Q, c = view_geometry(rng, scene.centre, scene.look_dir, scene.up, session_views, single_views, tilt_deg,
                             distance_mm)
        if layout_misses(K, Q, c, scene, image_size).size == 0:
            break
    check_layout(K, Q, c, scene, image_size)
    return Q, c
