"""transcalib: camera calibration and metric reconstruction from known translations.

After T. Pajdla and V. Hlavac, *Camera Calibration and Euclidean Reconstruction from
Known Translations* (1996). See ``docs/`` for the method and conventions.
"""

from .types import (
    Calibration,
    DegenerateError,
    Diagnostic,
    InputError,
    LinearEstimate,
    MirroredError,
    TranscalibError,
)
from . import simulate

__all__ = [
    "Calibration",
    "DegenerateError",
    "Diagnostic",
    "InputError",
    "LinearEstimate",
    "MirroredError",
    "TranscalibError",
    "simulate",
]
__version__ = "0.1.0"
