"""Image front-end: images of a robot-held camera (or of an object the robot carries) -> tracks.

``track`` (:mod:`.dispatch`) groups the views by orientation and tracks each
pure-translation session (:mod:`.session`, by stage: :mod:`.detect` detection and
matching, :mod:`.epipoles`, :mod:`.propagate` chaining, :mod:`.refine`, :mod:`.checks`,
:mod:`.rotation` the rotation test), then links the groups across orientations
(:mod:`.link`); the target mode (:mod:`.target`) finds the corners of dark squares. This
is the only package that needs OpenCV's image functions.
"""

from __future__ import annotations

import importlib

# loaded on first use (PEP 562): importing a light module such as :mod:`.frames` or
# :mod:`.detect` does not import the SciPy-based stages (:func:`.dispatch.track` loads
# them on a second thread while it decodes the images)
_LAZY = {"track": ".dispatch", "epipole_ransac": ".epipoles", "GroupInfo": ".frames", "LinkInfo": ".frames",
         "PairInfo": ".frames", "TrackInfo": ".frames", "Tracks": ".frames", "load_images": ".frames",
         "RotatedViewsError": ".rotation", "track_sessions": ".sessions", "track_squares": ".target"}

__all__ = ["Tracks", "TrackInfo", "PairInfo", "GroupInfo", "LinkInfo", "track", "track_squares", "load_images",
           "epipole_ransac", "RotatedViewsError", "track_sessions"]


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'transcalib.images' has no attribute {name!r}")
    return getattr(importlib.import_module(_LAZY[name], __name__), name)
