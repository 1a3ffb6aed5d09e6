"""Tests of the planner (issue 12): prediction = CRLB, box and visibility, plan vs patterns, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

import transcalib
from transcalib.cli.main import main
from transcalib.errors import DegenerateError, InputError
from transcalib.planning import PATTERNS, PlanOptions, evaluate_plan, plan, view_rotation
from transcalib import crlb
from transcalib.planning.fisher import predict
from transcalib.planning.model import design_scene, scene_points, visible
from transcalib.planning.optimise import Pool, _criterion_index, _rest, _score

BOX = (-150.0, 150.0, -150.0, 150.0, 0.0, 250.0)
SCENE = dict(image_size=(800, 600), focal_px=700.0, distance=900.0, depth_range=300.0, n_points=40, noise_px=0.5)


@pytest.fixture(scope="module")
def planned():
    return plan(BOX, 5, **SCENE)


def _points(result):
    return scene_points(result.options, result.box.mean(axis=1), 0)


def test_prediction_equals_crlb_of_the_same_scene(planned):
    scene = design_scene(planned.options, _points(planned), planned.T)
    bound = crlb(scene)
    for k, v in planned.predicted_std.items():
        assert v == pytest.approx(bound[k], rel=1e-8), k
    for name, ev in planned.patterns.items():
        bound = crlb(design_scene(planned.options, _points(planned), ev.T))
        assert ev.predicted_std["fx"] == pytest.approx(bound["fx"], rel=1e-8), name


@pytest.mark.parametrize("extra", [dict(robot_noise=0.2), dict(distortion="radial2", dist=(-0.1, 0.02)),
                                   dict(margin_px=20.0, view_direction="0.3,-0.2,-1")])
def test_evaluation_equals_crlb_with_robot_noise_distortion_margin(extra):
    options = PlanOptions(**SCENE, **extra)
    T = np.random.default_rng(1).uniform(-120, 120, (7, 3)) + [0, 0, 125]
    ev = evaluate_plan(T, options, box=BOX)
    scene = design_scene(options, scene_points(options, np.mean(np.reshape(BOX, (3, 2)), axis=1), 0), T)
    bound = crlb(scene, distortion=options.distortion)
    assert set(ev.predicted_std) == {k for k in bound if not k.startswith("T")}
    for k, v in ev.predicted_std.items():
        assert v == pytest.approx(bound[k], rel=1e-8), k
    assert np.isnan(scene.uv[..., 0]).any()  # some observations leave the image: only visible ones count


@pytest.mark.parametrize("robot_noise", [0.0, 0.4])
def test_orientation_error_prediction_equals_the_marginal_information(robot_noise):
    """With each view's orientation (and position) error the prediction eliminates them as
    nuisance parameters with priors; the oracle integrates them out instead: per view the
    observations' covariance ``sigma^2 I + J_e diag(s_rot^2 I, s_pos^2 I) J_e^T`` and the
    Fisher information ``sum_i J_i^T Sigma_i^-1 J_i`` over the camera and the points, with
    central differences of :func:`transcalib.geometry.camera.project` (Gaussian
    marginalisation: the two agree exactly)."""
    from transcalib.geometry.camera import project
    from transcalib.geometry.rotation import rotvec_to_matrix

    options = PlanOptions(image_size=(640, 480), focal_px=600.0, distance=500.0, depth_range=200.0, n_points=12,
                          noise_px=0.5, robot_noise=robot_noise, robot_sigma_deg=0.08)
    X = scene_points(options, np.zeros(3), 3)
    T = np.random.default_rng(4).uniform(-60, 60, (6, 3))
    seen = visible(options, X, T)
    predicted = predict(options, X, T).std
    K, R0, n = options.K, options.R, len(X)

    def views(theta, i, e):
        """The visible pixels of view i: theta = (fx, fy, cx, cy, w, X), e = (delta, eps)."""
        Kt = np.array([[theta[0], 0, theta[2]], [0, theta[1], theta[3]], [0, 0, 1]])
        R = rotvec_to_matrix(theta[4:7]) @ R0 @ rotvec_to_matrix(-e[:3])
        uv = project(Kt, R, theta[7:].reshape(n, 3), (T[i] + e[3:])[None])[0]
        return uv[seen[i]].ravel()

    def jac(f, x, h):
        return np.stack([(f(x + h * d) - f(x - h * d)) / (2 * h) for d in np.eye(len(x))], axis=1)

    theta0 = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], np.zeros(3), X.ravel()])
    s_e = np.r_[np.full(3, np.radians(0.08)), np.full(3, robot_noise)]
    info = np.zeros((len(theta0), len(theta0)))
    for i in range(len(T)):
        J = jac(lambda th: views(th, i, np.zeros(6)), theta0, 1e-6)
        Je = jac(lambda e: views(theta0, i, e), np.zeros(6), 1e-7)
        Sigma = options.noise_px**2 * np.eye(len(J)) + (Je * s_e**2) @ Je.T
        info += J.T @ np.linalg.solve(Sigma, J)
    std = np.sqrt(np.diag(np.linalg.inv(info)))
    assert seen.sum(axis=0).min() >= 2
    for k, (name, unit) in enumerate([("fx", 1), ("fy", 1), ("cx", 1), ("cy", 1)] +
                                     [(a, np.degrees(1)) for a in ("rx", "ry", "rz")]):
        assert predicted[name] == pytest.approx(unit * std[k], rel=1e-5), name


def test_pool_score_equals_batched_prediction(planned):
    X = _points(planned)
    design = Pool.of(planned.options, X, planned.T)
    fast = _score(_rest(design, 2), design.take([2]), _criterion_index(planned.options))[0]
    p = predict(planned.options, X, planned.T)
    assert fast * planned.options.noise_px == pytest.approx(np.sqrt((p.std["fx"] ** 2 + p.std["fy"] ** 2) / 2),
                                                            rel=1e-9)


def test_plan_stays_in_box_and_keeps_points_visible(planned):
    b = np.reshape(BOX, (3, 2))
    assert planned.T.shape == (5, 3)
    assert np.all(planned.T >= b[:, 0] - 1e-9) and np.all(planned.T <= b[:, 1] + 1e-9)
    seen = visible(planned.options, _points(planned), planned.T)
    assert np.all(seen.mean(axis=1) >= planned.options.min_visible)
    np.testing.assert_allclose(planned.evaluation.visible, seen.mean(axis=1))
    d = np.linalg.norm(planned.T[:, None] - planned.T[None], axis=2)[np.triu_indices(5, 1)]
    assert d.min() >= 0.05 * 300 - 1e-9  # no repeated positions
    for name, ev in planned.patterns.items():
        assert np.all(ev.T >= b[:, 0] - 1e-9) and np.all(ev.T <= b[:, 1] + 1e-9), name


def test_flat_box_cannot_be_planned():
    with pytest.raises(DegenerateError, match="three axes"):
        plan((-150, 150, -150, 150, 0, 0), 5, **SCENE)


def test_plan_beats_every_standard_pattern(planned):
    assert set(planned.patterns) == set(PATTERNS)
    for name, ev in planned.patterns.items():
        assert planned.predicted_std["fx"] <= ev.predicted_std["fx"] * (1 + 1e-9), name
        assert planned.evaluation.criterion <= ev.criterion * (1 + 1e-9), name
    assert planned.patterns["naive"].predicted_std["fx"] > 2 * planned.predicted_std["fx"]


def test_plan_from_allowed_positions_uses_only_them():
    rng = np.random.default_rng(3)
    allowed = rng.uniform(-150, 150, (30, 3)) + [0, 0, 125]
    res = plan(BOX, 6, positions=allowed, **SCENE)
    assert all(np.any(np.all(np.isclose(t, allowed), axis=1)) for t in res.T)


def test_public_api_and_options_fail_loudly():
    assert transcalib.plan is plan and transcalib.evaluate_plan is evaluate_plan
    with pytest.raises(InputError, match="focal_pix"):
        plan(BOX, 5, focal_pix=700)
    with pytest.raises(InputError, match="n_views"):
        plan(BOX, 3, **SCENE)
    with pytest.raises(InputError, match="box"):
        plan((0, 1, 0, 1, 0), 5, **SCENE)
    with pytest.raises(InputError, match="view_direction"):
        PlanOptions(view_direction="up")


@pytest.mark.parametrize("d", ["-z", "+x", "y", "1,2,-3"])
def test_view_rotation_is_a_rotation_along_the_direction(d):
    R = view_rotation(d)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    axis = {"-z": [0, 0, -1], "+x": [1, 0, 0], "y": [0, 1, 0], "1,2,-3": np.array([1, 2, -3]) / np.sqrt(14)}[d]
    np.testing.assert_allclose(R[2], axis, atol=1e-12)


def test_weak_designs_are_warned_about():
    codes = lambda T: {w.code for w in evaluate_plan(T, **SCENE).warnings}  # noqa: E731
    flat = [[0, 0, 0], [100, 0, 0], [0, 100, 0], [100, 100, 1], [50, 20, 0]]
    assert "coplanar_moves" in codes(flat)
    tiny = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    assert {"small_moves", "weak_design"} <= codes(tiny)
    assert "too_few_views" in codes(tiny[:3])
    assert "repeated_positions" in codes(np.vstack([tiny, tiny[:1]]) * 100)
    good = plan(BOX, 6, **SCENE)
    assert not {"coplanar_moves", "small_moves", "weak_design", "repeated_positions"} & codes(good.T)


ARGS = ["plan", "--image-size", "800,600", "--focal-px", "700", "--distance", "900", "--depth-range", "300",
        "--points", "40", "--noise-px", "0.5", "--box", "-150,150,-150,150,0,250", "--views", "5"]


def test_cli_writes_poses_and_plan(tmp_path, capsys):
    assert main(ARGS + ["--out", str(tmp_path / "p")]) == 0
    raw = (tmp_path / "p" / "poses.csv").read_bytes()
    assert b"\r" not in raw and raw.startswith(b"view,x,y,z\n")
    T = np.loadtxt(tmp_path / "p" / "poses.csv", delimiter=",", skiprows=1)[:, 1:]
    data = json.loads((tmp_path / "p" / "plan.json").read_text())
    np.testing.assert_allclose(data["R"], view_rotation("-z"))
    assert set(data["predicted_std"]) >= {"fx", "fy", "cx", "cy", "rx", "ry", "rz"}
    assert set(data["patterns"]) == set(PATTERNS)
    ref = evaluate_plan(T, box=BOX, **SCENE)
    assert data["predicted_std"]["fx"] == pytest.approx(ref.predicted_std["fx"], rel=1e-9)
    assert "plan" in capsys.readouterr().out
    # and evaluate it back
    assert main(ARGS[:15] + ["--evaluate", str(tmp_path / "p" / "poses.csv"), "--out", str(tmp_path / "e")]) == 0
    ev = json.loads((tmp_path / "e" / "evaluation.json").read_text())
    assert ev["predicted_std"]["fx"] == pytest.approx(data["predicted_std"]["fx"], rel=1e-9)


def _replace(args, option, value):
    out = list(args)
    if option not in out:
        return out + [option, value]
    out[out.index(option) + 1] = value
    return out


@pytest.mark.parametrize("option,value", [("--focal-px", "abc"), ("--focal-px", "-3"), ("--box", "0,1,0,1,0"),
                                          ("--box", "1,0,0,1,0,1"), ("--views", "2"), ("--image-size", "800"),
                                          ("--depth-range", "5000"), ("--points", "1.5"), ("--noise-px", "0"),
                                          ("--dist-coeffs", "1,2,3"), ("--view-direction", "up")])
def test_cli_rejects_bad_options(tmp_path, capsys, option, value):
    code = main(_replace(ARGS, option, value) + ["--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2
    assert option in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_cli_rejects_unwritable_out_before_computing(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(ARGS + ["--out", str(blocker / "sub")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and len(err.strip().splitlines()) == 1


def test_cli_unknown_option_is_one_line(capsys):
    assert main(ARGS + ["--vews", "4"]) == 2
    err = capsys.readouterr().err
    assert "--vews" in err and len(err.strip().splitlines()) == 1
