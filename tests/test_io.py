"""CSV readers: every malformed input gets a clear InputError; writers are atomic."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from transcalib import io as tio
from transcalib.types import InputError


def write(path, text):
    path.write_text(text)
    return path


@pytest.fixture
def poses(tmp_path):
    return write(tmp_path / "poses.csv", "view,x,y,z\n0,0,0,0\n1,10,0,0\n2,0,10,0\n3,0,0,10\n")


def test_round_trip(tmp_path, poses):
    uv = np.full((4, 3, 2), np.nan)
    uv[:, 0] = [[1.5, 2.5], [3, 4], [5, 6], [7, 8]]
    uv[1:, 2] = [[9, 10], [11, 12], [13, 14]]
    tio.write_tracks_csv(tmp_path / "tracks.csv", uv, ["a", "b", "c"])
    p = tio.read_poses(poses)
    got, ids = tio.tracks_to_uv(tmp_path / "tracks.csv", p)
    assert ids.tolist() == ["a", "c"]  # point b has no observation
    np.testing.assert_array_equal(got, uv[:, [0, 2]])


def test_point_order_is_first_appearance_and_ids_any_text(tmp_path, poses):
    tracks = write(tmp_path / "t.csv", "view,point,u,v\n0,zeta,1,2\n0,alpha,3,4\n1,zeta,5,6\n")
    uv, ids = tio.tracks_to_uv(tracks, tio.read_poses(poses))
    assert ids.tolist() == ["zeta", "alpha"]
    assert uv[1, 0, 0] == 5 and np.isnan(uv[1, 1, 0])


def test_views_in_poses_order_and_integer_ids(tmp_path):
    poses = write(tmp_path / "p.csv", "view,x,y,z\n3,0,0,0\n1,1,0,0\n2,0,1,0\n0,0,0,1\n")
    tracks = write(tmp_path / "t.csv", "view,point,u,v\n00,p,1,2\n3,p,3,4\n")
    uv, _ = tio.tracks_to_uv(tracks, tio.read_poses(poses))
    assert uv[3, 0, 0] == 1 and uv[0, 0, 0] == 3  # view "00" is view "0", the 4th row


def test_header_case_whitespace_and_bom(tmp_path):
    p = write(tmp_path / "p.csv", "\ufeffView, X ,y,Z\n0, 1 ,2,3\n")
    poses = tio.read_poses(p)
    np.testing.assert_array_equal(poses.T, [[1, 2, 3]])


def test_quaternions_and_images(tmp_path):
    p = write(tmp_path / "p.csv", "view,x,y,z,qx,qy,qz,qw,image\n0,0,0,0,0,0,0,1,a.png\n")
    poses = tio.read_poses(p)
    np.testing.assert_allclose(poses.R, [np.eye(3)])
    assert poses.images == ["a.png"] and poses.rotation_format == "quaternion" and poses.session is None


def test_no_orientation_is_none(tmp_path, poses):
    p = tio.read_poses(poses)
    assert p.R is None and p.rotation_format is None and p.images is None and p.session is None
    assert p.views == ["0", "1", "2", "3"] and p.lines == (2, 3, 4, 5) and p.path == str(poses) and p.unit is None


def _pose_rows(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")
    return path


def test_orientation_formats_found_from_columns_against_scipy(tmp_path):
    """Each orientation format, found from the columns or given (also by a maker's name),
    gives scipy's rotation matrices (an independent implementation); JSON like CSV."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(5)
    rots = Rotation.random(4, random_state=7)
    T = rng.uniform(-1, 1, (4, 3))
    cases = {"quaternion": (["qx", "qy", "qz", "qw"], rots.as_quat(), "ros"),
             "rotvec": (["rx", "ry", "rz"], rots.as_rotvec(), "ur"),
             "euler_zyx": (["a", "b", "c"], rots.as_euler("ZYX", degrees=True), "kuka")}  # Rz(a) Ry(b) Rx(c)
    for fmt, (cols, values, alias) in cases.items():
        path = _pose_rows(tmp_path / f"{fmt}.csv", ["view", "x", "y", "z", *cols],
                          [[i, *map(repr, T[i].tolist()), *map(repr, values[i].tolist())] for i in range(4)])
        for given in (None, fmt, alias):
            p = tio.read_poses(path, rotation_format=given)
            assert p.rotation_format == fmt and np.abs(p.R - rots.as_matrix()).max() < 1e-12, (fmt, given)
            np.testing.assert_array_equal(p.T, T)
    q = rots.as_quat()
    js = tmp_path / "p.json"
    js.write_text(json.dumps({"poses": [{"view": i, "X": T[i, 0], "y": T[i, 1], "z": T[i, 2], "qx": q[i, 0],
                                         "qy": q[i, 1], "qz": q[i, 2], "qw": q[i, 3]} for i in range(4)]}, indent=1))
    p = tio.read_poses(js)
    assert np.abs(p.R - rots.as_matrix()).max() < 1e-12 and p.views == ["0", "1", "2", "3"]
    assert p.lines == (3, 13, 23, 33)  # the line of each object's opening brace


def test_units(tmp_path, poses):
    p = tio.read_poses(poses, unit="m", output_unit="mm")
    np.testing.assert_array_equal(p.T[1], [10000, 0, 0])
    assert p.unit == "mm" and tio.read_poses(poses, unit="mm").unit == "mm"
    with pytest.raises(InputError, match="needs the unit of the file"):
        tio.read_poses(poses, output_unit="mm")
    with pytest.raises(InputError, match="unit must be one of mm, m, got 'inch'"):
        tio.read_poses(poses, unit="inch")
    with pytest.raises(InputError, match="rotation_format must be one of"):
        tio.read_poses(poses, rotation_format="matrix")


def test_zero_padded_view_ids_are_integers(tmp_path):
    """View ids compare as integers in poses and tracks alike: "01" is view "1"."""
    poses = write(tmp_path / "p.csv", "view,x,y,z\n00,0,0,0\n01,1,0,0\n02,0,1,0\n 3.0 ,0,0,1\n")
    p = tio.read_poses(poses)
    assert p.views == ["0", "1", "2", "3"]
    for ids in (["0", "1", "2", "3"], ["000", "01", "2", "03"]):
        tracks = write(tmp_path / "t.csv", "view,point,u,v\n" + "".join(f"{v},p,{k},0\n" for k, v in enumerate(ids)))
        uv, _ = tio.tracks_to_uv(tracks, p)
        np.testing.assert_array_equal(uv[:, 0, 0], [0, 1, 2, 3])
    with pytest.raises(InputError, match=r"line 3, column 'view': view id '1' appears more than once \(as view "
                                         r"'1' on line 2"):
        tio.read_poses(write(tmp_path / "d.csv", "view,x,y,z\n01,0,0,0\n1,1,0,0\n"))


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "is empty"),
        ("view,x,y,z\n", "no data rows"),
        ("view,x,y\n0,1,2\n", r"p.csv', line 1: lacks column\(s\) z"),
        ("view,x,y,z\n0,1,two,3\n", r"line 2, column 'y': 'two' is not a finite number"),
        ("view,x,y,z\n0,1,2,nan\n", "not a finite number"),
        ("view,x,y,z\n0,1,2\n", "3 cells, expected 4"),
        ("view,x,y,z\n0,1,2,3\n0,1,2,3\n", "more than once"),
        ("view,x,y,z\n0,1,2,3\n ,1,2,3\n", "line 3, column 'view': the view id is empty"),
        ("view,x,x,y,z\n0,1,1,2,3\n", r"line 1: column\(s\) x appear more than once"),
        ("view,x,y,z,qx\n0,1,2,3,0\n", r"line 1: column\(s\) qx of the orientation qx,qy,qz,qw "
                                        r"\(quaternion\) without qy,qz,qw.*rotation_format"),
        ("view,x,y,z,a,b\n0,1,2,3,0,0\n", r"a,b of the orientation a,b,c \(euler_zyx\) without c"),
        ("view,x,y,z,qx,qy,qz,qw,rx,ry,rz\n0,1,2,3,0,0,0,1,0,0,0\n",
         r"line 1: two orientations, qx,qy,qz,qw \(quaternion\) and rx,ry,rz \(rotvec\); choose .*rotation_format"),
        ("view,x,y,z,qx,qy,qz,qw\n0,1,2,3,0,0,0,1\n1,1,2,3,0,0,0.5,0.5\n",
         r"line 3: quaternion qx,qy,qz,qw has norm 0\.707107, expected 1"),
        ("view,x,y,z,qx,qy,qz,qw,image\n0,0,0,0,0,0,0,2,a.png\n", "norm 2, expected 1"),
        ("view,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,0\n", "norm 0, expected 1"),
        ("view,x,y,z,rx,ry,rz\n0,1,2,3,0,inf,0\n", "line 2, column 'ry': 'inf' is not a finite number"),
        ("view,x,y,z,a,b,c\n0,1,2,3,0,,0\n", "line 2, column 'b': '' is not a finite number"),
    ],
)
def test_bad_poses(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        tio.read_poses(write(tmp_path / "p.csv", text))


@pytest.mark.parametrize("fmt, columns", [("quaternion", "qx,qy,qz,qw"), ("rotvec", "rx,ry,rz"),
                                          ("kuka", "a,b,c")])
def test_given_rotation_format_needs_its_columns(tmp_path, poses, fmt, columns):
    with pytest.raises(InputError, match=f"rotation_format='.*' needs {columns}; it has view,x,y,z"):
        tio.read_poses(poses, rotation_format=fmt)


def test_given_rotation_format_ignores_other_columns(tmp_path):
    """A given format reads its own columns; another set (even a partial one) is left alone."""
    p = write(tmp_path / "p.csv", "view,x,y,z,qx,qy,qz,qw,a\n0,1,2,3,0,0,0,1,label\n")
    with pytest.raises(InputError, match="qx,qy,qz,qw"):
        tio.read_poses(p)
    np.testing.assert_array_equal(tio.read_poses(p, rotation_format="quaternion").R, [np.eye(3)])


@pytest.mark.parametrize("text, match", [
    ('[\n {"view": 0, "x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1},\n'
     ' {"view": 1, "x": 0, "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 2}\n]\n', r"q\.json', line 3: quaternion"),
    ('[\n {"view": 0, "x": 0, "y": 0, "z": 0},\n {"view": 1, "x": 0, "y": 0}\n]\n', r"line 3, key 'z': is missing"),
    ('[\n {"view": 0, "x": 0, "y": 0, "z": true}\n]\n', r"line 2, key 'z': True is not a finite number"),
    ('[\n {"view": "01", "x": 0, "y": 0, "z": 0},\n {"view": 1, "x": 0, "y": 0, "z": 0}\n]', "more than once"),
    ('[{"view": 0, "x": 0,\n "y": 0 "z": 0}]', r"line 2, column \d+: not valid JSON"),
    ('{"poses": []}', "expected a non-empty list of objects"),
    ('[{"view": 0, "x": 0, "y": 0}]', r"lacks key\(s\) z"),
])
def test_bad_json_poses(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        tio.read_poses(write(tmp_path / "q.json", text))


def test_poses_written_read_back(tmp_path):
    """``write_poses_csv`` with orientations and sessions reads back exactly (view ids as
    given, zero-padded too)."""
    from scipy.spatial.transform import Rotation

    R = Rotation.random(3, random_state=1).as_matrix()
    T = np.array([[0.1, 1 / 3, 2.0], [1e-9, 5.0, 6.0], [7.0, 8.0, 9.0]])
    tio.write_poses_csv(tmp_path / "p.csv", T, ["07", "08", "09"], images=["a", "b", "c"], R=R, session=["s", "s", "t"])
    p = tio.read_poses(tmp_path / "p.csv")
    assert p.views == ["7", "8", "9"] and p.session == ["s", "s", "t"] and p.images == ["a", "b", "c"]
    np.testing.assert_array_equal(p.T, T)
    assert np.abs(p.R - R).max() < 1e-15


@pytest.mark.parametrize(
    "text, match",
    [
        ("", "is empty"),
        ("view,point,u\n0,a,1\n", r"lacks column\(s\) v"),
        ("view,point,u,v\n0,a,1,x\n", "line 2, column 'v'"),
        ("view,point,u,v\n0,a,1,inf\n", "not a finite number"),
        ("view,point,u,v\n0,a,1,2\n0,a,3,4\n", r"more than one row for \(view, point\)"),
        ("view,point,u,v\n7,a,1,2\n", r"view\(s\) \['7'\] that are not in the poses file"),
    ],
)
def test_bad_tracks(tmp_path, poses, text, match):
    with pytest.raises(InputError, match=match):
        tio.tracks_to_uv(write(tmp_path / "t.csv", text), tio.read_poses(poses))


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        tio.read_poses(tmp_path / "nope.csv")


def test_binary_file(tmp_path):
    p = tmp_path / "p.csv"
    p.write_bytes(b"\xff\xfe\x00\x81binary")
    with pytest.raises(InputError, match="UTF-8"):
        tio.read_poses(p)


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with tio.atomic_write(target) as fh:
            fh.write("partial")
            raise RuntimeError("interrupted")
    assert target.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.json"]


def test_json_nan_becomes_null(tmp_path):
    tio.write_json(tmp_path / "a.json", {"x": np.array([1.0, np.nan]), "n": np.int64(3), "b": np.bool_(True)})
    assert json.loads((tmp_path / "a.json").read_text()) == {"x": [1.0, None], "n": 3, "b": True}


def test_points_csv(tmp_path):
    X = np.array([[1.0, 2.0, 3.0], [np.nan] * 3])
    tio.write_points_csv(tmp_path / "p.csv", ["a", "b"], X, X_std=np.ones((2, 3)), inliers=np.array([True, False]))
    lines = (tmp_path / "p.csv").read_text().splitlines()
    assert lines[0] == "point,x,y,z,sx,sy,sz,inlier"
    assert lines[1] == "a,1,2,3,1,1,1,1"
    assert lines[2] == "b,,,,1,1,1,0"
    assert b"\r" not in (tmp_path / "p.csv").read_bytes()


def test_text_outputs_have_lf_endings(tmp_path):
    uv = np.arange(4 * 3 * 2, dtype=float).reshape(4, 3, 2) / 7
    tio.write_tracks_csv(tmp_path / "t.csv", uv)
    tio.write_poses_csv(tmp_path / "p.csv", np.eye(4, 3), images=["a.png"] * 4)
    tio.write_json(tmp_path / "a.json", {"x": [1, 2]})
    for name in ("t.csv", "p.csv", "a.json"):
        data = (tmp_path / name).read_bytes()
        assert b"\r" not in data and data.endswith(b"\n"), name


def _random_tracks(rng, n_views=5, n_points=200):
    uv = rng.uniform(-10, 700, (n_views, n_points, 2))
    uv[rng.random((n_views, n_points)) < 0.3] = np.nan
    return uv


@pytest.mark.parametrize("suffix", [".csv", ".npz", ".parquet"])
@pytest.mark.parametrize("ids", ["int", "text"])
def test_tracks_round_trip_every_format(tmp_path, suffix, ids):
    """Each tracks format reads back bit-exactly, points in order, views by id."""
    rng = np.random.default_rng(4)
    uv = _random_tracks(rng)
    uv[:, 0] = [[0.1, 1 / 3], [1e-300, 2.5e5], [640.0, 479.999], [7, 8], [9, 10]]  # point 0 seen everywhere
    point_ids = [f"p,{k}" if ids == "text" else str(k) for k in range(uv.shape[1])]
    view_ids = ["10", "11", "12", "13", "14"]
    path = tmp_path / f"tracks{suffix}"
    tio.write_tracks(path, uv, point_ids, view_ids)
    poses = tio.Poses(views=["14", "10", "11", "12", "13"], T=np.zeros((5, 3)))  # another view order
    got, got_ids = tio.tracks_to_uv(path, poses)
    seen = np.isfinite(uv[..., 0]).any(axis=0)
    np.testing.assert_array_equal(got, uv[[4, 0, 1, 2, 3]][:, seen])
    expected = [int(p) if ids == "int" else p for p, s in zip(point_ids, seen) if s]  # integer ids read as int64
    assert got_ids.dtype.kind == ("i" if ids == "int" else "U") and got_ids.tolist() == expected


def test_fast_and_careful_csv_readers_agree(tmp_path):
    """The vectorised reader and the line-by-line reader give the same table."""
    from transcalib.io import tables

    text = "View, Point ,u,v\n3, a ,1.5,2\n03,b,3,4\n\n1,a,5,6e-3\n"
    path = write(tmp_path / "t.csv", text)
    fast = tables._tracks_fast(path, tables._header(path, ["view", "point", "u", "v"], "tracks"))
    assert fast is not None
    assert fast.view_ids == ["3", "1"] and fast.point_ids.tolist() == ["a", "b"]
    np.testing.assert_array_equal(fast.view_index, [0, 0, 1])
    np.testing.assert_array_equal(fast.uv, [[1.5, 2], [3, 4], [5, 6e-3]])
    bad = write(tmp_path / "bad.csv", "view,point,u,v\n0,a,1,2\n0,b,inf,2\n")
    with pytest.raises(InputError, match="line 3, column 'u'"):
        tio.read_tracks(bad)


def test_check_writable(tmp_path):
    f = write(tmp_path / "file", "x")
    with pytest.raises(InputError, match="--out .* is an existing file"):
        tio.check_writable_dir(f)
    with pytest.raises(InputError, match="--out .* is a file"):
        tio.check_writable_dir(f / "sub")
    with pytest.raises(InputError, match="-o .* is a folder"):
        tio.check_writable_file(tmp_path, "-o")
    assert tio.check_writable_dir(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # checking creates nothing


# --------------------------------------------------------------------------------------
# calibration.json + arrays.npz
# --------------------------------------------------------------------------------------


def full_calibration(n_points=40, n_views=5, seed=0):
    """A Calibration with every field set (NaNs, nested options, arrays in info)."""
    from transcalib.errors import Diagnostic
    from transcalib.geometry.camera import Camera, K_from_params
    from transcalib.types import (CalibrateOptions, Calibration, CalibrationStats, DistortionStep, HandEye,
                                  LinearEstimate, RansacOptions, RansacStats, RefineOptions, RefineStats,
                                  ViewRotations)

    rng = np.random.default_rng(seed)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(rng.normal(size=3) * 0.3).as_matrix()
    K = K_from_params(812.25, 809.5, 321.125, 239.75, 0.0)
    camera = Camera(K, R, dist=[-0.1, 0.01], dist_model="radial2", image_size=(640, 480))
    X = (rng.normal(size=(n_points, 3)) + [0, 0, 10]) @ R  # in front of the camera
    X[3] = np.nan
    res = rng.normal(size=(n_views, n_points, 2)) / 3
    res[1, 5] = np.nan
    lin = LinearEstimate(K=K * 1.01, R=R, A=K @ R, X=X + 0.01, depth=rng.uniform(5, 15, (n_views, n_points)),
                         singular_values=np.array([1e-9, 0.3, 0.5]), n_used_points=n_points - 1,
                         used=np.arange(n_points) != 3, method="fast")
    opts = CalibrateOptions(robust=True, ransac=RansacOptions(threshold_px=3.5),
                            refinement=RefineOptions(distortion="radial2", fix={"cx": 321.125},
                                                     sigma_T=(0.0, 0.1, 0.1, 0.1, 0.2), loss="huber"),
                            unit="mm")
    names = ("fx", "fy", "cy", "k1", "k2", "rx", "ry", "rz")
    cov = np.diag(np.arange(1.0, 9.0)) / 7
    return Calibration(
        camera=camera, X=X, residuals_px=res, rms_px=float(np.sqrt(np.nanmean(np.sum(res**2, 2)))),
        T=rng.normal(size=(n_views, 3)) * 0.5, sigma_px=0.33,
        diagnostics=[Diagnostic("few_points", "only 40 points: add points"), Diagnostic("x", "second, with ±")],
        linear=lin, cov=cov, std={n: float(np.sqrt(cov[k, k])) for k, n in enumerate(names)} | {"skew": np.nan},
        param_names=names, X_std=np.abs(X) / 100, inliers=np.arange(n_points) % 7 != 0, options=opts,
        T_std=np.ones((n_views, 3)) / 3,
        flange_rotations=np.stack([Rotation.from_rotvec([0.1 * i, -0.05, 0.2]).as_matrix() for i in range(n_views)]),
        hand_eye=HandEye("eye-to-hand", Rotation.from_rotvec([0.3, 0.1, -0.2]).as_matrix(), np.array([1.5, -2.0, 0.0]),
                         np.array([0.01, 0.02, np.nan]), np.diag([0.1, 0.2, 0.0]), np.array([[0.0], [0.0], [1.0]]),
                         np.array([0, 0, 1, 1, 2]), ("a", "b", "c"), ("one note",)),
        view_rotations=ViewRotations(np.arange(15.0).reshape(5, 3) / 7, np.full((5, 3), 0.01), np.arange(5.0)),
        stats=CalibrationStats(
            stages=("robust", "refine"), timings_s={"robust_s": 0.125, "refine_s": 0.25},
            ransac=RansacStats(trials=48, trials_needed=float("inf"), n_inliers=34, sigma_px=0.31, rule_sigma_px=0.5,
                               time_s=0.01),
            refine=RefineStats(iterations=7, cost=1.5, stop_reason="converged: cost decrease below tol", converged=True,
                               dof=101, n_observations=180, n_points_used=39, n_points_excluded=1,
                               n_points_behind_camera=1, n_points_undetermined=0, inlier_threshold_px=1.25,
                               time_s=0.2),
            distortion_selection=(DistortionStep("radial2", 12.5, 1e-8, 0.01, True),
                                  DistortionStep("opencv5", 0.5, 0.7, 0.01, False, "not asked for")),
            sigma_truncation_factor=0.98),
        info={"nan": float("nan"), "none": None, "pair": (1, 2), "array": np.ones((2, 3)) / 3},
    )


def test_calibration_round_trip_every_field(tmp_path):
    from transcalib.io.calibration_file import load_calibration, load_saved, save_calibration

    cal = full_calibration()
    ids = [f"pt{k}" for k in range(cal.n_points)]
    json_path, arrays_path = save_calibration(cal, tmp_path / "out", point_ids=ids, inputs={"tracks": "t.csv"})
    assert json_path.name == "calibration.json" and arrays_path.name == "arrays.npz"
    back = load_calibration(tmp_path / "out")
    assert back == cal
    from dataclasses import fields
    for f in fields(cal):  # each field on its own, so a failure names it
        from transcalib.types.results import _same
        assert _same(getattr(back, f.name), getattr(cal, f.name)), f.name
    assert back.options == cal.options and back.options.refinement.sigma_T == (0.0, 0.1, 0.1, 0.1, 0.2)
    assert [d.code for d in back.diagnostics] == ["few_points", "x"]
    assert isinstance(back.info["array"], np.ndarray) and back.info["pair"] == (1, 2)
    assert back.stats.ransac.trials_needed == float("inf") and back.stats.distortion_selection[1].reason
    with pytest.raises(ValueError):  # a loaded result is frozen like a computed one
        back.X[0, 0] = 1.0
    saved = load_saved(json_path)
    assert saved.point_ids.tolist() == ids and saved.inputs["tracks"] == "t.csv" and saved.inputs["n_points"] == 40
    doc = json.loads(json_path.read_text())  # plain JSON: no NaN tokens
    assert doc["schema_version"] == 2 and doc["image_size"] == [640, 480] and doc["software"]["name"] == "transcalib"
    assert doc["stats"]["timings_s"] == {"robust_s": 0.125, "refine_s": 0.25}
    # a changed field is detected (the test can fail)
    from dataclasses import replace
    assert load_calibration(json_path) != replace(cal, rms_px=cal.rms_px + 1e-12)
    assert load_calibration(json_path) != replace(cal, stats=replace(cal.stats, stages=("linear",)))


def test_schema_1_file_still_loads():
    """A calibration saved by the schema-1 writer (tests/data/calibration-v1: 30 points,
    5 views, robot noise 0.2 mm; its statistics and T_std in one ``info`` dict) loads
    with the statistics and estimates in their typed fields."""
    from transcalib.io.calibration_file import load_calibration

    cal = load_calibration(Path(__file__).parent / "data" / "calibration-v1")
    assert cal.stats.stages == ("robust", "refine") and set(cal.stats.timings_s) >= {"robust_s", "refine_s"}
    assert cal.stats.refine.converged and cal.stats.refine.n_points_used == 30
    assert cal.T_std.shape == (5, 3) and np.all(cal.T_std[1:] > 0)
    assert cal.stats.distortion_selection[0].model == "radial2" and cal.stats.sigma_truncation_factor < 1
    assert dict(cal.info) == {}


def test_calibration_json_stays_small(tmp_path):
    from transcalib.io.calibration_file import save_calibration

    json_path, arrays_path = save_calibration(full_calibration(n_points=20000), tmp_path)
    assert json_path.stat().st_size < 20_000 < arrays_path.stat().st_size


def test_load_errors(tmp_path):
    from transcalib.io.calibration_file import load_calibration, save_calibration

    with pytest.raises(InputError, match="does not exist"):
        load_calibration(tmp_path)
    json_path, arrays_path = save_calibration(full_calibration(), tmp_path)
    arrays_path.unlink()
    with pytest.raises(InputError, match="sidecar"):
        load_calibration(tmp_path)
    doc = json.loads(json_path.read_text())
    doc["schema_version"] = 99
    json_path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="upgrade"):
        load_calibration(json_path)


def test_transcalib_save_round_trip(tmp_path):
    """``transcalib.save`` writes what ``transcalib.load`` reads back equal; anything but a
    Calibration is an InputError saying what was expected."""
    import transcalib
    from transcalib.errors import InputError

    cal = full_calibration(n_points=10)
    transcalib.save(cal, tmp_path / "c.json")
    assert (tmp_path / "c.arrays.npz").is_file()
    assert transcalib.load(tmp_path / "c.json") == cal
    with pytest.raises(InputError, match="transcalib.save: expected a Calibration.*got dict"):
        transcalib.save({"K": cal.K}, tmp_path / "d.json")
    assert not (tmp_path / "d.json").exists()


# --------------------------------------------------------------------------------------
# point ids: int64 when every id is a canonical integer, else text
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("ids, kind", [
    (["0", "1", "2"], "i"),
    (["5", "3", "9223372036854775807"], "i"),                           # the largest int64
    (["-5", "3"], "U"),                                                  # a sign: text
    (["007", "1"], "U"),                                                 # leading zeros stay text
    (["1", "2", "x"], "U"),
    (["99999999999999999999"], "U"),                                     # beyond int64
    (["+5"], "U"), ([" 5"], "U"), (["1_000"], "U"), (["0x10"], "U"), (["-0"], "U"), (["1e3"], "U"), (["٣"], "U"),
    (["9223372036854775808"], "U"), ([""], "U"),
])
def test_point_id_array(ids, kind):
    from transcalib.io.ids import FEW_IDS, point_id_array

    got = point_id_array(ids)
    assert got.dtype.kind == kind
    assert [str(v) for v in got.tolist()] == ids  # the text of each id is kept
    assert point_id_array(got) is got or kind == "U"  # already an id array: no new work
    many = ids * (FEW_IDS // len(ids) + 1)  # read by Arrow, not one by one: the same verdict
    assert point_id_array(many).dtype.kind == kind


def test_point_id_array_from_numpy_and_arrow():
    import pyarrow as pa

    from transcalib.io.ids import point_id_array

    assert point_id_array(np.arange(3, dtype=np.uint8)).dtype == np.int64
    assert point_id_array(pa.array(["3", "4"])).tolist() == [3, 4]
    assert point_id_array(pa.array(["03", "4"])).tolist() == ["03", "4"]


@pytest.mark.parametrize("rows, ids", [
    ("0,5,1,2\n1,5,3,4\n0,2,5,6\n", [5, 2]),                      # unsorted: first appearance
    ("0,2,1,2\n1,2,3,4\n0,5,5,6\n1,9,7,8\n", [2, 5, 9]),          # grouped by point, increasing
    ("0,7,1,2\n0,007,3,4\n1,7,5,6\n", ["7", "007"]),              # "007" is not "7": all text
    ("0,99999999999999999999,1,2\n0,3,3,4\n", ["99999999999999999999", "3"]),
    ("0, 4 ,1,2\n1,4,3,4\n", [4]),                                # spaces stripped, then an integer
])
def test_integer_and_text_point_ids_read(tmp_path, poses, rows, ids):
    uv, got = tio.tracks_to_uv(write(tmp_path / "t.csv", "view,point,u,v\n" + rows), tio.read_poses(poses))
    assert got.dtype.kind == ("i" if isinstance(ids[0], int) else "U") and got.tolist() == ids
    assert uv.shape == (4, len(ids), 2) and np.isfinite(uv[..., 0]).sum() == rows.count("\n")


def test_duplicate_integer_ids_named(tmp_path, poses):
    with pytest.raises(InputError, match=r"\('1', 5\)"):
        tio.tracks_to_uv(write(tmp_path / "t.csv", "view,point,u,v\n1,5,1,2\n1,5,3,4\n"), tio.read_poses(poses))


@pytest.mark.parametrize("ids", [[5, 3, 11, 0, 4, 8, 9], ["007", "a", "3", "b", "c", "d", "e"]])
def test_point_ids_round_trip_through_calibration_file(tmp_path, ids):
    from transcalib.io.calibration_file import load_saved, save_calibration

    cal = full_calibration(n_points=7)
    save_calibration(cal, tmp_path, point_ids=[str(p) for p in ids])
    saved = load_saved(tmp_path)
    assert saved.point_ids.tolist() == ids  # int64 for integers, text otherwise
    assert saved.point_ids.dtype.kind == ("i" if isinstance(ids[0], int) else "U")


def test_truth_index():
    from transcalib.io.ids import truth_index

    assert truth_index(["2", "0"], 3).tolist() == [2, 0]
    assert truth_index(np.array([2, 0]), 3).tolist() == [2, 0]
    for ids in (["3"], ["-1"], ["a"], ["01"], [], None):
        assert truth_index(ids, 3) is None, ids


def test_careful_reader_gives_the_same_id_types(tmp_path, poses):
    """A line of spaces sends the file to the line-by-line reader: same ids, same types."""
    from transcalib.io import tables

    for ids, kind in ((["7", "3"], "i"), (["007", "3"], "U")):
        text = f"view,point,u,v\n0,{ids[0]},1,2\n   \n1,{ids[0]},3,4\n0,{ids[1]},5,6\n"
        path = write(tmp_path / "t.csv", text)
        assert tables._tracks_fast(path, tables._header(path, ["view", "point", "u", "v"], "tracks")) is None
        got = tio.read_track_table(path).point_ids
        assert got.dtype.kind == kind and [str(p) for p in got.tolist()] == ids


# --------------------------------------------------------------------------------------
# text output: Arrow formatting, chunks on threads
# --------------------------------------------------------------------------------------


def test_decimal_text():
    from transcalib.io.text import decimal_text

    x = np.array([-0.4, 0.5, -1e-9, 123.4567894, 1e6, np.nan, -1234.5, 0.1, 1 / 3, 2.5e-300])
    assert decimal_text(x, 6).to_pylist() == ["-0.400000", "0.500000", "0.000000", "123.456789", "1000000.000000",
                                              None, "-1234.500000", "0.100000", "0.333333", "0.000000"]
    full = decimal_text(x).to_pylist()
    assert full[5] is None and [float(s) for s in full if s is not None] == x[np.isfinite(x)].tolist()  # exact
    assert decimal_text(np.array([1e300, 1.5]), 6).to_pylist() == ["1e+300", "1.5"]  # beyond int64: exact form


def test_write_in_order_keeps_the_order(tmp_path):
    """Pieces finish in any order on the threads; the file has them in the given order."""
    import time
    from functools import partial

    from transcalib.io.text import write_in_order

    def slow(k):
        time.sleep(0.002 * (10 - k))  # the first pieces finish last
        return f"{k}\n".encode()

    with open(tmp_path / "f.txt", "wb") as fh:
        write_in_order(fh, (partial(slow, k) if k % 3 else f"{k}\n".encode() for k in range(10)), threads=3)
    assert (tmp_path / "f.txt").read_text() == "".join(f"{k}\n" for k in range(10))


def test_points_csv_in_chunks_is_the_same(tmp_path, monkeypatch):
    from transcalib.io import text

    rng = np.random.default_rng(1)
    X = rng.normal(size=(50, 3)) * 1e3
    X[7] = np.nan
    tio.write_points_csv(tmp_path / "one.csv", np.arange(50) * 3, X, np.abs(X), np.arange(50) % 2 == 0)
    monkeypatch.setattr(text, "CHUNK", 7)
    tio.write_points_csv(tmp_path / "many.csv", np.arange(50) * 3, X, np.abs(X), np.arange(50) % 2 == 0)
    assert (tmp_path / "one.csv").read_text() == (tmp_path / "many.csv").read_text()
    lines = (tmp_path / "many.csv").read_text().splitlines()
    assert len(lines) == 51 and lines[8].startswith("21,,,,")
    back = np.genfromtxt(tmp_path / "many.csv", delimiter=",", skip_header=1)
    np.testing.assert_array_equal(back[:, 1:4], X)  # full precision
