"""Readers and writers: tracks and poses in, calibration and points out."""

from .tables import (Poses, atomic_write, read_poses, read_tracks, tracks_to_uv, write_json, write_points_csv,
                     write_poses_csv, write_tracks_csv)

__all__ = ["Poses", "read_poses", "read_tracks", "tracks_to_uv", "write_tracks_csv", "write_points_csv",
           "write_json", "write_poses_csv", "atomic_write"]
