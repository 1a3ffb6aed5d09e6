"""Renders of a robot's views at any flange pose (synth/robot.py): the pixel truth is exact,
eye-to-hand the carried object moves with the flange while the background stays, the poses
and the truth round-trip through the pose reader and the command line, and exact pixel
tracks of the renders calibrate to the truth (the conventions of the renderer and of
``calibrate`` agree)."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from transcalib import Poses, calibrate
from transcalib.cli.main import main as cli_main
from transcalib.errors import InputError
from transcalib.geometry.rotation import rotvec_to_matrix
from transcalib.images import target
from transcalib.io import read_poses, write_poses_csv, write_tracks
from transcalib.synth import render
from transcalib.synth.robot import PRESET_DIST, render_robot, robot_scene
from transcalib.synth.robot_layout import EYE_TO_HAND_R_BC, EYE_TO_HAND_T_BC, flange_poses, preset_camera
from transcalib.handeye.simulate import DEFAULT_R_X, DEFAULT_T_X, look_rotation

SETUPS = ("eye-in-hand", "eye-to-hand")
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(scope="module", params=SETUPS)
def layout(request):
    """The preset's poses and truth (no pixels cast), with the lens distortion."""
    return robot_scene(request.param, rng=5, images=False)


def _base_points(r, X):
    """``(n_views, n, 3)`` scene points in the base frame at each view, written out here
    from the model (not from the module under test)."""
    if r.setup == "eye-in-hand":
        return np.broadcast_to(X, (r.n_views,) + X.shape)
    return np.einsum("vij,nj->vni", r.R, X) + r.T[:, None]


def _opencv_pixels(r, X):
    """Pixels of scene points by ``cv2.projectPoints`` from each view's base-frame camera."""
    Xb = _base_points(r, X)
    out = []
    for i in range(r.n_views):
        if r.setup == "eye-in-hand":
            Rc, C = (r.R[i] @ r.R_X).T, r.T[i] + r.R[i] @ r.t_X
        else:
            Rc, C = r.R_X.T, r.t_X
        uv, _ = cv2.projectPoints(Xb[i], cv2.Rodrigues(Rc)[0], -Rc @ C, r.K, r.dist)
        out.append(uv.reshape(-1, 2))
    return np.array(out)


def test_projection_agrees_with_opencv_and_with_the_ray_cast(layout):
    r = layout
    X = r.sample_points(3000, rng=0)  # inside the faces (a ray through an edge may slip off it by rounding)
    uv = r.project(X)
    w, h = r.image_size
    Q, c = r.camera_rotations(), r.camera_centres()
    depth = np.einsum("vk,vnk->vn", Q[:, 2], X[None] - c[:, None])
    inside = (depth > 0) & (uv[..., 0] > -0.5) & (uv[..., 0] < w - 0.5) & (uv[..., 1] > -0.5) & (uv[..., 1] < h - 0.5)
    assert np.abs(uv - _opencv_pixels(r, X))[inside].max() < 1e-7  # px: the model, independently written
    uvc = r.project(r.corners)
    near = np.abs(uvc - r.K[:2, 2]).max(-1) < 2 * w  # distortion's polynomial is meant for the field of view
    assert np.abs(uvc - _opencv_pixels(r, r.corners))[near].max() < 1e-7
    exact = np.zeros_like(inside)
    for i in range(r.n_views):
        m = inside[i]
        hit = r.backproject(i, uv[i, m])  # the renderer's ray cast, in the base frame, mapped back
        err = np.linalg.norm(hit - X[m], axis=1)
        hit_depth = (hit - c[i]) @ Q[i, 2]
        ok = err < 1e-9 * depth[i, m]
        # the ray meets the point itself, or an occluder strictly in front of it
        assert np.all(ok | (hit_depth < depth[i, m] * (1 - 1e-9))), (i, err[~ok].min())
        exact[i, m] = ok
        # backproject at a given depth inverts project
        assert np.abs(r.backproject(i, uv[i, m], depth=depth[i, m]) - X[m]).max() < 1e-9 * depth[i, m].max()
    assert np.array_equal(exact, r.visible(X))
    per_view = exact.sum(1)
    assert per_view.min() >= (50 if r.setup == "eye-to-hand" else 20), per_view  # every view sees the scene
    assert np.array_equal(r.exact_tracks(X), np.where(exact[..., None], uv, np.nan), equal_nan=True)
    assert r.visible(r.corners).sum() >= r.n_views * 4  # box and plate corners, on the faces' edges


def test_preset_layout(layout):
    r = layout
    assert r.n_views == 12 and np.array_equal(r.session_of_view, [0] * 6 + list(range(1, 7)))
    assert np.abs(r.R[:6] - r.R[0]).max() == 0  # one session: pure translations
    moves = r.T[1:6] - r.T[0]
    assert np.linalg.matrix_rank(moves, tol=1.0) == 3  # spanning 3-D
    tilt = np.degrees(np.arccos(np.clip((np.trace(r.R[0].T @ r.R[6:], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert np.all((tilt >= 15 - 1e-6) & (tilt <= 45 + 1e-6)), tilt  # single views turned 15-45 deg
    centre = (0.0, 0.0, 50.0) if r.setup == "eye-in-hand" else (0.0, 0.0, 60.0)
    dist = np.linalg.norm(r.camera_centres() - centre, axis=1)
    assert np.all((dist >= 500) & (dist <= 1000)), dist
    # every view sees enough of the textured scene: the mat and boxes (eye-in-hand), the
    # carried plate and box (eye-to-hand), on a grid of every 8th pixel
    w, h = r.image_size
    grid = np.stack(np.meshgrid(np.arange(0, w, 8.0), np.arange(0, h, 8.0)), -1).reshape(-1, 2)
    central = [k for k, sf in enumerate(r.scene_surfaces) if not sf.name.startswith(("wall", "table"))]
    cover = np.array([np.isin(r.ray_hits(i, grid)[1], central).mean() for i in range(r.n_views)])
    assert cover.min() > (0.4 if r.setup == "eye-in-hand" else 0.1), cover
    assert np.array_equal(r.dist, PRESET_DIST)


def _board_pose(setup, tilt_deg, distance_mm, board_centre):
    """Flange pose putting the camera ``distance_mm`` from ``board_centre`` (scene frame),
    looking at it ``tilt_deg`` off the board's normal (+z)."""
    look = rotvec_to_matrix(np.radians([tilt_deg, 0.6 * tilt_deg, 0.0])) @ np.array([0.0, 0.0, -1.0])
    Q = look_rotation(look)[None]
    c = board_centre - distance_mm * Q[0, 2]
    R_X, t_X = (DEFAULT_R_X, DEFAULT_T_X) if setup == "eye-in-hand" else (EYE_TO_HAND_R_BC, EYE_TO_HAND_T_BC)
    R, T = flange_poses(Q, c[None], R_X, t_X, setup)
    return R, T, R_X, t_X


@pytest.mark.parametrize("setup", SETUPS)
def test_rendered_board_corners_land_on_the_projection(setup):
    """The images, not only the truth: the paper's board (on the table eye-in-hand, carried
    by the flange eye-to-hand), seen 25 deg off its normal; its corners found by target
    mode lie where ``project`` puts them."""
    size = (480, 360)
    K = preset_camera(size)
    board, corners = render.paper_board([0.0, 0.0, 20.0], np.eye(3), square=30.0, gap=20.0)
    wall = [render.plane([0, 0, -400], np.eye(3), (5000, 5000), render.Noise(6.0, (5000, 5000), 3), "wall")]
    R, T, R_X, t_X = _board_pose(setup, 25.0, 450.0, np.array([0.0, 0.0, 20.0]))
    if setup == "eye-to-hand":  # a static background far behind the carried board
        static = [sf.moved(R[0], T[0]) for sf in wall]
        r = render_robot([board], K, R, T, R_X, t_X, size, setup=setup, static_surfaces=static, corners=corners,
                         rng=0)
    else:
        r = render_robot([board] + wall, K, R, T, R_X, t_X, size, setup=setup, corners=corners, rng=0)
    uv = r.project(corners)[0]
    found = target.detect_squares(r.images[0], curved=False).reshape(-1, 2)
    d = np.linalg.norm(found[:, None] - uv[None], axis=-1).min(1)
    assert len(found) == 24
    assert np.median(d) < 0.03 and d.max() < 0.06, (np.median(d), d.max())


def test_eye_to_hand_object_moves_with_the_flange_background_stays():
    r = robot_scene("eye-to-hand", session_views=4, single_views=1, image_size=(200, 150), degrade=False,
                    supersample=1, rng=3)
    w, h = r.image_size
    uv = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2).astype(float)
    n_scene = len(r.scene_surfaces)
    carried = []
    for i in range(r.n_views):
        _, which = r.backproject(i, uv, return_surface=True)
        assert np.all(which >= 0)  # every pixel sees a surface: the wall fills the view
        carried.append((which < n_scene).reshape(h, w))
    carried = np.array(carried)
    assert np.all(carried.mean((1, 2)) > 0.1), carried.mean((1, 2))  # the object fills > 10 % of every view
    for i in range(1, r.n_views):
        assert (carried[0] != carried[i]).mean() > 0.01  # the object moved in the image
        wall = ~carried[0] & ~carried[i]
        assert np.array_equal(r.images[0][wall], r.images[i][wall])  # the static wall did not
        assert not np.array_equal(r.images[0][carried[0]], r.images[i][carried[0]])
    # the object's points follow the flange: P at view 0 is where the moved surfaces put it
    X = r.sample_points(500, rng=1)
    vis = r.visible(X)
    moved = np.einsum("vij,nj->vni", r.R, X) + r.T[:, None]
    assert np.ptp(moved[:, vis.all(0)], axis=0).max() > 50.0  # mm: the carried points moved in the base


def test_optics_blur_is_a_gaussian_of_the_sharp_render():
    kw = dict(session_views=4, single_views=0, image_size=(200, 150), degrade=False, supersample=1, rng=3)
    sharp, soft = robot_scene("eye-in-hand", **kw), robot_scene("eye-in-hand", blur_sigma=1.5, **kw)
    for a, b in zip(sharp.images, soft.images):
        expected = cv2.GaussianBlur(a.astype(float), (0, 0), 1.5, borderType=cv2.BORDER_REPLICATE)
        assert np.abs(b - expected).max() <= 1.0  # the sharp image was rounded to grey levels first
        assert np.abs(np.diff(b.astype(float), axis=1)).mean() < 0.7 * np.abs(np.diff(a.astype(float), axis=1)).mean()


def test_inputs_checked():
    r = robot_scene("eye-in-hand", images=False, rng=1)
    with pytest.raises(InputError, match="eye-in-hand the whole scene is fixed"):
        render_robot(r.scene_surfaces, r.K, r.R, r.T, r.R_X, r.t_X, r.image_size, static_surfaces=r.scene_surfaces[:1])
    with pytest.raises(InputError, match="setup"):
        robot_scene("eye-on-hand")
    with pytest.raises(InputError, match="R"):
        render_robot(r.scene_surfaces, r.K, r.R * 2, r.T, r.R_X, r.t_X, r.image_size)


def test_poses_round_trip_through_the_reader(layout, tmp_path):
    r = layout
    names = [f"view{i:02d}.jpg" for i in range(r.n_views)]
    write_poses_csv(tmp_path / "poses.csv", r.T, R=r.R, session=[str(s) for s in r.session_of_view], images=names)
    p = read_poses(tmp_path / "poses.csv")
    assert p.rotation_format == "quaternion" and p.images == names
    assert np.array_equal(p.T, r.T) and np.abs(p.R - r.R).max() < 1e-12
    assert p.session == [str(s) for s in r.session_of_view]


@pytest.mark.parametrize("setup", SETUPS)
def test_exact_tracks_calibrate_to_the_truth(setup):
    """calibrate(uv, Poses.of(T, R), setup=...) on pixel-exact tracks of the preset (ideal
    pinhole) returns K and the hand-eye pose of the renderer to 1e-9."""
    r = robot_scene(setup, degrade=False, images=False, rng=7)
    central = [k for k, sf in enumerate(r.scene_surfaces) if not sf.name.startswith(("wall", "table"))]
    uv = r.exact_tracks(r.sample_points(250, rng=2, surfaces=central))
    assert np.isfinite(uv[..., 0]).sum(1).min() >= 30
    cal = calibrate(uv, Poses.of(r.T, r.R), setup=setup, distortion="none", image_size=r.image_size, unit="mm", rng=0)
    assert np.abs(cal.K - r.K).max() < 1e-9 * r.K[0, 0]
    assert np.abs(cal.hand_eye.R - r.R_X).max() < 1e-9 and np.abs(cal.hand_eye.t - r.t_X).max() < 1e-7
    assert np.asarray(cal.hand_eye.undetermined).size == 0 and cal.hand_eye.setup == setup


def test_truth_round_trips_through_the_command_line(tmp_path):
    """Tracks and poses written as files, ``transcalib calibrate --setup eye-to-hand``: its
    hand_eye.json carries the truth's keys with the truth's values; the preset's lens is
    found with --distortion radial2."""
    r = robot_scene("eye-to-hand", images=False, rng=4)
    uv = r.exact_tracks(r.sample_points(250, rng=3))
    write_tracks(tmp_path / "tracks.csv", uv)
    write_poses_csv(tmp_path / "poses.csv", r.T, R=r.R)
    (tmp_path / "truth.json").write_text(json.dumps(r.truth_dict()))
    code = cli_main(["calibrate", "--tracks", str(tmp_path / "tracks.csv"), "--poses", str(tmp_path / "poses.csv"),
                     "--setup", "eye-to-hand", "--distortion", "radial2", "--truth", str(tmp_path / "truth.json"),
                     "--out", str(tmp_path / "out"), "--formats", "json", "--quiet"])
    assert code == 0
    he = json.loads((tmp_path / "out" / "hand_eye.json").read_text())
    truth = json.loads((tmp_path / "truth.json").read_text())
    for key in ("R_base_camera", "t_base_camera"):
        assert np.abs(np.subtract(he[key], truth[key])).max() < 1e-6, key
    assert he["setup"] == truth["setup"] == "eye-to-hand"


@pytest.mark.parametrize("folder, setup", [("robot_mixed", "eye-in-hand"), ("eye_to_hand", "eye-to-hand")])
def test_shipped_examples(folder, setup):
    """The files of examples/make_robot.py: poses and truth read back, the views listed
    exist at the truth's size, and the seed reproduces the poses."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_robot", EXAMPLES / "make_robot.py")
    make_robot = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_robot)
    out = EXAMPLES / folder
    truth = json.loads((out / "truth.json").read_text())
    p = read_poses(out / "poses.csv")
    seed = dict((f, s) for f, _, s in make_robot.EXAMPLES)[folder]
    r = make_robot.example_scene(setup, seed, images=False)
    assert truth["setup"] == setup and truth == {**truth, **json.loads(json.dumps(r.truth_dict()))}
    assert np.array_equal(p.T, r.T) and np.abs(p.R - r.R).max() < 1e-12
    for name in p.images:
        img = cv2.imread(str(out / name), cv2.IMREAD_GRAYSCALE)
        assert img is not None and img.shape[::-1] == tuple(truth["image_size"]), name


@pytest.mark.parametrize("dist", [[-0.3, 0.0, 0.0, 0.0, 0.0], [0.2, 0.1, 0.001, -0.002, 0.0], list(PRESET_DIST)])
def test_crop_through_the_lens_changes_no_pixel(dist, monkeypatch):
    """Each surface is cast only over the pixel box its rays can reach through the lens
    (raycast._distorted_box); casting every surface over the whole image gives the same
    bytes."""
    from transcalib.synth import raycast

    kw = dict(session_views=2, single_views=2, image_size=(160, 120), degrade=False, supersample=1, rng=1)
    for setup in SETUPS:
        r = robot_scene(setup, **kw)
        lensed = render_robot(r.scene_surfaces, r.K, r.R, r.T, r.R_X, r.t_X, r.image_size, setup=setup,
                              static_surfaces=r.static_surfaces, dist=dist, supersample=1)
        with monkeypatch.context() as m:
            m.setattr(raycast, "_distorted_box", lambda lo, hi, K, d, size: (np.array([-1.0, -1.0]),
                                                                              np.array(size, float)))
            whole = render_robot(r.scene_surfaces, r.K, r.R, r.T, r.R_X, r.t_X, r.image_size, setup=setup,
                                 static_surfaces=r.static_surfaces, dist=dist, supersample=1)
        assert np.array_equal(lensed.images, whole.images)
