"""Length units of robot positions: the names a pose file or an export may use, and the
factor between two of them."""

from __future__ import annotations

from ..errors import InputError

__all__ = ["length_scale"]

#: Length units, in millimetres.
LENGTH_UNITS = {"mm": 1.0, "m": 1000.0}


def length_scale(unit: str, to: str) -> float:
    """The factor that converts lengths in ``unit`` to ``to`` (``"mm"`` -> ``"m"``: 0.001).

    Raises
    ------
    InputError
        A unit not in :data:`LENGTH_UNITS`.
    """
    for u in (unit, to):
        if u not in LENGTH_UNITS:
            raise InputError(f"unit must be one of {', '.join(LENGTH_UNITS)}, got {u!r}")
    return LENGTH_UNITS[unit] / LENGTH_UNITS[to]
