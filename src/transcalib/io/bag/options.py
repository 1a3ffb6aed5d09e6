"""What the bag reader is asked (:class:`BagOptions`) and how it refuses (:class:`BagError`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ...errors import InputError

__all__ = ["BagOptions", "BagError", "STILL_MM", "STILL_DEG", "STILL_WINDOW_S"]

#: Default largest flange motion (mm) within the window for an image to count as still.
STILL_MM = 0.05
#: Default largest flange rotation (degrees) within the window.
STILL_DEG = 0.01
#: Default length (seconds) of the window centred on an image's stamp.
STILL_WINDOW_S = 0.5


class BagError(InputError):
    """A bag that cannot give what was asked; ``parameter`` names the
    :class:`BagOptions` field (or ``"path"``) at fault, for the command line to name
    its option."""

    def __init__(self, parameter: str, message: str):
        super().__init__(message)
        self.parameter = parameter


@dataclass(frozen=True)
class BagOptions:
    """How views are taken from a bag.

    Attributes
    ----------
    image_topic : str
        Topic of ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` messages.
    base_frame, flange_frame : str
        tf frames: the flange pose is ``T_base_flange`` at each image's ``header.stamp``,
        composed along the tf tree (intermediate frames allowed).
    still_mm, still_deg : float
        An image is still when the flange moved at most this far (mm) and turned at most
        this much (degrees) from its pose at the stamp, over the window.
    still_window_s : float
        Length of the window centred on the stamp (seconds).
    """

    image_topic: str
    base_frame: str
    flange_frame: str
    still_mm: float = STILL_MM
    still_deg: float = STILL_DEG
    still_window_s: float = STILL_WINDOW_S

    def __post_init__(self):
        for name in ("image_topic", "base_frame", "flange_frame"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name).strip("/ "):
                raise BagError(name, f"{name}: expected a non-empty name, got {getattr(self, name)!r}")
        for name in ("still_mm", "still_deg", "still_window_s"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise BagError(name, f"{name}: expected a positive number, got {value!r}")

    @property
    def still_m(self) -> float:
        """``still_mm`` in metres, the unit of tf."""
        return self.still_mm / 1000.0
