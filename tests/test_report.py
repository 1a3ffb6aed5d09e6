"""The report opens in a real (headless) browser: the page loads, every figure decodes,
no console error; figures are also PNG files on disk."""

import os

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
    return folder, written


def test_report_files(report):
    import cv2

    folder, written = report
    from transcalib.report import FIGURES

    assert [p.name for p in written] == ["report.html", *FIGURES]
    for p in written[1:]:
        img = cv2.imread(str(p))
        assert img is not None and img.shape[0] > 100 and img.shape[1] > 100, p
    page = (folder / "report.html").read_text()
    assert "<script" not in page and "http" not in page.split("</style>")[0]  # self-contained
    for word in ("fx", "cy", "k2", "few_points", "only 40 points", "truth"):
        assert word in page, word


@needs_chromium
def test_report_loads_in_browser(report):
    folder, written = report
    shown = browser.inspect(folder / "report.html")
    assert shown["title"] == "transcalib report"
    assert len(shown["images"]) == len(written) - 1
    assert all(src.startswith("data:image/png") and complete and width > 0
               for src, complete, width in shown["images"]), shown["images"]
    assert shown["errors"] == []


@needs_chromium
def test_browser_check_can_fail(tmp_path):
    """The harness sees a broken image and a console error (so the test above can fail)."""
    page = tmp_path / "bad.html"
    page.write_text("<html><body><img src='data:image/png;base64,AAAA'>"
                    "<script>console.error('boom')</script></body></html>")
    shown = browser.inspect(page)
    assert shown["images"][0][2] == 0 and "boom" in shown["errors"]


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
    """The figures' data (what the worker receives) hold at most a few thousand marks."""
    import pickle

    from transcalib.report import report_data
    from transcalib.report.figures import MAX_ARROWS, MAX_POINTS

    cal = full_calibration(n_points=20_000)
    data = report_data(cal)
    assert len(pickle.dumps(data)) < 2_000_000
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
