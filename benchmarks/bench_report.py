"""The report's cost at 10^2 .. 10^6 points x 5 views, each size in a fresh process.

A calibration is made up from a simulated scene (the true camera and points, the pixel
noise as residuals, 1 % outliers, a diagonal covariance of the intrinsics and of the
points): its report shows what a real one shows, and the cost depends on the number of
points only. Times, wall clock and CPU (``time.process_time``) of the same run:

- ``in-process``: :func:`transcalib.report.write_report` in a fresh interpreter, the
  matplotlib import included (what ``transcalib.export`` costs a library user);
- its parts: ``reduce`` (:func:`~transcalib.report.report_data`, numpy only, the 3-D
  view's reduction included), ``import`` (matplotlib), ``draw``
  (:func:`~transcalib.report.render_report`, the 3-D view's section included);
- the 3-D view alone: ``3-D reduce`` (:func:`~transcalib.report.viewer.viewer_data`) and
  ``3-D html`` (:func:`~transcalib.report.viewer.viewer_html`: base64, JSON, three.js),
  milliseconds, the least of 5 in the warm process;
- ``worker``: what ``transcalib calibrate`` waits for when nothing overlaps the drawing
  (reduce, hand over, draw in a warm :class:`~transcalib.report.worker.ReportWorker`);
  in the command the other formats are written meanwhile;
- ``in worker``: the worker's drawing and writing alone (``report_worker_s`` of
  ``calibrate --json``), wall and CPU;
- ``report.html``: its size, the 3-D view's section and the points it draws
  (:data:`~transcalib.report.viewer.MAX_POINTS` at most);
- per figure: drawing and PNG encoding of each figure in a warm process, milliseconds,
  the least of 5.

``--repeat N`` runs every size N times and keeps the least of each time (the machine's
noise only ever adds). The tables go to ``benchmarks/results/report.md`` (``--quick``: a
scratch folder).

    python benchmarks/bench_report.py              # 10^2, 10^3, 10^4, 10^5, 10^6 points
    python benchmarks/bench_report.py --quick      # 10^2, 10^3, 10^4
    python benchmarks/bench_report.py --repeat 3   # the least of 3 runs of each size
    python benchmarks/run.py report
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import json, os, sys, tempfile, time
def _timed(work):
    t0 = time.perf_counter(); work(); return time.perf_counter() - t0
n, mode = int(sys.argv[1]), sys.argv[2]
sys.path.insert(0, sys.argv[3])
from bench_report import made_up_calibration
cal, uv = made_up_calibration(n)
out, t = tempfile.mkdtemp(), {}
if mode == "in-process":
    from transcalib.report import render_report, report_data
    c0 = time.process_time()
    t0 = time.perf_counter(); data = report_data(cal, uv=uv); t["reduce"] = time.perf_counter() - t0
    t1 = time.perf_counter(); import matplotlib.figure, matplotlib.backends.backend_agg
    t["import"] = time.perf_counter() - t1
    t2 = time.perf_counter(); render_report(data, out); t["draw"] = time.perf_counter() - t2
    t["in-process"] = time.perf_counter() - t0
    t["in-process cpu"] = time.process_time() - c0
    t["page MB"] = os.path.getsize(os.path.join(out, "report.html")) / 1e6
    from transcalib.report.figures import DRAW, png
    from transcalib.report.viewer import viewer_data, viewer_html
    t["3-D MB"] = len(viewer_html(data.viewer).encode()) / 1e6
    t["drawn"] = data.viewer.n_drawn
    for name, work in (("3-D reduce", lambda: viewer_data(cal, uv=uv, image_size=cal.image_size, unit="mm")),
                       ("3-D html", lambda: viewer_html(data.viewer))):  # warm: the least of 5
        t[name] = min(_timed(work) for _ in range(5))
    for name, (_, fig_data) in data.figures.items():  # warm now, as in the worker: the least of 5
        t[name] = min(_timed(lambda: png(DRAW[name](fig_data))) for _ in range(5))
else:
    from transcalib.report import report_data
    from transcalib.report.worker import ReportWorker
    with ReportWorker() as worker:
        worker.wait_ready()
        t0 = time.perf_counter()
        pending = worker.submit(report_data(cal, uv=uv), out)
        pending.result()
        t["worker"] = time.perf_counter() - t0
        t["in worker"], t["in worker cpu"] = pending.worker_s, pending.worker_cpu_s
print(json.dumps(t))
"""

def made_up_calibration(n_points: int, n_views: int = 5):
    """A :class:`~transcalib.types.Calibration` of a simulated scene and its ``uv``."""
    import numpy as np

    from transcalib.geometry.camera import Camera
    from transcalib.synth import simulate
    from transcalib.types import CalibrateOptions, Calibration

    s = simulate.random_scene(n_points, n_views, noise_px=0.5, dist=(-0.05, 0.01), rng=0)
    names = ("fx", "fy", "cx", "cy", "k1", "k2")
    cov = np.diag([0.5, 0.5, 0.4, 0.4, 1e-6, 1e-6]) ** 2
    inliers = np.random.default_rng(1).random(n_points) > 0.01
    return Calibration(camera=Camera(s.K, s.R, dist=s.dist, dist_model="radial2", image_size=s.image_size),
                       X=s.X, residuals_px=s.uv - s.uv_true, rms_px=0.5 * np.sqrt(2), T=s.T, sigma_px=0.5,
                       cov=cov, std=dict(zip(names, np.sqrt(np.diag(cov)))), param_names=names, inliers=inliers,
                       X_std=np.full((n_points, 3), [0.05, 0.05, 0.2]),
                       options=CalibrateOptions(unit="mm"), info={"stages": ["made up"]}), s.uv


def run(n: int, mode: str) -> dict:
    here = str(Path(__file__).resolve().parent)
    out = subprocess.run([sys.executable, "-c", CHILD, str(n), mode, here], capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"bench_report child failed: {out.stderr.strip()[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def least(n: int, repeat: int) -> dict:
    """Each time of ``repeat`` runs of both modes at ``n`` points: the least."""
    runs = [run(n, "in-process") | run(n, "worker") for _ in range(repeat)]
    return {k: min(r[k] for r in runs) for k in runs[0]}


FIGURES = ("residuals.png", "residual_histogram.png", "reconstruction.png", "uncertainty.png")


def tables(times: dict) -> list[str]:
    """The printed tables (also the markdown file's), one line per size."""
    out = [f"{'points':>9}  {'in-process':>10}  {'cpu':>5}  {'reduce':>6}  {'import':>6}  {'draw':>6}  "
           f"{'worker':>6}  {'in worker':>9}  {'cpu':>5}   (seconds)"]
    for n, t in times.items():
        out.append(f"{n:>9,}  {t['in-process']:>10.2f}  {t['in-process cpu']:>5.2f}  {t['reduce']:>6.2f}  "
                   f"{t['import']:>6.2f}  {t['draw']:>6.2f}  {t['worker']:>6.2f}  {t['in worker']:>9.2f}  "
                   f"{t['in worker cpu']:>5.2f}")
    out += ["", "the 3-D view: report.html and its 3-D section (MB), points drawn; reduction and HTML, warm (ms)",
            f"{'points':>9}  {'report.html':>11}  {'3-D section':>11}  {'drawn':>7}  {'3-D reduce':>10}  {'3-D html':>8}"]
    for n, t in times.items():
        out.append(f"{n:>9,}  {t['page MB']:>11.2f}  {t['3-D MB']:>11.2f}  {t['drawn']:>7,}  "
                   f"{1e3 * t['3-D reduce']:>10.1f}  {1e3 * t['3-D html']:>8.1f}")
    names = [f.removesuffix(".png") for f in FIGURES]
    out += ["", "per figure, warm: drawing and PNG (milliseconds)", f"{'points':>9}  " + "  ".join(names)]
    for n, t in times.items():
        out.append(f"{n:>9,}  " + "  ".join(f"{1e3 * t[f]:>{len(name)}.0f}" for f, name in zip(FIGURES, names)))
    return out


def main(argv: list[str]) -> int:
    import os
    import time

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import results_dir

    quick = "--quick" in argv
    sizes = [10**2, 10**3, 10**4] if quick else [10**2, 10**3, 10**4, 10**5, 10**6]
    repeat = int(argv[argv.index("--repeat") + 1]) if "--repeat" in argv else 1
    load = os.getloadavg()
    times = {}
    for n in sizes:
        times[n] = least(n, repeat)
    lines = tables(times)
    print("\n".join(lines))
    note = (f"{time.strftime('%Y-%m-%d %H:%M')}, least of {repeat} run(s) a size; load average at the start "
            f"{load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (1 / 5 / 15 min) on 2 cores")
    print(f"({note})")
    out = results_dir(quick) / "report.md"
    out.write_text("# The report's cost (`bench_report.py`)\n\n" + note + ".\n\n```\n" + "\n".join(lines) + "\n```\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
