"""Rendering is exact to the pixel convention: corners land where camera.project says."""

import cv2
import numpy as np
import pytest

from transcalib.images import target
from transcalib.synth import render
from transcalib.geometry.camera import K_from_params, project
from transcalib.synth.simulate import Scene


def test_edge_pixel_is_exact_area_fraction():
    # fronto-parallel checkerboard, square pixels: a vertical edge at u0 covers pixel
    # round(u0) (which spans [k - 0.5, k + 0.5]) by the fraction k + 0.5 - u0
    K = K_from_params(300.0, 300.0, 100.3, 80.7)
    sf, corners = render.checker_board([0.37, -0.21, 100.0], np.eye(3), 10.0, 6, 6)
    img = render.render([sf], K, np.eye(3), np.zeros((1, 3)), (200, 160), supersample=1, dtype="float")[0]
    uv = project(K, np.eye(3), corners, np.zeros((1, 3)))[0]
    u0, v0 = uv[0]
    k = int(round(u0))
    row = int(round(v0 + 5))  # inside the cell below-left/right of the corner
    lo, hi = img[row, k - 3], img[row, k + 3]
    frac_hi = (img[row, k] - lo) / (hi - lo)
    assert frac_hi == pytest.approx(k + 0.5 - u0, abs=1e-9)


@pytest.mark.parametrize("image_size, seed", [((640, 480), 0), ((500, 400), 1)])
def test_board_corners_land_on_projection(image_size, seed):
    # non-square pixels and an off-centre principal point come from render_scene's default K
    r = render.render_scene("board", n_views=2, image_size=image_size, noise_std=0.0, rng=seed)
    assert r.K[0, 0] != r.K[1, 1] and r.K[0, 2] != image_size[0] / 2 - 0.5
    uv = r.project(r.corners)
    for v in range(2):
        found = target.detect_squares(r.images[v], curved=False).reshape(-1, 2)  # straight sides
        d = np.linalg.norm(found[:, None] - uv[v][None], axis=-1).min(1)
        assert len(found) == 24
        assert np.median(d) < 0.03 and d.max() < 0.05, (np.median(d), d.max())


def test_distortion_follows_opencv_convention():
    dist = np.array([-0.12, 0.03, 0.001, -0.0008, 0.0])
    r = render.render_scene("board", n_views=1, image_size=(640, 480), noise_std=0.0, dist=dist, rng=2)
    K = r.K.copy()
    K[0, 1] = 0.0
    und = cv2.undistort(r.images[0].astype(np.float32), K, dist)
    found = target.detect_squares(und).reshape(-1, 2)
    uv = project(r.K, r.R, r.corners, r.T[:1])[0]  # pinhole projection: undistorted image
    d = np.linalg.norm(found[:, None] - uv[None], axis=-1).min(1)
    assert len(found) == 24
    assert np.median(d) < 0.1, np.median(d)
    # and the distorted projection is where the distorted image shows the corner
    uvd = r.project(r.corners)[0]
    assert np.max(np.linalg.norm(uvd - uv, axis=1)) > 2.0  # the distortion is visible


def test_rendered_scene_truth_and_backprojection():
    r = render.render_scene("natural", n_views=4, image_size=(200, 150), rng=3, supersample=1)
    assert r.images.shape == (4, 150, 200) and r.images.dtype == np.uint8
    rng = np.random.default_rng(0)
    pix = rng.uniform([0, 0], [199, 149], size=(50, 2))
    X = r.backproject(0, pix)
    assert np.all(np.isfinite(X))
    assert np.allclose(r.project(X)[0], pix, atol=1e-8)
    sc = r.scene(X)
    assert isinstance(sc, Scene)
    assert sc.uv.shape == (4, 50, 2) and np.all(np.isfinite(sc.uv[0]))
    assert np.allclose(sc.uv_true, r.project(X))
    truth = sc.truth_dict()
    assert truth["image_size"] == [200, 150]


def test_noise_gain_and_blur_options():
    sf, _ = render.checker_board([0, 0, 100.0], np.eye(3), 10.0, 4, 4)
    K = K_from_params(200.0, 210.0, 40.0, 30.0)
    T = np.zeros((2, 3))
    a = render.render([sf], K, np.eye(3), T, (80, 60), dtype="float", gain=[1.0, 0.5])
    assert np.allclose(a[1], 0.5 * a[0])
    b = render.render([sf], K, np.eye(3), T, (80, 60), dtype="float", noise_std=2.0, rng=1)
    assert 1.5 < np.std(b[0] - a[0]) < 2.5
    c = render.render([sf], K, np.eye(3), T[:1], (80, 60), dtype="float", blur_sigma=2.0)
    assert np.abs(np.diff(c[0], axis=1)).max() < np.abs(np.diff(a[0], axis=1)).max()
