"""What is specific to several flange orientations: sessions, their linear start, the single
views joining it, what the motion determines of the hand-eye offset, the exports.

Model (``docs/hand-eye.md``): flange pose of view ``i`` in the robot base ``(R_i, T_i)``,
camera in the flange ``(R_X, t_X)``::

    x_ij ~ K (R_i R_X)^T (X_j - T_i - R_i t_X)

Modules: :mod:`.sessions` (views grouped by orientation), :mod:`.linear` (the
multi-session linear start), :mod:`.join` (single views at their own orientation join the
start: their poses from the images, checked against the recorded ones, the offset),
:mod:`.observability` (which parts of ``t_X`` the data determine; the CRLB),
:mod:`.export` (4x4, ROS tf, easy_handeye YAML, JSON), :mod:`.simulate` (scenes for tests
and benchmarks). :func:`transcalib.calibrate` runs them for every motion.
"""

from __future__ import annotations

import importlib

_LAZY = {"group_sessions": ".sessions", "SessionGrouping": ".sessions"}

__all__ = list(_LAZY)


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'transcalib.handeye' has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name], __name__), name)
