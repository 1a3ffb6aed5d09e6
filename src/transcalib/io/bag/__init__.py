"""ROS bags in: still images of one topic and the flange pose of each from tf.

``options`` (:class:`BagOptions`, :class:`BagError`), ``messages`` (opening a ROS 2 /
ROS 1 bag with ``rosbags``, decoding images), ``tf`` (the tf tree, chains, poses at any
time), ``still`` (still frames and stops, sharpness), ``reader`` (:func:`read_bag`).

The names below are imported from their modules on first use (PEP 562): every command
builds its parser with the bag options' defaults, and only ``--bag`` needs the readers
(importing them all costs each command some 30 ms).
"""

from __future__ import annotations

import importlib

_MODULE_OF = {"decode_image": "messages", "image_topics": "messages",
              "STILL_DEG": "options", "STILL_MM": "options", "STILL_WINDOW_S": "options", "BagError": "options",
              "BagOptions": "options",
              "BagViews": "reader", "read_bag": "reader", "view_name": "reader",
              "StillSelection": "still", "select_still": "still", "sharpness": "still",
              "Chain": "tf", "Edge": "tf", "TfTree": "tf"}

__all__ = sorted(_MODULE_OF)


def __getattr__(name: str):
    if name not in _MODULE_OF:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_MODULE_OF[name]}", __name__), name)
    globals()[name] = value  # found directly from now on
    return value


def __dir__():
    return sorted(set(globals()) | set(_MODULE_OF))
