"""The preset scenes of :func:`transcalib.synth.render.render_scene`, with exact corners.

Each preset (:data:`SCENE_KINDS`) is built in the frame of the first camera at a
distance ``D`` (walls, boxes, boards sized by the field of view), then moved to the
world: ``X_w = R^T X_c + T_0``. :func:`robot_translations` and :func:`default_camera`
give the robot moves and the camera when the caller gives none.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.camera import K_from_params
from .surfaces import Surface, box, checker_board, paper_board, plane, sphere
from .textures import Checker, Constant, Noise, Tiled

__all__ = ["SCENE_KINDS", "robot_translations", "ring_translations", "default_camera", "preset_scene"]

SCENE_KINDS = ("checker", "natural", "board", "mixed", "repetitive", "floor", "workspace")


def robot_translations(n_views: int, length: float, rng) -> np.ndarray:
    """``(n_views, 3)`` translations: view 0 at the origin, then three orthogonal moves of
    ``length`` (random directions), further views random with lengths ``U(0.6, 1) * length``."""
    rng = np.random.default_rng(rng)
    Q = np.linalg.qr(rng.normal(size=(3, 3)))[0].T
    dirs = [q for q in Q]
    for _ in range(max(0, n_views - 4)):
        v = rng.normal(size=3)
        dirs.append(v / np.linalg.norm(v) * rng.uniform(0.6, 1.0))
    T = np.vstack([np.zeros(3)] + [length * d for d in dirs])
    return T[:n_views]


def ring_translations(n_views: int, length: float, R: np.ndarray, rng=None, forward: float = 0.1) -> np.ndarray:
    """``(n_views, 3)`` world translations of a stereo rig around a reference: view 0 at
    the origin, the others on a ring of radius ``length`` in the image plane of the
    camera ``R`` (world -> camera), at evenly spread angles (a random start), each with a
    random camera-z component of up to ``forward * length`` - the layout of dense
    reconstruction, where view 0 is the most central view."""
    rng = np.random.default_rng(rng)
    m = max(n_views - 1, 1)
    ang = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(m) / m
    t_cam = np.column_stack([np.cos(ang), np.sin(ang), rng.uniform(-forward, forward, m)]) * length
    return np.vstack([np.zeros(3), t_cam @ np.asarray(R, float)])[:n_views]


def default_camera(K, R, T, image_size, n_views, length, rng):
    """``K``, ``R``, ``T`` as given, or the defaults of :func:`transcalib.synth.render.render_scene`."""
    w, h = image_size
    if K is None:
        fx = 0.95 * w
        K = K_from_params(fx, 1.04 * fx, w / 2 - 0.5 + 0.04 * w, h / 2 - 0.5 - 0.03 * h)
    if R is None:
        R = Rotation.from_euler("xyz", rng.uniform(-180, 180, 3), degrees=True).as_matrix()
    if T is None:
        T = robot_translations(n_views, length, rng)
    return np.asarray(K, float), np.asarray(R, float), np.asarray(T, float)


def _camera0_to_world(surfaces_c, corners_c, R, T0):
    """Move surfaces and corners built in the camera-0 frame to the world:
    ``X_w = R^T X_c + T_0`` (axes rotate likewise)."""
    Rt = R.T
    surfaces = [sphere(Rt @ sf.center + T0, sf.radius, sf.texture, Rt @ sf.frame, sf.name) if hasattr(sf, "radius")
                else Surface(Rt @ sf.origin + T0, Rt @ sf.axis_s, Rt @ sf.axis_t, sf.size, sf.texture, sf.name,
                             sf.cull_back) for sf in surfaces_c]
    corners = (np.vstack(corners_c) @ R + T0) if corners_c else np.zeros((0, 3))
    return surfaces, corners


def preset_scene(kind: str, distance: float, K: np.ndarray, R: np.ndarray, T0: np.ndarray,
                 image_size: tuple[int, int], seed: int) -> tuple[list, np.ndarray, list]:
    """The surfaces, exact corners ``(n_corners, 3)`` (world) and corner kinds
    (``"checker"`` / ``"board"``) of the preset ``kind`` at ``distance`` in front of the
    camera ``K``, ``R`` at ``T0``; ``seed`` seeds the noise textures."""
    surfaces_c, corners_c, kinds = _SCENE_BUILDERS[kind](distance, K, image_size, seed)
    surfaces, corners = _camera0_to_world(surfaces_c, corners_c, R, T0)
    return surfaces, corners, kinds


def _tilt(ax, ay):
    return Rotation.from_euler("xy", [ax, ay], degrees=True).as_matrix()


def _frame(D, K, image_size):
    """Field of view at distance ``D`` (camera-0 frame), the wall's depth and size."""
    w, h = image_size
    fov_w, fov_h = D * w / K[0, 0], D * h / K[1, 1]
    return fov_w, fov_h, 1.35 * D, (3.0 * fov_w * 1.35, 3.0 * fov_h * 1.35)


def _scene_checker(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    surfaces = [plane([0, 0, wall_z], _tilt(0, 0), wall_size, Constant(0.55), "wall")]
    cell = fov_w / 16
    sb, cb = checker_board([0.05 * fov_w, 0.02 * fov_h, D], _tilt(12, -18), cell, 13, 9, margin=0.6)
    surfaces.append(sb)
    cell2 = fov_w / 30
    surfaces += box([-0.25 * fov_w, 0.2 * fov_h, 0.8 * D], _tilt(25, 30), [5 * cell2] * 3, Checker(cell2), "cbox")
    return surfaces, [cb], ["checker"] * len(cb)


def _scene_natural(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    surfaces = [plane([0, 0, wall_z], _tilt(8, -6), wall_size, Noise(texel * 1.35, wall_size, seed), "wall")]
    for b, (c, dims, rot) in enumerate([
        ([-0.18 * fov_w, 0.1 * fov_h, 0.85 * D], [0.3 * fov_w] * 3, _tilt(20, 35)),
        ([0.2 * fov_w, -0.12 * fov_h, 0.7 * D], [0.22 * fov_w, 0.3 * fov_h, 0.2 * fov_w], _tilt(-15, -25)),
    ]):
        ext = (max(dims) * 1.1, max(dims) * 1.1)
        tex = [Noise(texel * 0.9, ext, seed + 10 * b + f) for f in range(6)]
        surfaces += box(c, rot, dims, tex, f"box{b}")
    return surfaces, [], []


def _scene_board(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    surfaces = [plane([0, 0, wall_z], _tilt(5, 5), wall_size, Noise(texel * 1.35, wall_size, seed), "wall")]
    sq = fov_w / 9
    sb, cb = paper_board([0, 0, D], _tilt(15, -10), square=sq, gap=0.66 * sq, margin=0.8 * sq)
    surfaces.append(sb)
    return surfaces, [cb], ["board"] * len(cb)


def _scene_mixed(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    surfaces = [plane([0, 0, wall_z], _tilt(6, -4), wall_size, Noise(texel * 1.35, wall_size, seed), "wall")]
    cell = fov_w / 24
    sb, cb = checker_board([-0.2 * fov_w, -0.17 * fov_h, 0.95 * D], _tilt(10, 20), cell, 8, 6, margin=0.5)
    sq = fov_w / 20
    pb, pc = paper_board([0.22 * fov_w, 0.2 * fov_h, 0.9 * D], _tilt(-12, -15), square=sq, gap=0.66 * sq,
                         margin=0.8 * sq)
    surfaces += [sb, pb]
    tex = [Noise(texel * 0.9, (0.25 * fov_w,) * 2, seed + f + 1) for f in range(6)]
    surfaces += box([0.22 * fov_w, -0.2 * fov_h, 0.8 * D], _tilt(25, 35), [0.2 * fov_w] * 3, tex, "box")
    return surfaces, [cb, pc], ["checker"] * len(cb) + ["board"] * len(pc)


def _scene_repetitive(D, K, image_size, seed):
    fov_w, fov_h, wall_z, wall_size = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    tile = fov_w / 7  # ~7 identical tiles across the image
    wall_tex = Tiled(Noise(texel * 1.35, (tile, tile), seed), tile, grout=0.06 * tile)
    surfaces = [plane([0, 0, wall_z], _tilt(6, -8), wall_size, wall_tex, "wall")]
    tile2 = fov_w / 12
    panel_tex = Tiled(Noise(texel * 0.9, (tile2, tile2), seed + 1), tile2, grout=0.08 * tile2)
    surfaces.append(plane([-0.12 * fov_w, 0.05 * fov_h, 0.9 * D], _tilt(15, 25), (0.55 * fov_w, 0.5 * fov_h),
                          panel_tex, "panel"))
    tex = [Noise(texel * 0.9, (0.2 * fov_w,) * 2, seed + f + 2) for f in range(6)]
    surfaces += box([0.25 * fov_w, -0.15 * fov_h, 0.75 * D], _tilt(-20, 30), [0.15 * fov_w] * 3, tex, "box")
    return surfaces, [], []


def _scene_floor(D, K, image_size, seed):
    """A checkered floor seen obliquely (depths about 0.8-1.3 D over the image), a
    textured cube and a textured sphere standing on it: curved and repetitive at once."""
    fov_w, fov_h, _, _ = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    tilt = _tilt(-40, 0)  # floor normal 40 deg from the optical axis: the image top is farther
    up = -tilt[:, 2]  # the floor's normal, towards the camera
    floor_size = (6.0 * fov_w, 8.0 * fov_h)
    surfaces = [plane([0, 0, D], tilt, floor_size, Checker(fov_w / 12), "floor")]
    side = 0.16 * D
    centre = np.array([-0.18 * fov_w, 0.0, D]) + 0.5 * side * up
    rot = tilt @ _tilt(0, 0) @ Rotation.from_euler("z", 25, degrees=True).as_matrix()
    tex = [Noise(texel * 0.9, (1.1 * side,) * 2, seed + f) for f in range(6)]
    surfaces += box(centre, rot, [side] * 3, tex, "cube")
    radius = 0.1 * D
    c = np.array([0.2 * fov_w, 0.0, D]) + 0.12 * fov_h * tilt[:, 1] + radius * up
    frame = np.column_stack([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # seam away from the camera
    surfaces.append(sphere(c, radius, Noise(texel * 0.9, (2 * np.pi * radius, np.pi * radius), seed + 7), frame))
    return surfaces, [], []


def _scene_workspace(D, K, image_size, seed):
    """Depths from 0.5 D to 1.5 D (0.4-1.2 m at D = 800 mm): a textured wall, a steeply
    slanted textured plane (a table top), three textured boxes at 0.5-1.1 D and one
    untextured panel (the dense-stereo benchmark's scene: every surface but the panel
    has texture)."""
    fov_w, fov_h, _, _ = _frame(D, K, image_size)
    texel = D / K[0, 0] * 1.4
    wall_z = 1.38 * D
    wall_size = (3.0 * fov_w * 1.38, 3.0 * fov_h * 1.38)
    surfaces = [plane([0, 0, wall_z], _tilt(6, -8), wall_size, Noise(texel * 1.35, wall_size, seed), "wall")]
    table_size = (1.1 * fov_w, 0.9 * D)
    surfaces.append(plane([0.05 * fov_w, 0.32 * fov_h, 0.95 * D], _tilt(-62, 4), table_size,
                          Noise(texel, table_size, seed + 1), "table"))
    for b, (c, dims, rot) in enumerate([
        ([-0.2 * fov_w, -0.02 * fov_h, 0.72 * D], [0.15 * fov_w, 0.18 * fov_w, 0.15 * fov_w], _tilt(20, 35)),
        ([0.24 * fov_w, -0.1 * fov_h, 0.95 * D], [0.22 * fov_w, 0.2 * fov_w, 0.2 * fov_w], _tilt(-15, -25)),
        ([0.02 * fov_w, 0.12 * fov_h, 0.6 * D], [0.08 * fov_w] * 3, _tilt(30, -20)),
    ]):
        ext = (max(dims) * 1.1, max(dims) * 1.1)
        surfaces += box(c, rot, dims, [Noise(texel * 0.8, ext, seed + 10 * b + f + 2) for f in range(6)], f"box{b}")
    surfaces.append(plane([-0.3 * fov_w, -0.3 * fov_h, 0.78 * D], _tilt(10, 15), (0.2 * fov_w, 0.14 * fov_h),
                          Constant(0.62), "panel"))
    return surfaces, [], []


_SCENE_BUILDERS = {"checker": _scene_checker, "natural": _scene_natural, "board": _scene_board,
                   "mixed": _scene_mixed, "repetitive": _scene_repetitive, "floor": _scene_floor,
                   "workspace": _scene_workspace}
