"""Writers of one format each, for other tools: OpenCV, ROS, COLMAP, PLY.

=================  ==========================================  ==================================
format             file(s)                                     read back by
=================  ==========================================  ==================================
``opencv``         ``camera.yaml``                             ``cv2.FileStorage``
``ros``            ``camera_info.yaml``                        ROS ``camera_calibration_parsers``
``colmap``         ``colmap/{cameras,images,points3D}.txt``    ``pycolmap.Reconstruction``
``ply``            ``points.ply``                              ``plyfile``, MeshLab, Open3D
=================  ==========================================  ==================================

Pixel conventions: transcalib and OpenCV put the centre of the top-left pixel at (0, 0),
COLMAP at (0.5, 0.5); the COLMAP export shifts ``cx, cy`` and the 2-D points by +0.5.
Every file is written atomically; the writers are vectorised over points.
:mod:`transcalib.io.export` writes these and the others (JSON, CSV, report) at once.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry.rotation import matrix_to_quaternion
from . import text
from .files import atomic_write

__all__ = ["write_opencv_yaml", "write_ros_camera_info", "write_colmap", "write_ply", "image_size_or_extent"]


def image_size_or_extent(cal, uv=None) -> tuple[int, int]:
    """The calibration's image size; else the smallest size holding every observation
    (from ``uv``, or the residual-bearing points); raises :class:`InputError` if neither."""
    if cal.image_size is not None:
        return tuple(cal.image_size)
    if uv is not None and np.isfinite(uv).any():
        w, h = np.nanmax(uv[..., 0]), np.nanmax(uv[..., 1])  # per column: 5x faster than axis=0 at 10^6
        return int(np.floor(w)) + 1, int(np.floor(h)) + 1
    raise InputError("the image size is unknown (give --image-size WIDTHxHEIGHT, or images): "
                     "camera.yaml, camera_info.yaml and COLMAP need it")


def _opencv_matrix(name: str, a: np.ndarray) -> str:
    a = np.atleast_2d(np.asarray(a, dtype=float))
    data = ", ".join(repr(float(x)) for x in a.ravel())
    return f"{name}: !!opencv-matrix\n   rows: {a.shape[0]}\n   cols: {a.shape[1]}\n   dt: d\n   data: [ {data} ]\n"


def write_opencv_yaml(cal, path, image_size) -> Path:
    """``camera.yaml`` in OpenCV FileStorage form: ``image_width``, ``image_height``,
    ``camera_matrix``, ``distortion_coefficients`` (the five OpenCV coefficients),
    ``R_cam_world`` (robot -> camera; with flange orientations ``R_cam_flange``, flange
    -> camera, or eye-to-hand ``R_cam_base``, robot base -> camera), ``distortion_model``
    (transcalib's name)."""
    w, h = image_size
    he = getattr(cal, "hand_eye", None)
    eye_to_hand = he is not None and he.setup == "eye-to-hand"
    rotation = "R_cam_world" if cal.flange_rotations is None else "R_cam_base" if eye_to_hand else "R_cam_flange"
    text = ("%YAML:1.0\n---\n"
            f"image_width: {int(w)}\nimage_height: {int(h)}\n"
            + _opencv_matrix("camera_matrix", cal.K)
            + _opencv_matrix("distortion_coefficients", cal.dist_opencv[None, :])
            + _opencv_matrix(rotation, cal.R)
            + f'distortion_model: "{cal.dist_model}"\n')
    with atomic_write(path, encoding="utf-8", newline="\n") as fh:
        fh.write(text)
    return Path(path)


def _ros_matrix(name: str, a: np.ndarray) -> str:
    a = np.atleast_2d(np.asarray(a, dtype=float))
    data = ", ".join(repr(float(x)) for x in a.ravel())
    return f"{name}:\n  rows: {a.shape[0]}\n  cols: {a.shape[1]}\n  data: [{data}]\n"


def write_ros_camera_info(cal, path, image_size, camera_name: str = "camera") -> Path:
    """``camera_info.yaml`` as ROS ``camera_calibration_parsers`` writes it
    (``distortion_model: plumb_bob``, identity rectification, ``P = [K | 0]``)."""
    w, h = image_size
    P = np.hstack([cal.K, np.zeros((3, 1))])
    text = (f"image_width: {int(w)}\nimage_height: {int(h)}\ncamera_name: {camera_name}\n"
            + _ros_matrix("camera_matrix", cal.K)
            + "distortion_model: plumb_bob\n"
            + _ros_matrix("distortion_coefficients", cal.dist_opencv[None, :])
            + _ros_matrix("rectification_matrix", np.eye(3))
            + _ros_matrix("projection_matrix", P))
    with atomic_write(path, encoding="utf-8", newline="\n") as fh:
        fh.write(text)
    return Path(path)


def _colmap_camera(cal, image_size) -> str:
    """``cameras.txt`` line: PINHOLE, OPENCV or FULL_OPENCV (COLMAP's pixel centres)."""
    fx, fy, cx, cy = cal.K[0, 0], cal.K[1, 1], cal.K[0, 2] + 0.5, cal.K[1, 2] + 0.5
    k1, k2, p1, p2, k3 = cal.dist_opencv
    if not np.any(cal.dist_opencv):
        model, params = "PINHOLE", [fx, fy, cx, cy]
    elif k3 == 0:
        model, params = "OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2]
    else:
        model, params = "FULL_OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    w, h = image_size
    return f"1 {model} {int(w)} {int(h)} " + " ".join(repr(float(p)) for p in params) + "\n"


#: Digits after the point of the 2-D points and of the errors in the COLMAP model (pixels).
COLMAP_DECIMALS = 6
#: Points (or observations of an image) formatted at a time by the COLMAP writer
#: (:data:`transcalib.io.text.CHUNK`): bounds its memory at any n.
CHUNK = text.CHUNK


def _points2d(uv_view: np.ndarray, cols: np.ndarray, pid: np.ndarray):
    """``X Y POINT3D_ID`` of the observations ``cols`` of one image, space separated:
    ``uv_view (n_points, 2)`` shifted to COLMAP's pixel centres, ``pid (n_points,)``."""
    x, y = (uv_view[cols] + 0.5).T
    xy_text = [text.decimal_text(c, COLMAP_DECIMALS) for c in (x, y)]
    return text.concatenated(text.join([*xy_text, text.integer_text(pid[cols])]), " ")


def _write_images(path, cal, uv, seen, pid, names) -> None:
    """``images.txt``: a pose line and a POINTS2D line per view (COLMAP's world to camera
    ``R_i``, ``t = -R_i C_i`` of :meth:`Calibration.camera_poses`); the line of a view is
    formatted in chunks of points, on threads."""
    from functools import partial

    R_cam, C = cal.camera_poses()

    def pieces():
        yield f"# Image list with two lines of data per image; {len(names)} images\n".encode()
        for i, name in enumerate(names):  # a loop over views, then chunks of points
            qx, qy, qz, qw = matrix_to_quaternion(R_cam[i]).tolist()
            t = (-R_cam[i] @ C[i]).tolist()
            yield f"{i + 1} {qw!r} {qx!r} {qy!r} {qz!r} {t[0]!r} {t[1]!r} {t[2]!r} 1 {name}\n".encode()
            cols = np.flatnonzero(seen[i])
            for k, s in enumerate(text.chunks(cols.size, CHUNK)):
                if k:
                    yield b" "
                yield partial(_points2d, uv[i], cols[s], pid)
            yield b"\n"

    with atomic_write(path, "wb") as fh:
        text.write_in_order(fh, pieces())


def _points3d(cal, rows: slice, pid: np.ndarray, rgb, seen: np.ndarray, before: np.ndarray):
    """Lines ``POINT3D_ID X Y Z R G B ERROR TRACK[]`` of the reconstructed points among
    ``rows``, each ended by a newline; the track is ``IMAGE_ID POINT2D_IDX`` per image
    that sees the point, the error the RMS reprojection error (pixels).

    ``rgb``: ``(n_points, 3)`` or one text for all; ``before (n_views,)``: observations
    of each image before ``rows`` (the POINT2D_IDX of the first one in ``rows``).
    """
    ok = np.flatnonzero(np.isfinite(cal.X[rows, 0]))
    j = rows.start + ok
    idx2d = (before[:, None] + np.cumsum(seen[:, rows], axis=1) - 1)[:, ok]
    s, r = seen[:, j], cal.residuals_px[:, j]
    r2 = np.einsum("vpk,vpk->vp", r, r)
    err = np.sqrt(np.sum(r2, axis=0, where=s & ~np.isnan(r2)) / np.maximum(s.sum(axis=0), 1))
    xyz = [text.decimal_text(x) for x in cal.X[j].T]
    colour = rgb if isinstance(rgb, str) else text.join([text.integer_text(c) for c in rgb[j].T])
    track = [text.prefixed(text.integer_text(idx, mask=~si), f"{i + 1} ")  # null where unseen
             for i, (idx, si) in enumerate(zip(idx2d, s))]
    line = [text.integer_text(pid[j]), *xyz, colour, text.decimal_text(err, COLMAP_DECIMALS), *track]
    return text.concatenated(text.join(line), "\n", end="\n")


def _write_points3d(path, cal, seen, pid, colors) -> None:
    """``points3D.txt``: the reconstructed points, formatted in chunks, on threads."""
    from functools import partial

    rgb = "128 128 128" if colors is None else np.asarray(colors, dtype=np.int64)

    def pieces():
        before = np.zeros(len(seen), dtype=np.int64)  # observations of each image so far
        for rows in text.chunks(cal.n_points, CHUNK):
            yield partial(_points3d, cal, rows, pid, rgb, seen, before.copy())
            before += seen[:, rows].sum(axis=1)

    with atomic_write(path, "wb") as fh:
        fh.write(f"# 3D point list; {pid[-1] if pid.size else 0} points\n".encode())
        text.write_in_order(fh, pieces())


def write_colmap(cal, folder, image_size, uv, view_names=None, colors=None) -> list[Path]:
    """A COLMAP text model (``cameras.txt``, ``images.txt``, ``points3D.txt``) in ``folder``.

    Each view is an image with pose ``x_c = R x_w + t``, ``t = -R T_i`` (COLMAP's world to
    camera); the reconstructed points are the 3-D points, with their observations in
    ``uv (n_views, n_points, 2)`` as tracks and the RMS reprojection error as ``ERROR``.
    3-D points and the camera are written in full (shortest exact form), 2-D points and
    errors with :data:`COLMAP_DECIMALS` digits after the point. Lines are formatted by
    Arrow, in chunks of points, on threads (:mod:`transcalib.io.text`).
    """
    if uv is None:
        raise InputError("the COLMAP export needs the observations uv")
    folder = Path(folder)
    n_views = uv.shape[0]
    names = list(view_names) if view_names is not None else [f"view{i:03d}.png" for i in range(n_views)]
    ok = np.isfinite(cal.X[:, 0])
    seen = np.isfinite(uv[..., 0]) & ok[None, :]          # observations that join a 3-D point
    pid = np.cumsum(ok)                                     # COLMAP point ids 1..n_ok
    out = [folder / "cameras.txt", folder / "images.txt", folder / "points3D.txt"]
    with atomic_write(out[0], encoding="utf-8", newline="\n") as fh:
        fh.write("# Camera list with one line of data per camera\n" + _colmap_camera(cal, image_size))
    _write_images(out[1], cal, uv, seen, pid, names)
    _write_points3d(out[2], cal, seen, pid, colors)
    return out


def write_ply(cal, path, colors=None) -> Path:
    """``points.ply`` (binary little endian): the reconstructed points' ``x, y, z`` (double,
    user units), ``red, green, blue`` (uchar, when ``colors (n_points, 3)`` is given) and
    their standard deviations ``sx, sy, sz`` (float, when known)."""
    ok = np.isfinite(cal.X[:, 0])
    dtype = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if colors is not None:
        dtype += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if cal.X_std is not None:
        dtype += [("sx", "<f4"), ("sy", "<f4"), ("sz", "<f4")]
    v = np.empty(int(ok.sum()), dtype=dtype)
    v["x"], v["y"], v["z"] = cal.X[ok].T
    if colors is not None:
        c = np.asarray(colors)[ok]
        v["red"], v["green"], v["blue"] = c[:, 0], c[:, 1], c[:, 2]
    if cal.X_std is not None:
        v["sx"], v["sy"], v["sz"] = cal.X_std[ok].T
    return write_vertices_ply(path, v, "written by transcalib")


#: PLY property types of the numpy field types the writers use.
_PLY_TYPES = {"<f8": "double", "u1": "uchar", "<f4": "float"}


def write_vertices_ply(path, vertices: np.ndarray, comment: str) -> Path:
    """A binary little-endian PLY of one ``vertex`` element: the structured array
    ``vertices (n,)`` (fields of types ``<f8``, ``<f4``, ``u1``), written atomically."""
    props = [f"property {_PLY_TYPES[vertices.dtype[name].str.replace('|', '')]} {name}"
             for name in vertices.dtype.names]
    header = ["ply", "format binary_little_endian 1.0", f"comment {comment}", f"element vertex {vertices.size}",
              *props, "end_header", ""]
    with atomic_write(path, "wb") as fh:
        fh.write("\n".join(header).encode("ascii"))
        fh.write(vertices.tobytes())
    return Path(path)
