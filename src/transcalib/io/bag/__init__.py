"""ROS bags in: still images of one topic and the flange pose of each from tf.

``options`` (:class:`BagOptions`, :class:`BagError`), ``messages`` (opening a ROS 2 /
ROS 1 bag with ``rosbags``, decoding images), ``tf`` (the tf tree, chains, poses at any
time), ``still`` (still frames and stops, sharpness), ``reader`` (:func:`read_bag`).
"""

from .messages import decode_image, image_topics
from .options import STILL_DEG, STILL_MM, STILL_WINDOW_S, BagError, BagOptions
from .reader import BagViews, read_bag, view_name
from .still import StillSelection, select_still, sharpness
from .tf import Chain, Edge, TfTree

__all__ = ["BagOptions", "BagError", "BagViews", "read_bag", "view_name", "decode_image", "image_topics",
           "StillSelection", "select_still", "sharpness", "TfTree", "Chain", "Edge", "STILL_MM", "STILL_DEG",
           "STILL_WINDOW_S"]
