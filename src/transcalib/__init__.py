"""transcalib: camera calibration and metric reconstruction from known translations.

After T. Pajdla and V. Hlavac, *Camera Calibration and Euclidean Reconstruction from
Known Translations* (1996). See ``docs/`` for the method and conventions.

``import transcalib`` is light: the public names below are imported on first use, and
OpenCV only when images are touched.
"""

from __future__ import annotations

import importlib

from .types import (
    CalibrateOptions,
    Calibration,
    Camera,
    DegenerateError,
    Diagnostic,
    HandEye,
    InputError,
    LinearEstimate,
    MirroredError,
    Poses,
    RansacOptions,
    RefineOptions,
    TranscalibError,
)

__version__ = "0.1.0"

#: public name -> (module, attribute); attribute None: the module itself
_LAZY = {
    "calibrate": (".pipeline.run", "calibrate"),
    "estimate_linear": (".estimate.linear", "estimate_linear"),
    "estimate_robust": (".estimate.robust", "estimate_robust"),
    "RobustEstimate": (".estimate.robust", "RobustEstimate"),
    "refine": (".estimate.refine", "refine"),
    "calibrate_sessions": (".pipeline.deprecated", "calibrate_sessions"),
    "read_poses": (".io.poses", "read_poses"),
    "load": (".io.calibration_file", "load_calibration"),
    "save": (".io.calibration_file", "save_calibration"),
    "export": (".io.export", "export_calibration"),
    "crlb": (".estimate.covariance", "crlb"),
    "diagnose": (".check", "diagnose"),
    "validate_views": (".pipeline.validate", "validate_views"),
    "track": (".images", "track"),
    "track_squares": (".images", "track_squares"),
    "Tracks": (".images.frames", "Tracks"),
    "simulate": (".synth.simulate", None),
    "plan": (".planning", "plan"), "evaluate_plan": (".planning", "evaluate_plan"),
    "render": (".synth.render", None),
    "dense": (".dense", None), "DenseOptions": (".dense", "DenseOptions"),
}

__all__ = [
    "CalibrateOptions", "Calibration", "Camera", "DegenerateError", "Diagnostic", "HandEye", "InputError",
    "LinearEstimate", "MirroredError", "Poses", "RansacOptions", "RefineOptions", "TranscalibError", *_LAZY,
]


def __getattr__(name: str):
    try:
        module, attr = _LAZY[name]
    except KeyError:
        raise AttributeError(f"module 'transcalib' has no attribute {name!r}") from None
    mod = importlib.import_module(module, __name__)
    value = mod if attr is None else getattr(mod, attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(__all__)
