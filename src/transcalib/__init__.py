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
from . import render, simulate
from .diagnostics import diagnose
from .linear import estimate_linear
from .pipeline import calibrate
from .refine import crlb, refine
from .robust import RobustEstimate, estimate_robust
from .target import track_squares
from .tracks import Tracks, track

__all__ = [
    "Calibration",
    "DegenerateError",
    "Diagnostic",
    "InputError",
    "LinearEstimate",
    "MirroredError",
    "TranscalibError",
    "RobustEstimate",
    "Tracks",
    "calibrate",
    "crlb",
    "diagnose",
    "estimate_linear",
    "estimate_robust",
    "refine",
    "render",
    "simulate",
    "track",
    "track_squares",
]
__version__ = "0.1.0"
