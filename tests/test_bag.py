"""Calibration straight from ROS bags (``calibrate --bag``, ``extract``): bags written
here with ``rosbags``' writer from the renderer (``examples/make_bag.py``: the sessions
example's robot, tf at 50 Hz, stops and moves, motion-blurred and defocused frames), in
ROS 2 (mcap, sqlite3; folders and single files) and ROS 1; every error of the issue."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags")

from transcalib.cli import main  # noqa: E402
from transcalib.geometry.rotation import rotation_angle_deg, rotvec_to_matrix  # noqa: E402
from transcalib.io import read_poses  # noqa: E402
from transcalib.io.bag import BagError, BagOptions, TfTree, decode_image, read_bag  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TOPIC = "/camera/image_raw"
FRAMES = ["--image-topic", TOPIC, "--base-frame", "base_link", "--flange-frame", "tool0"]
OPTIONS = BagOptions(TOPIC, "base_link", "tool0")
STOPS_PER_SESSION = 4  # 8 views: K and the hand-eye pose from 2 sessions, tracked in ~4 s
#: The robot's pose error given as zero: by default the score test finds a per-view
#: error of 0.0003 deg in the raw frames' tracks (p = 0.0003; the tracker's own per-view
#: structure at 0.01 px of pixel noise) and not in JPEG's, and eye-to-hand puts it on the
#: scene side; the tests that compare two readings of the same images compare without it.
PERFECT_ROBOT = ["--robot-sigma-deg", "0", "--robot-sigma", "0"]


def _make_bag_module():
    spec = importlib.util.spec_from_file_location("make_bag", EXAMPLES / "make_bag.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


MB = _make_bag_module()
N_VIEWS, N_IMAGES = 2 * STOPS_PER_SESSION, len(MB.frame_times(MB.make_run(stops_per_session=STOPS_PER_SESSION)))


@pytest.fixture(scope="module")
def rendered():
    """The run and its frames (rendered once for every bag of this module)."""
    run = MB.make_run(stops_per_session=STOPS_PER_SESSION)
    times = MB.frame_times(run)
    return run, times, MB.render_frames(run, times)


@pytest.fixture(scope="module")
def bags(rendered, tmp_path_factory):
    """Bags of the same run, written on first use: ``bags(storage, encoding)`` -> path."""
    root, made = tmp_path_factory.mktemp("bags"), {}
    run, _, frames = rendered

    def get(storage="mcap", encoding="mono8", setup="eye-in-hand"):
        if (storage, encoding, setup) not in made:
            name = f"{storage}_{encoding}_{setup}" + (".bag" if storage == "ros1" else "")
            made[storage, encoding, setup] = MB.write_bag(root / name, storage, encoding, run=run, frames=frames,
                                                          setup=setup)
        return made[storage, encoding, setup]

    return get


def _cli(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def _calibration(folder: Path) -> dict:
    return json.loads((folder / "calibration.json").read_text())


@pytest.fixture(scope="module")
def raw_route(bags, tmp_path_factory):
    """``calibrate --bag`` on the mcap folder (mono8), and ``extract`` of the same bag."""
    root = tmp_path_factory.mktemp("raw")
    bag = bags("mcap")
    assert main(["calibrate", "--bag", str(bag), *FRAMES, "--out", str(root / "cal"), "--formats", "json",
                 "--quiet"]) == 0
    assert main(["extract", "--bag", str(bag), *FRAMES, "--out", str(root / "views"), "--quiet"]) == 0
    assert main(["calibrate", "--bag", str(bag), *FRAMES, *PERFECT_ROBOT, "--out", str(root / "cal_exact"),
                 "--formats", "json", "--quiet"]) == 0
    return root


# ------------------------------------------------------------------ the two routes agree

def test_bag_route_equals_images_and_poses_route(raw_route, capsys):
    views = raw_route / "views"
    pngs = sorted(views.glob("view*.png"))
    assert len(pngs) == N_VIEWS and (views / "poses.csv").is_file()
    code, _, err = _cli(capsys, "calibrate", "--images", *pngs, "--poses", views / "poses.csv", "--unit", "m",
                        "--out", raw_route / "images", "--formats", "json", "--quiet")
    assert code == 0, err
    a, b = _calibration(raw_route / "cal"), _calibration(raw_route / "images")
    Ka, Kb = np.array(a["K"]), np.array(b["K"])
    assert np.abs(Ka - Kb).max() <= 1e-6 * np.abs(Kb).max()
    assert a["unit"] == b["unit"] == "m" and a["inputs"]["bag_images"]["used"] == N_VIEWS
    K_true = MB.K
    assert np.all(np.abs(Ka[[0, 1, 0, 1], [0, 1, 2, 2]] - K_true[[0, 1, 0, 1], [0, 1, 2, 2]]) < 0.5)


def test_views_are_the_stops_with_their_tf_poses(bags, rendered):
    """One view per stop, at the stop's pose (metres); moving frames and those whose
    window leaves the stop dropped; the defocused first frame of a stop never chosen."""
    run, times, _ = rendered
    views = read_bag(bags("mcap"), OPTIONS)
    assert views.n_views == len(run.T) == N_VIEWS
    np.testing.assert_allclose(views.T, run.T / 1000.0, atol=1e-12)
    assert rotation_angle_deg(np.swapaxes(views.R, 1, 2) @ run.R).max() < 1e-9
    t = (views.stamps_ns - MB.START_NS) / 1e9
    arrive = np.concatenate([[0.0], run.arrive[1:]])
    assert np.all(t - arrive >= 1.0 / MB.FPS - 1e-9), "a defocused first frame was chosen"
    # the verdict on every frame against the robot's true motion over its window
    sel, h = views.selection, OPTIONS.still_window_s / 2
    fine = [np.linspace(s - h, s + h, 101) for s in times]
    truly_still = np.array([np.ptp(run.pose(f)[0], axis=0).max() < 1e-9 for f in fine])
    covered = (times - h >= 0) & (times + h <= run.end_s + 0.5 - 1.0 / MB.TF_HZ)
    np.testing.assert_array_equal(sel.stop >= 0, truly_still & covered)
    np.testing.assert_array_equal(sel.uncovered, ~covered)
    c = views.counts()
    assert c["images"] == len(times) and c["used"] + c["still_not_sharpest"] + c["moved"] + c["outside_tf"] == c["images"]
    assert c["moved"] > N_IMAGES / 3 and c["stops"] == N_VIEWS


@pytest.mark.parametrize("storage, single_file", [("sqlite3", False), ("sqlite3", True), ("mcap", True),
                                                  ("ros1", False)])
def test_every_storage_gives_the_same_views(bags, storage, single_file):
    """ROS 2 sqlite3 and mcap (the folder or its one storage file) and ROS 1 (frames
    with a leading slash) give the pixels and poses of the mcap folder exactly."""
    ref = read_bag(bags("mcap"), OPTIONS)
    path = bags(storage)
    if single_file:
        path = next(path.glob("*.db3" if storage == "sqlite3" else "*.mcap"))
    views = read_bag(path, OPTIONS)
    assert views.n_views == ref.n_views
    assert all(np.array_equal(a, b) for a, b in zip(views.images, ref.images))
    np.testing.assert_array_equal(views.stamps_ns, ref.stamps_ns)
    np.testing.assert_allclose(views.T, ref.T, atol=1e-15)
    np.testing.assert_allclose(views.R, ref.R, atol=1e-15)


def test_compressed_images_within_the_calibrations_std(bags, raw_route, tmp_path, capsys):
    """JPEG at quality 95 moves K by less than 4.5 standard deviations of the difference
    of the two calibrations, sqrt(std_raw^2 + std_jpeg^2) (measured, the robot's error
    given as zero: fx 2.0, fy 1.9, cx 3.8, cy 1.4; fx by 2.3e-4 of itself, at a pixel
    noise of 0.012 px, where JPEG's own errors, shared by neighbouring windows, are of the
    noise's size; with the links' affine windows, before their projective row was held:
    fx 1.9, fy 1.8, cx 2.8). At quality 80, image_transport's default, fx and fy moved by
    up to 3.8 raw std (2.5 combined)."""
    code, _, err = _cli(capsys, "calibrate", "--bag", bags("mcap", "jpeg"), *FRAMES, *PERFECT_ROBOT,
                        "--out", tmp_path / "jpeg", "--formats", "json", "--quiet")
    assert code == 0, err
    raw, jpeg = _calibration(raw_route / "cal_exact"), _calibration(tmp_path / "jpeg")
    K, Kj = np.array(raw["K"]), np.array(jpeg["K"])
    for name, (i, j) in {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}.items():
        std = np.hypot(raw["std"][name], jpeg["std"][name])
        assert abs(Kj[i, j] - K[i, j]) < 4.5 * std, (name, Kj[i, j] - K[i, j], std)
    assert abs(Kj[0, 0] / K[0, 0] - 1) < 3e-4


def test_eye_to_hand_bag(bags, raw_route, tmp_path, capsys):
    """The same images with tf read eye-to-hand (the flange carries the scene, tf the
    inverse poses): --setup eye-to-hand gives the eye-in-hand K and the camera in the
    base at the eye-in-hand R_X (the robot's error given as zero: :data:`PERFECT_ROBOT`)."""
    from transcalib.handeye.simulate import DEFAULT_R_X

    code, _, err = _cli(capsys, "calibrate", "--bag", bags(setup="eye-to-hand"), *FRAMES, "--setup", "eye-to-hand",
                        *PERFECT_ROBOT, "--out", tmp_path / "e2h", "--formats", "json", "--quiet")
    assert code == 0, err
    K, Ke = np.array(_calibration(raw_route / "cal_exact")["K"]), np.array(_calibration(tmp_path / "e2h")["K"])
    assert np.abs(Ke - K).max() <= 1e-6 * np.abs(K).max()
    he = json.loads((tmp_path / "e2h" / "hand_eye.json").read_text())
    assert he["setup"] == "eye-to-hand" and he["unit"] == "m"
    assert rotation_angle_deg(np.array(he["R_base_camera"]).T @ DEFAULT_R_X) < 0.05


# ------------------------------------------------------------------ image encodings

def _roundtrip(msg):
    """The message serialised and read back as a ROS 2 bag stores it."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    return store.deserialize_cdr(store.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)


@pytest.fixture(scope="module")
def frame(rendered):
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    grey = rendered[2][5]
    rgb = np.stack([grey, (grey * 0.9).astype(np.uint8), (grey * 0.8).astype(np.uint8)], -1)
    return store, grey, rgb, MB._header(store, 1.0, "camera_link", False)[0]


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "rgb8", "bgr8", "png"])
def test_encodings_decode_exactly(frame, encoding):
    store, grey, rgb, header = frame
    msg = _roundtrip(MB._encode(store, grey, encoding, header))
    image = decode_image(msg, msg.__msgtype__)
    expected = {"mono8": grey, "png": grey, "mono16": grey.astype(np.uint16) * 257, "rgb8": rgb, "bgr8": rgb}
    assert image.dtype == expected[encoding].dtype
    np.testing.assert_array_equal(image, expected[encoding])


def test_big_endian_mono16_and_padded_rows(frame):
    store, grey, _, header = frame
    h, w = grey.shape
    rows = np.zeros((h, 2 * w + 6), np.uint8)  # 6 bytes of padding per row
    rows[:, : 2 * w] = (grey.astype(">u2") * 257).view(np.uint8).reshape(h, 2 * w)
    msg = store.types["sensor_msgs/msg/Image"](header=header, height=h, width=w, encoding="mono16", is_bigendian=1,
                                               step=2 * w + 6, data=rows.ravel())
    np.testing.assert_array_equal(decode_image(_roundtrip(msg), msg.__msgtype__), grey.astype(np.uint16) * 257)


def test_bayer_pattern_keeps_each_sites_colour(frame):
    """Demosaiced RGGB: every pixel keeps the colour its site sampled (R at even rows
    and columns, B at odd ones, G elsewhere), and smooth regions come out close."""
    store, grey, rgb, header = frame
    msg = _roundtrip(MB._encode(store, grey, "bayer_rggb8", header))
    image = decode_image(msg, msg.__msgtype__)
    assert image.shape == rgb.shape
    np.testing.assert_array_equal(image[2:-2:2, 2:-2:2, 0], rgb[2:-2:2, 2:-2:2, 0])
    np.testing.assert_array_equal(image[3:-2:2, 3:-2:2, 2], rgb[3:-2:2, 3:-2:2, 2])
    np.testing.assert_array_equal(image[2:-2:2, 3:-2:2, 1], rgb[2:-2:2, 3:-2:2, 1])
    assert np.median(np.abs(image.astype(int) - rgb)) <= 3


def test_unknown_encoding_named(frame):
    store, grey, _, header = frame
    msg = store.types["sensor_msgs/msg/Image"](header=header, height=2, width=2, encoding="yuv422", is_bigendian=0,
                                               step=4, data=np.zeros(8, np.uint8))
    with pytest.raises(BagError, match="yuv422.*not supported"):
        decode_image(msg, msg.__msgtype__)


# ------------------------------------------------------------------ tf

def _transform(store, parent, child, sec, t, rotvec):
    from transcalib.geometry.rotation import matrix_to_quaternion

    types = store.types
    q = matrix_to_quaternion(rotvec_to_matrix(np.asarray(rotvec, float)))
    header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=0),
                                          frame_id=parent)
    tr = types["geometry_msgs/msg/Transform"](translation=types["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
                                              rotation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2],
                                                                                             w=q[3]))
    return types["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child, transform=tr)


def test_chain_through_a_common_ancestor_interpolated():
    """base and flange both below ``world``: T_base_flange = T_world_base^-1 T_world_flange,
    each edge interpolated (linear, slerp) at the middle of its samples."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    tree = TfTree()
    tree.add(_transform(store, "world", "base", 0, [1.0, 2.0, 0.5], [0, 0, 0.4]), static=True)
    tree.add(_transform(store, "world", "link", 10, [0.0, 0.0, 0.0], [0, 0, 0]), static=False)
    tree.add(_transform(store, "world", "link", 12, [0.2, -0.4, 0.6], [0.0, 0.3, 0.0]), static=False)
    tree.add(_transform(store, "link", "flange", 0, [0.1, 0.0, 0.0], [0.5, 0, 0]), static=True)
    T, R, valid = tree.chain("base", "flange").pose_at(np.array([11, 9, 13], np.int64) * 10**9)
    assert valid.tolist() == [True, False, False]
    Rb, Rl, Rf = rotvec_to_matrix([0, 0, 0.4]), rotvec_to_matrix([0, 0.15, 0]), rotvec_to_matrix([0.5, 0, 0])
    tl = np.array([0.1, -0.2, 0.3])
    R_wf, t_wf = Rl @ Rf, tl + Rl @ [0.1, 0.0, 0.0]
    np.testing.assert_allclose(R[0], Rb.T @ R_wf, atol=1e-12)
    np.testing.assert_allclose(T[0], Rb.T @ (t_wf - [1.0, 2.0, 0.5]), atol=1e-12)
    with pytest.raises(BagError, match="two parents"):
        tree.add(_transform(store, "base", "link", 11, [0, 0, 0], [0, 0, 0]), static=False)
    tree.add(_transform(store, "elsewhere", "camera", 0, [0, 0, 0], [0, 0, 0]), static=True)
    with pytest.raises(BagError, match="separate trees"):
        tree.chain("base", "camera")


# ------------------------------------------------------------------ errors, exit 2, no output

def _clean_error(code, err, *words):
    assert code == 2, err
    lines = err.strip().splitlines()
    assert lines[-1].startswith("transcalib: error:") and "Traceback" not in err, err
    for w in words:
        assert w in lines[-1], (w, lines[-1])


@pytest.mark.parametrize("command", ["calibrate", "extract"])
@pytest.mark.parametrize("change, words", [
    ({"--image-topic": "/camera/missing"}, ["--image-topic", "'/camera/missing' is not in the bag",
                                            f"its image topics: /camera/image_raw (Image, {N_IMAGES} messages)"]),
    ({"--image-topic": "/tf"}, ["--image-topic", "TFMessage topic, not an image topic"]),
    ({"--flange-frame": "tool1"}, ["--flange-frame", "'tool1' is not in the tf tree",
                                   "base_link, camera_link, link_1, tool0, world"]),
    ({"--base-frame": "base"}, ["--base-frame", "'base' is not in the tf tree"]),
    ({"--still-window": "3"}, ["--bag: no still frames", f"of {N_IMAGES} images, ", "were taken while the flange moved",
                                "--still-mm"]),
])
def test_bag_errors_name_the_option(bags, tmp_path, capsys, command, change, words):
    args = dict(zip(FRAMES[::2], FRAMES[1::2]))
    args.update(change)
    out = tmp_path / "out"
    code, _, err = _cli(capsys, command, "--bag", bags("mcap"), *[x for kv in args.items() for x in kv],
                        "--out", out, "--quiet")
    _clean_error(code, err, *words)
    assert not out.exists()


@pytest.mark.parametrize("extra, words", [
    (["--unit", "mm"], ["--unit", "tf lengths are in metres", "got 'mm'"]),
    (["--poses", "poses.csv"], ["--poses", "not with --bag"]),
    (["--rotation-format", "quaternion"], ["--rotation-format", "not with --bag"]),
])
def test_calibrate_bag_option_conflicts(bags, tmp_path, capsys, extra, words):
    code, _, err = _cli(capsys, "calibrate", "--bag", bags("mcap"), *FRAMES, *extra, "--out", tmp_path / "o")
    _clean_error(code, err, *words)
    assert not (tmp_path / "o").exists()


def test_bag_paths_and_missing_options(tmp_path, capsys, bags):
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "folder").mkdir()
    cases = [(["--bag", tmp_path / "nope.bag", *FRAMES], ["--bag", "does not exist"]),
             (["--bag", tmp_path / "notes.txt", *FRAMES], ["--bag", "is not a ROS bag"]),
             (["--bag", tmp_path / "folder", *FRAMES], ["--bag", "without metadata.yaml"]),
             (["--bag", bags("mcap"), "--image-topic", TOPIC, "--base-frame", "base_link"],
              ["--flange-frame", "required with --bag"])]
    for args, words in cases:
        code, _, err = _cli(capsys, "extract", *args, "--out", tmp_path / "o")
        _clean_error(code, err, *words)
    code, _, err = _cli(capsys, "calibrate", "--tracks", "t.csv", "--poses", "p.csv", "--image-topic", TOPIC,
                        "--out", tmp_path / "o")
    _clean_error(code, err, "--image-topic", "applies to --bag only")
    assert not (tmp_path / "o").exists()


def test_extract_writes_what_the_pose_reader_reads(raw_route, bags):
    """poses.csv: view, x, y, z (metres), quaternion, image; images named in it exist."""
    poses = read_poses(raw_route / "views" / "poses.csv")
    ref = read_bag(bags("mcap"), OPTIONS)
    assert poses.rotation_format == "quaternion" and poses.images == ref.names
    np.testing.assert_array_equal(poses.T, ref.T)
    assert rotation_angle_deg(np.swapaxes(poses.R, 1, 2) @ ref.R).max() < 1e-6


def test_sparse_tf_motion_seen_between_samples():
    """tf at 0.1 Hz: no sample falls in an image's window, yet the interpolated motion
    at the window's ends marks it moved; where the samples agree, it is still."""
    from rosbags.typesys import Stores, get_typestore

    from transcalib.io.bag import select_still

    store = get_typestore(Stores.ROS2_HUMBLE)
    tree = TfTree()
    for sec, x in ((0, 0.0), (10, 0.0), (20, 1.0)):
        tree.add(_transform(store, "base", "flange", sec, [x, 0.0, 0.0], [0, 0, 0]), static=False)
    sel = select_still(tree.chain("base", "flange"), np.array([5, 15, 25]) * 10**9, OPTIONS)
    assert sel.stop.tolist() == [0, -1, -1] and sel.moved.tolist() == [False, True, False]
    assert sel.uncovered.tolist() == [False, False, True]
    np.testing.assert_allclose(sel.max_move_mm[1], 25.0)
