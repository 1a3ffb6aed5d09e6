"""The report opens in a real (headless) browser: the page loads, every figure decodes,
no console error, no request leaves the page; the 3-D view draws the points and the
frusta (counted by three.js and read back from the page), orbits, pans, zooms and
answers a click; figures are also PNG files on disk."""

import json
import os
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

import browser
from test_io import full_calibration

needs_chromium = pytest.mark.skipif(
    browser.chromium() is None and not os.environ.get("CI"),
    reason="chromium not installed (make test installs it; CI requires it)")


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from transcalib.report import write_report

    cal = full_calibration(n_points=300)
    folder = tmp_path_factory.mktemp("report")
    truth = {"K": (cal.K * 1.0005).tolist(), "R": cal.R.tolist(), "dist": [0.0, 0.0], "points": cal.X.tolist()}
    written = write_report(cal, folder, truth=truth, point_ids=[str(k) for k in range(cal.n_points)])
    return folder, written, cal


class _References(HTMLParser):
    """Every resource a page names: ``src``/``href``/``data`` attributes, ``<link>``,
    scripts with a ``src``, CSS ``url(...)`` and ``@import``."""

    def __init__(self):
        super().__init__()
        self.refs, self.scripts = [], 0

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self.scripts += tag == "script"
        for key in ("src", "href", "data", "srcset", "poster", "action"):
            if a.get(key) and not a[key].startswith(("data:", "#")):
                self.refs.append(f"<{tag} {key}={a[key][:60]}>")
        if tag in ("link", "iframe", "embed", "object", "base"):
            self.refs.append(f"<{tag}>")

    def handle_data(self, data):
        if self.lasttag == "style":
            self.refs += re.findall(r"url\((?!\s*['\"]?data:)[^)]*\)|@import", data)


def external_references(page: str) -> list:
    parser = _References()
    parser.feed(page)
    return parser.refs


def test_report_files(report):
    import cv2

    folder, written, _ = report
    from transcalib.report import FIGURES

    assert [p.name for p in written] == ["report.html", *FIGURES]
    for p in written[1:]:
        img = cv2.imread(str(p))
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 100, p
    page = (folder / "report.html").read_text()
    assert external_references(page) == []  # self-contained: every script, style and image inline
    assert list(folder.rglob("*.js")) == []  # nothing beside the page that it could need
    for word in ("fx", "cy", "k2", "few_points", "only 40 points", "truth", "3-D view", "three.js 0.187.0"):
        assert word in page, word


def test_reference_check_can_fail():
    """The self-containment check sees each kind of outside resource."""
    for bad in ("<script src='three.js'></script>", "<link rel='stylesheet' href='a.css'>",
                "<img src='http://example.org/a.png'>", "<style>body{background:url(a.png)}</style>",
                "<style>@import 'a.css';</style>", "<iframe></iframe>"):
        assert external_references(f"<html><head></head><body>{bad}</body></html>"), bad
    assert external_references("<img src='data:image/png;base64,AAAA'><script>var a = 1;</script>") == []


@needs_chromium
def test_report_loads_in_browser(report):
    folder, written, _ = report
    shown = browser.inspect(folder / "report.html")
    assert shown["title"] == "transcalib report"
    assert len(shown["images"]) == len(written) - 1
    assert all(src.startswith("data:image/png") and complete and width > 0
               for src, complete, width in shown["images"]), shown["images"]
    assert shown["errors"] == []


def _outside(requests: list, page: Path) -> list:
    """The requests that are neither the page itself nor data inside it."""
    return [u for u in requests if u != page.resolve().as_uri() and not u.startswith("data:")]


@needs_chromium
def test_browser_check_can_fail(tmp_path):
    """The harness sees a broken image, a console error, an exception in a script and a
    request for a resource outside the page (so the tests of the report can fail)."""
    page = tmp_path / "bad.html"
    page.write_text("<html><body><img src='data:image/png;base64,AAAA'>"
                    "<script>console.error('boom')</script><script>null.x</script>"
                    "<script src='http://127.0.0.1:9/three.js'></script></body></html>")  # loopback: refused
    shown = browser.inspect(page)
    assert shown["images"][0][2] == 0 and "boom" in shown["errors"]
    assert any("TypeError" in e for e in shown["errors"]), shown["errors"]
    assert _outside(shown["requests"], page) == ["http://127.0.0.1:9/three.js"]


def test_uncertainty_grows_away_from_the_centre():
    """The projection-uncertainty map is smallest near the principal point when only the
    focal length is uncertain (std grows linearly with the distance to cx, cy)."""
    from dataclasses import replace

    from transcalib.report.figures import projection_std

    cal = full_calibration()
    cov = np.zeros((8, 8))
    cov[0, 0] = 4.0  # fx only: std 2 px of focal length
    cal = replace(cal, cov=cov)
    u, v, std = projection_std(cal)
    iu, iv = np.argmin(abs(u - cal.K[0, 2])), np.argmin(abs(v - cal.K[1, 2]))
    assert std[iv, iu] < 0.05 * std.max()
    x = (u[-1] - cal.K[0, 2]) / cal.K[0, 0]  # du = x dfx at the right edge (ignoring distortion)
    assert abs(std[iv, -1] - 2.0 * abs(x)) < 0.2 * 2.0 * abs(x)


def test_residual_arrows_point_along_the_residual():
    """An arrow starts at the observed point and points along its residual in image axes
    (y down): a residual straight down in the image is drawn downwards."""
    from transcalib.report.figures import draw_residuals

    view = {"xy": np.array([[400.0, 200.0]]), "d": np.array([[0.0, 2.0]]), "inlier": np.array([True]), "n": 1,
            "rms": 2.0}
    fig = draw_residuals({"size": (800.0, 600.0), "scale": 50.0, "views": [view]})
    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    rows, cols = np.nonzero(np.abs(rgb - [31, 119, 180]).sum(axis=-1) < 60)  # tab:blue pixels
    start, tip = fig.axes[0].transData.transform([(400, 200), (400, 300)])  # display: y up from the bottom
    assert rows.size and abs(cols.mean() - start[0]) < 3
    assert rgb.shape[0] - start[1] - 3 <= rows.min() and rows.max() <= rgb.shape[0] - tip[1] + 3


def test_reconstruction_draws_near_points_over_far_ones():
    """Where a near and a far point coincide in the front view, the near point's colour
    (dark: the nearest depth bin) shows, whatever their order in the data."""
    from matplotlib import colormaps

    from transcalib.report.figures import draw_reconstruction

    X = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 9.0], [4.0, 3.0, 5.0]])  # the first two coincide seen from the front
    fig = draw_reconstruction({"X": X, "T": np.array([[4.0, -3.0, 0.0]]), "axes": np.eye(3), "n": 3, "unit": "mm"})
    fig.canvas.draw()
    x, y = fig.axes[0].transData.transform((0.0, 0.0))  # display: y up from the bottom
    rgb = np.asarray(fig.canvas.buffer_rgba())[int(fig.canvas.get_width_height()[1] - y), int(x), :3]
    near = 255 * np.array(colormaps["viridis"](1 / 16)[:3])  # the middle of the nearest of 8 bins
    assert np.abs(rgb - near).max() < 30, rgb


def test_report_data_is_small_whatever_n():
    """The figures' data (what the worker receives) hold at most a few thousand marks,
    the 3-D view's at most ``viewer_points`` points."""
    import pickle

    from transcalib.report import report_data
    from transcalib.report.figures import MAX_ARROWS, MAX_POINTS

    cal = full_calibration(n_points=20_000)
    data = report_data(cal, viewer_points=5000)
    assert len(pickle.dumps(data)) < 2_000_000 and data.viewer.n_drawn == 5000 and data.viewer.n_points == 19_999
    views = data.figures["residuals.png"][1]["views"]
    assert all(len(v["xy"]) <= MAX_ARROWS + 50 for v in views)
    assert len(data.figures["reconstruction.png"][1]["X"]) == MAX_POINTS
    hist = data.figures["residual_histogram.png"][1]  # counted from every observation
    assert hist["n_in"] + hist["n_out"] == np.isfinite(cal.residuals_px[..., 0]).sum()
    assert hist["inliers"].sum() + hist["outliers"].sum() == hist["n_in"] + hist["n_out"]


def test_worker_writes_the_same_report(report, tmp_path):
    from transcalib.report import FIGURES, report_data
    from transcalib.report.worker import ReportWorker

    cal = full_calibration(n_points=300)
    with ReportWorker() as worker:
        written = worker.submit(report_data(cal), tmp_path).result()
    assert [p.name for p in written] == ["report.html", *FIGURES[:4]]
    assert all(p.stat().st_size > 1000 for p in written)
    assert not list(tmp_path.rglob("*.tmp"))


def test_worker_failure_is_a_clear_error(tmp_path):
    """A drawing that raises in the worker: ReportWorkerError naming the cause, no page."""
    from transcalib.report import ReportData
    from transcalib.report.worker import ReportWorker, ReportWorkerError

    bad = ReportData(title="t", sections=[], figures={"residuals.png": ("Residuals", {"size": None})})
    with ReportWorker() as worker:
        pending = worker.submit(bad, tmp_path)
        with pytest.raises(ReportWorkerError, match=r"report worker failed \(TypeError.*not written"):
            pending.result()
    assert not (tmp_path / "report.html").exists()


def test_worker_that_dies_or_hangs_is_an_error(tmp_path):
    """A killed worker and one past its timeout raise ReportWorkerError; nothing hangs."""
    import os
    import signal
    import time

    from transcalib.report import report_data
    from transcalib.report.worker import ReportWorker, ReportWorkerError

    data = report_data(full_calibration(n_points=300))
    with ReportWorker() as worker:
        os.kill(worker._process.pid, signal.SIGKILL)
        t0 = time.monotonic()
        with pytest.raises(ReportWorkerError, match="stopped unexpectedly"):
            worker.submit(data, tmp_path).result()
        assert time.monotonic() - t0 < 10
    with ReportWorker(timeout_s=0.01) as worker:
        with pytest.raises(ReportWorkerError, match="did not answer within 0.01 s"):
            worker.submit(data, tmp_path).result()
    assert not list(tmp_path.rglob("*.tmp"))


def test_ctrl_c_while_the_worker_starts_is_ignored_there():
    """Ctrl-C reaches the whole process group; one that lands while the worker's
    interpreter is still starting (before it can ignore it) is dropped there: no traceback
    on the command's stderr, and the worker still comes up."""
    import subprocess
    import sys

    script = ("import os, signal, sys\n"
              "from transcalib.report.worker import ReportWorker\n"
              "with ReportWorker() as w:\n"
              "    os.kill(w._process.pid, signal.SIGINT)\n"
              "    w.wait_ready()\n"
              "print('ready')\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.strip() == "ready", run.stderr
    assert "Traceback" not in run.stderr, run.stderr


# --------------------------------------------------------------------------------------
# the 3-D view
# --------------------------------------------------------------------------------------

_STATS = "JSON.stringify(transcalibViewer.stats())"


def _load(tab, page: Path) -> dict:
    """Load ``page``, scroll the 3-D view into sight; its stats."""
    tab.load(page)
    tab.evaluate("document.getElementById('tc-viewer').scrollIntoView()")
    return json.loads(tab.evaluate(_STATS))


def _legend(tab) -> str:
    return tab.evaluate("document.getElementById('tc-viewer-legend').textContent")


@needs_chromium
def test_3d_view_draws_every_point_and_frustum_and_loads_nothing(report):
    """The view loads without a console error; three.js drew every reconstructed point
    (299: one of 300 is NaN), 11 segments per view's frustum, the 3 world axes and 3 per
    view for the robot base of each view (the calibration is eye-to-hand); the page
    requested nothing but itself (and the data inside it)."""
    folder, _, cal = report
    page = folder / "report.html"
    with browser.Tab() as tab:
        stats = _load(tab, page)
        legend, revision = _legend(tab), tab.evaluate("transcalibViewer.revision")
        attrs = json.loads(tab.evaluate("JSON.stringify(Object.assign({}, document.getElementById('tc-viewer').dataset))"))
        errors, requests = tab.errors, tab.requests
    n = int(np.isfinite(cal.X).all(axis=1).sum())
    assert n == cal.n_points - 1
    assert errors == []
    assert stats["points"] == stats["cloud"] == n  # primitives of the last frame, counted by three.js
    assert stats["frusta"] == cal.n_views and stats["frustum_lines"] == 11 * cal.n_views
    assert stats["frames"] == cal.n_views and stats["extra"] == 0  # eye-to-hand: the robot base of each view
    assert stats["lines"] == 11 * cal.n_views + 3 + 3 * cal.n_views
    assert attrs == {"pointsDrawn": str(n), "pointsTotal": str(n), "frusta": str(cal.n_views), "extraDrawn": "0"}
    assert f"all {n} reconstructed points" in legend and f"each of the {cal.n_views} views" in legend
    assert revision == "187"
    assert requests[0] == page.resolve().as_uri() and _outside(requests, page) == []


def _isolated_point(tab, n: int) -> tuple[int, list]:
    """The drawn point farthest on screen from every other, inside the canvas: (index, xy)."""
    xy = json.loads(tab.evaluate(f"JSON.stringify(Array.from({{length: {n}}}, (_, i) => transcalibViewer.screenOf(i)))"))
    box = json.loads(tab.evaluate("JSON.stringify(document.querySelector('#tc-viewer canvas').getBoundingClientRect())"))
    xy = np.array([p if p is not None else (np.nan, np.nan) for p in xy], float)
    inside = (xy[:, 0] > box["left"] + 20) & (xy[:, 0] < box["right"] - 20) & \
             (xy[:, 1] > box["top"] + 40) & (xy[:, 1] < box["bottom"] - 20)
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    gap = np.where(inside, np.nan_to_num(d, nan=np.inf).min(axis=1), -1)
    i = int(np.argmax(gap))
    assert gap[i] > 10, "no point stands alone on screen"
    return i, xy[i].tolist()


@needs_chromium
def test_a_click_shows_id_position_std_and_views(tmp_path):
    """A real mouse click on a point: the panel shows its id, each coordinate with the
    std (to the precision the std warrants), the views that saw it and whether it is an
    inlier; a click on empty space says so."""
    from transcalib.report import viewer_data, write_report
    from transcalib.report.figures import observed_pixels

    cal = full_calibration(n_points=200)
    uv = observed_pixels(cal).copy()
    uv[2, ::3] = np.nan  # view 2 misses every third point
    ids, names = [f"p{k}" for k in range(cal.n_points)], [f"img{v}.png" for v in range(cal.n_views)]
    write_report(cal, tmp_path, uv=uv, point_ids=ids, view_names=names)
    index = viewer_data(cal, uv=uv).index  # drawn point -> calibration point
    with browser.Tab() as tab:
        _load(tab, tmp_path / "report.html")
        i, (x, y) = _isolated_point(tab, len(index))
        tab.click(x, y)
        text = tab.evaluate("document.getElementById('tc-viewer-info').textContent")
        tab.evaluate("transcalibViewer.pickAt(-50, -50)")  # far outside: nothing
        nothing = tab.evaluate("document.getElementById('tc-viewer-info').textContent")
        errors = tab.errors
    j = int(index[i])
    assert text.startswith(f"point p{j}: "), text
    values = re.findall(r"([xyz]) (-?[\d.]+) ± ([\d.]+)", text)
    assert [v[0] for v in values] == ["x", "y", "z"], text
    for k, (_, value, std) in enumerate(values):
        s = cal.X_std[j, k]
        assert abs(float(value) - cal.X[j, k]) <= 0.06 * s + 1e-6 * abs(cal.X[j, k]), (text, cal.X[j], s)
        assert abs(float(std) - s) <= 0.06 * s, (text, s)  # float16 and 2 significant digits
    seen = [v for v in range(cal.n_views) if np.isfinite(uv[v, j, 0])]
    assert f"seen in {len(seen)} of {cal.n_views} views: " + ", ".join(f"{v} (img{v}.png)" for v in seen) in text
    assert text.endswith("inlier" if cal.inliers[j] else "outlier")
    assert nothing == "no point within 8 px of the click" and errors == []


@needs_chromium
def test_orbit_pan_and_zoom(report):
    """A left drag orbits (the eye turns about the target at the same distance), a right
    drag pans (the target moves), the wheel zooms (the eye comes closer); the buttons
    bring back the first view."""
    folder, _, _ = report
    with browser.Tab() as tab:
        _load(tab, folder / "report.html")
        box = json.loads(tab.evaluate("JSON.stringify(document.querySelector('#tc-viewer canvas').getBoundingClientRect())"))
        c = (box["left"] + box["width"] / 2, box["top"] + box["height"] / 2)

        def state():
            s = json.loads(tab.evaluate("JSON.stringify(transcalibViewer.camera())"))
            return np.array(s["eye"]), np.array(s["target"])

        eye0, target0 = state()
        tab.drag(c, (c[0] + 150, c[1] + 60))
        eye1, target1 = state()
        tab.send("Input.dispatchMouseEvent", type="mousePressed", x=c[0], y=c[1], button="right", clickCount=1)
        tab.send("Input.dispatchMouseEvent", type="mouseMoved", x=c[0] + 80, y=c[1], button="right", buttons=2)
        tab.send("Input.dispatchMouseEvent", type="mouseReleased", x=c[0] + 80, y=c[1], button="right", clickCount=1)
        eye2, target2 = state()
        tab.send("Input.dispatchMouseEvent", type="mouseWheel", x=c[0], y=c[1], deltaX=0, deltaY=-400)
        eye3, target3 = state()
        tab.evaluate("document.querySelector(\"button[data-view='oblique']\").click()")
        eye4, target4 = state()
        errors = tab.errors
    r0 = np.linalg.norm(eye0 - target0)
    assert np.allclose(target1, target0) and abs(np.linalg.norm(eye1 - target1) - r0) < 1e-6 * r0
    assert np.linalg.norm(eye1 - eye0) > 0.1 * r0  # turned
    assert np.linalg.norm(target2 - target1) > 1e-3 * r0 and np.allclose(eye2 - target2, eye1 - target1)  # panned
    assert np.linalg.norm(eye3 - target3) < 0.95 * np.linalg.norm(eye2 - target2)  # zoomed in
    assert np.allclose(eye4, eye0) and np.allclose(target4, target0) and errors == []


@needs_chromium
def test_large_clouds_are_subsampled_and_the_page_says_how_many(tmp_path):
    """60 000 points and an extra coloured cloud of 70 000 (1 000 of them NaN): 50 000 of
    each drawn, and the page says so; the extra cloud keeps its colours."""
    from transcalib.report import PointCloud, write_report
    from transcalib.report.viewer import MAX_POINTS

    cal = full_calibration(n_points=60_000)
    rng = np.random.default_rng(3)
    X = rng.normal(size=(70_000, 3)) + [0, 0, 12]
    X[:1000] = np.nan
    colors = rng.integers(0, 256, (70_000, 3), dtype=np.uint8)
    write_report(cal, tmp_path, extra=PointCloud(X, colors, name="dense cloud"))
    with browser.Tab() as tab:
        stats = _load(tab, tmp_path / "report.html")
        legend, errors = _legend(tab), tab.errors
    assert MAX_POINTS == 50_000 and errors == []
    assert stats["cloud"] == stats["extra"] == MAX_POINTS and stats["points"] == 2 * MAX_POINTS
    assert "50,000 of 59,999 reconstructed points (a random subsample)" in legend, legend
    assert "dense cloud: 50,000 of 69,000 points" in legend, legend


def test_extra_cloud_colours_and_subsample():
    """The extra cloud: its own colours, else depth colours; NaN rows left out; at most
    ``viewer_points`` drawn, the same ones for the same seed."""
    from transcalib.report import PointCloud, viewer_data

    cal = full_calibration(n_points=100)
    X = np.random.default_rng(1).normal(size=(500, 3)) @ cal.R + [0, 0, 10] @ cal.R
    X[7] = np.nan
    rgb = np.arange(1500).reshape(500, 3) % 256
    d = viewer_data(cal, extra=PointCloud(X, rgb.astype(np.uint8), "dense"), max_points=200)
    e = d.extra
    assert e["n_points"] == 499 and len(e["X"]) == 200 and e["name"] == "dense"
    keep = [int(np.flatnonzero((np.abs(X - d.origin - x) < 1e-4).all(axis=1))[0]) for x in e["X"]]
    assert np.array_equal(e["colors"], rgb[keep]) and 7 not in keep
    again = viewer_data(cal, extra=PointCloud(X, None), max_points=200).extra
    assert np.array_equal(again["X"], e["X"]) and not np.array_equal(again["colors"], e["colors"])
    from transcalib import InputError

    with pytest.raises(InputError, match=r"the extra cloud's colors must be an array of shape \(500, 3\)"):
        viewer_data(cal, extra=PointCloud(X, rgb[:10]))
    with pytest.raises(InputError, match=r"the extra cloud's X must have shape \(m, 3\), got \(500,\)"):
        viewer_data(cal, extra=PointCloud(X[:, 0]))


def test_points_coloured_by_image_colour_else_depth():
    """Image colours when given (the drawn points' own); else viridis by depth along view
    0's optical axis: the nearest point dark purple, the farthest yellow."""
    from transcalib.report import viewer_data

    cal = full_calibration(n_points=300)
    rgb = np.random.default_rng(0).integers(0, 256, (300, 3), dtype=np.uint8)
    d = viewer_data(cal, colors=rgb)
    assert d.colour_by == "image" and np.array_equal(d.colors, rgb[d.index])
    d = viewer_data(cal)
    R_cam, C = cal.camera_poses()
    z = (cal.X[d.index] - C[0]) @ R_cam[0, 2]
    assert d.colour_by == "depth" and np.allclose(d.depth_range, np.percentile(z, [2, 98]))
    assert np.array_equal(d.colors[np.argmin(z)], [68, 1, 84]) and np.array_equal(d.colors[np.argmax(z)], [253, 231, 37])


def _reprojection_px(poses, K, X, uv) -> float:
    """Largest distance between ``uv`` and the projection of ``X`` by each view's pose."""
    x = np.einsum("vij,vnj->vni", poses.R_cam_world, X[None] - poses.centres[:, None]) @ K.T
    return float(np.nanmax(np.linalg.norm(x[..., :2] / x[..., 2:] - uv, axis=-1)))


def _calibration(motion: str):
    """A noise-free calibration of each kind of motion, and its scene."""
    from transcalib import Poses, calibrate
    from transcalib.handeye.simulate import session_scene
    from transcalib.synth import simulate

    if motion == "translations":
        s = simulate.random_scene(60, 5, noise_px=0.0, rng=4)
        return calibrate(s.uv, s.T, robust=False), s
    sc = session_scene(2, n_sessions=3, moves="3d")
    if motion == "eye-to-hand":
        sc = sc.eye_to_hand()
    return calibrate(sc.uv, Poses.of(sc.T, sc.R), setup=motion, robust=False), sc


@pytest.mark.parametrize("motion", ["translations", "eye-in-hand", "eye-to-hand"])
def test_view_poses_reproject_the_points(motion):
    """The poses the view draws are the model's: they project the points onto the
    noise-free observations. One orientation: every view ``cal.R`` at ``cal.T[i]``, no
    robot frame. Eye-in-hand (three sessions): camera ``R_X^T R_i^T`` at the true centre
    ``T_i + R_i t_X``, the flange at ``(R_i, T_i)``. Eye-to-hand (the same images, the
    flange carrying the scene): the same cameras in the flange frame, and the robot base
    of each view where the eye-in-hand flange was."""
    from transcalib.report import view_poses

    cal, sc = _calibration(motion)
    poses = view_poses(cal)
    assert _reprojection_px(poses, cal.K, cal.X, sc.uv) < 1e-6
    if motion == "translations":
        assert poses.frame_T is None and "T = 0" in poses.origin
        return
    ein = sc if motion == "eye-in-hand" else sc.as_eye_in_hand()
    assert np.abs(poses.centres - ein.camera_centres()).max() < 1e-8
    assert np.abs(poses.frame_R - ein.R).max() < 1e-12 and np.abs(poses.frame_T - ein.T).max() < 1e-9
    assert ("flange of every view" in poses.frames) == (motion == "eye-in-hand")
    assert ("robot base of every view" in poses.frames) == (motion == "eye-to-hand")


@needs_chromium
@pytest.mark.parametrize("motion", ["translations", "eye-in-hand"])
def test_robot_frames_drawn_where_known(tmp_path, motion):
    """The flange of every view is drawn (3 segments each) with a hand-eye pose, nothing
    of the kind with translations alone; the page says which."""
    from transcalib.report import write_report

    cal, _ = _calibration(motion)
    write_report(cal, tmp_path)
    with browser.Tab() as tab:
        stats = _load(tab, tmp_path / "report.html")
        legend, errors = _legend(tab), tab.errors
    V, frames = cal.n_views, motion != "translations"
    assert errors == [] and stats["frusta"] == V and stats["frames"] == V * frames
    assert stats["lines"] == 11 * V + 3 + 3 * V * frames
    assert ("the axes of the flange of every view" in legend) == frames
    assert ("the robot axes at the camera centre of robot position T = 0" in legend) == (not frames)


@needs_chromium
def test_without_webgl_the_page_says_so_without_an_error(report):
    folder, _, _ = report
    with browser.Tab(flags=["--disable-webgl", "--disable-webgl2"]) as tab:
        tab.load(folder / "report.html")
        ready = json.loads(tab.evaluate("JSON.stringify(transcalibViewer)"))
        text = tab.evaluate("document.getElementById('tc-viewer-info').textContent")
        errors = tab.errors
    assert ready == {"ready": False, "webgl": False} and "no WebGL 2" in text and errors == []


@pytest.mark.parametrize("kwargs, message", [
    ({"colors": np.zeros((3, 3))}, r"colors must be an array of shape \(40, 3\)"),
    ({"colors": np.full((40, 3), 0.5)}, "colors must be RGB values, integers 0-255"),
    ({"extra": None, "colors": np.full((40, 3), 256)}, "colors must be RGB values"),
    ({"extra": np.zeros((10, 3))}, "extra must be a transcalib.report.PointCloud"),
    ({"viewer_points": 0}, "viewer_points must be a positive integer"),
    ({"point_ids": ["a", "b"]}, r"point_ids must hold one id per point \(40\), got 2"),
    ({"view_names": ["a.png"]}, r"view_names must hold one name per view \(5\), got 1"),
    ({"uv": np.zeros((5, 39, 2))}, r"uv must have shape \(n_views, n_points, 2\) = \(5, 40, 2\)"),
])
def test_bad_viewer_input_is_named(kwargs, message):
    from transcalib import InputError
    from transcalib.report import report_data

    with pytest.raises(InputError, match=message):
        report_data(full_calibration(), **kwargs)


def test_vendored_library_ships_with_its_licence():
    """three.js and our script are package data (a wheel carries them), next to three's
    licence; the bundle names its version and licence."""
    import tomllib

    import transcalib.report as report

    here = Path(report.__file__).parent
    data = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())
    shipped = data["tool"]["setuptools"]["package-data"]["transcalib.report"]
    assert sorted(shipped) == ["vendor/LICENSE.three.txt", "vendor/three.min.js", "viewer.js"]
    assert all((here / f).is_file() for f in shipped)
    head = (here / "vendor" / "three.min.js").read_text()[:300]
    assert "three.js 0.187.0" in head and "MIT" in head and "LICENSE.three.txt" in head
    assert (here / "vendor" / "LICENSE.three.txt").read_text().startswith("The MIT License")
