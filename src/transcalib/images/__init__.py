"""Image front-end: images of a robot-held camera (or of an object the robot carries) -> tracks.

``track`` (:mod:`.dispatch`) groups the views by orientation and tracks each
pure-translation session (:mod:`.session`, by stage: :mod:`.detect` detection and
matching, :mod:`.epipoles`, :mod:`.propagate` chaining, :mod:`.refine`, :mod:`.checks`,
:mod:`.rotation` the rotation test), then links the groups across orientations
(:mod:`.link`); the target mode (:mod:`.target`) finds the corners of dark squares. This
is the only package that needs OpenCV's image functions.
"""

from __future__ import annotations

from .dispatch import track
from .epipoles import epipole_ransac
from .frames import GroupInfo, LinkInfo, PairInfo, TrackInfo, Tracks, load_images
from .rotation import RotatedViewsError
from .sessions import track_sessions
from .target import track_squares

__all__ = ["Tracks", "TrackInfo", "PairInfo", "GroupInfo", "LinkInfo", "track", "track_squares", "load_images",
           "epipole_ransac", "RotatedViewsError", "track_sessions"]
