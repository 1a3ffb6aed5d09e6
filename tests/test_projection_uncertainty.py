"""The report's projection-uncertainty map against a Monte Carlo of whole refinements.

The oracle is independent of the map's Jacobians: scenes are simulated afresh, refined,
and a fixed point (in the camera frame, or in the robot frame) is projected with every
trial's estimate; the scatter of those pixels is what the map must predict.
"""

import numpy as np
import pytest

from transcalib.estimate.layout import FlangeModel
from transcalib.estimate.refine import fit_refine
from transcalib.geometry.camera import project_camera_frame
from transcalib.geometry.rotation import rotvec_to_matrix
from transcalib.handeye.simulate import session_scene
from transcalib.report.figures import projection_std
from transcalib.types import Calibration, Camera, RefineOptions

K_SQUARE = np.array([[600.0, 0.0, 330.0], [0.0, 600.0, 235.0], [0.0, 0.0, 1.0]])
GRID = (4, 3)  # the map's nodes: corners, edges and the middle of the image
TRIALS = 60


def _trial(sessions: int, seed: int):
    """One refinement of a fresh scene (0.5 px noise, k1 = -0.1) from near the truth:
    ``(calibration, scene, the truth's offset of the model frame from the base frame)``."""
    rng = np.random.default_rng(seed)
    sc = session_scene(rng, n_sessions=sessions, views_per_session=12 // sessions, n_points=60, noise_px=0.5,
                       K=K_SQUARE, dist=(-0.1,))
    turn = rotvec_to_matrix(np.radians(0.2) * rng.normal(size=3))
    if sessions == 1:  # translations only: the points relative to the camera centre at T = 0
        R0, shift, flange = (sc.R[0] @ sc.R_X).T, sc.R[0] @ sc.t_X, None
    else:
        R0, shift = sc.R_X.T, np.zeros(3)
        flange = FlangeModel(np.transpose(sc.R, (0, 2, 1)), sc.t_X + rng.normal(0, 2.0, 3), np.eye(3))
    K = K_SQUARE * [[1 + 0.01 * rng.normal(), 1, 1], [1, 1 + 0.01 * rng.normal(), 1], [1, 1, 1]]
    start = Calibration(camera=Camera(K, turn @ R0), X=sc.X - shift, residuals_px=np.zeros_like(sc.uv), rms_px=0.0,
                        T=sc.T)
    opts = RefineOptions(distortion="radial1", robot_error=False, square_pixels=sessions == 1)
    return fit_refine(sc.uv, sc.T, start, opts, flange=flange), sc, shift


@pytest.mark.parametrize("sessions", [1, 3])
def test_projection_std_matches_the_scatter_of_refined_projections(sessions):
    """Per node of the map, the predicted std (RMS over the trials) is within 25 % of the
    empirical worst-direction std of the projected fixed point, in both frames; one
    session fits square pixels (the parameter ``f``), three also the offset ``t``."""
    first, sc, shift = _trial(sessions, 0)
    size = tuple(sc.image_size)
    u, v = np.linspace(0, size[0] - 1, GRID[0]), np.linspace(0, size[1] - 1, GRID[1])
    # the fixed points: the true rays through the nodes at the scene's median depth, view 0
    R_true = (sc.R[0] @ sc.R_X).T
    C_true = sc.T[0] + sc.R[0] @ sc.t_X
    depth = np.median((sc.X - C_true) @ R_true[2])
    rays = Camera(sc.K, np.eye(3), sc.dist, "radial1").pixels_to_rays(np.stack(np.meshgrid(u, v), axis=-1))  # (gh, gw, 3)
    x_cam = rays * depth
    X_model = x_cam @ R_true + C_true - shift  # robot (model) frame
    pixels = {"camera": [], "robot": []}
    predicted = {"camera": [], "robot": []}
    for seed in range(TRIALS):
        cal, _, _ = (first, sc, shift) if seed == 0 else _trial(sessions, seed)
        R_cam, C = cal.camera_poses()
        intr, dist5 = cal.camera.intrinsics, cal.camera.dist5
        pixels["camera"].append(project_camera_frame(intr, dist5, np.moveaxis(x_cam, -1, 0)).pred)
        pixels["robot"].append(project_camera_frame(intr, dist5, np.moveaxis((X_model - C[0]) @ R_cam[0].T, -1, 0)).pred)
        for frame in predicted:
            predicted[frame].append(projection_std(cal, GRID, size=size, frame=frame)[2])
    for frame in pixels:
        p = np.array(pixels[frame])  # (trials, 2, gh, gw)
        d = p - p.mean(axis=0)
        cov = np.einsum("tagw,tbgw->gwab", d, d) / (len(p) - 1)
        empirical = np.sqrt(np.linalg.eigvalsh(cov)[..., -1])
        ratio = np.sqrt(np.mean(np.array(predicted[frame]) ** 2, axis=0)) / empirical
        assert np.all((ratio > 0.75) & (ratio < 1.25)), (frame, ratio)
    # the frames differ: the robot frame carries the camera's orientation too
    assert not np.allclose(np.mean(predicted["robot"], axis=0), np.mean(predicted["camera"], axis=0), rtol=0.25)
