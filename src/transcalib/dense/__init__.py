"""Dense metric reconstruction: multi-baseline stereo under known translations.

``transcalib.dense(calibration, images, poses, ...)`` (:func:`dense`) gives, for each
reference view, depth, confidence and depth standard deviation on the view's original
pixel grid, and the fused metric point cloud in the robot frame. This package is itself
callable: ``transcalib.dense(...)`` is :func:`dense` whether or not one of its modules
was imported first (``from transcalib.dense import DenseOptions``).

Modules: ``views`` (the camera of every view, sessions, the default reference view),
``images`` (grey levels, noise, normalisation, the pinhole canvas), ``sweep`` (the plane
sweep in inverse depth), ``depth`` (depth, confidence, matching uncertainty),
``uncertainty`` (the calibration's part), ``fuse`` (the cloud and the consistency check),
``reconstruct`` (``dense`` itself), ``options`` (options and results).
"""

import sys
import types

from .options import DenseOptions, DenseResult, DepthMap, DepthStats
from .reconstruct import dense

__all__ = ["dense", "DenseOptions", "DenseResult", "DepthMap", "DepthStats"]


class _CallablePackage(types.ModuleType):
    """The package module, callable as :func:`dense` (``transcalib.dense(...)``)."""

    def __call__(self, *args, **kwargs):
        return dense(*args, **kwargs)


sys.modules[__name__].__class__ = _CallablePackage
