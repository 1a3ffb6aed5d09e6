"""The preset scenes of :func:`transcalib.synth.robot.robot_scene`, and the flange poses that
put a camera where a view wants it.

A view is placed first relative to the **scene frame** (the base frame eye-in-hand, the
flange frame eye-to-hand): its rotation ``Q`` (scene -> camera) and its centre ``c`` (scene
frame, mm). The flange pose that puts the camera there follows from the hand-eye transform
``(R_X, t_X)`` (:func:`flange_poses`, the inverse of :func:`camera_poses`)::

    eye-in-hand   Q = (R_i R_X)^T    c = T_i + R_i t_X       R_i = Q^T R_X^T   T_i = c - R_i t_X
    eye-to-hand   Q = R_X^T R_i      c = R_i^T (t_X - T_i)   R_i = R_X Q       T_i = t_X - R_i c

:func:`view_geometry` aims every optical axis at the scene's centre from the scene's front
side, so the scene is in view for any random draw; :func:`check_layout` confirms it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry.camera import K_from_params, project
from ..geometry.rotation import rotvec_to_matrix
from ..handeye.simulate import look_rotation
from .degrade import Degradations
from .surfaces import box, plane
from .textures import Noise

__all__ = ["camera_poses", "flange_poses", "view_geometry", "preset_camera", "preset_degradations",
           "work_cell", "carried_object", "layout_misses", "check_layout", "PresetScene", "EYE_TO_HAND_R_BC",
           "EYE_TO_HAND_T_BC"]

#: Eye-to-hand preset: the camera fixed in the base, on a stand beside the robot 0.9 m out,
#: 0.65 m up, looking 25 deg down at the workspace: camera -> base rotation and centre (mm).
EYE_TO_HAND_R_BC = look_rotation(np.array([-550.0, 350.0, -300.0]), up=(0.0, 0.0, 1.0)).T
EYE_TO_HAND_T_BC = np.array([900.0, -350.0, 650.0])

SESSION_TILT_DEG = 10.0  # the session's viewing direction, off the scene's nominal one
SESSION_LATERAL = (0.06, 0.10)  # session moves across the optical axis, fraction of the distance
SESSION_AXIAL = (0.12, 0.20)  # and along it (alternating sign)
SINGLE_AXIS_FROM_OPTICAL_DEG = (35.0, 90.0)  # single views' turn axes: with some roll about it


def camera_poses(R, T, R_X, t_X, setup: str) -> tuple[np.ndarray, np.ndarray]:
    """Camera rotations ``Q (n, 3, 3)`` (scene -> camera) and centres ``c (n, 3)`` (scene
    frame) of flange poses ``R (n, 3, 3)``, ``T (n, 3)`` (module docstring's table)."""
    if setup == "eye-in-hand":
        return np.transpose(R @ R_X, (0, 2, 1)), T + R @ t_X
    return R_X.T @ R, np.einsum("nji,nj->ni", R, t_X - T)


def flange_poses(Q, c, R_X, t_X, setup: str) -> tuple[np.ndarray, np.ndarray]:
    """Flange poses ``R (n, 3, 3)`` (flange -> base), ``T (n, 3)`` (base frame) that put the
    camera at rotations ``Q`` and centres ``c`` in the scene frame: :func:`camera_poses`
    inverted."""
    if setup == "eye-in-hand":
        R = np.transpose(Q, (0, 2, 1)) @ R_X.T
        return R, c - R @ t_X
    R = R_X @ Q
    return R, t_X - np.einsum("nij,nj->ni", R, c)


def view_geometry(rng, centre, look_dir, up, n_session: int, n_single: int, tilt_deg, distance_mm):
    """Camera rotations ``Q (n, 3, 3)`` and centres ``c (n, 3)`` in the scene frame: a
    pure-translation session, then single views.

    The session looks along ``look_dir`` tilted by up to 10 deg, rolled at random, from
    ``D_s = d0 + 0.6 (d1 - d0)`` at the ``centre``; its views move by ``D_s`` times 0.06-0.1
    across the optical axis (at evenly spread azimuths) and 0.12-0.2 along it (alternating
    sign): moves of 13-22 % of the distance spanning 3-D. Single view ``j`` is the session's
    camera turned by ``U(tilt_deg)`` about an axis 35-90 deg from the optical axis (some
    roll), aimed at the ``centre`` from ``U(distance_mm)``.
    """
    d0, d1 = distance_mm
    Q0 = _session_rotation(rng, np.asarray(look_dir, float), up)
    D_s = d0 + 0.6 * (d1 - d0)
    c_session = centre - D_s * Q0[2] + (D_s * _session_moves(rng, n_session)) @ Q0
    Q_single = _single_turns(rng, n_single, tilt_deg) @ Q0
    c_single = centre - rng.uniform(d0, d1, n_single)[:, None] * Q_single[:, 2]
    return np.concatenate([np.repeat(Q0[None], n_session, 0), Q_single]), np.concatenate([c_session, c_single])


def _session_rotation(rng, look_dir, up) -> np.ndarray:
    """Scene -> camera rotation looking along ``look_dir`` tilted by ``U(0, 10)`` deg about a
    random perpendicular axis, rolled by ``U(-180, 180)`` deg about the optical axis."""
    axis = np.cross(look_dir, rng.normal(size=3))
    tilt = rotvec_to_matrix(np.radians(rng.uniform(0, SESSION_TILT_DEG)) * axis / np.linalg.norm(axis))
    roll = rotvec_to_matrix(np.radians(rng.uniform(-180, 180)) * np.array([0.0, 0.0, 1.0]))
    return roll @ look_rotation(tilt @ look_dir, up)


def _session_moves(rng, n: int) -> np.ndarray:
    """``(n, 3)`` camera-frame moves in units of the distance: view 0 at 0, then around a
    ring across the optical axis (lateral) with alternating moves along it (axial)."""
    if n == 0:
        return np.zeros((0, 3))
    k = np.arange(1, n)
    phi = 2 * np.pi * k / max(n - 1, 1) + rng.uniform(0, 2 * np.pi)
    lateral = rng.uniform(*SESSION_LATERAL, n - 1)
    axial = (-1.0) ** k * rng.uniform(*SESSION_AXIAL, n - 1)
    return np.vstack([np.zeros((1, 3)), np.column_stack([lateral * np.cos(phi), lateral * np.sin(phi), axial])])


def _single_turns(rng, n: int, tilt_deg) -> np.ndarray:
    """``(n, 3, 3)`` camera-frame rotations by ``U(tilt_deg)`` about axes at evenly spread
    azimuths and 35-90 deg from the optical axis."""
    phi = 2 * np.pi * (np.arange(n) + rng.uniform(0, 1, n)) / max(n, 1)
    beta = np.radians(rng.uniform(*SINGLE_AXIS_FROM_OPTICAL_DEG, n))
    axes = np.column_stack([np.sin(beta) * np.cos(phi), np.sin(beta) * np.sin(phi), np.cos(beta)])
    return rotvec_to_matrix(np.radians(rng.uniform(*tilt_deg, n))[:, None] * axes)


def preset_camera(image_size) -> np.ndarray:
    """``K`` of the presets: fx = 660, fy = 655 px at 640 x 480 (a 52 x 40 deg field of
    view), the principal point 4 px right and 3 px up of the centre; scaled with the width."""
    w, h = image_size
    s = w / 640.0
    return K_from_params(660.0 * s, 655.0 * s, (w - 1) / 2 + 4.0 * s, (h - 1) / 2 - 3.0 * s)


def preset_degradations(image_size) -> Degradations:
    """Moderate camera effects: vignetting 0.25, exposure +-15 %, shot noise (6000 e- full
    well) and read noise 1.2 DN, JPEG 90, a highlight of 0.5 (sized for the width)."""
    s = image_size[0] / 640.0
    return Degradations(vignetting=0.25, exposure=0.15, full_well_e=6000.0, read_noise_dn=1.2, jpeg_quality=90,
                        specular=0.5, specular_sigma_px=12.0 * s, specular_drift_px=25.0 * s)


@dataclass(frozen=True, eq=False)
class PresetScene:
    """A preset's surfaces and what its views must respect.

    Attributes
    ----------
    scene_surfaces, static_surfaces : list of Surface
        Moving with the scene frame; fixed in the base (eye-to-hand).
    corners : (m, 3) float
        Exact feature points (box and plate corners), scene frame.
    centre, look_dir, up : (3,) float
        Where the optical axes aim, the nominal viewing direction and image-up hint (scene frame).
    in_view : (k, 3) float
        Points every view must show inside the image.
    front : (2, 3) float
        A point and a normal: every camera must be on the normal's side (sees the front).
    """

    scene_surfaces: list
    static_surfaces: list
    corners: np.ndarray
    centre: np.ndarray
    look_dir: np.ndarray
    up: np.ndarray
    in_view: np.ndarray
    front: np.ndarray


def _noise_box(centre, yaw_deg, dims, texel, seed, name):
    """A box standing on its base, turned ``yaw_deg`` about z, each face with its own noise."""
    ext = (1.2 * max(dims),) * 2
    faces = box(centre, rotvec_to_matrix(np.radians([0.0, 0.0, yaw_deg])), dims,
                [Noise(texel, ext, seed + f) for f in range(6)], name)
    corners = np.array([f.point(np.array([[0, 0], [f.size[0], 0], [0, f.size[1]], [f.size[0], f.size[1]]]))
                        for f in faces[:2]]).reshape(-1, 3)  # the +x and -x faces hold all 8 vertices
    return faces, corners


def work_cell(seed: int) -> PresetScene:
    """Eye-in-hand: a table top in the base frame (mm, z up). A 2.4 x 2.4 m table (coarse
    noise) fenced by 1.5 m walls, so that every ray meets a surface; an 800 x 600 mm mat of
    fine noise at its centre; four boxes 45-130 mm high, each face its own noise."""
    flat = np.eye(3)
    sf = [plane([0, 0, 0], flat, (2400, 2400), Noise(3.0, (2400, 2400), seed), "table"),
          plane([0, 0, 0.5], flat, (800, 600), Noise(1.2, (800, 600), seed + 1), "mat")]
    for k in range(4):  # inward-facing walls
        turn = rotvec_to_matrix(np.radians([0.0, 0.0, 90.0 * k]))
        a, b = -turn[:, 1], np.array([0.0, 0.0, 1.0])
        sf.append(plane(turn @ [1200, 0, 750], np.column_stack([a, b, np.cross(a, b)]), (2400, 1500),
                        Noise(6.0, (2400, 1500), seed + 2 + k), f"wall{k}"))
    corners = []
    for b, (xy, dims, yaw) in enumerate([([-150, 100], [120, 90, 60], 15), ([110, 140], [90, 90, 130], -25),
                                         ([140, -120], [150, 100, 90], 40), ([-120, -130], [80, 110, 45], -10)]):
        faces, c = _noise_box([*xy, 0.5 + dims[2] / 2], yaw, dims, 1.0, seed + 10 + 6 * b, f"box{b}")
        sf += faces
        corners.append(c)
    return PresetScene(sf, [], np.vstack(corners), np.array([0.0, 0.0, 50.0]), np.array([0.0, 0.0, -1.0]),
                       np.array([0.0, 1.0, 0.0]), np.array([[0.0, 0.0, 50.0]]),
                       np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))


def carried_object(seed: int, R_bc, t_bc, wall_distance_mm: float) -> PresetScene:
    """Eye-to-hand: in the flange frame (mm, z along the tool) a 360 x 280 mm plate of fine
    noise 20 mm off the flange and a 180 x 130 x 90 mm box standing on it off-centre (each
    face its own noise); in the base frame a 4.2 x 3.2 m wall of coarser noise, vertical
    (for a camera looking roughly horizontally), ``wall_distance_mm`` from the camera
    ``(R_bc, t_bc)`` along its axis. Every view must show the box and the plate's inner
    three quarters."""
    plate = plane([0, 0, 20], np.eye(3), (360, 280), Noise(1.0, (360, 280), seed), "plate")
    faces, corners = _noise_box([50, 30, 20 + 45], 15.0, [180, 130, 90], 0.9, seed + 1, "box")
    inner = plate.point(np.array([[45, 35], [315, 35], [45, 245], [315, 245]], float))
    axis = R_bc[:, 2]
    normal = -np.array([axis[0], axis[1], 0.0]) if abs(axis[2]) < 0.7 else -axis
    normal /= np.linalg.norm(normal)
    a = np.cross([0.0, 0.0, 1.0], normal) if abs(normal[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    wall = plane(t_bc + wall_distance_mm * axis, np.column_stack([a, np.cross(normal, a), normal]), (4200, 3200),
                 Noise(5.0, (4200, 3200), seed + 20), "wall")
    outer = plate.point(np.array([[0, 0], [360, 0], [0, 280], [360, 280]], float))
    return PresetScene([plate] + faces, [wall], np.vstack([outer, corners]), np.array([0.0, 0.0, 60.0]),
                       np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0]), np.vstack([inner, corners]),
                       np.array([[0.0, 0.0, 20.0], [0.0, 0.0, 1.0]]))


def layout_misses(K, Q, c, scene: PresetScene, image_size) -> np.ndarray:
    """Indices of the views whose camera ``(Q, c)`` (scene frame) is behind ``scene.front``
    or misses one of ``scene.in_view`` (outside the image or behind the camera)."""
    w, h = image_size
    uv = project(K, Q, scene.in_view, c)
    depth = np.einsum("nk,njk->nj", Q[:, 2], scene.in_view[None] - c[:, None])
    inside = (uv[..., 0] >= -0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= h - 0.5)
    behind = (c - scene.front[0]) @ scene.front[1] <= 0
    return np.flatnonzero(~np.all(inside & (depth > 0), axis=1) | behind)


def check_layout(K, Q, c, scene: PresetScene, image_size) -> None:
    """Raise :class:`InputError` naming the views of :func:`layout_misses`."""
    bad = layout_misses(K, Q, c, scene, image_size)
    if bad.size:
        raise InputError(f"robot_scene: views {bad.tolist()} would not show the whole scene from its front; "
                         "use a larger distance_mm or a smaller tilt_deg")
