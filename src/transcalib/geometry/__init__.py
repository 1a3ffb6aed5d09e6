"""Pure geometry, no I/O: the camera model (projection, distortion), rotations,
triangulation with a known camera and known translations, and ``A = K R``."""
