"""Simulated robot motions: a camera on a flange, sessions of translations at several wrist
orientations, single views at any orientation, and the same motions eye-to-hand.

The camera of view ``i`` has rotation ``(R_i R_X)^T`` (base -> camera) and centre
``C_i = T_i + R_i t_X``; pixels come from :func:`transcalib.geometry.camera.project` (the
project's one camera model), one call per view. The default layout: a table-top scene
(base z up, points within ``+-150 x +-150 x 0..100`` mm) seen from about 0.5 m above, the
camera mounted ~100 mm off the flange, the wrist tilted by ``tilt_deg`` between sessions.

Eye-to-hand (:meth:`SessionScene.eye_to_hand`) is the same geometry read the other way: the
scene is carried by the flange (its points are in the flange frame), the camera is fixed in
the base with pose ``(R_X, t_X)``, and the robot records the flange poses, the inverses
``(R_i^T, -R_i^T T_i)`` of the camera's motion relative to the scene.
Used by the tests, the benchmarks and ``examples/make_sessions.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError
from ..geometry.camera import project
from ..geometry.rotation import rotvec_to_matrix
from ..types.options import SETUPS

__all__ = ["session_scene", "flange_rotations_looking", "DEFAULT_R_X", "DEFAULT_T_X"]

DEFAULT_K = np.array([[800.0, 0.0, 322.0], [0.0, 790.0, 238.0], [0.0, 0.0, 1.0]])
#: Camera in the flange: looking roughly along the flange z axis, mounted off-centre (mm).
DEFAULT_R_X = rotvec_to_matrix(np.radians([3.0, -4.0, 91.0]) * np.array([1, 1, 1]))
DEFAULT_T_X = np.array([42.0, -65.0, 95.0])


@dataclass(frozen=True, eq=False)
class SessionScene:
    """A simulated multi-session problem with its ground truth.

    Attributes
    ----------
    uv : (n_views, n_points, 2) float
        Observed pixels (noise added, NaN outside the image).
    uv_true : (n_views, n_points, 2) float
    T : (n_views, 3) float
        Flange positions (base frame, mm).
    R : (n_views, 3, 3) float
        Flange -> base rotations.
    session_of_view : (n_views,) int
        Session of each view; single views have their own session each.
    K, R_X, t_X, dist, X, noise_px, image_size
        Truth: intrinsics, camera in the flange (eye-to-hand: in the base), distortion,
        points (base frame; eye-to-hand: flange frame).
    setup : {"eye-in-hand", "eye-to-hand"}
    """

    uv: np.ndarray
    uv_true: np.ndarray
    T: np.ndarray
    R: np.ndarray
    session_of_view: np.ndarray
    K: np.ndarray
    R_X: np.ndarray
    t_X: np.ndarray
    dist: np.ndarray
    X: np.ndarray
    noise_px: float
    image_size: tuple
    setup: str = "eye-in-hand"

    @property
    def truth(self) -> dict:
        """The hand-eye truth named as in ``hand_eye.json``: ``R_<frame>_camera``,
        ``t_<frame>_camera`` (frame ``flange`` eye-in-hand, ``base`` eye-to-hand), plus
        ``K`` and ``image_size``."""
        frame = "flange" if self.setup == "eye-in-hand" else "base"
        return {f"R_{frame}_camera": self.R_X, f"t_{frame}_camera": self.t_X, "K": self.K,
                "image_size": self.image_size}

    def eye_to_hand(self) -> "SessionScene":
        """The same images seen by a camera fixed in the base while the flange carries the
        scene: the recorded poses become ``R_i^T`` and ``-R_i^T T_i``."""
        if self.setup != "eye-in-hand":
            raise InputError("eye_to_hand() applies to an eye-in-hand scene")
        return self._poses_inverted("eye-to-hand")

    def as_eye_in_hand(self) -> "SessionScene":
        """The scene with the poses the model uses: eye-to-hand poses inverted (itself
        eye-in-hand)."""
        return self if self.setup == "eye-in-hand" else self._poses_inverted("eye-in-hand")

    def _poses_inverted(self, setup: str) -> "SessionScene":
        Rt = np.transpose(self.R, (0, 2, 1))
        return replace(self, R=Rt, T=-np.einsum("vij,vj->vi", Rt, self.T), setup=setup)

    def camera_rotations(self) -> np.ndarray:
        """(n_views, 3, 3) scene -> camera rotations ``(R_i R_X)^T`` (eye-in-hand)."""
        return np.transpose(self.as_eye_in_hand().R @ self.R_X, (0, 2, 1))

    def camera_centres(self) -> np.ndarray:
        """(n_views, 3) camera centres in the scene frame, ``T_i + R_i t_X`` (eye-in-hand)."""
        scene = self.as_eye_in_hand()
        return scene.T + scene.R @ self.t_X


def look_rotation(direction: np.ndarray, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Base -> camera rotation of a camera looking along ``direction`` (its z axis), with
    its image y axis as close as possible to ``-up`` (y down)."""
    z = np.asarray(direction, float) / np.linalg.norm(direction)
    x = np.cross(-np.asarray(up, float), z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def flange_rotations_looking(directions: np.ndarray, R_X: np.ndarray) -> np.ndarray:
    """Flange -> base rotations ``R_s`` making the camera look along each direction:
    ``(R_s R_X)^T = look_rotation(d)``, i.e. ``R_s = look^T R_X^T``."""
    return np.stack([look_rotation(d).T @ R_X.T for d in directions])


def session_scene(rng=None, *, n_sessions: int = 3, views_per_session: int = 6, n_points: int = 60,
                  moves: str = "3d", step_mm: float = 60.0, tilt_deg: float = 25.0, distance_mm: float = 500.0,
                  noise_px: float = 0.0, K=None, R_X=None, t_X=None, dist=(), image_size=(640, 480),
                  rotations=None, X=None, single_views: int = 0, single_tilt_deg=(15.0, 40.0),
                  setup: str = "eye-in-hand") -> SessionScene:
    """Simulate sessions of a flange-mounted camera over a table-top scene.

    Parameters
    ----------
    rng : seed or Generator
    n_sessions : int
        Wrist orientations; session ``s`` tilts the viewing direction by ``tilt_deg`` about
        the base x axis (s = 1) and y axis (s = 2), ... (s = 0 looks straight down).
    views_per_session : int
    n_points : int
    moves : {"3d", "xy", "line"}
        Translations inside a session: random in a box, in the base xy plane (a 2-axis
        stage), or along base x.
    step_mm : float
        Size of the moves.
    tilt_deg, distance_mm : float
    noise_px : float
        Gaussian pixel noise per coordinate.
    K, R_X, t_X, dist, image_size
        Camera and hand-eye truth (defaults :data:`DEFAULT_K`, ...).
    rotations : (n_sessions, 3, 3) float, optional
        Flange rotations to use instead of the tilts (e.g. a SCARA wrist about base z).
    X : (n_points, 3) float, optional
        Scene points (base frame).
    single_views : int
        Views added after the sessions, each at its own orientation: the viewing direction
        tilted from straight down by a uniform angle in ``single_tilt_deg`` about a random
        horizontal axis, rolled by up to 30 deg, the distance varied by 10 %.
    single_tilt_deg : (2,) float
    setup : {"eye-in-hand", "eye-to-hand"}
        Eye-to-hand returns :meth:`SessionScene.eye_to_hand` of the simulated scene.

    Returns
    -------
    SessionScene
    """
    rng = np.random.default_rng(rng)
    K = DEFAULT_K if K is None else np.asarray(K, float)
    R_X = DEFAULT_R_X if R_X is None else np.asarray(R_X, float)
    t_X = DEFAULT_T_X if t_X is None else np.asarray(t_X, float)
    if moves not in ("3d", "xy", "line"):
        raise InputError(f"moves must be '3d', 'xy' or 'line', got {moves!r}")
    if setup not in SETUPS:
        raise InputError(f"setup must be one of {SETUPS}, got {setup!r}")
    if rotations is None and n_sessions == 0:
        rotations = np.zeros((0, 3, 3))
    elif rotations is None:
        axes = [np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([1.0, 1.0, 0]) / np.sqrt(2),
                np.array([1.0, -1.0, 0]) / np.sqrt(2)]
        dirs = [rotvec_to_matrix(np.radians(tilt_deg) * axes[s % len(axes)]) @ [0, 0, -1.0] for s in range(n_sessions)]
        rotations = flange_rotations_looking(np.array(dirs), R_X)
    rotations = np.asarray(rotations, float)
    if X is None:
        X = rng.uniform([-150, -150, 0], [150, 150, 100], (n_points, 3))
    centre = np.array([0.0, 0.0, 50.0])
    T, R, sess = [], [], []
    for s, Rs in enumerate(rotations):
        view_dir = (Rs @ R_X)[:, 2]  # camera z in the base frame
        T0 = centre - distance_mm * view_dir - Rs @ t_X
        T.append(T0 + _moves(rng, moves, views_per_session, step_mm))
        R.append(np.repeat(Rs[None], views_per_session, axis=0))
        sess += [s] * views_per_session
    for j in range(single_views):
        Rs, Ts = _single_view(rng, centre, distance_mm, R_X, t_X, rng.uniform(*single_tilt_deg))
        T.append(Ts[None])
        R.append(Rs[None])
        sess.append(len(rotations) + j)
    T, R, sess = np.concatenate(T), np.concatenate(R), np.array(sess)
    uv_true, unseen = _observe(K, np.transpose(R @ R_X, (0, 2, 1)), T + R @ t_X, X, dist, image_size)
    uv = uv_true + rng.normal(0.0, noise_px, uv_true.shape) if noise_px > 0 else uv_true.copy()
    uv[unseen] = np.nan
    scene = SessionScene(uv, uv_true, T, R, sess, K, R_X, t_X, np.asarray(dist, float), X, float(noise_px),
                         tuple(image_size))
    return scene.eye_to_hand() if setup == "eye-to-hand" else scene


def _moves(rng, moves: str, n: int, step_mm: float) -> np.ndarray:
    """(n, 3) translations of one session from its first view (mm): random in a box, in the
    base xy plane, or along base x."""
    if moves == "3d":
        d = rng.uniform(-step_mm, step_mm, (n, 3))
    elif moves == "xy":
        d = np.c_[rng.uniform(-step_mm, step_mm, (n, 2)), np.zeros(n)]
    else:
        d = np.c_[np.linspace(-step_mm, step_mm, n), np.zeros((n, 2))]
    d[0] = 0.0
    return d


def _single_view(rng, centre, distance_mm: float, R_X, t_X, tilt_deg: float):
    """Flange pose ``(R, T)`` of one view looking at ``centre`` from a direction tilted from
    straight down by ``tilt_deg`` about a random horizontal axis, rolled by up to 30 deg,
    at ``distance_mm`` +- 10 %."""
    axis = np.r_[rng.normal(size=2), 0.0]
    down = rotvec_to_matrix(np.radians(tilt_deg) * axis / np.linalg.norm(axis)) @ [0, 0, -1.0]
    roll = rotvec_to_matrix(np.radians(rng.uniform(-30, 30)) * np.array([0, 0, 1.0]))
    look = roll @ look_rotation(down)  # base -> camera, rolled about the optical axis
    R = look.T @ R_X.T
    C = centre - distance_mm * rng.uniform(0.9, 1.1) * down
    return R, C - R @ t_X


def with_robot_error(scene: SessionScene, sigma_rot_deg: float, sigma_pos: float, rng=None, *,
                     session_rot_deg: float = 0.0, session_pos: float = 0.0):
    """The scene taken by a robot with pose errors: the recorded poses stay the scene's (what
    the robot reports), the images become those of the true poses ``R_i exp([delta_i]x)``,
    ``T_i + eps_i`` (the reported pose times the error, :mod:`transcalib.estimate.robot_error`;
    the scene's pixel noise kept; points it does not see, or that leave the image, unseen),
    with ``delta_i`` (rad) of per-axis std ``sigma_rot_deg`` degrees and ``eps_i`` of per-axis
    std ``sigma_pos`` (mm), independent per view, plus a part common to each session's
    views of per-axis std ``session_rot_deg`` and ``session_pos`` (a robot whose error
    follows its arm configuration, which a session's small moves hardly change; drawn
    after the per-view part, so that without it a seed gives the same errors as before).
    Eye-to-hand the error is the flange's (the recorded robot poses). Inside one
    orientation the images so turn with the errors while the recorded orientations agree,
    as on a real robot. Returns ``(scene, errors (n_views, 6))``."""
    from ..estimate.robot_error import perturb_poses, sample_errors

    errors = sample_errors(len(scene.T), sigma_rot_deg, sigma_pos, rng)
    if session_rot_deg or session_pos:
        sessions = np.asarray(scene.session_of_view)
        errors = errors + sample_errors(sessions.max() + 1, session_rot_deg, session_pos, rng)[sessions]
    R_true, T_true = perturb_poses(scene.R, scene.T, errors)
    true = replace(scene, R=R_true, T=T_true)
    uv_true, unseen = _observe(scene.K, true.camera_rotations(), true.camera_centres(), scene.X, scene.dist,
                               scene.image_size)
    uv = uv_true + np.nan_to_num(scene.uv - scene.uv_true)
    uv[unseen | np.isnan(scene.uv[..., 0])] = np.nan
    return replace(scene, uv=uv, uv_true=uv_true), errors


def _observe(K, Rc, C, X, dist, image_size):
    """Exact pixels ``(V, n, 2)`` of the points ``X`` in cameras ``Rc (V, 3, 3)`` at
    centres ``C (V, 3)``, and ``(V, n)`` bool: outside the image or behind the camera."""
    uv_true = np.stack([project(K, Rc[i], X, C[i:i + 1], dist)[0] for i in range(len(C))])
    w, h = image_size
    depth = np.einsum("vb,vnb->vn", Rc[:, 2], X[None] - C[:, None])
    outside = (uv_true[..., 0] < 0) | (uv_true[..., 0] > w - 1) | (uv_true[..., 1] < 0) | (uv_true[..., 1] > h - 1)
    return uv_true, outside | (depth <= 0)
