"""Every export read back by its real consumer (cv2, PyYAML as ROS reads it, pycolmap,
plyfile), values compared with the calibration."""

import numpy as np
import pytest

from transcalib.io import export, formats
from transcalib.io.export import ExportContext, export_calibration

from test_io import full_calibration


@pytest.fixture(scope="module")
def cal():
    return full_calibration(n_points=60, n_views=5, seed=1)


@pytest.fixture(scope="module")
def uv(cal):
    """Observations consistent with the calibration: projections plus the residuals."""
    from transcalib.geometry.camera import project

    R_cam, C = cal.camera_poses()  # a rotation per view: the calibration has flange orientations
    uv = project(cal.K, R_cam, np.nan_to_num(cal.X), C, cal.dist) + np.nan_to_num(cal.residuals_px)
    uv[np.isnan(cal.residuals_px)] = np.nan
    uv[2, :10] = np.nan  # some points unseen in view 2
    return uv


def test_opencv_yaml_read_by_cv2(cal, tmp_path):
    import cv2

    formats.write_opencv_yaml(cal, tmp_path / "camera.yaml", (640, 480))
    fs = cv2.FileStorage(str(tmp_path / "camera.yaml"), cv2.FILE_STORAGE_READ)
    assert fs.isOpened()
    np.testing.assert_array_equal(fs.getNode("camera_matrix").mat(), cal.K)
    np.testing.assert_array_equal(fs.getNode("distortion_coefficients").mat().ravel(), cal.dist_opencv)
    np.testing.assert_array_equal(fs.getNode("R_cam_base").mat(), cal.R)  # eye-to-hand: robot base -> camera
    assert fs.getNode("image_width").real() == 640 and fs.getNode("image_height").real() == 480
    assert fs.getNode("distortion_model").string() == "radial2"
    fs.release()


def test_ros_camera_info(cal, tmp_path):
    import yaml

    formats.write_ros_camera_info(cal, tmp_path / "camera_info.yaml", (640, 480), "wrist")
    d = yaml.safe_load((tmp_path / "camera_info.yaml").read_text())
    assert d["image_width"] == 640 and d["image_height"] == 480 and d["camera_name"] == "wrist"
    assert d["distortion_model"] == "plumb_bob"
    np.testing.assert_array_equal(np.reshape(d["camera_matrix"]["data"], (3, 3)), cal.K)
    np.testing.assert_array_equal(d["distortion_coefficients"]["data"], cal.dist_opencv)
    np.testing.assert_array_equal(np.reshape(d["rectification_matrix"]["data"], (3, 3)), np.eye(3))
    P = np.reshape(d["projection_matrix"]["data"], (3, 4))
    np.testing.assert_array_equal(P[:, :3], cal.K)
    assert d["projection_matrix"]["rows"] == 3 and d["projection_matrix"]["cols"] == 4


def test_colmap_model_read_by_pycolmap(cal, uv, tmp_path):
    import pycolmap

    formats.write_colmap(cal, tmp_path, (640, 480), uv, view_names=[f"im{i}.png" for i in range(5)])
    rec = pycolmap.Reconstruction(str(tmp_path))
    assert rec.num_cameras() == 1 and rec.num_images() == 5
    ok = np.isfinite(cal.X[:, 0])
    assert rec.num_points3D() == ok.sum()
    cam = rec.cameras[1]
    assert cam.model.name == "OPENCV" and (cam.width, cam.height) == (640, 480)
    np.testing.assert_allclose(cam.params[:4], [cal.K[0, 0], cal.K[1, 1], cal.K[0, 2] + 0.5, cal.K[1, 2] + 0.5])
    np.testing.assert_allclose(cam.params[4:6], cal.dist)
    X_ok = cal.X[ok]
    for image_id, image in rec.images.items():
        i = image_id - 1
        assert image.name == f"im{i}.png"
        pose = image.cam_from_world() if callable(image.cam_from_world) else image.cam_from_world
        M = pose.matrix()
        R_cam, C = cal.camera_poses()
        np.testing.assert_allclose(M[:, :3], R_cam[i], atol=1e-12)
        np.testing.assert_allclose(M[:, 3], -R_cam[i] @ C[i], atol=1e-9)
        # COLMAP projects its own points with its own camera onto the observations
        seen = np.isfinite(uv[i, :, 0]) & ok
        assert len(image.points2D) == seen.sum()
        xy = np.array([p.xy for p in image.points2D])
        np.testing.assert_allclose(xy - 0.5, uv[i, seen], atol=1e-9)
        ids = [p.point3D_id for p in image.points2D]
        X_col = np.array([rec.points3D[k].xyz for k in ids])
        np.testing.assert_allclose(X_col, cal.X[seen], atol=1e-12)
        # pycolmap 3.10 returns (1, 2) per point, 3.11 and later (2,)
        proj = np.array([np.reshape(cam.img_from_cam(M[:, :3] @ x + M[:, 3]), 2) for x in X_col])
        from transcalib.geometry.camera import project

        ours = project(cal.K, R_cam[i], X_col, C[i:i + 1], cal.dist)[0]
        np.testing.assert_allclose(proj - 0.5, ours, atol=1e-6)
    assert len(rec.points3D[1].track.elements) == np.isfinite(uv[:, np.flatnonzero(ok)[0], 0]).sum()
    del X_ok


def test_ply_read_by_plyfile(cal, tmp_path):
    from plyfile import PlyData

    colors = np.random.default_rng(0).integers(0, 256, (cal.n_points, 3)).astype(np.uint8)
    formats.write_ply(cal, tmp_path / "points.ply", colors)
    v = PlyData.read(str(tmp_path / "points.ply"))["vertex"]
    ok = np.isfinite(cal.X[:, 0])
    np.testing.assert_array_equal(np.column_stack([v["x"], v["y"], v["z"]]), cal.X[ok])
    np.testing.assert_array_equal(np.column_stack([v["red"], v["green"], v["blue"]]), colors[ok])
    np.testing.assert_allclose(np.column_stack([v["sx"], v["sy"], v["sz"]]), cal.X_std[ok], rtol=1e-6)


def test_export_all_and_errors(cal, uv, tmp_path):
    from transcalib.io.calibration_file import load_calibration

    fmts = [f for f in export.FORMATS if f != "report"]
    written = export_calibration(cal, tmp_path, fmts, ExportContext(uv=uv))
    names = sorted(str(p.relative_to(tmp_path)) for p in written)
    assert names == sorted(["calibration.json", "arrays.npz", "points.csv", "camera.yaml", "camera_info.yaml",
                            "colmap/cameras.txt", "colmap/images.txt", "colmap/points3D.txt", "points.ply"])
    assert load_calibration(tmp_path) == cal
    from transcalib.errors import InputError
    with pytest.raises(InputError, match="unknown export format"):
        export_calibration(cal, tmp_path, ["opencv", "matlab"])
    from dataclasses import replace
    no_size = replace(cal, camera=replace(cal.camera, image_size=None))
    with pytest.raises(InputError, match="image size is unknown"):
        export_calibration(no_size, tmp_path / "x", ["opencv"])
    assert formats.image_size_or_extent(no_size, np.array([[[639.4, 10.0]], [[5.0, 479.6]]])) == (640, 480)


def test_transcalib_export_takes_names_as_text(cal, uv, tmp_path):
    """``transcalib.export(cal, folder, "opencv, ply")`` writes those two; "all" every format;
    a misspelt name or anything but a Calibration is an InputError naming it."""
    import transcalib
    from transcalib.errors import InputError

    written = transcalib.export(cal, tmp_path / "two", "opencv, ply")
    assert [p.name for p in written] == ["camera.yaml", "points.ply"]
    assert [p.name for p in transcalib.export(cal, tmp_path / "one", ["ply"])] == ["points.ply"]
    with pytest.raises(InputError, match="unknown export format.*opencvv"):
        transcalib.export(cal, tmp_path / "x", "opencvv,ply")
    with pytest.raises(InputError, match="transcalib.export: expected a Calibration"):
        transcalib.export(cal.camera, tmp_path / "x", "ply")
    assert not (tmp_path / "x").exists()
    with_all = transcalib.export(cal, tmp_path / "all", formats="all", context=ExportContext(uv=uv))
    assert {p.name for p in with_all} >= {"calibration.json", "camera.yaml", "points.ply", "report.html"}


def test_colmap_in_chunks_reads_back_the_same(cal, uv, tmp_path, monkeypatch):
    """Formatting a few points at a time (as at 10^6 points) writes the same model."""
    formats.write_colmap(cal, tmp_path / "one", (640, 480), uv)
    monkeypatch.setattr(formats, "CHUNK", 7)
    formats.write_colmap(cal, tmp_path / "many", (640, 480), uv)
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        assert (tmp_path / "one" / name).read_text() == (tmp_path / "many" / name).read_text(), name


def test_export_with_a_report_worker(cal, uv, tmp_path):
    """With a worker, the same files in the same order; the report's timings recorded."""
    from transcalib.report.worker import ReportWorker

    timings = {}
    alone = export_calibration(cal, tmp_path / "alone", ["csv", "report"], ExportContext(uv=uv))
    with ReportWorker() as worker:
        written = export_calibration(cal, tmp_path / "worker", ["csv", "report"], ExportContext(uv=uv),
                                     timings=timings, report_worker=worker)
    assert [p.relative_to(tmp_path / "worker") for p in written] == [p.relative_to(tmp_path / "alone") for p in alone]
    assert timings["report_worker_s"] > 0 and timings["report_s"] >= 0 and "csv_s" in timings


def test_colmap_precision(cal, uv, tmp_path):
    """2-D points and errors with 6 digits after the point (1e-6 px), 3-D points exact."""
    formats.write_colmap(cal, tmp_path, (640, 480), uv)
    lines = (tmp_path / "images.txt").read_text().splitlines()
    assert not any("  " in line or line != line.strip() for line in lines)  # COLMAP splits on single spaces
    ok = np.isfinite(cal.X[:, 0])
    for i, line in enumerate(lines[2::2]):
        cells = line.split(" ")
        assert all(len(c.split(".")[1]) == 6 for c in cells[0::3] + cells[1::3])
        xy = np.array(cells, dtype=float).reshape(-1, 3)[:, :2]
        seen = np.isfinite(uv[i, :, 0]) & ok
        err = np.abs(xy - 0.5 - uv[i, seen])
        assert err.max() <= 5e-7 + 1e-12 and err.max() > 0  # rounded, to the nearest 1e-6 px
    lines = (tmp_path / "points3D.txt").read_text().splitlines()[1:]
    assert not any("  " in line or line != line.strip() for line in lines)
    rows = [line.split(" ") for line in lines]
    np.testing.assert_array_equal(np.array([r[1:4] for r in rows], dtype=float), cal.X[ok])  # exact
    assert all(len(r[7].split(".")[1]) == 6 for r in rows)
