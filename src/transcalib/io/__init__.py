"""Readers, writers and exports: tracks and poses in; calibration, points and exports out.

``poses`` (the one pose-file reader and the ``poses.csv`` writer), ``tables`` (CSV /
binary tracks), ``files`` (atomic writes), ``calibration_file`` (``calibration.json`` +
``arrays.npz``), ``formats`` (OpenCV, ROS, COLMAP, PLY), ``export`` (all at once).
"""

from .files import atomic_write, check_writable_dir, check_writable_file, write_json
from .poses import Poses, read_poses, write_poses_csv
from .tables import (TrackTable, read_track_table, read_tracks, tracks_to_uv, write_points_csv, write_tracks,
                     write_tracks_csv)

__all__ = ["Poses", "TrackTable", "read_poses", "read_tracks", "read_track_table", "tracks_to_uv", "write_tracks",
           "write_tracks_csv", "write_points_csv", "write_json", "write_poses_csv", "atomic_write",
           "check_writable_dir", "check_writable_file"]
