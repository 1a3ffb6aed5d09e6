"""Several flange orientations through the one model (``transcalib.calibrate`` with poses that
carry rotations): exactness, observability of t_X, SCARA, sessions, the command with several
orientations, the deprecated ``calibrate_sessions`` alias.

Ground truth comes from :mod:`transcalib.handeye.simulate`; quaternions are checked
against scipy's independent implementation (the pose reader: ``tests/test_io.py``).
"""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from transcalib import DegenerateError, InputError, Poses, RefineOptions, calibrate
from transcalib.geometry.rotation import matrix_to_quaternion, matrix_to_rotvec, quaternion_to_matrix, rotvec_to_matrix
from transcalib.handeye.export import easy_handeye_yaml, hand_eye_json, hand_eye_matrix, hand_eye_tf
from transcalib.handeye.sessions import group_sessions
from transcalib.io import read_poses
from transcalib.handeye.simulate import DEFAULT_R_X, flange_rotations_looking, session_scene

EXACT = 1e-9


def _axis(Ra, Rb):
    w = matrix_to_rotvec(Ra.T @ Rb)
    return w / np.linalg.norm(w)


def _calibrate(uv, T, R, session=None, **kw):
    """``calibrate`` with the flange poses ``T, R`` (distortion ``none`` unless given)."""
    return calibrate(uv, Poses.of(T, R, session=session), **{"distortion": "none", **kw})


def _check_camera(cal, sc):
    assert np.abs(cal.K - sc.K).max() < EXACT * sc.K[0, 0]
    assert np.abs(cal.hand_eye.R - sc.R_X).max() < EXACT


def test_one_session_3d_exact_and_offset_reported_undetermined():
    sc = session_scene(0, n_sessions=1, moves="3d")
    he = _calibrate(sc.uv, sc.T, sc.R)
    _check_camera(he, sc)
    assert he.hand_eye.undetermined.shape == (3, 3)
    assert np.all(he.hand_eye.t == 0)  # the stated convention
    ok = np.isfinite(he.X[:, 0])
    # with t_X = 0 the points are the truth shifted by -R t_X
    assert np.abs(he.X[ok] - (sc.X[ok] - sc.R[0] @ sc.t_X)).max() < EXACT * 500
    assert "is not determined" in he.hand_eye.notes[0] and "two different axes" in he.hand_eye.notes[0]


def test_two_coplanar_sessions_full_K_and_axis_component_undetermined():
    sc = session_scene(1, n_sessions=2, moves="xy")
    with pytest.raises(DegenerateError):  # one 2-axis session alone does not determine K
        _calibrate(sc.uv[:6], sc.T[:6], sc.R[:6])
    he = _calibrate(sc.uv, sc.T, sc.R)
    _check_camera(he, sc)
    a = _axis(sc.R[0], sc.R[-1])  # relative rotation axis, flange frame
    assert he.hand_eye.undetermined.shape == (3, 1)
    assert abs(abs(he.hand_eye.undetermined[:, 0] @ a) - 1) < 1e-9
    alpha = sc.t_X @ a
    assert np.abs(he.hand_eye.t - (sc.t_X - alpha * a)).max() < 1e-8
    ok = np.isfinite(he.X[:, 0])
    assert np.abs(he.X[ok] - (sc.X[ok] - alpha * sc.R[0] @ a)).max() < 1e-8
    assert "not determined" in he.hand_eye.notes[0] and "perpendicular" in he.hand_eye.notes[0]
    entry = hand_eye_json(he.hand_eye)
    assert len(entry["undetermined_directions"]) == 1
    assert abs(abs(np.dot(entry["undetermined_directions"][0], a)) - 1) < 1e-9


@pytest.mark.parametrize("moves", ["xy", "3d"])
def test_three_sessions_exact(moves):
    sc = session_scene(2, n_sessions=3, moves=moves)
    he = _calibrate(sc.uv, sc.T, sc.R)
    _check_camera(he, sc)
    assert he.hand_eye.undetermined.shape == (3, 0)
    assert np.abs(he.hand_eye.t - sc.t_X).max() < 1e-8
    ok = np.isfinite(he.X[:, 0])
    assert ok.sum() > 50 and np.abs(he.X[ok] - sc.X[ok]).max() < 1e-8


def test_three_sessions_noisy_within_reported_std():
    errs = []
    for seed in range(6):
        sc = session_scene(10 + seed, n_sessions=3, moves="xy", noise_px=0.3, n_points=80)
        he = _calibrate(sc.uv, sc.T, sc.R)
        errs.append((he.hand_eye.t - sc.t_X) / he.hand_eye.t_std)
    z = np.array(errs)
    assert np.abs(z).max() < 4.5 and 0.3 < np.sqrt(np.mean(z**2)) < 2.0


def _scara_rotations(n):
    R0 = flange_rotations_looking(np.array([[0.2, 0.1, -1.0]]), DEFAULT_R_X)[0]
    return np.stack([rotvec_to_matrix(np.radians([0, 0, 30.0 * s])) @ R0 for s in range(n)])


def test_scara_coplanar_ambiguity_is_named():
    sc = session_scene(3, n_sessions=3, moves="xy", rotations=_scara_rotations(3))
    with pytest.raises(DegenerateError, match="SCARA"):
        _calibrate(sc.uv, sc.T, sc.R)


def test_scara_with_z_moves_leaves_the_vertical_offset_undetermined():
    sc = session_scene(4, n_sessions=3, moves="3d", rotations=_scara_rotations(3))
    he = _calibrate(sc.uv, sc.T, sc.R)
    _check_camera(he, sc)
    a = sc.R[0].T @ np.array([0, 0, 1.0])  # base z in the flange frame
    assert he.hand_eye.undetermined.shape == (3, 1) and abs(abs(he.hand_eye.undetermined[:, 0] @ a) - 1) < 1e-9


def test_bad_rotation_input():
    sc = session_scene(0, n_sessions=2, moves="3d")
    R = sc.R.copy()
    R[3] *= 1.01
    with pytest.raises(InputError, match=r"views \[3\]"):
        _calibrate(sc.uv, sc.T, R)


def test_calibrate_sessions_is_a_deprecated_alias():
    from transcalib import calibrate_sessions

    sc = session_scene(2, n_sessions=3, moves="xy", noise_px=0.3)
    with pytest.warns(DeprecationWarning, match="transcalib.calibrate"):
        old = calibrate_sessions(sc.uv, sc.T, sc.R, robust=True, rng=0)
    new = _calibrate(sc.uv, sc.T, sc.R, robust=True, rng=0)
    assert np.array_equal(old.K, new.K) and np.array_equal(old.t_flange_camera, new.hand_eye.t)
    assert np.array_equal(old.R_flange_camera, new.hand_eye.R) and old.undetermined.shape == (3, 0)


# -------------------------------------------------------------------------- sessions

def test_grouping_tolerance_and_override():
    rng = np.random.default_rng(0)
    base = [np.eye(3), rotvec_to_matrix(np.radians([20.0, 0, 0]))]
    jitter = [rotvec_to_matrix(np.radians(0.3) * rng.normal(size=3) / np.sqrt(3)) for _ in range(8)]
    R = np.stack([base[k // 4] @ jitter[k] for k in range(8)])
    g = group_sessions(R, tolerance_deg=2.0)
    assert g.n_sessions == 2 and list(g.session_of_view) == [0] * 4 + [1] * 4 and not g.off_views
    assert group_sessions(R, tolerance_deg=0.01).n_sessions == 8
    labels = ["a"] * 4 + ["b"] * 3 + ["a"]  # the last view is 20 deg off session "a"
    g = group_sessions(R, tolerance_deg=2.0, session=labels)
    assert [i for i, _ in g.off_views] == [7] and 15 < g.off_views[0][1] < 25
    assert "view 7" in g.messages()[0] and "deg off" in g.messages()[0]


def test_exports_roundtrip():
    R = Rotation.random(random_state=3).as_matrix()
    t = np.array([12.0, -4.0, 80.0])
    M = hand_eye_matrix(R, t)
    assert np.allclose(M[:3, :3], R) and np.allclose(M[:3, 3], t) and np.allclose(M[3], [0, 0, 0, 1])
    q = matrix_to_quaternion(R)
    assert np.allclose(quaternion_to_matrix(q), R, atol=1e-12)
    assert np.allclose(Rotation.from_quat(q).as_matrix(), R, atol=1e-12)
    tf = hand_eye_tf(R, t)
    assert np.isclose(tf["translation"]["z"], 0.08)
    y = easy_handeye_yaml(R, t)
    assert "eye_on_hand: true" in y and "transformation:" in y and f"  z: {0.08!r}" in y


# ------------------------------------------------------------------- rendered examples

def _make_sessions_module():
    import importlib.util
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "examples" / "make_sessions.py"
    spec = importlib.util.spec_from_file_location("make_sessions", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod, path.parent


def _ground_truth_tracks(rendered, rng, n_random=400, noise_px=0.3):
    """Tracks from the renderer's ground truth (cross-session tracking is not on main yet):
    checkerboard corners and random points on the table and the box tops, seen where the
    renderer says they are visible (in the image, not occluded), plus pixel noise."""
    table, boxes = rendered[0].surfaces[0], [sf for sf in rendered[0].surfaces if sf.name.startswith("box")]
    tops = [sf for sf in boxes if sf.normal[2] > 0.9]
    pts = [rendered[0].corners, table.point(rng.uniform(0, 1, (n_random, 2)) * table.size)]
    pts += [sf.point(rng.uniform(0.1, 0.9, (20, 2)) * sf.size) for sf in tops]
    X = np.concatenate(pts)
    uv = np.concatenate([np.where(r.visible(X, margin_px=2)[..., None], r.project(X), np.nan) for r in rendered])
    return uv + rng.normal(0, noise_px, uv.shape), X


@pytest.mark.parametrize("n_sessions", [2, 3])
def test_rendered_examples_ground_truth_tracks(n_sessions):
    mod, root = _make_sessions_module()
    folder = root / f"sessions{n_sessions}"
    poses = read_poses(folder / "poses.csv")  # quaternions, session column
    truth = json.loads((folder / "truth.json").read_text())
    assert all((folder / name).is_file() for name in poses.images)
    rendered = mod.rendered_sessions(n_sessions, with_images=False)
    uv, X = _ground_truth_tracks(rendered, np.random.default_rng(n_sessions))
    he = _calibrate(uv, poses.T, poses.R, session=poses.session)
    K, R_X, t_X = (np.array(truth[k]) for k in ("K", "R_flange_camera", "t_flange_camera"))
    assert abs(he.K[0, 0] / K[0, 0] - 1) < 0.005 and abs(he.K[1, 1] / K[1, 1] - 1) < 0.005
    angle = np.degrees(np.linalg.norm(matrix_to_rotvec(he.hand_eye.R.T @ R_X)))
    assert angle < 0.2
    B = np.linalg.svd(he.hand_eye.undetermined, full_matrices=True)[0][:, he.hand_eye.undetermined.shape[1]:] \
        if he.hand_eye.undetermined.shape[1] else np.eye(3)
    assert he.hand_eye.undetermined.shape[1] == (1 if n_sessions == 2 else 0)
    assert np.linalg.norm(B.T @ (he.hand_eye.t - t_X)) < 1.0  # mm, determined part


def test_robust_finds_planted_outliers():
    sc = session_scene(6, n_sessions=3, moves="xy", noise_px=0.3, n_points=80)
    uv = sc.uv.copy()
    rng = np.random.default_rng(1)
    bad = rng.choice(80, 8, replace=False)
    views = np.flatnonzero(sc.session_of_view == 1)
    uv[views[:, None], bad[None]] += rng.uniform(15, 30, (len(views), 8, 2))  # wrong matches in session 1
    he = _calibrate(uv, sc.T, sc.R, robust=True, rng=0)
    seen1 = np.isfinite(sc.uv[views][..., 0]).sum(axis=0) >= 2
    rejected = set(np.flatnonzero(~he.inliers))  # a track with wrong matches in one session is rejected whole
    assert set(bad[seen1[bad]]) <= rejected and len(rejected - set(bad)) <= 3  # 1 % false rejection
    assert np.linalg.norm(he.hand_eye.t - sc.t_X) < 5 * np.linalg.norm(he.hand_eye.t_std)


def test_monte_carlo_std_near_the_crlb():
    """Small Monte Carlo (the full study is benchmarks/bench_handeye.py): with 30 trials
    the sample std is within ~13 % (1 sigma) of the true std; allow 40 %."""
    from dataclasses import replace

    from transcalib.handeye.observability import sessions_crlb
    base = session_scene(21, n_sessions=3, moves="xy", n_points=60)
    bound = sessions_crlb(replace(base, noise_px=0.5))
    rng = np.random.default_rng(0)
    est = []
    for _ in range(30):
        uv = np.where(np.isfinite(base.uv), base.uv_true + rng.normal(0, 0.5, base.uv.shape), np.nan)
        he = _calibrate(uv, base.T, base.R)
        est.append([he.K[0, 0], he.K[1, 1], *he.hand_eye.t])
    ratio = np.std(est, axis=0, ddof=1) / np.array([bound[k] for k in ("fx", "fy", "t_x", "t_y", "t_z")])
    assert np.all((ratio > 0.6) & (ratio < 1.4)), ratio


def _link_by_truth(blocks, n_views, tol_mm=0.3):
    """Join per-session tracks into points across sessions by their true 3-D point (the
    renderer's ``track_truth``): a stand-in for cross-session matching, which is not on
    main yet. ``blocks``: per session (views, uv (k, m, 2), X (m, 3), junction (m,))."""
    from scipy.spatial import cKDTree
    ref_X, cols = np.zeros((0, 3)), []  # cols: per point, {session: track index}
    for s, (_, _, X, junction) in enumerate(blocks):
        idx = np.flatnonzero(np.isfinite(X[:, 0]) & ~junction)
        hit = np.full(len(idx), -1)
        if len(ref_X):
            d, m = cKDTree(ref_X).query(X[idx])
            hit = np.where(d < tol_mm, m, -1)
        for k, h in zip(idx, hit):
            if h >= 0 and s not in cols[h]:
                cols[h][s] = k
            else:
                cols.append({s: k})
                ref_X = np.vstack([ref_X, X[k]])
    uv = np.full((n_views, len(cols), 2), np.nan)
    for j, d in enumerate(cols):
        for s, k in d.items():
            uv[blocks[s][0], j] = blocks[s][1][:, k]
    return uv, sum(len(d) > 1 for d in cols)


@pytest.mark.parametrize("n_sessions", [2, 3])
def test_rendered_images_end_to_end(n_sessions):
    """Images -> calibration: the project's tracker inside each session on the rendered
    PNGs, tracks linked across sessions by ground truth, robust calibration."""
    import cv2

    from transcalib import track
    mod, root = _make_sessions_module()
    folder = root / f"sessions{n_sessions}"
    poses = read_poses(folder / "poses.csv")
    truth = json.loads((folder / "truth.json").read_text())
    rendered = mod.rendered_sessions(n_sessions, with_images=False)
    sess = np.array([int(s) for s in poses.session])
    blocks = []
    for s in range(n_sessions):
        views = np.flatnonzero(sess == s)
        uv_s = track([cv2.imread(str(folder / poses.images[i]), cv2.IMREAD_GRAYSCALE) for i in views]).uv
        blocks.append((views, uv_s, *rendered[s].track_truth(uv_s)))
    uv, n_linked = _link_by_truth(blocks, len(poses.T))
    assert n_linked > 100
    he = _calibrate(uv, poses.T, poses.R, session=poses.session, robust=True, rng=0,
                    refinement=RefineOptions(loss="huber"))
    K, R_X, t_X = (np.array(truth[k]) for k in ("K", "R_flange_camera", "t_flange_camera"))
    assert abs(he.K[0, 0] / K[0, 0] - 1) < 0.005 and abs(he.K[1, 1] / K[1, 1] - 1) < 0.005
    assert np.degrees(np.linalg.norm(matrix_to_rotvec(he.hand_eye.R.T @ R_X))) < 0.2
    P = np.eye(3) - he.hand_eye.undetermined @ he.hand_eye.undetermined.T
    assert np.linalg.norm(P @ (he.hand_eye.t - t_X)) < 1.0


def test_refinement_uses_each_views_own_rotation():
    """Orientations jitter by ~0.1 deg inside the sessions (a real controller): the linear
    start uses the session mean, the refinement each view's R_i, so noise-free data are
    still fitted exactly."""
    from dataclasses import replace

    from transcalib.geometry.camera import project
    sc = session_scene(8, n_sessions=3, moves="3d")
    rng = np.random.default_rng(2)
    R = np.stack([rotvec_to_matrix(np.radians(0.1) * rng.normal(size=3)) @ r for r in sc.R])
    Rc = np.transpose(R @ sc.R_X, (0, 2, 1))
    C = sc.T + R @ sc.t_X
    uv = np.stack([project(sc.K, Rc[i], sc.X, C[i:i + 1])[0] for i in range(len(R))])
    uv[~np.isfinite(sc.uv)] = np.nan
    sc = replace(sc, uv=uv, R=R)
    he = _calibrate(sc.uv, sc.T, sc.R)
    assert he.hand_eye.n_sessions == 3
    _check_camera(he, sc)
    assert np.abs(he.hand_eye.t - sc.t_X).max() < 1e-8


@pytest.mark.parametrize("poses_ids, tracks_ids", [("{}", "{}"), ("{:02d}", "{}"), ("{:02d}", "{:03d}")])
def test_cli_uses_the_sessions_model_when_orientations_vary(tmp_path, poses_ids, tracks_ids):
    """``transcalib calibrate`` with quaternions that differ between groups of views: the
    hand-eye model, hand_eye.json / hand_eye.yaml, errors against the truth; view ids
    compare as integers ("00" in the poses is view 0 of the tracks)."""
    import json
    import subprocess
    import sys

    from transcalib import io as tio

    sc = session_scene(4, n_sessions=3, moves="xy", noise_px=0.3, n_points=60)
    n = len(sc.T)
    tio.write_tracks_csv(tmp_path / "tracks.csv", sc.uv, view_ids=[tracks_ids.format(i) for i in range(n)])
    tio.write_poses_csv(tmp_path / "poses.csv", sc.T, [poses_ids.format(i) for i in range(n)], R=sc.R)
    assert (tmp_path / "poses.csv").read_text().splitlines()[1].startswith(poses_ids.format(0) + ",")
    truth = {"R_flange_camera": sc.R_X.tolist(), "t_flange_camera": list(map(float, sc.t_X)),
             "K": sc.K.tolist(), "image_size": [640, 480]}
    (tmp_path / "truth.json").write_text(json.dumps(truth))
    r = subprocess.run([sys.executable, "-m", "transcalib.cli", "calibrate", "--tracks", str(tmp_path / "tracks.csv"),
                        "--poses", str(tmp_path / "poses.csv"), "--out", str(tmp_path / "out"), "--quiet",
                        "--truth", str(tmp_path / "truth.json"), "--formats", "json", "--distortion", "none"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "Camera in the flange (hand-eye)" in r.stdout and "error vs truth" in r.stdout
    he = json.loads((tmp_path / "out" / "hand_eye.json").read_text())
    assert np.linalg.norm(np.array(he["t_flange_camera"]) - sc.t_X) < 2.0  # mm, 0.3 px noise
    assert "eye_on_hand: true" in (tmp_path / "out" / "hand_eye.yaml").read_text()


def test_distortion_chosen_from_the_data_with_sessions():
    """``distortion="auto"`` works on the sessions model too: none kept without a lens,
    radial2 found with one (k1 = -0.1)."""
    plain = session_scene(4, n_sessions=3, moves="xy", noise_px=0.3, n_points=80)
    assert _calibrate(plain.uv, plain.T, plain.R, distortion="auto").dist_model == "none"
    lens = session_scene(4, n_sessions=3, moves="xy", noise_px=0.3, n_points=80, dist=(-0.1, 0.02))
    he = _calibrate(lens.uv, lens.T, lens.R, distortion="auto")
    assert he.dist_model == "radial2" and abs(he.dist[0] + 0.1) < 0.005
