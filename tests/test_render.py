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


# --------------------------------------------------------------------------- degradations
from transcalib.errors import InputError  # noqa: E402
from transcalib.synth.degrade import REALISTIC, Degradations  # noqa: E402


def _flat(opt, n=3, size=(120, 90), value=0.5, rng=0):
    """Views of a uniform grey plane filling the image, degraded by ``opt``."""
    sf = render.plane([0, 0, 100.0], np.eye(3), (1e4, 1e4), render.Constant(value))
    K = K_from_params(100.0, 100.0, size[0] / 2 - 0.5, size[1] / 2 - 0.5)
    return render.render([sf], K, np.eye(3), np.zeros((n, 3)), size, supersample=1, degrade=opt, rng=rng,
                         return_effects=True)


def test_vignetting_exposure_and_noise_follow_their_models():
    img, _ = _flat(Degradations(vignetting=0.4), n=1)
    centre, corner = img[0, 44:46, 59:61].mean(), img[0, 0, 0]
    assert centre == pytest.approx(0.5 * 255, abs=0.6) and corner == pytest.approx(0.6 * 0.5 * 255, abs=0.6)
    img, eff = _flat(Degradations(exposure=0.3), n=4)
    assert np.allclose(img.mean(axis=(1, 2)), np.clip(np.rint(0.5 * 255 * eff.gain), 0, 255), atol=0.01)
    assert np.ptp(eff.gain) > 0 and np.all(np.abs(eff.gain - 1) <= 0.3)
    # shot + read noise: variance I * 255 / full_well + read^2 (grey levels), within 10 %
    img, _ = _flat(Degradations(full_well_e=1000.0, read_noise_dn=2.0), n=2, size=(200, 150))
    expected = 0.5 * 255 * 255 / 1000.0 + 4.0
    assert np.var(img.astype(float)) == pytest.approx(expected + 1 / 12, rel=0.1)


def test_overlay_is_static_and_specular_moves_with_the_camera():
    sf, _ = render.checker_board([0, 0, 100.0], np.eye(3), 10.0, 8, 8)
    K = K_from_params(200.0, 200.0, 80.0, 60.0)
    T = np.array([[0, 0, 0], [5.0, 0, 0], [0, 5.0, 0]])
    opt = Degradations(overlay="CAM 1 {view:02d}", overlay_scale=1.0)  # a solid white core in OpenCV 4.8 and 5
    img = render.render([sf], K, np.eye(3), T, (160, 120), degrade=opt)
    from transcalib.synth.degrade import overlay_box
    u0, v0, u1, v1 = overlay_box(opt, (160, 120))
    white = img[:, v0:v1, u0:u1] >= 250  # the text's core (the scene is at most 235 here)
    assert white[0].sum() > 20 and (white[0] & white[1]).sum() > 0.6 * white[0].sum()  # same pixels
    img, eff = _flat(Degradations(specular=0.4, specular_sigma_px=5.0, specular_drift_px=20.0), n=3)
    peaks = np.array([np.unravel_index(np.argmax(v), v.shape)[::-1] for v in img], float)
    assert np.allclose(peaks, eff.specular_uv, atol=1.0)
    assert np.ptp(eff.specular_uv, axis=0).max() > 2.0  # it moves, though the camera does not


def test_jpeg_and_truth_unchanged():
    r0 = render.render_scene("natural", n_views=2, image_size=(160, 120), noise_std=0.0, supersample=1, rng=4)
    r1 = render.render_scene("natural", n_views=2, image_size=(160, 120), noise_std=0.0, supersample=1, rng=4,
                             degrade=REALISTIC)
    assert np.array_equal(r0.K, r1.K) and np.array_equal(r0.T, r1.T) and np.array_equal(r0.R, r1.R)
    d = np.abs(r0.images.astype(float) - r1.images)
    assert 2.0 < d.mean() < 60.0
    j = render.render_scene("natural", n_views=1, image_size=(160, 120), noise_std=0.0, supersample=1, rng=4,
                            degrade=Degradations(jpeg_quality=30))
    e = np.abs(j.images[0].astype(float) - r0.images[0])
    assert 0.3 < e.mean() < 8.0  # lossy, but the same picture
    assert set(r1.meta["degrade"]) == {"vignetting", "exposure", "full_well_e", "read_noise_dn", "jpeg_quality",
                                       "specular", "overlay"}


def test_bad_degradation_options_raise():
    with pytest.raises(InputError, match="vignetting"):
        Degradations(vignetting=1.5)
    with pytest.raises(InputError, match="jpeg_quality"):
        Degradations(jpeg_quality=0)
    with pytest.raises(InputError, match="uint8"):
        render.render([], np.eye(3), np.eye(3), np.zeros((1, 3)), (20, 20), dtype="float",
                      degrade=Degradations(vignetting=0.1))


def test_repetitive_scene_has_identical_tiles():
    r = render.render_scene("repetitive", n_views=1, image_size=(320, 240), noise_std=0.0, supersample=1, rng=0)
    wall = r.surfaces[0]
    tex = wall.texture
    s = np.linspace(0.1, 0.5, 50) * tex.period
    a = tex(s, s, 0 * s, 0 * s)
    b = tex(s + 3 * tex.period, s - 2 * tex.period, 0 * s, 0 * s)
    assert np.allclose(a, b, atol=1e-5) and np.ptp(a) > 0.1


def test_strips_render_the_whole_image_alike(monkeypatch):
    """render_view works in strips of STRIP_ROWS pixel rows; each surface's footprints
    take the rows beyond a strip's edge from its crop: the same values, bit for bit, as
    one strip over the whole image (distortion, a sphere, surfaces cut by strip edges)."""
    from transcalib.synth import raycast

    def images():
        return render.render_scene("floor", n_views=2, image_size=(160, 120), supersample=3, dist=(-0.1, 0.02),
                                   noise_std=0.0, rng=4).images

    strips = images()
    monkeypatch.setattr(raycast, "STRIP_ROWS", 10**6)
    whole = images()
    assert all(np.array_equal(a, b) for a, b in zip(strips, whole))
    monkeypatch.setattr(raycast, "STRIP_ROWS", 1)  # strips of one pixel row: as many edges as rows
    assert all(np.array_equal(a, b) for a, b in zip(images(), whole))


def test_moving_a_surface_with_its_rays_leaves_the_hits():
    """Casting in the camera frame (the surfaces moved, not the rays) is the same cast:
    a plane and a sphere moved by ``x -> Q x + t`` with the rays' centre and directions
    give the same depths and texture coordinates."""
    from scipy.spatial.transform import Rotation
    from transcalib.synth import surfaces
    from transcalib.synth.raycast import surface_hits

    rng = np.random.default_rng(3)
    Q, t = Rotation.from_rotvec([0.3, -0.8, 0.5]).as_matrix(), np.array([40.0, -15.0, 300.0])
    plane = surfaces.plane([10.0, 5.0, 500.0], Rotation.from_rotvec([0.2, 0.1, 0.0]).as_matrix(), (400.0, 300.0),
                           texture=None)
    ball = surfaces.sphere([30.0, -20.0, 450.0], 60.0, texture=None,
                           frame=Rotation.from_rotvec([0.4, 0.0, -0.3]).as_matrix())
    C = np.array([5.0, -3.0, 2.0])
    d = np.r_[rng.uniform(-0.25, 0.25, (2, 500)), np.ones((1, 500))]
    for sf in (plane, ball):
        z, s, u = surface_hits(sf, list(d), C)
        z2, s2, u2 = surface_hits(sf.moved(Q, t), list(Q @ d), Q @ C + t)
        hit = np.isfinite(z)
        assert 50 < hit.sum() and np.array_equal(hit, np.isfinite(z2))
        np.testing.assert_allclose(np.c_[z2, s2, u2][hit], np.c_[z, s, u][hit], rtol=0, atol=1e-9)
