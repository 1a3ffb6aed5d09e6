"""Image front-end: images taken at pure translations -> point tracks.

``track`` (:mod:`.dispatch`) chooses between feature tracking (:mod:`.features`, SIFT and
corners verified by the pure-translation epipolar geometry ``F = [e]x``) and the target
mode (:mod:`.target`, corners of dark squares). This is the only package that needs
OpenCV's image functions.
"""

from __future__ import annotations

from .dispatch import track
from .features import RotatedViewsError, epipole_ransac
from .frames import Tracks, load_images
from .sessions import track_sessions
from .target import track_squares

__all__ = ["Tracks", "track", "track_squares", "load_images", "epipole_ransac", "RotatedViewsError",
           "track_sessions"]
