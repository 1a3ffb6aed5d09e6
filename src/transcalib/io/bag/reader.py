"""Views from a ROS bag: the still images of one topic, one per stop (the sharpest), and
the flange pose at each from tf.

Two passes over the bag: the first gathers tf and every image's ``header.stamp``; the
still frames and stops are judged from those alone (:mod:`.still`); the second decodes
only the still images, keeping the sharpest of each stop.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...types import Poses
from .messages import TF_TOPICS, decode_image, image_topics, open_bag
from .options import BagError, BagOptions
from .still import StillSelection, select_still, sharpness
from .tf import TfTree

__all__ = ["BagViews", "read_bag", "view_name"]


def view_name(k: int) -> str:
    """File name of view ``k``'s image (``view000.png``), as ``transcalib extract`` writes it."""
    return f"view{k:03d}.png"


@dataclass(frozen=True, eq=False)
class BagViews:
    """The views taken from a bag, in time order.

    Attributes
    ----------
    images : tuple of (h, w) or (h, w, 3) ndarray (n_views)
        Decoded pixels (grey, or RGB), uint8 or uint16.
    stamps_ns : (n_views,) int64
        ``header.stamp`` of each image, nanoseconds.
    T : (n_views, 3) float
        Flange positions in the base frame, metres (tf's unit).
    R : (n_views, 3, 3) float
        Flange -> base rotations.
    sharpness : (n_views,) float
        Variance of the Laplacian of each chosen image.
    selection : StillSelection
        The verdict on every image of the topic.
    path, topic, msgtype : str
    """

    images: tuple
    stamps_ns: np.ndarray
    T: np.ndarray
    R: np.ndarray
    sharpness: np.ndarray
    selection: StillSelection
    path: str
    topic: str
    msgtype: str

    @property
    def n_views(self) -> int:
        return len(self.images)

    @property
    def names(self) -> list[str]:
        return [view_name(k) for k in range(self.n_views)]

    def poses(self) -> Poses:
        """The views' flange poses (metres) with image names, as ``poses.csv`` has them."""
        return Poses([str(k) for k in range(self.n_views)], self.T, self.R, images=self.names, unit="m",
                     rotation_format="quaternion", path=self.path)

    def counts(self) -> dict:
        """How many images of the topic were used and why the others were dropped."""
        sel = self.selection
        still = int((sel.stop >= 0).sum())
        return {"images": len(sel.stop), "used": self.n_views, "still_not_sharpest": still - self.n_views,
                "moved": int(sel.moved.sum()), "outside_tf": int(sel.uncovered.sum()), "stops": sel.n_stops}

    def describe(self, options: BagOptions) -> str:
        """One line: the images used and the dropped ones by reason."""
        c = self.counts()
        return (f"{c['images']} images on {self.topic}: {c['used']} used (the sharpest of each of {c['stops']} "
                f"stops); dropped {c['still_not_sharpest']} still but less sharp, {c['moved']} moved (more than "
                f"{options.still_mm:g} mm or {options.still_deg:g} deg within {options.still_window_s:g} s), "
                f"{c['outside_tf']} outside the tf's time span")


def _first_pass(reader, topic: str) -> tuple[TfTree, np.ndarray]:
    """The tf tree and the ``header.stamp`` (ns) of every image of ``topic``, in bag order."""
    tree, stamps = TfTree(), []
    conns = [c for c in reader.connections
             if c.topic == topic or (c.topic in TF_TOPICS and c.msgtype == "tf2_msgs/msg/TFMessage")]
    for conn, _, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        if conn.topic == topic:
            stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        else:
            for transform in msg.transforms:
                tree.add(transform, TF_TOPICS[conn.topic])
    return tree, np.array(stamps, dtype=np.int64)


def _check_topic(reader, path: Path, topic: str) -> str:
    """The message type of ``topic``; :class:`BagError` listing the image topics if it is
    not an image topic of the bag."""
    topics = image_topics(reader)
    if topic in topics:
        return topics[topic][0]
    listed = ", ".join(f"{t} ({m.rsplit('/', 1)[-1]}, {n} messages)" for t, (m, n) in topics.items()) or "none"
    other = {c.topic: c.msgtype for c in reader.connections}
    what = f"is a {other[topic]} topic, not an image topic" if topic in other else "is not in the bag"
    raise BagError("image_topic", f"{topic!r} {what} {str(path)!r}; its image topics: {listed}")


def _no_still_error(sel: StillSelection, topic: str, options: BagOptions) -> BagError:
    n, moved, uncovered = len(sel.stop), int(sel.moved.sum()), int(sel.uncovered.sum())
    least = f"; the least motion within a window was {sel.max_move_mm[sel.moved].min():.3g} mm and " \
            f"{sel.max_turn_deg[sel.moved].min():.3g} deg" if moved else ""
    return BagError("still", f"no still frames on {topic}: of {n} images, {moved} were taken while the flange moved "
                    f"more than {options.still_mm:g} mm or {options.still_deg:g} deg within {options.still_window_s:g} "
                    f"s{least}, {uncovered} outside the tf's time span; record stops, or loosen --still-mm / "
                    "--still-deg / --still-window")


def _sharpest(reader, conn_topic: str, msgtype: str, stop: np.ndarray) -> tuple[list, np.ndarray, np.ndarray]:
    """Second pass: decode the still images and keep the sharpest of each stop.
    Returns the images, the index (into the topic's messages) and sharpness of each."""
    n_stops = int(stop.max()) + 1
    best_img, best_idx, best_score = [None] * n_stops, np.full(n_stops, -1), np.full(n_stops, -np.inf)
    conns = [c for c in reader.connections if c.topic == conn_topic]
    for k, (conn, _, raw) in enumerate(reader.messages(connections=conns)):
        s = stop[k]
        if s < 0:
            continue
        image = decode_image(reader.deserialize(raw, conn.msgtype), msgtype)
        score = sharpness(image)
        if score > best_score[s]:
            best_img[s], best_idx[s], best_score[s] = image, k, score
    return best_img, best_idx, best_score


def read_bag(path, options: BagOptions, log=None) -> BagViews:
    """The views of a bag: still images of ``options.image_topic``, the sharpest of each
    stop, with the flange pose ``T_base_flange`` from tf at each ``header.stamp``.

    Parameters
    ----------
    path : path-like
        A ROS 2 bag folder, a single ``.mcap`` or ``.db3`` file, or a ROS 1 ``.bag``.
    options : BagOptions
    log : callable(str) or None
        Progress lines.

    Raises
    ------
    BagError
        An unreadable bag, a topic that is not an image topic of the bag (the image
        topics listed), a frame not in the tf tree (the frames listed), no still frames
        (how many moved).
    """
    path = Path(path)
    log = log or (lambda _: None)
    reader = open_bag(path)
    try:
        msgtype = _check_topic(reader, path, options.image_topic)
        tree, stamps = _first_pass(reader, options.image_topic)
        chain = tree.chain(options.base_frame, options.flange_frame)
        sel = select_still(chain, stamps, options)
        if sel.n_stops == 0:
            raise _no_still_error(sel, options.image_topic, options)
        log(f"{len(stamps)} images, {sel.n_stops} stops: decoding {(sel.stop >= 0).sum()} still images")
        images, idx, score = _sharpest(reader, options.image_topic, msgtype, sel.stop)
    finally:
        reader.close()
    return BagViews(tuple(images), stamps[idx], sel.T[idx], sel.R[idx], score, sel, str(path), options.image_topic,
                    msgtype)

