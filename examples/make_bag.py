"""Write a ROS bag of a robot run for ``transcalib calibrate --bag`` / ``transcalib extract``.

The scene and the flange poses are those of ``examples/make_sessions.py`` (a camera on the
flange over a table top, two wrist orientations, six stops each), rendered at 320 x 240.
The robot stands still at each stop for ``STOP_S`` and moves between stops in
``MOVE_S`` (a smooth cosine profile, translation and slerp of the rotation). The camera
runs at ``FPS``: frames while the robot moves are motion-blurred (the mean of renders
over the exposure), the first frame of every stop is defocused (so the sharpest must be
chosen), the others carry independent pixel noise. tf at ``TF_HZ``:

    world -> base_link            /tf_static
    base_link -> link_1           /tf   (the flange translation)
    link_1 -> tool0               /tf   (the flange rotation)
    tool0 -> camera_link          /tf_static (not used)

so ``base_link -> tool0`` is the flange pose of ``make_sessions.poses`` (in metres).
Storage: ``mcap`` or ``sqlite3`` (ROS 2 folder), ``ros1`` (a ``.bag`` file); encodings:
``mono8``, ``mono16``, ``rgb8``, ``bgr8``, ``bayer_rggb8`` (Image), ``jpeg``, ``png``
(CompressedImage; JPEG at quality 95). Deterministic.

With ``--setup eye-to-hand`` tf holds the same motion read the other way: the flange
carries the scene, the camera is fixed in the base, tf has the inverse flange poses.

    python examples/make_bag.py OUT [--storage mcap|sqlite3|ros1] [--encoding mono8|...] [--setup ...]
"""

from __future__ import annotations

import argparse
import importlib.util
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from transcalib.geometry.rotation import matrix_to_quaternion, matrix_to_rotvec, rotvec_to_matrix
from transcalib.synth import render

IMAGE_SIZE = (320, 240)
FPS, TF_HZ = 5.0, 50.0
STOP_S, MOVE_S, LEAD_S = 1.0, 0.8, 0.6
EXPOSURE_S, BLUR_SAMPLES, DEFOCUS_SIGMA, NOISE_STD = 0.06, 3, 1.5, 1.0
START_NS = 1_700_000_000_000_000_000
IMAGE_TOPIC = "/camera/image_raw"
JPEG_QUALITY = 95  # image_transport's default, 80, moves K by up to ~4 std in this scene


def _sessions_module():
    path = Path(__file__).resolve().parent / "make_sessions.py"
    spec = importlib.util.spec_from_file_location("make_sessions", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


SESSIONS = _sessions_module()
#: The sessions example's camera, scaled to 320 x 240.
K = np.diag([0.8, 0.8, 1.0]) @ SESSIONS.K


@dataclass(frozen=True)
class Run:
    """The robot's run: stop poses (mm, flange -> base) and the time line (s)."""

    R: np.ndarray  # (n_stops, 3, 3)
    T: np.ndarray  # (n_stops, 3) mm
    arrive: np.ndarray  # (n_stops,) s: time the robot reaches each stop

    @property
    def end_s(self) -> float:
        return float(self.arrive[-1] + STOP_S)

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flange pose at times ``t (n,)``: ``T (n, 3)`` mm, ``R (n, 3, 3)``."""
        t = np.asarray(t, float)
        k = np.clip(np.searchsorted(self.arrive, t, side="right") - 1, -1, len(self.arrive) - 1)
        nxt = np.clip(k + 1, 0, len(self.arrive) - 1)
        k0 = np.maximum(k, 0)
        f = np.clip((t - (self.arrive[k0] + STOP_S)) / MOVE_S, 0.0, 1.0)
        f = np.where(k < 0, 0.0, 0.5 - 0.5 * np.cos(np.pi * f))
        T = self.T[k0] + f[:, None] * (self.T[nxt] - self.T[k0])
        rel = matrix_to_rotvec(np.swapaxes(self.R[k0], 1, 2) @ self.R[nxt])
        return T, self.R[k0] @ rotvec_to_matrix(f[:, None] * rel)


def make_run(n_sessions: int = 2, stops_per_session: int = 6) -> Run:
    """The sessions example's poses (the first ``stops_per_session`` of each session's
    moves) on a time line: a lead-in, then a stop at each pose and a move to the next."""
    R, T, session = SESSIONS.poses(n_sessions)
    keep = np.concatenate([np.flatnonzero(session == s)[:stops_per_session] for s in range(n_sessions)])
    R, T = R[keep], T[keep]
    arrive = LEAD_S + np.arange(len(T)) * (STOP_S + MOVE_S)
    return Run(R, T, arrive)


def frame_times(run: Run) -> np.ndarray:
    """Image stamps (s): the camera runs at ``FPS`` through the whole run."""
    return np.arange(0.5 / FPS, run.end_s, 1.0 / FPS)


def render_frames(run: Run, times: np.ndarray, seed: int = 7) -> np.ndarray:
    """Grey uint8 frames ``(n, h, w)`` at ``times``: still ones sharp (the first of a stop
    defocused) plus noise, moving ones the mean of renders over the exposure."""
    from transcalib.handeye.simulate import DEFAULT_R_X, DEFAULT_T_X

    sf, _ = SESSIONS.surfaces()
    rng = np.random.default_rng(seed)
    cache, out = {}, []
    for t in times:
        ts = t + np.linspace(-EXPOSURE_S / 2, EXPOSURE_S / 2, BLUR_SAMPLES)
        T, R = run.pose(ts)
        if np.ptp(T, axis=0).max() < 1e-9 and np.allclose(R[0], R[-1]):
            key = tuple(np.round(T[0], 9))
            if key not in cache:
                cache[key] = render.render(sf, K, (R[0] @ DEFAULT_R_X).T, (T[0] + R[0] @ DEFAULT_T_X)[None],
                                           IMAGE_SIZE, supersample=2, dtype="float")[0]
            img = cache[key]
            k = np.searchsorted(run.arrive, t, side="right") - 1
            at_stop = t - (run.arrive[k] if k >= 0 else 0.0)
            if at_stop < 1.0 / FPS:
                img = cv2.GaussianBlur(img, (0, 0), DEFOCUS_SIGMA)
        else:
            img = np.mean([render.render(sf, K, (Ri @ DEFAULT_R_X).T, (Ti + Ri @ DEFAULT_T_X)[None], IMAGE_SIZE,
                                         supersample=1, dtype="float")[0] for Ti, Ri in zip(T, R)], axis=0)
        out.append(np.clip(np.rint(img + rng.normal(0, NOISE_STD, img.shape)), 0, 255).astype(np.uint8))
    return np.array(out)


def _encode(store, grey: np.ndarray, encoding: str, header):
    """An Image / CompressedImage message of the grey frame in ``encoding``."""
    types = store.types
    if encoding in ("jpeg", "png"):
        ok, buf = cv2.imencode(f".{'jpg' if encoding == 'jpeg' else 'png'}", grey,
                               [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if encoding == "jpeg" else [])
        return types["sensor_msgs/msg/CompressedImage"](header=header, format=encoding, data=buf.ravel())
    rgb = np.stack([grey, (grey * 0.9).astype(np.uint8), (grey * 0.8).astype(np.uint8)], -1)
    pixels = {"mono8": grey, "mono16": grey.astype(np.uint16) * 257, "rgb8": rgb, "bgr8": rgb[..., ::-1],
              "bayer_rggb8": _bayer_rggb(rgb)}[encoding]
    h, w = grey.shape
    data = np.ascontiguousarray(pixels).view(np.uint8).ravel()
    return types["sensor_msgs/msg/Image"](header=header, height=h, width=w, encoding=encoding, is_bigendian=0,
                                          step=data.size // h, data=data)


def _bayer_rggb(rgb: np.ndarray) -> np.ndarray:
    """The RGGB mosaic of an RGB image: R at even rows and columns, B at odd ones."""
    out = rgb[..., 1].copy()
    out[0::2, 0::2] = rgb[0::2, 0::2, 0]
    out[1::2, 1::2] = rgb[1::2, 1::2, 2]
    return out


def _header(store, t_s: float, frame: str, ros1: bool):
    ns = START_NS + int(round(t_s * 1e9))
    stamp = store.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    kw = {"seq": 0} if ros1 else {}
    return store.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **kw), ns


def _transform(store, header, child: str, t, R):
    types = store.types
    q = matrix_to_quaternion(R)
    tr = types["geometry_msgs/msg/Transform"](translation=types["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
                                              rotation=types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2],
                                                                                             w=q[3]))
    return types["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child, transform=tr)


def messages(store, run: Run, frames: np.ndarray, times: np.ndarray, encoding: str, ros1: bool,
             eye_to_hand: bool = False):
    """``(topic, ns, message)`` of the run in time order: tf_static once, tf at ``TF_HZ``,
    the images. ``eye_to_hand``: the same images read the other way (the flange carries
    the scene, the camera is fixed in the base at the eye-in-hand ``(R_X, t_X)``), so tf
    holds the inverse flange poses ``(R_i^T, -R_i^T T_i)``."""
    tfm = store.types["tf2_msgs/msg/TFMessage"]
    h0, _ = _header(store, 0.0, "world", ros1)
    static = [_transform(store, h0, "base_link", [0.5, -0.2, 0.8], rotvec_to_matrix([0, 0, 0.3])),
              _transform(store, _header(store, 0.0, "tool0", ros1)[0], "camera_link", [0.04, 0, 0.1], np.eye(3))]
    out = [("/tf_static", START_NS, tfm(transforms=static))]
    tf_t = np.arange(0.0, run.end_s + 0.5, 1.0 / TF_HZ)
    T, R = run.pose(tf_t)
    if eye_to_hand:
        R = np.swapaxes(R, 1, 2)
        T = -np.einsum("nij,nj->ni", R, T)
    for t, Ti, Ri in zip(tf_t, T / 1000.0, R):
        hb, ns = _header(store, t, "base_link", ros1)
        hl, _ = _header(store, t, "/link_1" if ros1 else "link_1", ros1)  # ROS 1 frames may carry a slash
        out.append(("/tf", ns, tfm(transforms=[_transform(store, hb, "link_1", Ti, np.eye(3)),
                                               _transform(store, hl, "tool0", np.zeros(3), Ri)])))
    for t, img in zip(times, frames):
        header, ns = _header(store, t, "camera_link", ros1)
        out.append((IMAGE_TOPIC, ns, _encode(store, img, encoding, header)))
    return sorted(out, key=lambda m: m[1])


def write_bag(path, storage: str = "mcap", encoding: str = "mono8", run: Run | None = None, frames=None,
              setup: str = "eye-in-hand") -> Path:
    """Write the run's bag at ``path`` (a folder for ``mcap`` / ``sqlite3``, a ``.bag``
    file for ``ros1``); ``frames`` from :func:`render_frames` (rendered when None);
    ``setup="eye-to-hand"``: tf of the same images read eye-to-hand (see :func:`messages`)."""
    from rosbags.typesys import Stores, get_typestore

    run = run or make_run()
    times = frame_times(run)
    frames = render_frames(run, times) if frames is None else frames
    ros1 = storage == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:  # Noetic's store in rosbags lacks tf2_msgs
        from rosbags.typesys import get_types_from_msg

        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    writer = _writer(Path(path), storage)
    with writer:
        conns, kw = {}, {"typestore": store}
        for topic, ns, msg in messages(store, run, frames, times, encoding, ros1, setup == "eye-to-hand"):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, **kw)
            data = store.serialize_ros1(msg, msg.__msgtype__) if ros1 else store.serialize_cdr(msg, msg.__msgtype__)
            writer.write(conns[topic], ns, data)
    return Path(path)


def _writer(path: Path, storage: str):
    if storage == "ros1":
        from rosbags.rosbag1 import Writer

        return Writer(path)
    from rosbags.rosbag2 import StoragePlugin, Writer

    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    return Writer(path, version=9, storage_plugin=plugin)


def main(argv=None) -> Path:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("out")
    p.add_argument("--storage", choices=["mcap", "sqlite3", "ros1"], default="mcap")
    p.add_argument("--encoding", choices=["mono8", "mono16", "rgb8", "bgr8", "bayer_rggb8", "jpeg", "png"],
                   default="mono8")
    p.add_argument("--setup", choices=["eye-in-hand", "eye-to-hand"], default="eye-in-hand")
    args = p.parse_args(argv)
    return write_bag(args.out, args.storage, args.encoding, setup=args.setup)


if __name__ == "__main__":
    print(main())
