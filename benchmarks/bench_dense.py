"""Dense reconstruction on renders with exact depth, against two-view methods.

    python benchmarks/bench_dense.py [--quick | --timing-only]

(``--quick``: one scene of 512 x 384; ``--timing-only``: scene A, the command timed
``TIMING_RUNS`` times with the load average, printed and not written - to time it again
when the machine is quiet.)

Scenes (``transcalib.synth.render``, the realistic degradations ``degrade.REALISTIC`` on:
vignetting, exposure changes, shot and read noise, JPEG 85, a specular highlight, a
burnt-in timestamp): 6 views of 1024 x 768 on a ring of radius 60 mm (90 mm for C)
around the reference view 0, the robot frame turned at random against the camera:

- A: the ``workspace`` scene (textured wall, slanted textured table, three textured
  boxes, an untextured panel; depths 0.43-1.19 m), no lens distortion;
- B: the same kind of scene (another draw), a lens with barrel distortion
  (k1 = -0.12, k2 = 0.03) given to ``dense`` through the calibration;
- C: the ``natural`` scene (a textured wall and two textured boxes, 0.56-1.1 m), a scene
  kind the defaults were not tuned on;
- D: the ``workspace`` scene seen from two flange orientations 15 deg apart, the camera
  at ``(R_X, t_X)`` in the flange (a hand-eye calibration, true values, saved with the
  orientations): two views at the first orientation, six at the second (the reference,
  view 2, and five sources), each source turned by a random rotation of 0.2 deg standard
  deviation per axis, within ``calibrate``'s session tolerance: each view's camera comes
  from the calibration and the flange poses (quaternions in ``poses.csv``), the turns
  enter the sweep as homographies. Its two-view and SGBM rows use the reference and
  its best horizontal source, their true relative pose.

Methods, each on reference view 0 with the true calibration and depth limits
0.38-1.3 m (SGBM: the same limits as disparities): ``transcalib dense`` end to end as a
user runs it (``transcalib dense --calibration --images --poses --out``, default
options: 256 hypotheses, 7 x 7 windows, best 2 of 5 views); the same sweep with one
source view (a two-view plane sweep); OpenCV's ``StereoSGBM`` on the rectified pair of
the reference and that source (the one whose baseline is most nearly horizontal),
its disparities carried back to the reference's original pixels (5 x 5 blocks, the
usual penalties ``P1 = 8 B^2``, ``P2 = 32 B^2``, ``preFilterCap = 63``, uniqueness 10,
speckle filter, full 8-path mode; rectified with ``alpha = 1`` on a canvas 1.4 times
the image so that every reference pixel keeps its resolution). For scene A also
``transcalib dense`` with the calibration ``transcalib calibrate --images`` finds from the
scene's view 0 and four views moved 120 mm along three robot axes and a diagonal (a 3-D
motion; the ring alone is nearly planar), its covariance entering ``depth_std``.

Columns, on the textured surfaces (pixels whose true surface has a texture, outside the
timestamp's box): median of ``|z - z_true| / z_true`` (%), completeness (% of them with a
depth), errors over 1 % of depth (% of those with a depth); on every pixel with a depth:
the share of the large errors (> 1 %) held by the 10 % least confident pixels, and the
median of ``|z - z_true| / depth_std`` (0.67 for a calibrated Gaussian); time of the
method (wall; CPU of the process in brackets). The timing of scene A is repeated
(``TIMING_RUNS``) and the machine's load average is printed with it. Writes
``benchmarks/results/dense.md``.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import md_table, results_dir  # noqa: E402

import transcalib  # noqa: E402
from transcalib.dense import dense  # noqa: E402
from transcalib.geometry.camera import Camera  # noqa: E402
from transcalib.io import write_poses_csv  # noqa: E402
from transcalib.synth import render  # noqa: E402
from transcalib.synth.degrade import REALISTIC, overlay_box  # noqa: E402
from transcalib.synth.presets import default_camera, preset_scene  # noqa: E402
from transcalib.types import Calibration, HandEye, Poses  # noqa: E402

LIMITS = (380.0, 1300.0)
TIMING_RUNS = 3
#: Length of the calibration moves of scene A (robot axes and a diagonal).
CALIB_MOVE_MM = 80.0
DIST = np.array([-0.12, 0.03])
#: name -> (scene kind, ring radius mm, lens distortion, seed)
SCENES = {"A": ("workspace", 60.0, (), 101), "B": ("workspace", 60.0, DIST, 202), "C": ("natural", 90.0, (), 303),
          "D": ("workspace", 60.0, (), 404)}
#: Scene D: camera in the flange, the second orientation, the turns within the session.
R_X = Rotation.from_euler("xyz", [180, 10, -20], degrees=True).as_matrix()
T_X = np.array([10.0, -25.0, 120.0])
TILT_DEG, TURN_STD_DEG = 15.0, 0.2


@dataclass(frozen=True)
class Setup:
    """A scene as the methods see it: ``truth`` (a Rendered whose view 0 is the
    reference), ``cal`` (what ``dense`` gets), ``poses``, ``images`` and the true
    cameras of every view (``R_cam``, ``C``), ``ref`` (the reference's index) and the
    reference's ``camera`` (K, lens) for SGBM."""

    truth: object
    cal: object
    poses: Poses
    images: list
    R_cam: np.ndarray
    C: np.ndarray
    ref: int
    camera: Camera


def make_session_scene(size, folder: Path) -> Setup:
    """Scene D (module docstring): write ``cal/`` (the true hand-eye calibration),
    ``view<i>.png`` and ``poses.csv`` with orientations."""
    kind, radius, _, seed = SCENES["D"]
    rng = np.random.default_rng(seed)
    K = default_camera(None, np.eye(3), np.zeros((1, 3)), size, 1, 1.0, rng)[0]
    axis = np.array([0.0, 1.0, 0.3]) / np.hypot(1.0, 0.3)
    R_tilt = Rotation.from_rotvec(np.radians(TILT_DEG) * axis).as_matrix()
    ahead = 800.0 * R_X.T[2]  # the scene's middle, 800 mm ahead of the first camera (at the origin)
    surfaces = preset_scene(kind, 800.0, K, R_X.T, np.zeros(3), size, seed)[0]
    C = np.vstack([np.zeros(3), radius * R_X.T[0],
                   ahead - R_tilt @ ahead + render.ring_translations(6, radius, R_X.T @ R_tilt.T, rng)])
    turns = Rotation.from_rotvec(rng.normal(0, np.radians(TURN_STD_DEG), (6, 3))).as_matrix()
    turns[0] = np.eye(3)
    Rf = np.concatenate([np.repeat(np.eye(3)[None], 2, 0), R_tilt @ turns])
    R_cam = R_X.T @ np.transpose(Rf, (0, 2, 1))
    images = [render.render(surfaces, K, R_cam[i], C[i:i + 1], size, degrade=REALISTIC, rng=rng, noise_std=0.0)[0]
              for i in range(len(C))]
    T = C - Rf @ T_X
    he = HandEye(setup="eye-in-hand", R=R_X, t=T_X, R_std_deg=np.zeros(3), t_cov=np.zeros((3, 3)),
                 undetermined=np.zeros((3, 0)), session_of_view=np.repeat([0, 1], [2, 6]), session_labels=("0", "1"))
    cal = Calibration(camera=Camera(K, R_X.T, image_size=size), X=np.zeros((0, 3)), residuals_px=np.zeros((8, 0, 2)),
                      rms_px=0.0, T=T, flange_rotations=Rf, hand_eye=he)
    _write(folder, cal, images, T, Rf)
    truth = render.Rendered(images=np.stack(images[2:]), K=K, R=R_cam[2], dist=np.zeros(0), T=C[2:],
                            surfaces=surfaces, corners=np.zeros((0, 3)), corner_kind=np.zeros(0), image_size=size,
                            meta={"overlay_box": overlay_box(REALISTIC, size)})
    return Setup(truth, cal, Poses.of(T, Rf), images, R_cam, C, 2, Camera(K, R_cam[2], image_size=size))


def _write(folder: Path, cal, images, T, R=None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    transcalib.save(cal, folder / "cal")
    for i, img in enumerate(images):
        cv2.imwrite(str(folder / f"view{i}.png"), img)
    write_poses_csv(folder / "poses.csv", T, R=R)


def make_scene(name, size, folder: Path, calibration_views: bool = False) -> Setup:
    """Render scene ``name`` (A-C), write ``cal/``, ``view<i>.png``, ``poses.csv``. With
    ``calibration_views``, also four views moved 120 mm from view 0 along three
    orthogonal robot axes and one diagonal (``calib<i>.png`` and ``calib_poses.csv``,
    view 0 among them): the 3-D motion a calibration needs."""
    if name == "D":
        return make_session_scene(size, folder)
    kind, radius, dist, seed = SCENES[name]
    rng = np.random.default_rng(seed)
    R = Rotation.from_euler("xyz", rng.uniform(-180, 180, 3), degrees=True).as_matrix()
    T = render.ring_translations(6, radius, R, rng)
    if calibration_views:
        T = np.vstack([T, CALIB_MOVE_MM * np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.6, -0.6, 0.5]])])
    r = render.render_scene(kind, n_views=len(T), image_size=size, R=R, T=T, distance=800.0, dist=dist,
                            degrade=REALISTIC, rng=rng, noise_std=0.0)
    folder.mkdir(parents=True, exist_ok=True)
    if calibration_views:
        for k, i in enumerate([0, 6, 7, 8, 9]):
            cv2.imwrite(str(folder / f"calib{k}.png"), r.images[i])
        write_poses_csv(folder / "calib_poses.csv", T[[0, 6, 7, 8, 9]])
        T = T[:6]
    model = {0: "none", 2: "radial2"}[len(dist)]
    cam = Camera(r.K, r.R, np.asarray(dist, float), model, r.image_size)
    cal = Calibration(camera=cam, X=np.zeros((0, 3)), residuals_px=np.zeros((6, 0, 2)), rms_px=0.0, T=T)
    _write(folder, cal, r.images[:6], T)
    return Setup(r, cam, Poses.of(T), list(r.images[:6]), np.repeat(r.R[None], 6, 0), T, 0, cam)


def _children_cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def run_cli(folder: Path, setup: Setup, cal: str = "cal"):
    """``transcalib dense`` as a user runs it: depth, confidence, std, wall and CPU time."""
    out = folder / f"out-{cal}"
    cmd = [sys.executable, "-m", "transcalib.cli", "dense", "--calibration", str(folder / cal), "--images",
           *[str(folder / f"view{i}.png") for i in range(len(setup.images))], "--poses", str(folder / "poses.csv"),
           "--out", str(out), "--depth-limits", f"{LIMITS[0]},{LIMITS[1]}", "--reference-view", str(setup.ref),
           "--quiet"]
    c0, t0 = _children_cpu(), time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    if r.returncode != 0:
        raise RuntimeError(r.stderr)
    v = setup.ref
    return (np.load(out / f"depth_{v}.npy"), np.load(out / f"confidence_{v}.npy"), np.load(out / f"depth_std_{v}.npy"),
            wall, cpu)


def _relative(setup: Setup, j: int):
    """``(R, t)`` of view ``j`` relative to the reference: ``x_j = R x_ref + t``."""
    R = setup.R_cam[j] @ setup.R_cam[setup.ref].T
    return R, setup.R_cam[j] @ (setup.C[setup.ref] - setup.C[j])


def pair_source(setup: Setup) -> int:
    """The source of the reference's session whose baseline is most nearly horizontal in
    the reference camera."""
    ref = setup.ref
    views = [j for j in range(ref + 1, len(setup.C))]
    t = (setup.C[views] - setup.C[ref]) @ setup.R_cam[ref].T
    return views[int(np.argmax(np.abs(t[:, 0]) / np.linalg.norm(t, axis=1)))]


def two_view_sweep(setup: Setup, j: int):
    c0, t0 = time.process_time(), time.perf_counter()
    pair = [setup.ref, j]
    poses = Poses.of(setup.poses.T[pair], None if setup.poses.R is None else setup.poses.R[pair],
                     views=[str(v) for v in pair])
    m = dense(setup.cal, [setup.images[v] for v in pair], poses, reference_views=[str(setup.ref)],
              depth_limits=LIMITS).maps[0]
    return m.depth, m.confidence, m.depth_std, time.perf_counter() - t0, time.process_time() - c0


def sgbm(setup: Setup, j: int):
    """OpenCV StereoSGBM on the rectified pair (reference, source ``j``), depths on the
    reference's original pixels (nearest rectified pixel)."""
    c0, t0 = time.process_time(), time.perf_counter()
    w, h = setup.camera.image_size
    K, d5 = setup.camera.K, setup.camera.dist5
    R_rel, t_rel = _relative(setup, j)
    big = (int(1.4 * w), int(1.4 * h))  # every reference pixel in the rectified image, at its resolution
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(K, d5, K, d5, (w, h), R_rel, t_rel.reshape(3, 1), alpha=1,
                                                newImageSize=big)
    maps = [cv2.initUndistortRectifyMap(K, d5, Ri, Pi, big, cv2.CV_32FC1) for Ri, Pi in ((R1, P1), (R2, P2))]
    left, right = (cv2.remap(setup.images[k], *maps[i], cv2.INTER_LINEAR) for i, k in ((0, setup.ref), (1, j)))
    flip = P2[0, 3] > 0  # the source is on the left: mirror both so that the reference is the left image
    if flip:
        left, right = left[:, ::-1].copy(), right[:, ::-1].copy()
    f, base = P1[0, 0], abs(P2[0, 3] / P2[0, 0])
    dmin, dmax = int(np.floor(f * base / LIMITS[1])), int(np.ceil(f * base / LIMITS[0]))
    n = 16 * int(np.ceil((dmax - dmin + 1) / 16))
    block = 5
    matcher = cv2.StereoSGBM_create(minDisparity=dmin, numDisparities=n, blockSize=block, P1=8 * block**2,
                                    P2=32 * block**2, disp12MaxDiff=1, preFilterCap=63, uniquenessRatio=10,
                                    speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_HH)
    disp = matcher.compute(left, right).astype(np.float32) / 16.0
    if flip:
        disp = disp[:, ::-1]
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    q = cv2.undistortPoints(np.stack([uu, vv], -1).reshape(-1, 1, 2), K, d5, R=R1, P=P1).reshape(h, w, 2)
    qi = np.rint(q).astype(int)
    inside = (qi[..., 0] >= 0) & (qi[..., 0] < big[0]) & (qi[..., 1] >= 0) & (qi[..., 1] < big[1])
    dq = np.full((h, w), np.nan, np.float32)
    dq[inside] = disp[qi[..., 1][inside], qi[..., 0][inside]]
    dq[dq < max(dmin, 0.5)] = np.nan
    Z = f * base / dq  # depth in the rectified reference camera
    Xr = np.stack([(q[..., 0] - P1[0, 2]) / f * Z, (q[..., 1] - P1[1, 2]) / P1[1, 1] * Z, Z], -1)
    X = Xr @ R1  # back to the reference camera: R1^T X_rect
    return X[..., 2].astype(np.float32), None, None, time.perf_counter() - t0, time.process_time() - c0


def score(r, depth, conf, std):
    truth, surface = r.depth_map(0, return_surface=True)
    mask = r.textured()[surface] & (surface >= 0)
    box = r.meta["overlay_box"]
    if box is not None:
        u0, v0, u1, v1 = box
        mask[max(v0, 0):v1, max(u0, 0):u1] = False
    rel = np.abs(depth - truth) / truth
    known = np.isfinite(depth) & np.isfinite(truth)
    q = mask & known
    row = {"median_pct": 100 * float(np.median(rel[q])), "complete_pct": 100 * q.sum() / mask.sum(),
           "over1_pct": 100 * float(np.mean(rel[q] > 0.01)), "share10": None, "err_over_std": None}
    if conf is not None:
        big = rel[known] > 0.01
        low = conf[known] <= np.quantile(conf[known], 0.1)
        row["share10"] = 100 * (big & low).sum() / max(big.sum(), 1)
    if std is not None:
        row["err_over_std"] = float(np.median(np.abs(depth - truth)[known] / std[known]))
    return row


def scene_rows(name, size, tmp: Path, timing: bool):
    folder = tmp / name
    t0 = time.perf_counter()
    setup = make_scene(name, size, folder, calibration_views=timing)
    r = setup.truth
    print(f"  scene {name}: rendered in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    rows, times = [], []
    load = [os.getloadavg()[0]]
    for _ in range(TIMING_RUNS if timing else 1):
        depth, conf, std, wall, cpu = run_cli(folder, setup)
        times.append((wall, cpu))
    load.append(os.getloadavg()[0])
    j = pair_source(setup)
    wall, cpu = min(times)
    label = "transcalib dense, 6 views" + (" (5 sources turned)" if name == "D" else "")
    rows.append((name, label, score(r, depth, conf, std), wall, cpu))
    if timing and name == "A":
        estimated = calibrate_from_images(folder)
        if estimated is not None:
            d2, c2, s2, w2, p2 = run_cli(folder, setup, "cal-est")
            rows.append((name, "  same, calibration from the images", score(r, d2, c2, s2), w2, p2))
    pair = f"({setup.ref}, {j})"
    for label, method in ((f"plane sweep, 2 views {pair}", two_view_sweep), (f"OpenCV SGBM, pair {pair}", sgbm)):
        d, c, s, w, p = method(setup, j)
        rows.append((name, label, score(r, d, c, s), w, p))
    return rows, times, load


def calibrate_from_images(folder: Path):
    cmd = [sys.executable, "-m", "transcalib.cli", "calibrate", "--images",
           *[str(folder / f"calib{i}.png") for i in range(5)], "--poses", str(folder / "calib_poses.csv"),
           "--out", str(folder / "cal-est"), "--formats", "json", "--quiet"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode not in (0, 4):
        print(f"  calibrate from images failed: {r.stderr.strip()[-300:]}", file=sys.stderr)
        return None
    return folder / "cal-est"


def table(rows) -> str:
    header = ["scene", "method", "median err %", "complete %", "> 1 % err %",
              "large errors in least confident 10 % (%)", "median err/std", "time s (CPU s)"]
    body = [[s, m, x["median_pct"], x["complete_pct"], x["over1_pct"], x["share10"], x["err_over_std"],
             f"{w:.2f} ({c:.2f})"] for s, m, x, w, c in rows]
    return md_table(header, body)


def timing_only(size=(1024, 768)) -> str:
    """Scene A's command timed alone (module docstring)."""
    with tempfile.TemporaryDirectory(prefix="bench-dense-") as tmp:
        setup = make_scene("A", size, Path(tmp) / "A")
        load = [os.getloadavg()[0]]
        times = [run_cli(Path(tmp) / "A", setup)[3:] for _ in range(TIMING_RUNS)]
        load.append(os.getloadavg()[0])
    return _timing_line(size, times, load)


def _timing_line(size, times, load) -> str:
    walls, cpus = sorted(w for w, _ in times), sorted(c for _, c in times)
    return (f"`transcalib dense` end to end on scene A (6 x {size[0]}x{size[1]}, one reference view, 256 hypotheses), "
            f"{len(walls)} runs: wall {', '.join(f'{w:.2f}' for w in walls)} s; CPU "
            f"{', '.join(f'{c:.2f}' for c in cpus)} s; load average {load[0]:.2f} before, {load[1]:.2f} "
            f"after, on {os.cpu_count()} cores.")


def main(argv: list[str] = ()) -> list:
    if "--timing-only" in argv:
        print(timing_only())
        return []
    quick = "--quick" in argv
    size = (512, 384) if quick else (1024, 768)
    names = ["A"] if quick else list(SCENES)
    rows, timing = [], None
    with tempfile.TemporaryDirectory(prefix="bench-dense-") as tmp:
        for name in names:
            r, times, load = scene_rows(name, size, Path(tmp), timing=name == "A")
            rows += r
            if name == "A":
                timing = (times, load)
    lines = [f"Dense reconstruction, renders with exact depth, 6 views of {size[0]}x{size[1]}, realistic degradations; "
             "`python benchmarks/bench_dense.py`", "", table(rows), "", _timing_line(size, *timing)]
    text = "\n".join(lines)
    print(text)
    out = results_dir(quick) / "dense.md"
    out.write_text(text + "\n")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
