"""Dense reconstruction: the renderer's depth truth, the sweep's geometry (exact), depth on
rendered scenes, confidence and uncertainty, fusion, the views' poses, the command's
outputs and bad inputs, and the complete-or-absent output folder."""

import json
import os
import signal
import subprocess
import sys

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import transcalib
from transcalib.dense import DenseOptions, dense
from transcalib.dense.fuse import fuse
from transcalib.dense.images import make_canvas
from transcalib.dense.sweep import warp_matrix
from transcalib.dense.views import central_view, view_cameras
from transcalib.errors import DegenerateError, InputError
from transcalib.geometry.camera import Camera, K_from_params, project_camera_frame
from transcalib.io import write_poses_csv
from transcalib.io.folders import MANIFEST, read_manifest

from test_cli_folders import default_sigint
from transcalib.cli.main import main
from transcalib.synth import render
from transcalib.synth.degrade import Degradations
from transcalib.synth.presets import preset_scene
from transcalib.geometry.rotation import rotation_angle_deg
from transcalib.types import Calibration, HandEye, Poses

SIZE = (256, 192)
LIGHT = Degradations(vignetting=0.3, exposure=0.2, read_noise_dn=1.5)  # a real camera without JPEG or overlay


def _calibration(camera, T, cov=None, names=()):
    n = len(T)
    return Calibration(camera=camera, X=np.zeros((0, 3)), residuals_px=np.zeros((n, 0, 2)), rms_px=0.0,
                       T=np.asarray(T, float), cov=cov, param_names=tuple(names))


def _scene(rng=0, n_views=5, size=SIZE, degrade=LIGHT, dist=()):
    R = Rotation.from_euler("xyz", [170, 20, -30], degrees=True).as_matrix()
    T = render.ring_translations(n_views, 60.0, R, rng)
    return render.render_scene("workspace", n_views=n_views, image_size=size, R=R, T=T, distance=800.0,
                               degrade=degrade, rng=rng, noise_std=0.0, supersample=1, dist=dist)


@pytest.fixture(scope="module")
def scene():
    return _scene()


@pytest.fixture(scope="module")
def result(scene):
    return dense(Camera(scene.K, scene.R, image_size=scene.image_size), list(scene.images), scene.T,
                 reference_views=["0"], depth_limits=(380, 1300))


def _errors(scene, depth, view=0):
    truth, surface = scene.depth_map(view, return_surface=True)
    textured = scene.textured()[surface] & (surface >= 0)
    return np.abs(depth - truth) / truth, textured


# --------------------------------------------------------------------------- the renderer's truth


def test_depth_map_is_the_exact_truth_of_every_pixel():
    r = render.render_scene("workspace", n_views=2, image_size=(120, 90), rng=4, supersample=1,
                            dist=(-0.1, 0.02))
    z, surface = r.depth_map(1, return_surface=True)
    assert z.shape == (90, 120) and np.isfinite(z).all() and (surface >= 0).all()
    rng = np.random.default_rng(0)
    v, u = rng.integers(0, 90, 40), rng.integers(0, 120, 40)
    X = r.backproject(1, np.column_stack([u, v]).astype(float))
    assert np.allclose((X - r.T[1]) @ r.R.T[:, 2], z[v, u], rtol=1e-12)  # camera z of the point seen
    assert np.allclose(r.project(X)[1], np.column_stack([u, v]), atol=1e-7)  # through the lens


def test_workspace_scene_spans_the_benchmark_depths():
    r = render.render_scene("workspace", n_views=1, image_size=(160, 120), distance=800.0, rng=1, supersample=1)
    z, surface = r.depth_map(0, return_surface=True)
    assert 0.5 * 800 <= np.nanmin(z) and np.nanmax(z) <= 1.5 * 800
    textured = r.textured()
    assert textured.sum() == len(textured) - 1 and not textured[surface].all()  # one untextured panel, in view


# --------------------------------------------------------------------------- exact geometry


def test_warp_lands_exactly_on_the_projection():
    K = K_from_params(700.0, 720.0, 330.2, 241.7, skew=0.8)
    cam = Camera(K, Rotation.from_euler("xyz", [10, -20, 5], degrees=True).as_matrix(), image_size=(640, 480))
    canvas = make_canvas(cam, (640, 480))
    rng = np.random.default_rng(2)
    uv = rng.uniform([0, 0], [639, 479], (50, 2))
    for t in ([55.0, -3.0, 8.0], [-20.0, 40.0, -30.0]):
        e = canvas.K @ np.array(t)
        for rho in (1 / 400.0, 1 / 1300.0):
            x = cam.pixels_to_rays(uv) / rho - t  # the hypothesis in the source's camera frame
            expected = project_camera_frame(cam.intrinsics, cam.dist5, x.T).pred.T
            M = warp_matrix(e, rho, canvas.offset, row0=17)
            got = np.column_stack([uv[:, 0], uv[:, 1] - 17, np.ones(50)]) @ M.T
            assert np.abs(got - expected).max() < 1e-9


@pytest.mark.parametrize("dist", [(), (-0.2, 0.05)])
def test_turned_source_on_the_canvas_lands_on_the_projection(dist):
    """A source turned by 0.8 deg against the reference, resampled once onto the canvas
    in the reference's axes: the sweep's pure-translation warp of a hypothesis, read
    through the turned maps, is the source pixel of the hypothesis's point."""
    cam = Camera(K_from_params(300.0, 310.0, 160.4, 121.1), dist=np.array(dist, float),
                 dist_model="radial2" if dist else "none", image_size=(320, 240))
    canvas = make_canvas(cam, (320, 240))
    R_rel = Rotation.from_rotvec([0.01, -0.005, 0.008]).as_matrix()  # x_source = R_rel x_ref - t
    maps = canvas.turned(R_rel)
    rng = np.random.default_rng(4)
    uv = rng.integers([20, 20], [300, 220], (50, 2))
    t = np.array([25.0, -4.0, 6.0])  # source centre in the source's axes
    e = canvas.K @ (R_rel.T @ t)  # the epipole on the canvas in the reference's axes
    u_t = cam.pixels_to_rays(uv.astype(float)) @ canvas.K.T
    for rho in (1 / 400.0, 1 / 1300.0):
        q = (u_t[:, :2] - rho * e[:2]) / (1 - rho * e[2])  # the sweep's canvas position
        i, f = np.floor(q).astype(int), q - np.floor(q)  # bilinear in double (cv2.remap: 1/32 px steps)
        got = sum(maps[:, i[:, 1] + dv, i[:, 0] + du].T * ((f[:, :1] if du else 1 - f[:, :1])
                                                             * (f[:, 1:] if dv else 1 - f[:, 1:]))
                  for du in (0, 1) for dv in (0, 1))
        x = (cam.pixels_to_rays(uv.astype(float)) / rho) @ R_rel.T - t
        expected = project_camera_frame(cam.intrinsics, cam.dist5, x.T).pred.T
        assert np.abs(got - expected).max() < 2e-3  # float32 maps, bilinear between canvas pixels


def test_canvas_of_a_lens_with_distortion_is_exact():
    cam = Camera(K_from_params(300.0, 310.0, 160.4, 121.1), dist=[-0.2, 0.05], dist_model="radial2",
                 image_size=(320, 240))
    canvas = make_canvas(cam, (320, 240))
    rng = np.random.default_rng(3)
    uv = rng.integers([0, 0], [320, 240], (50, 2))
    pin = cam.pixels_to_rays(uv.astype(float)) @ canvas.K.T
    assert np.abs(canvas.ref[uv[:, 1], uv[:, 0]] - pin[:, :2]).max() < 1e-3  # float32 maps
    q = rng.integers([0, 0], list(canvas.size), (50, 2))
    ray = np.linalg.solve(canvas.K, np.column_stack([q, np.ones(50)]).T)
    src = project_camera_frame(cam.intrinsics, cam.dist5, ray).pred.T
    assert np.abs(canvas.maps[:, q[:, 1], q[:, 0]].T - src).max() < 1e-3
    assert canvas.size[0] > 320 and canvas.size[1] > 240  # barrel distortion: the whole image kept


def test_points_reproject_onto_their_pixel_centres(result):
    m = result.maps[0]
    known = np.isfinite(m.depth)
    X = m.points(known)
    v, u = np.nonzero(known)
    uv = m.camera.project(X, m.centre[None])[0]
    assert np.abs(uv - np.column_stack([u, v])).max() < 1e-6
    assert len(result.points) == known.sum() and np.array_equal(result.points, X)


@pytest.mark.parametrize("dist, turn_deg", [((), 0.0), ((-0.2, 0.05), 0.0), ((), 0.5), ((-0.2, 0.05), 0.5),
                                            ((), 4.0)])
def test_noise_free_plane_to_a_small_fraction_of_a_pixel(dist, turn_deg):
    """A textured plane, noise-free; with ``turn_deg`` the source views are turned by that
    angle about random axes (0.5: a session within its tolerance; 4: every view at an
    orientation of its own, as from general motion, matched with ``max_turn_deg``), each
    resampled once onto the canvas in the reference's axes."""
    K = K_from_params(300.0, 310.0, 161.3, 118.2)
    tex = render.Noise(1000 / 300 * 1.4, (2000, 2000), 3)
    plane = render.plane([0, 0, 1000.0], Rotation.from_euler("xy", [15, -10], degrees=True).as_matrix(),
                         (2000, 2000), tex)
    T = np.array([[0, 0, 0], [60, 0, 0], [-60, 5, 0], [0, 60, 3], [3, -60, -4]], float)
    axes = np.random.default_rng(5).normal(size=(5, 3))
    Rf = Rotation.from_rotvec(axes / np.linalg.norm(axes, axis=1, keepdims=True) * np.radians(turn_deg)).as_matrix()
    Rf[0] = np.eye(3)
    img = np.stack([render.render([plane], K, Rf[i].T, T[i:i + 1], (320, 240), dist=dist, rng=i)[0]
                    for i in range(5)])
    cam = Camera(K, dist=np.array(dist, float), dist_model="radial2" if dist else "none", image_size=(320, 240))
    if turn_deg:  # the camera in the flange at (I, 0): each view's camera turned by R_i
        he = HandEye(setup="eye-in-hand", R=np.eye(3), t=np.zeros(3), R_std_deg=np.zeros(3),
                     t_cov=np.zeros((3, 3)), undetermined=np.zeros((3, 0)), session_of_view=np.zeros(5, int))
        cam = Calibration(camera=cam, X=np.zeros((0, 3)), residuals_px=np.zeros((5, 0, 2)), rms_px=0.0, T=T,
                          flange_rotations=Rf, hand_eye=he)
    opts = DenseOptions(max_turn_deg=10.0) if turn_deg > 1 else None
    if opts is not None:
        with pytest.raises(InputError, match="no other view at its orientation.*--max-turn-deg"):
            dense(cam, list(img), Poses.of(T, Rf), reference_views=["0"], depth_limits=(700, 1500))
    res = dense(cam, list(img), Poses.of(T, Rf), reference_views=["0"], depth_limits=(700, 1500), options=opts)
    assert res.maps[0].sources == ("1", "2", "3", "4")
    z = res.maps[0].depth
    r = render.Rendered(images=img, K=K, R=np.eye(3), dist=np.array(dist, float), T=T, surfaces=[plane],
                        corners=np.zeros((0, 3)), corner_kind=np.zeros(0), image_size=(320, 240))
    signed = (z - r.depth_map(0)) / r.depth_map(0)
    rel = np.abs(signed)
    known = np.isfinite(z)
    inner = np.zeros_like(known)
    inner[10:-10, 10:-10] = True
    disparity_px = 300 * 60 / 1000.0  # 18 px at the longest baseline
    assert known[inner].mean() > 0.95
    # px of disparity (noise-free 8-bit images: 0.011-0.013, turned or not, with or without distortion)
    assert np.median(rel[known]) * disparity_px < 0.025
    assert abs(np.mean(signed[known & inner])) * disparity_px < 0.005  # no bias (measured 0.00001-0.0009 px)
    assert np.percentile(rel[known & inner], 99) < 0.005  # measured 0.26-0.33 %


# --------------------------------------------------------------------------- depth on rendered scenes


def test_textured_surfaces_accurate_and_untextured_unknown(scene, result):
    m = result.maps[0]
    rel, textured = _errors(scene, m.depth)
    known = np.isfinite(m.depth)
    assert (known & textured).sum() / textured.sum() > 0.85
    assert np.median(rel[known & textured]) < 0.005  # 0.5 % of depth at 256 x 192 (f = 243 px)
    assert known[~textured].mean() < 0.15  # the untextured panel: unknown, not guessed
    assert m.depth.dtype == np.float32 and m.confidence.min() >= 0 and m.confidence.max() <= 1
    assert np.all(m.confidence[~known] == 0) and np.isnan(m.depth_std[~known]).all()
    assert (m.depth_std[known] > 0).all() and m.stats.known_fraction == pytest.approx(known.mean())


def test_confidence_ranks_errors_and_std_is_calibrated(scene, result):
    m = result.maps[0]
    rel, _ = _errors(scene, m.depth)
    known = np.isfinite(m.depth)
    big = rel[known] > 0.02
    low = m.confidence[known] <= np.quantile(m.confidence[known], 0.1)
    assert big.sum() > 10 and (big & low).sum() / big.sum() > 0.5  # the least confident 10 % hold most
    truth = scene.depth_map(0)
    ratio = np.abs(m.depth - truth)[known] / m.depth_std[known]
    assert 0.35 < np.median(ratio) < 1.2  # 0.674 for a calibrated Gaussian


def test_exposure_changes_and_occlusions(scene):
    cam = Camera(scene.K, scene.R, image_size=scene.image_size)
    wild = _scene(degrade=Degradations(vignetting=0.3, exposure=0.45, read_noise_dn=1.5))
    base = dense(cam, list(scene.images), scene.T, reference_views=["0"], depth_limits=(380, 1300))
    exp = dense(cam, list(wild.images), wild.T, reference_views=["0"], depth_limits=(380, 1300))
    everyone = dense(cam, list(scene.images), scene.T, reference_views=["0"], depth_limits=(380, 1300),
                     options=DenseOptions(best_k=4))
    rel0, tex = _errors(scene, base.maps[0].depth)
    rel1, _ = _errors(wild, exp.maps[0].depth)
    assert np.nanmedian(rel1[tex]) < 1.5 * np.nanmedian(rel0[tex])  # gains of 0.55-1.45 between views
    assert np.isfinite(exp.maps[0].depth[tex]).mean() > 0.9 * np.isfinite(base.maps[0].depth[tex]).mean()
    # occlusion: near depth edges the best-2 views keep pixels that all four views lose
    truth = scene.depth_map(0)
    grad = np.hypot(*np.gradient(truth))
    edge = cv2.dilate((grad > 20).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool) & tex
    assert np.isfinite(base.maps[0].depth[edge]).mean() > np.isfinite(everyone.maps[0].depth[edge]).mean() + 0.05


def test_calibration_covariance_enters_depth_std():
    K = K_from_params(300.0, 300.0, 160.0, 120.0)
    tex = render.Noise(1000 / 300 * 1.4, (2000, 2000), 5)
    plane = render.plane([0, 0, 1000.0], np.eye(3), (2000, 2000), tex)
    T = np.array([[0, 0, 0], [60, 0, 0], [-60, 0, 0]], float)  # baselines along x: z = fx b / d
    img = render.render([plane], K, np.eye(3), T, (320, 240), rng=1)
    sf = 3.0  # px
    cal = _calibration(Camera(K, image_size=(320, 240)), T, cov=np.diag([sf**2, 1.0, 1.0]),
                       names=("fx", "cy", "t_x"))
    m = dense(cal, list(img), T, reference_views=["0"], depth_limits=(700, 1500)).maps[0]
    known = np.isfinite(m.depth)
    rel = m.depth_std_calibration[known] / m.depth[known]
    assert np.allclose(rel, sf / 300.0, rtol=0.02)  # sigma_z / z = sigma_fx / fx; cy and t_x do not enter
    assert np.all(m.depth_std[known] >= m.depth_std_calibration[known])


def test_several_reference_views_are_fused_with_a_consistency_check(scene):
    cam = Camera(scene.K, scene.R, image_size=scene.image_size)
    res = dense(cam, list(scene.images), scene.T, reference_views=["0", "2"], depth_limits=(380, 1300))
    a, b = res.maps
    assert (a.view, b.view) == ("0", "2") and set(np.unique(res.point_view)) == {0, 1}
    assert res.n_rejected < 0.05 * len(res.points)
    # a map that puts part of the scene 20 % nearer is contradicted by the other view there
    bad = np.array(a.depth)
    bad[60:120, 80:160] *= 0.8
    from dataclasses import replace

    region = np.isfinite(bad[60:120, 80:160]).sum()

    def rejected_from_first(depth):
        cloud = fuse([replace(a, depth=depth), b], 0.01)
        return np.isfinite(depth).sum() - np.sum(cloud.view == 0)

    assert rejected_from_first(bad) > 0.8 * region
    assert rejected_from_first(a.depth) < 0.02 * np.isfinite(a.depth).sum()


def test_default_reference_view_is_the_most_central():
    T = np.array([[50.0, 0, 0], [0, 50, 0], [-50, 0, 0], [0, 0, 0], [0, -50, 0]])
    cams = view_cameras(Camera(np.eye(3) * 500 + np.diag([0, 0, -499])), T)
    assert central_view(cams) == 3


# --------------------------------------------------------------------------- the views' poses


def test_orientations_that_differ_from_each_other_are_refused():
    cam = Camera(K_from_params(500, 500, 320, 240))
    T = np.zeros((4, 3)) + np.arange(4)[:, None] * [10.0, 0, 0]
    Rf = np.repeat(Rotation.from_euler("z", 30, degrees=True).as_matrix()[None], 4, axis=0)
    poses = Poses.of(T, Rf, views=["a", "b", "c", "d"])
    cams = view_cameras(cam, poses)  # one orientation, whatever it is: accepted
    assert np.allclose(cams.R, cam.R) and np.allclose(cams.C, T) and cams.session.tolist() == [0] * 4
    Rf[2] = Rotation.from_euler("z", 35, degrees=True).as_matrix()
    with pytest.raises(InputError, match=r"view c at 5 deg.*calibration's orientation"):
        view_cameras(cam, Poses.of(T, Rf, views=["a", "b", "c", "d"]))


def _hand_eye_calibration(setup="eye-in-hand", n_views=4, T_std=None, T=None, Rf=None):
    """A calibration with orientations: the camera at ``(R_X, t_X)`` in the flange."""
    R_X = Rotation.from_euler("xyz", [90, 0, 10], degrees=True).as_matrix()  # camera -> flange
    t_X = np.array([5.0, -2.0, 80.0])
    he = HandEye(setup=setup, R=R_X, t=t_X, R_std_deg=np.zeros(3), t_cov=np.zeros((3, 3)),
                 undetermined=np.zeros((3, 0)), session_of_view=np.zeros(n_views, int))
    T = np.zeros((n_views, 3)) if T is None else T
    Rf = np.repeat(np.eye(3)[None], n_views, axis=0) if Rf is None else Rf
    return Calibration(camera=Camera(K_from_params(500, 500, 320, 240), R_X.T), X=np.zeros((0, 3)),
                       residuals_px=np.zeros((n_views, 0, 2)), rms_px=0.0, T=T, T_std=T_std, flange_rotations=Rf,
                       hand_eye=he), R_X, t_X


@pytest.mark.parametrize("setup", ["eye-in-hand", "eye-to-hand"])
def test_hand_eye_calibration_places_every_view(setup):
    cal, R_X, t_X = _hand_eye_calibration(setup)
    Rf = Rotation.from_euler("xyz", [[0, 0, 0], [0, 0, 0.3], [20, 0, 0], [20, 0, 0]], degrees=True).as_matrix()
    T = np.array([[0, 0, 0], [30, 0, 0], [0, 0, 0], [0, 30, 0]], float)
    cams = view_cameras(cal, Poses.of(T, Rf))
    assert cams.session.tolist() == [0, 0, 1, 1] and cams.known.tolist() == [-1] * 4
    for i in range(4):
        if setup == "eye-in-hand":  # x ~ K (R_i R_X)^T (X - T_i - R_i t_X)
            R_cam, C = (Rf[i] @ R_X).T, T[i] + Rf[i] @ t_X
        else:  # x ~ K R_X^T (R_i P + T_i - t_X): in the flange frame the camera is at R_i^T (t_X - T_i)
            R_cam, C = R_X.T @ Rf[i], Rf[i].T @ (t_X - T[i])
        assert np.allclose(cams.R[i], R_cam) and np.allclose(cams.C[i], C)
    R_rel, t = cams.relative(0, [1])  # within a session each view keeps its own (small) rotation
    assert rotation_angle_deg(R_rel[0]) == pytest.approx(0.3)
    assert np.allclose(t[0], cams.R[1] @ (cams.C[1] - cams.C[0]))
    with pytest.raises(InputError, match="orientation of every view"):
        view_cameras(cal, T)


def test_views_the_calibration_saw_take_its_refined_positions():
    T_cal = np.array([[0, 0, 0], [30, 0, 0], [0, 30, 0], [0, 0, 30]], float)
    cal, _, _ = _hand_eye_calibration(T_std=np.full((4, 3), 0.05), T=T_cal)
    measured = T_cal[[2, 0]] + [[0.1, -0.1, 0.05], [0.0, 0.2, 0.0]]  # within 6 sigma: views 2 and 0
    new = np.array([[10.0, 10, 10]])
    cams = view_cameras(cal, Poses.of(np.vstack([measured, new]), np.repeat(np.eye(3)[None], 3, axis=0)))
    assert cams.known.tolist() == [2, 0, -1]
    R_cam, C = cal.camera_poses()
    assert np.array_equal(cams.C[:2], C[[2, 0]]) and np.allclose(cams.C[2], new[0] + cal.hand_eye.t)


def _two_orientation_scene(rng=7, size=SIZE, tilt_deg=15.0, wobble_deg=0.4):
    """Two sessions of 5 views of one workspace at flange orientations ``tilt_deg`` apart
    (the second's views each turned by up to ``wobble_deg`` about a random axis, within
    the session tolerance), the camera at ``(R_X, t_X)`` in the flange; each session
    rendered with its own camera orientation. Returns the flange poses, the Rendered
    of each session (true depth of its first view, the reference) and ``(K, R_X, t_X)``."""
    rng = np.random.default_rng(rng)
    R_X = Rotation.from_euler("xyz", [180, 10, -20], degrees=True).as_matrix()  # camera -> flange
    t_X = np.array([10.0, -25.0, 120.0])
    K = K_from_params(0.95 * size[0], 0.99 * size[0], size[0] / 2 + 3.1, size[1] / 2 - 2.4)
    centre = np.array([100.0, 50.0, 0.0])  # the first session's camera centre, view 0
    R_cam_a = R_X.T  # flange -> base rotation I
    ahead = centre + 800.0 * R_cam_a[2]  # the scene's middle
    turn = Rotation.from_rotvec(np.radians(tilt_deg) * np.array([0.0, 1.0, 0.3]) / np.hypot(1, 0.3)).as_matrix()
    truth, T, Rf = [], [], []
    surfaces = preset_scene("workspace", 800.0, K, R_cam_a, centre, size, 11)[0]
    for R_flange in (np.eye(3), turn):
        R_cam = R_X.T @ R_flange.T
        C = ahead + R_flange @ (centre - ahead) + render.ring_translations(5, 60.0, R_cam, rng)
        wob = Rotation.from_rotvec(rng.normal(size=(5, 3)) * np.radians(wobble_deg / 2)).as_matrix()
        wob[0] = np.eye(3)  # the reference view's orientation is the session's
        Rs = R_flange @ wob
        imgs = np.stack([render.render(surfaces, K, R_X.T @ Rs[i].T, C[i:i + 1], size, supersample=1,
                                       degrade=LIGHT, rng=rng)[0] for i in range(5)])
        truth.append(render.Rendered(images=imgs, K=K, R=R_cam, dist=np.zeros(0), T=C, surfaces=surfaces,
                                     corners=np.zeros((0, 3)), corner_kind=np.zeros(0), image_size=size))
        T.append(C - Rs @ t_X)  # the flange positions of the camera centres C with orientations Rs
        Rf.append(Rs)
    return np.vstack(T), np.concatenate(Rf), truth, (K, R_X, t_X)


def _project_views(K, R_cam, C, X):
    """Pixels ``(n_views, n, 2)`` of ``X (n, 3)`` in views ``(R_cam (n_views, 3, 3), C)``."""
    xc = np.einsum("vab,vnb->vna", R_cam, X[None] - C[:, None])
    return xc[..., :2] / xc[..., 2:] @ K[:2, :2].T + K[:2, 2]


def test_calibration_from_two_orientations_places_each_session(tmp_path):
    """Calibrate from sparse tracks of views at two flange orientations (the one model),
    then dense-match a view of each session with its own session's views: each view's
    camera comes from the calibration, and the depth is as good as with one orientation."""
    T, Rf, truth, (K, R_X, t_X) = _two_orientation_scene()
    # the wobble of the second session: its views are not pure translations of each other
    R_cam_true = R_X.T @ np.transpose(Rf, (0, 2, 1))
    C_true = T + Rf @ t_X
    rng = np.random.default_rng(1)
    uv0 = rng.uniform([10, 10], [SIZE[0] - 10, SIZE[1] - 10], (80, 2))
    X = truth[0].backproject(0, uv0)
    X = X[np.isfinite(X).all(axis=1)]
    uv = _project_views(K, R_cam_true, C_true, X) + rng.normal(0, 0.2, (len(T), len(X), 2))
    poses = Poses.of(T, Rf)
    cal = transcalib.calibrate(uv, poses, image_size=SIZE, rng=0)
    assert cal.hand_eye is not None and cal.hand_eye.n_sessions == 2
    images = list(truth[0].images) + list(truth[1].images)
    res = dense(cal, images, poses, reference_views=["0", "5"], depth_limits=(380, 1300))
    for m, scene, view in zip(res.maps, truth, (0, 5)):
        assert m.sources == tuple(str(v) for v in range(view, view + 5) if v != view)
        rel, textured = _errors(scene, m.depth)
        known = np.isfinite(m.depth)
        assert (known & textured).sum() / textured.sum() > 0.75  # measured 0.84-0.86 (0.3 deg wobble)
        assert np.median(rel[known & textured]) < 0.006  # 0.38 % (0.32 % with the true calibration)
    # the cloud is in the robot frame: off the truth only along the hand-eye offset's
    # undetermined direction (the relative rotation's axis: a shift of the whole cloud)
    m = res.maps[1]
    d = cal.hand_eye.undetermined
    assert res.frame.startswith("the robot base frame, up to a shift along") and d.shape == (3, 1)
    shift = m.centre - C_true[5]
    assert np.linalg.norm(shift - d @ (d.T @ shift)) < 3.0  # mm at 800 mm (measured 1.3; 10.4 along it)
    known = np.isfinite(m.depth)
    X_true = truth[1].backproject(0, np.column_stack(np.nonzero(known)[::-1]).astype(float))
    err = np.linalg.norm(m.points(known) - shift - X_true, axis=1) / m.depth[known]
    assert np.median(err[np.isfinite(err)]) < 0.008  # measured 0.43 % (the calibration's 0.16 deg included)
    # the command: the saved calibration, the poses file with orientations (quaternions)
    transcalib.save(cal, tmp_path / "cal")
    names = [tmp_path / f"v{i}.png" for i in range(10)]
    for name, img in zip(names, images):
        cv2.imwrite(str(name), img)
    write_poses_csv(tmp_path / "poses.csv", T, R=Rf)
    code = main(["dense", "--calibration", str(tmp_path / "cal"), "--images", *map(str, names), "--poses",
                 str(tmp_path / "poses.csv"), "--out", str(tmp_path / "out"), "--depth-limits", "380,1300",
                 "--reference-view", "5", "--no-report", "--quiet"])
    assert code == 0 and json.loads((tmp_path / "out" / "dense.json").read_text())["cloud"]["frame"] == res.frame
    assert np.allclose(np.load(tmp_path / "out" / "depth_5.npy"), m.depth, equal_nan=True, rtol=1e-4)
    # the sweep with each view's own small rotation beats one rotation for the session
    no_wobble = replace_poses_rotations(poses, 5, 10)
    flat = dense(cal, images, no_wobble, reference_views=["5"], depth_limits=(380, 1300)).maps[0]
    rel_flat, textured = _errors(truth[1], flat.depth)
    rel_own, _ = _errors(truth[1], m.depth)  # measured: 84 % known, 0.38 %; without: 63 %, 4.1 %
    assert np.isfinite(m.depth[textured]).mean() > np.isfinite(flat.depth[textured]).mean() + 0.1
    assert np.nanmedian(rel_flat[textured]) > 4 * np.nanmedian(rel_own[textured])


def replace_poses_rotations(poses, a, b):
    """``poses`` with views ``a .. b - 1`` given the orientation of view ``a`` (the small
    rotations within the session left out)."""
    R = np.array(poses.R)
    R[a:b] = R[a]
    return Poses.of(poses.T, R)


# --------------------------------------------------------------------------- bad input in Python


def test_bad_inputs_raise_clear_errors(scene):
    cam = Camera(scene.K, scene.R, image_size=scene.image_size)
    imgs = list(scene.images)
    with pytest.raises(InputError, match="5 images but 4 poses"):
        dense(cam, imgs, scene.T[:4])
    with pytest.raises(InputError, match="calibrated at 256x192"):
        dense(cam, [cv2.resize(i, (128, 96)) for i in imgs], scene.T)
    with pytest.raises(InputError, match="different sizes"):
        dense(Camera(scene.K, scene.R), imgs[:4] + [imgs[4][:100]], scene.T)
    with pytest.raises(InputError, match="reference view"):
        dense(cam, imgs, scene.T, reference_views=["7"])
    with pytest.raises(InputError, match="near < far"):
        dense(cam, imgs, scene.T, depth_limits=(900, 500))
    with pytest.raises(InputError, match="window_px"):
        DenseOptions(window_px=4)
    with pytest.raises(InputError, match="8- or 16-bit"):
        dense(cam, [i.astype(np.float32) for i in imgs], scene.T)
    with pytest.raises(DegenerateError, match="no baseline"):
        dense(cam, imgs, np.zeros((5, 3)))
    with pytest.raises(TypeError):
        DenseOptions(n_depth=10)  # a misspelt option fails loudly


def test_package_is_callable_whatever_was_imported_first(scene):
    import transcalib.dense.views  # noqa: F401 - the submodule import must not hide the function

    assert callable(transcalib.dense) and transcalib.DenseOptions is DenseOptions


# --------------------------------------------------------------------------- the command


def run(*args):
    return subprocess.run([sys.executable, "-m", "transcalib.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def assert_clean_error(r, *words, code=2):
    assert r.returncode == code, (r.returncode, r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert lines[-1].startswith("transcalib: error:") and "Traceback" not in r.stderr, r.stderr
    assert [line for line in lines if "error" in line.lower()] == lines[-1:], r.stderr
    for w in words:
        assert w in lines[-1], (w, lines[-1])


@pytest.fixture(scope="module")
def files(scene, tmp_path_factory):
    d = tmp_path_factory.mktemp("dense")
    transcalib.save(_calibration(Camera(scene.K, scene.R, image_size=scene.image_size), scene.T), d / "cal")
    for i, img in enumerate(scene.images):
        cv2.imwrite(str(d / f"view{i}.png"), img)
    write_poses_csv(d / "poses.csv", scene.T)
    return d


def _args(d, out, *extra):
    return ["dense", "--calibration", d / "cal", "--images", *[d / f"view{i}.png" for i in range(5)],
            "--poses", d / "poses.csv", "--out", out, "--depth-limits", "380,1300", *extra]


def test_command_outputs_and_their_formats(files, scene, result):
    from plyfile import PlyData

    out = files / "out"
    r = run(*_args(files, out, "--reference-view", "0"))
    assert r.returncode == 0, r.stderr
    doc = json.loads((out / "dense.json").read_text())
    names = {p.name for p in out.iterdir()}
    assert names == {"depth_0.npy", "confidence_0.npy", "depth_std_0.npy", "depth_0.png", "dense.ply", "dense.json",
                     "report.html", MANIFEST}
    manifest = read_manifest(out)
    assert manifest["command"] == "dense" and {f["path"] for f in manifest["files"]} == names - {MANIFEST}
    depth, conf, std = (np.load(out / f"{k}_0.npy") for k in ("depth", "confidence", "depth_std"))
    assert depth.dtype == conf.dtype == std.dtype == np.float32 and depth.shape == (192, 256)
    assert np.array_equal(depth, result.maps[0].depth, equal_nan=True)  # the command is the library
    png = cv2.imread(str(out / "depth_0.png"), cv2.IMREAD_UNCHANGED)
    scale = doc["reference_views"][0]["depth_png_scale"]
    assert png.dtype == np.uint16 and np.array_equal(png == 0, np.isnan(depth))
    assert np.nanmax(np.abs(png * scale - depth)) <= scale / 2 + 1e-6 * np.nanmax(depth)
    ply = PlyData.read(str(out / "dense.ply"))["vertex"]
    assert ply.count == doc["cloud"]["points"] == np.isfinite(depth).sum()
    assert {"x", "y", "z", "red", "green", "blue", "confidence", "depth_std", "view"} <= set(ply.data.dtype.names)
    assert np.allclose(np.column_stack([ply["x"], ply["y"], ply["z"]]), result.points)
    assert "<img" in (out / "report.html").read_text() and "view 0" in r.stdout


def test_command_fuses_several_reference_views(files, capsys):
    out = files / "two"
    assert main([str(a) for a in _args(files, out, "--reference-view", "0", "--reference-view", "03", "--json",
                                       "--no-report")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert [v["view"] for v in summary["reference_views"]] == ["0", "3"]
    assert (out / "depth_3.npy").exists() and not (out / "report.html").exists()


@pytest.mark.parametrize("case, words", [
    ("no-calibration", ["--calibration"]),
    ("count", ["--images", "4 images but 5 poses"]),
    ("not-an-image", ["--images", "not an image"]),
    ("size", ["--images", "calibrated at 256x192"]),
    ("no-poses", ["--poses", "does not exist"]),
    ("reference", ["--reference-view", "9"]),
    ("limits", ["--depth-limits"]),
    ("window", ["--window"]),
    ("depths", ["--depths", "n_depths"]),
    ("confidence", ["--min-confidence"]),
    ("turn", ["--max-turn-deg", "(0, 45]"]),
    ("orientation", ["--poses", "orientation"]),
    ("out-file", ["--out", "existing file"]),
    ("out-foreign", ["--out", "not a transcalib run", "--force"]),
    ("out-input", ["--out", "holds the input"]),
])
def test_command_bad_input_one_line_exit_2(files, tmp_path, capsys, case, words):
    """In this process (the command's own main, as the console script runs it)."""
    d = files
    args = _args(d, tmp_path / "out")
    if case == "no-calibration":
        args[args.index("--calibration") + 1] = tmp_path / "nothing"
    elif case == "count":
        args.remove(d / "view4.png")
    elif case == "not-an-image":
        (tmp_path / "view4.png").write_text("text")
        args[args.index(d / "view4.png")] = tmp_path / "view4.png"
    elif case == "size":
        cv2.imwrite(str(tmp_path / "small.png"), np.zeros((10, 12), np.uint8))
        args[args.index(d / "view4.png")] = tmp_path / "small.png"
    elif case == "no-poses":
        args[args.index("--poses") + 1] = tmp_path / "none.csv"
    elif case == "reference":
        args += ["--reference-view", "9"]
    elif case == "limits":
        args[args.index("--depth-limits") + 1] = "900,100"
    elif case == "window":
        args += ["--window", "4"]
    elif case == "depths":
        args += ["--depths", "2"]
    elif case == "confidence":
        args += ["--min-confidence", "1.5"]
    elif case == "turn":
        args += ["--max-turn-deg", "90"]
    elif case == "orientation":
        Rf = np.repeat(np.eye(3)[None], 5, axis=0)
        Rf[3] = Rotation.from_euler("x", 3, degrees=True).as_matrix()
        T = np.loadtxt(d / "poses.csv", delimiter=",", skiprows=1)[:, 1:]
        write_poses_csv(tmp_path / "poses.csv", T, R=Rf)
        args[args.index("--poses") + 1] = tmp_path / "poses.csv"
    elif case == "out-file":
        (tmp_path / "out").write_text("x")
    elif case == "out-foreign":
        (tmp_path / "out").mkdir()
        (tmp_path / "out" / "notes.txt").write_text("mine")
    elif case == "out-input":
        args[args.index("--out") + 1] = d
    try:
        code = main([str(a) for a in args])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    captured = capsys.readouterr()
    assert_clean_error(subprocess.CompletedProcess(args, code, captured.out, captured.err), *words)
    if case == "out-foreign":
        assert (tmp_path / "out" / "notes.txt").read_text() == "mine"


# --------------------------------------------------------------------------- complete or absent


@pytest.mark.parametrize("earlier, sig", [(False, signal.SIGINT), (True, signal.SIGTERM)])
def test_interrupted_command_leaves_nothing(files, tmp_path, earlier, sig):
    """Ctrl-C or kill during the sweep: exit 130, no temporary folder, an earlier run intact."""
    out = tmp_path / "out"
    if earlier:  # an earlier run (as far as the folder rule can tell)
        out.mkdir()
        (out / MANIFEST).write_text('{"kind": "transcalib run", "files": []}')
        (out / "depth_0.npy").write_bytes(b"earlier")
        before = (out / MANIFEST).read_bytes()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.Popen([sys.executable, "-m", "transcalib.cli", *map(str, _args(files, out, "--depths", "3000"))],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, preexec_fn=default_sigint)
    for line in p.stderr:  # wait until the sweep has started writing its progress
        if "dense: sweep" in line:
            break
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err[-2000:]
    assert sorted(x.name for x in tmp_path.iterdir()) == (["out"] if earlier else [])  # no temporary folder
    if earlier:
        assert (out / MANIFEST).read_bytes() == before and (out / "depth_0.npy").exists()


def test_command_replaces_an_earlier_run_and_forces_a_foreign_folder(files, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / MANIFEST).write_text('{"kind": "transcalib run", "files": []}')  # an earlier run
    (out / "stray.txt").write_text("x")
    assert main([str(a) for a in _args(files, out, "--no-report", "--quiet", "--depths", "16")]) == 0
    assert not (out / "stray.txt").exists() and read_manifest(out)["command"] == "dense"
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert main([str(a) for a in _args(files, foreign, "--no-report", "--force", "--quiet", "--depths", "16")]) == 0
    assert not (foreign / "notes.txt").exists() and (foreign / "depth_0.npy").exists()


def test_default_depth_limits_bracket_the_scene(scene):
    m = dense(Camera(scene.K, scene.R, image_size=scene.image_size), list(scene.images), scene.T).maps[0]
    assert m.view == "0"  # the ring's centre is the most central view
    truth = scene.depth_map(0)
    near, far = m.depth_limits
    assert near <= np.nanpercentile(truth, 1) and far >= np.nanpercentile(truth, 99)
    # found, not pushed out by the border (measured 1.19 x the farthest depth; 1.79 when the
    # windows that leave the image, matching the replicated edge at no motion, counted)
    assert far < 1.5 * np.nanmax(truth)
