"""Several translation sessions at different wrist orientations: full K from 2-axis moves
and the camera-to-flange (hand-eye) transform without a target.

Model (``docs/hand-eye.md``): flange pose of view ``i`` in the robot base ``(R_i, T_i)``,
camera in the flange ``(R_X, t_X)``::

    x_ij ~ K (R_i R_X)^T (X_j - T_i - R_i t_X)

Modules: :mod:`.sessions` (views grouped by orientation), :mod:`.linear` (the
multi-session linear start), :mod:`.observability` (which parts of ``t_X`` the data
determine; the CRLB), :mod:`.calibrate` (:func:`calibrate_sessions`), :mod:`.export`
(4x4, ROS tf, easy_handeye YAML, JSON), :mod:`.simulate` (scenes for tests and benchmarks).
"""

from __future__ import annotations

import importlib

_LAZY = {"calibrate_sessions": ".calibrate", "HandEyeCalibration": ".calibrate", "group_sessions": ".sessions",
         "SessionGrouping": ".sessions"}

__all__ = list(_LAZY)


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'transcalib.handeye' has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name], __name__), name)
