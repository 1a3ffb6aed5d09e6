"""Random rendered scenes for the tracker's studies (not a benchmark itself).

:func:`study_scene` draws one scene of the rotation-test study (``bench_tracker_rotation``)
and of the tracker's tests: a floor or a wall with a cube and one or two spheres (curved
surfaces), textures drawn from checkers, tiles (repetitive) and noise, robot moves of
3-50 % of the scene distance, 4-6 views, sometimes lens distortion and JPEG. A view can
be rotated (``rotate_deg``: the model violation the tracker must detect) and every view
can carry a small orientation error (``pose_error_deg``: what real robots do, which it
must not refuse). :func:`floor_scene` is the false refusal of issue 21: a checkered
floor, a checkered cube and a sphere at 2-3 m, 250 mm moves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from transcalib.synth import render
from transcalib.synth.degrade import Degradations
from transcalib.synth.presets import _camera0_to_world, _tilt, default_camera
from transcalib.synth.surfaces import box, plane, sphere
from transcalib.synth.textures import Checker, Noise, Tiled

TEXTURES = ("checker", "tiled", "noise")


@dataclass(frozen=True, eq=False)
class StudyScene:
    """Rendered views with one camera ``K`` and a rotation per view.

    Attributes
    ----------
    images : (n_views, h, w) uint8
    K : (3, 3) float
    R : (n_views, 3, 3) float
        World -> camera rotation of each view (all equal for pure translations).
    T : (n_views, 3) float
        Camera centres.
    dist : (k,) float
    surfaces : list
    config : dict
        What was drawn (layout, textures, distance, move, ...).
    """

    images: np.ndarray
    K: np.ndarray
    R: np.ndarray
    T: np.ndarray
    dist: np.ndarray
    surfaces: list
    config: dict

    def rendered(self, view: int = 0) -> render.Rendered:
        """The scene as :class:`~transcalib.synth.render.Rendered` with the rotation of ``view``
        (exact for the views that share it)."""
        w, h = self.images.shape[2], self.images.shape[1]
        return render.Rendered(images=self.images, K=self.K, R=self.R[view], dist=self.dist, T=self.T,
                               surfaces=self.surfaces, corners=np.zeros((0, 3)),
                               corner_kind=np.array([], dtype=object), image_size=(w, h))


def _texture(kind, extent, texel, seed, period):
    if kind == "checker":
        return Checker(period)
    if kind == "tiled":
        return Tiled(Noise(texel, (period, period), seed), period, grout=0.06 * period)
    return Noise(texel, extent, seed)


def _objects(layout, D, fov_w, fov_h, texel, seed, textures, rng):
    """The surfaces of the scene in the camera-0 frame: the ground (floor or wall), a
    cube and one or two spheres on it."""
    if layout == "floor":
        frame = _tilt(-rng.uniform(30, 50), rng.uniform(-10, 10))
    else:
        frame = _tilt(rng.uniform(-15, 15), rng.uniform(-15, 15))
    up = -frame[:, 2]  # ground normal towards the camera
    size = (6 * fov_w, 8 * fov_h)
    depth = D if layout == "floor" else 1.3 * D
    surfaces = [plane([0, 0, depth], frame, size,
                      _texture(textures[0], size, texel * 1.35, seed, fov_w * rng.uniform(1 / 16, 1 / 8)), "ground")]

    def on_ground(x, y):
        return np.array([0.0, 0.0, depth]) + x * fov_w * frame[:, 0] + y * fov_h * frame[:, 1]

    side = rng.uniform(0.12, 0.2) * D
    rot = frame @ Rotation.from_euler("z", rng.uniform(0, 90), degrees=True).as_matrix()
    faces = [_texture(textures[1], (1.1 * side,) * 2, texel * 0.9, seed + f, side / 4) for f in range(6)]
    surfaces += box(on_ground(rng.uniform(-0.3, -0.1), rng.uniform(-0.2, 0.2)) + 0.5 * side * up, rot,
                    [side] * 3, faces, "cube")
    for k in range(int(rng.integers(1, 3))):
        r = rng.uniform(0.06, 0.12) * D
        sframe = np.column_stack([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # seam at the back
        tex = _texture(textures[2], (2 * np.pi * r, np.pi * r), texel * 0.9, seed + 7 + k, r / 2)
        surfaces.append(sphere(on_ground(rng.uniform(0.1, 0.3), rng.uniform(-0.25, 0.25) + 0.3 * k) + r * up, r,
                               tex, sframe, f"sphere{k}"))
    return surfaces


def _small_rotation(angle_deg, rng):
    axis = rng.normal(size=3)
    return Rotation.from_rotvec(np.radians(angle_deg) * axis / np.linalg.norm(axis)).as_matrix()


def study_scene(rng, *, image_size=(480, 360), rotate_deg: float = 0.0, pose_error_deg=None,
                layout: str | None = None, textures=None, distance=None, move_fraction=None, n_views=None,
                distortion: bool | None = None, noise_std=None, jpeg: bool | None = None,
                supersample: int = 1) -> StudyScene:
    """One random scene of the rotation-test study (module docstring).

    Parameters
    ----------
    rng : seed or Generator
    image_size : (w, h)
    rotate_deg : float
        One view (random, not the first) is rotated by this angle about a random axis.
    pose_error_deg : (lo, hi) or None
        Every view's orientation carries an error of ``U(lo, hi)`` degrees about a random axis.
    layout, textures, distance, move_fraction, n_views, distortion, noise_std, jpeg
        Fix what is otherwise drawn: ``"floor"`` / ``"wall"``; the (ground, cube, sphere)
        textures from :data:`TEXTURES`; the scene distance (mm); the robot move as a
        fraction of it (3-50 %); 4-6 views; a lens with ``k1`` in [-0.15, 0.05]; the
        pixel noise (0.5-2 grey levels); JPEG at quality 80-95.
    """
    rng = np.random.default_rng(rng)
    layout = layout or str(rng.choice(["floor", "wall"]))
    textures = tuple(textures or rng.choice(TEXTURES, 3))
    D = float(distance if distance is not None else rng.uniform(600, 3000))
    frac = float(move_fraction if move_fraction is not None else np.exp(rng.uniform(np.log(0.03), np.log(0.5))))
    n = int(n_views if n_views is not None else rng.integers(4, 7))
    lens = bool(rng.uniform() < 0.25) if distortion is None else distortion
    dist = np.array([rng.uniform(-0.15, 0.05), 0.0, 0.0, 0.0, 0.0]) if lens else np.zeros(0)
    noise = float(noise_std if noise_std is not None else rng.uniform(0.5, 2.0))
    use_jpeg = bool(rng.uniform() < 0.3) if jpeg is None else jpeg
    K, R, T = default_camera(None, None, None, image_size, n, frac * D, rng)
    w, h = image_size
    fov_w, fov_h = D * w / K[0, 0], D * h / K[1, 1]
    seed = int(rng.integers(2**31))
    surfaces_c = _objects(layout, D, fov_w, fov_h, D / K[0, 0] * 1.4, seed, textures, rng)
    surfaces, _ = _camera0_to_world(surfaces_c, [], R, T[0])
    Rv = np.repeat(R[None], n, axis=0)
    rotated = -1
    if rotate_deg:
        rotated = int(rng.integers(1, n))
        Rv[rotated] = _small_rotation(rotate_deg, rng) @ R
    if pose_error_deg is not None:
        Rv = np.stack([_small_rotation(rng.uniform(*pose_error_deg), rng) @ Ri for Ri in Rv])
    degrade = Degradations(jpeg_quality=int(rng.integers(80, 96))) if use_jpeg else None
    images = np.concatenate([render.render(surfaces, K, Rv[i], T[i:i + 1], image_size, dist=dist,
                                           supersample=supersample, noise_std=noise, degrade=degrade,
                                           rng=int(rng.integers(2**31))) for i in range(n)])
    config = {"layout": layout, "textures": textures, "distance": D, "move_fraction": frac, "n_views": n,
              "k1": float(dist[0]) if lens else 0.0, "noise_std": noise, "jpeg": use_jpeg, "rotated_view": rotated,
              "rotate_deg": rotate_deg, "pose_error_deg": pose_error_deg}
    return StudyScene(images=images, K=K, R=Rv, T=T, dist=dist, surfaces=surfaces, config=config)


def orbit_scene(rng, *, kind: str = "natural", image_size=(640, 480), views_per_session: int = 6,
                angles_deg=(30.0,), singles_deg=(), distance: float = 800.0, baseline: float = 0.1,
                noise_std: float = 1.0, degrade=None, supersample: int = 1):
    """Sessions at several orientations looking at one preset scene, and single views.

    Session 0 is the preset's camera with ``views_per_session`` translations; each angle
    of ``angles_deg`` adds a session whose camera orbits the scene centre (the point at
    ``distance`` on the first camera's axis) by that angle about a random axis, with its
    own translations; each angle of ``singles_deg`` adds one view orbited likewise.

    Returns
    -------
    scene : StudyScene
        ``R`` per view; ``config["groups"]`` the group label of each view, ``config["angle"]``
        the orbit angle of each group.
    """
    rng = np.random.default_rng(rng)
    base = render.render_scene(kind, n_views=views_per_session, image_size=image_size, distance=distance,
                               baseline=baseline, noise_std=noise_std, supersample=1, rng=rng)
    centre = base.T[0] + distance * base.R[2]
    Rs, Ts, labels = [base.R] * views_per_session, list(base.T), ["s0"] * views_per_session
    angle = {"s0": 0.0}
    for g, (deg, n) in enumerate([(d, views_per_session) for d in angles_deg] + [(d, 1) for d in singles_deg]):
        Q = _small_rotation(deg, rng)
        R = base.R @ Q.T  # camera rotated with the orbit: it keeps looking at the centre
        moves = render.robot_translations(n, baseline * distance, rng) if n > 1 else np.zeros((1, 3))
        label = f"s{g + 1}" if n > 1 else f"v{g + 1}"
        for t in moves:
            Rs.append(R)
            Ts.append(centre + Q @ (base.T[0] - centre) + t)
            labels.append(label)
        angle[label] = float(deg)
    R, T = np.array(Rs), np.array(Ts)
    images = np.concatenate([render.render(base.surfaces, base.K, R[i], T[i:i + 1], image_size, supersample=supersample,
                                           noise_std=noise_std, degrade=degrade, rng=int(rng.integers(2**31)))
                             for i in range(len(T))])
    return StudyScene(images=images, K=base.K, R=R, T=T, dist=np.zeros(0), surfaces=base.surfaces,
                      config={"kind": kind, "groups": labels, "angle": angle})


def link_quality(scene: StudyScene, uv: np.ndarray, groups: list, margin_px: float = 12.0, tol_px: float = 2.0):
    """How well the points of ``uv`` are linked across the groups of ``scene``.

    A point's truth is the scene point seen at its first observation; it is *visible* in a
    group when, unoccluded and ``margin_px`` inside the image, it is seen by 2+ of the
    group's views (1 for a single view). For every pair of groups: the points visible in
    both, those of them seen in both (*linked*), and the observations in the other group
    farther than ``tol_px`` from the truth's projection (*wrong links*, points next to an
    occlusion edge left out): the observations in the group that does not hold the point's
    first observation. Returns ``{(g, h): (visible, linked, wrong, linked_all)}``.
    """
    labels = list(dict.fromkeys(groups))
    views = {g: [i for i, x in enumerate(groups) if x == g] for g in labels}
    seen = np.isfinite(uv[..., 0])
    first = np.argmax(seen, axis=0)
    X = np.full((uv.shape[1], 3), np.nan)
    ghost = np.zeros(uv.shape[1], bool)
    for v in range(uv.shape[0]):
        mine = first == v
        if mine.any():
            rv = replace_view(scene, v)
            X[mine] = rv.backproject(0, uv[v, mine])
            ghost[mine] = rv.near_occlusion(0, uv[v, mine])
    vis = np.zeros(seen.shape, bool)
    err = np.full(seen.shape, np.inf)
    for v in range(uv.shape[0]):
        rv = replace_view(scene, v)
        vis[v] = rv.visible(X, margin_px=margin_px)[0]
        err[v] = np.linalg.norm(rv.project(X)[0] - uv[v], axis=-1)
    out = {}
    for a in labels:
        for b in labels:
            if a >= b:
                continue
            need_a, need_b = min(2, len(views[a])), min(2, len(views[b]))
            both = (vis[views[a]].sum(0) >= need_a) & (vis[views[b]].sum(0) >= need_b) & ~ghost
            in_a, in_b = seen[views[a]].any(0), seen[views[b]].any(0)
            linked = in_a & in_b & ~ghost
            grp = np.array([groups[v] for v in first])
            other = np.where(grp == a, 1, 0)  # the group not holding the first observation: b for points of a
            off_b = (np.where(seen[views[b]], err[views[b]], 0.0) > tol_px).any(0)
            off_a = (np.where(seen[views[a]], err[views[a]], 0.0) > tol_px).any(0)
            bad = linked & np.where(other == 1, off_b, off_a)
            out[(a, b)] = (int(both.sum()), int((both & linked).sum()), int(bad.sum()), int(linked.sum()))
    return out


def replace_view(scene: StudyScene, v: int) -> render.Rendered:
    """View ``v`` of ``scene`` alone as :class:`~transcalib.synth.render.Rendered`."""
    w, h = scene.images.shape[2], scene.images.shape[1]
    return render.Rendered(images=scene.images[v:v + 1], K=scene.K, R=scene.R[v], dist=scene.dist,
                           T=scene.T[v:v + 1], surfaces=scene.surfaces, corners=np.zeros((0, 3)),
                           corner_kind=np.array([], dtype=object), image_size=(w, h))


def floor_scene(rng=0, *, image_size=(640, 480), n_views: int = 5, noise_std: float = 1.0) -> StudyScene:
    """The false refusal of issue 21: 5 views, 250 mm moves at 2-3 m over a checkered
    floor with a checkered cube and a noise-textured sphere (pure translation, no
    distortion); seed 0 was refused by the tracker before issue 21."""
    return study_scene(rng, image_size=image_size, layout="floor", textures=("checker", "checker", "noise"),
                       distance=2500.0, move_fraction=0.1, n_views=n_views, distortion=False, noise_std=noise_std,
                       jpeg=False, supersample=2)
