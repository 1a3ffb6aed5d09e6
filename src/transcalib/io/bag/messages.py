"""Opening a bag with ``rosbags`` (ROS 2 folder, single ``.mcap`` / ``.db3`` file, ROS 1
``.bag``) and decoding its image messages to pixel arrays.

Decoded images are what the tracker takes: ``(h, w)`` grey or ``(h, w, 3)`` RGB, uint8
or uint16. Raw encodings: ``mono8``, ``mono16``, ``rgb8``, ``bgr8``, ``rgba8``,
``bgra8``, ``8UC1``, ``8UC3`` (taken as bgr8, as cv_bridge does), ``16UC1``, and Bayer
``bayer_{rggb,bggr,gbrg,grbg}{8,16}`` (demosaiced as cv_bridge does);
``CompressedImage`` in any format OpenCV decodes (JPEG, PNG).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .options import BagError

__all__ = ["IMAGE_TYPES", "TF_TOPICS", "bag_kind", "open_bag", "image_topics", "decode_image"]

#: Message types of image topics.
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
#: tf topics and whether their transforms hold at all times.
TF_TOPICS = {"/tf": False, "/tf_static": True, "tf": False, "tf_static": True}
#: Bayer encodings -> OpenCV conversion to RGB (OpenCV names the pattern by row 2, col 2).
BAYER = {"rggb": cv2.COLOR_BayerBG2RGB, "bggr": cv2.COLOR_BayerRG2RGB, "gbrg": cv2.COLOR_BayerGR2RGB,
         "grbg": cv2.COLOR_BayerGB2RGB}
#: Raw encodings: (channels, dtype, conversion to RGB or None).
RAW = {"mono8": (1, np.uint8, None), "8uc1": (1, np.uint8, None), "mono16": (1, np.uint16, None),
       "16uc1": (1, np.uint16, None), "rgb8": (3, np.uint8, None), "bgr8": (3, np.uint8, cv2.COLOR_BGR2RGB),
       "8uc3": (3, np.uint8, cv2.COLOR_BGR2RGB), "rgba8": (4, np.uint8, cv2.COLOR_RGBA2RGB),
       "bgra8": (4, np.uint8, cv2.COLOR_BGRA2RGB)}
RAW.update({f"bayer_{p}{b}": (1, np.uint8 if b == 8 else np.uint16, code)
            for p, code in BAYER.items() for b in (8, 16)})


def bag_kind(path: Path) -> str:
    """``"ros2"`` (a folder with ``metadata.yaml``, or a ``.mcap`` / ``.db3`` file) or
    ``"ros1"`` (a ``.bag`` file); :class:`BagError` for anything else."""
    if not path.exists():
        raise BagError("path", f"{str(path)!r} does not exist")
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "ros2"
        raise BagError("path", f"{str(path)!r} is a folder without metadata.yaml, not a ROS 2 bag; give the bag "
                               "folder, a .mcap or .db3 file, or a ROS 1 .bag file")
    suffix = path.suffix.lower()
    if suffix in (".mcap", ".db3"):
        return "ros2"
    if suffix == ".bag":
        return "ros1"
    raise BagError("path", f"{str(path)!r} is not a ROS bag: expected a ROS 2 bag folder, a .mcap or .db3 file, or "
                           "a ROS 1 .bag file")


def open_bag(path: Path):
    """An open ``rosbags.highlevel.AnyReader`` on the bag (type definitions from the bag,
    else those of ROS 2 Humble / ROS 1 Noetic); :class:`BagError` if it cannot be read."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    kind = bag_kind(path)
    store = get_typestore(Stores.ROS2_HUMBLE if kind == "ros2" else Stores.ROS1_NOETIC)
    try:
        reader = AnyReader([path], default_typestore=store)
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as exc:
        raise BagError("path", f"{str(path)!r} cannot be read as a {kind.replace('ros', 'ROS ')} bag ({exc})") from None
    return reader


def image_topics(reader) -> dict[str, tuple[str, int]]:
    """``{topic: (message type, message count)}`` of the bag's image topics."""
    out = {}
    for conn in reader.connections:
        if conn.msgtype in IMAGE_TYPES:
            _, count = out.get(conn.topic, (conn.msgtype, 0))
            out[conn.topic] = (conn.msgtype, count + max(int(conn.msgcount), 0))
    return dict(sorted(out.items()))


def _raw(msg) -> np.ndarray:
    """A ``sensor_msgs/Image`` as ``(h, w[, c])`` of its encoding's dtype, rows cut to
    the pixels (``step`` may pad them), byte order from ``is_bigendian``."""
    encoding = msg.encoding.strip().lower()
    if encoding not in RAW:
        raise BagError("image_topic", f"image encoding {msg.encoding!r} is not supported; supported: "
                                      + ", ".join(sorted(RAW)) + ", or CompressedImage")
    channels, dtype, code = RAW[encoding]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    itemsize = np.dtype(dtype).itemsize
    data = np.asarray(msg.data, dtype=np.uint8)
    if step < w * channels * itemsize or data.size < h * step:
        raise BagError("image_topic", f"an image of {w}x{h} {msg.encoding} has {data.size} bytes, step {step}: "
                                      "too few for its size")
    rows = data[: h * step].reshape(h, step)[:, : w * channels * itemsize]
    order = ">" if msg.is_bigendian else "<"
    pixels = np.ascontiguousarray(rows).view(np.dtype(dtype).newbyteorder(order)).astype(dtype)
    pixels = pixels.reshape(h, w, channels) if channels > 1 else pixels.reshape(h, w)
    return pixels if code is None else cv2.cvtColor(pixels, code)


def _compressed(msg) -> np.ndarray:
    """A ``sensor_msgs/CompressedImage`` decoded by OpenCV (colour to RGB)."""
    pixels = cv2.imdecode(np.asarray(msg.data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        raise BagError("image_topic", f"a compressed image (format {msg.format!r}) cannot be decoded by OpenCV")
    if pixels.ndim == 3:
        pixels = cv2.cvtColor(pixels, cv2.COLOR_BGRA2RGB if pixels.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return pixels


def decode_image(msg, msgtype: str) -> np.ndarray:
    """Pixels of an image message: ``(h, w)`` grey or ``(h, w, 3)`` RGB, uint8 or uint16."""
    return _compressed(msg) if msgtype.endswith("CompressedImage") else _raw(msg)
