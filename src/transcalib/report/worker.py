"""The report worker: a second process that draws the report while the caller works.

``transcalib calibrate`` starts a :class:`ReportWorker` right after checking its options.
The worker imports matplotlib and draws a first figure (about a second of start-up)
while the main process reads the tracks and calibrates. At export time the main process
reduces the calibration to a :class:`~transcalib.report.ReportData` (kilobytes, whatever
the number of points), hands it over with :meth:`ReportWorker.submit`, writes the other
formats, and collects the report with :meth:`PendingReport.result`.

The worker is a ``spawn`` process (never a plain ``fork`` of a process that may run
threads) talking over one pipe: it answers ``ready`` once warm, then ``done`` or
``failed`` for the job. Its files are written atomically as in the main process. A
failure never goes unnoticed and never hangs: an exception in the worker, a worker that
died, or one that does not answer within ``timeout_s`` raises :class:`ReportWorkerError`
(an ``OSError`` while writing is raised again as an ``OSError``). Library users need
none of this: :func:`~transcalib.report.write_report` draws in the calling process.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

__all__ = ["ReportWorker"]


def _started(process) -> None:
    """Start ``process`` with Ctrl-C ignored from its birth: the group's SIGINT otherwise
    lands in its interpreter's start-up, before ``_serve`` can ignore it, and prints a
    traceback on the command's stderr. An ignored signal stays ignored across ``exec``;
    here Ctrl-C is held meanwhile (blocked, so not lost) and delivered after."""
    import threading

    if threading.current_thread() is not threading.main_thread():  # handlers are the main thread's
        process.start()
        return
    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        process.start()
    finally:
        signal.signal(signal.SIGINT, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


class ReportWorkerError(RuntimeError):
    """The report worker failed, died or timed out: ``report.html`` was not written."""


def warm_up() -> float:
    """Import matplotlib and draw a small figure to PNG (fonts, caches); returns seconds."""
    t0 = time.perf_counter()
    import numpy as np

    from .figures import draw_histogram, png

    png(draw_histogram({"edges": np.linspace(0, 1, 3), "inliers": np.ones(2), "outliers": np.zeros(2),
                        "n_in": 2, "n_out": 0, "s": 0.5}))
    return time.perf_counter() - t0


def _serve(conn) -> None:
    """The worker process: warm up, say ``ready``, draw the one job, say ``done``."""
    import gc
    import os
    import sys
    import traceback

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's (ignored from birth: _started)
    # stopped during the job: unwind (no temporary file left); before it nothing is
    # written, so end at once: a shutdown that cuts an import short once wrote "Fatal
    # Python error: PyThreadState_Get" on the command's stderr beside its own error
    job = []
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1) if job else os._exit(1))
    from . import render_report

    try:
        warm_up()
        gc.disable()  # no collection pauses in the one job: its garbage (megabytes) ends with the process
        conn.send(("ready", None))
        data, folder = conn.recv()
        job.append(folder)
        t0, c0 = time.perf_counter(), time.process_time()
        paths = render_report(data, folder)
        conn.send(("done", ([str(p) for p in paths], time.perf_counter() - t0, time.process_time() - c0)))
    except (EOFError, BrokenPipeError):
        return  # the main process closed the pipe: nothing more to do
    except SystemExit:
        raise  # stopped by the main process
    except BaseException as exc:  # noqa: BLE001 -- every failure goes back to the main process
        os_error = (exc.errno, exc.strerror, exc.filename) if isinstance(exc, OSError) else None
        try:
            conn.send(("failed", (f"{type(exc).__name__}: {exc}", traceback.format_exc(), os_error)))
        except OSError:
            pass  # the main process is gone


class PendingReport:
    """A report being drawn by the worker: :meth:`result` waits for its files."""

    def __init__(self, worker: "ReportWorker"):
        self._worker = worker
        self.worker_s = None  # seconds the worker spent drawing and writing, once done
        self.worker_cpu_s = None  # and its CPU seconds

    def result(self) -> list[Path]:
        """Wait for the worker; return ``report.html`` and the PNG paths.

        Raises
        ------
        ReportWorkerError
            The drawing raised, the worker process died, or it did not answer in time.
        OSError
            Writing a file failed (disk full, folder removed meanwhile).
        """
        paths, self.worker_s, self.worker_cpu_s = self._worker._receive("done")
        return [Path(p) for p in paths]


class ReportWorker:
    """One worker process for one report; use as a context manager or :meth:`close` it.

    Parameters
    ----------
    timeout_s : float
        Longest wait for each answer of the worker (start-up and drawing take about a
        second each).
    """

    def __init__(self, timeout_s: float = 120.0):
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        self.timeout_s = timeout_s
        self._ready = False
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(target=_serve, args=(child,), name="transcalib-report", daemon=True)
        _started(self._process)
        child.close()

    def wait_ready(self) -> None:
        """Wait until the worker has imported matplotlib and drawn its first figure."""
        if not self._ready:
            self._receive("ready")
            self._ready = True

    def submit(self, data, folder) -> PendingReport:
        """Draw ``data`` (a :class:`~transcalib.report.ReportData`) into ``folder`` in the
        worker; waits until the worker is warm (it usually is long before)."""
        self.wait_ready()
        try:
            self._conn.send((data, str(folder)))
        except (BrokenPipeError, ConnectionResetError):
            raise self._died() from None
        return PendingReport(self)

    def _receive(self, expected: str):
        """The payload of the worker's next answer, which must be ``expected``."""
        deadline = time.monotonic() + self.timeout_s
        while not self._conn.poll(0.05):  # returns as soon as an answer arrives
            if not self._process.is_alive():
                raise self._died()
            if time.monotonic() > deadline:
                raise ReportWorkerError(f"the report worker did not answer within {self.timeout_s:g} s "
                                        "(stopped); report.html was not written")
        try:
            kind, payload = self._conn.recv()
        except (EOFError, ConnectionResetError):
            raise self._died() from None
        if kind == "failed":
            message, trace, os_error = payload
            if os_error is not None:
                raise OSError(*os_error)
            raise ReportWorkerError(f"the report worker failed ({message}); report.html was not written\n"
                                    f"worker traceback:\n{trace}")
        if kind != expected:
            raise ReportWorkerError(f"the report worker answered {kind!r} instead of {expected!r}")
        return payload

    def _died(self) -> ReportWorkerError:
        self._process.join(1.0)
        return ReportWorkerError(f"the report worker process stopped unexpectedly (exit code "
                                 f"{self._process.exitcode}: killed, or out of memory); report.html was not written")

    def close(self) -> None:
        """End the worker at once: a finished report is on disk (its files are written
        before the worker answers), a job still running is stopped. Stopping beats
        waiting for the interpreter to shut down matplotlib (a tenth of a second)."""
        self._conn.close()
        self._process.terminate()
        self._process.join(5.0)

    def __enter__(self) -> "ReportWorker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
