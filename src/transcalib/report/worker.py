"""The report worker: a second process that draws the report while the caller works.

``transcalib calibrate`` starts a :class:`ReportWorker` right after checking its options.
The worker imports matplotlib and draws a first figure (about a second of start-up)
while the main process reads the tracks and calibrates. At export time the main process
reduces the calibration to a :class:`~transcalib.report.ReportData` (kilobytes, whatever
the number of points), hands it over with :meth:`ReportWorker.submit`, writes the other
formats, and collects the report with :meth:`PendingReport.result`.

The worker is started with the ``spawn`` method (never a plain ``fork`` of a process
that may run threads). Its files are written atomically as in the main process. A
failure never goes unnoticed: an exception in the worker, a worker that died, or one
that is still drawing after ``timeout_s`` raises :class:`ReportWorkerError` (an
``OSError`` while writing is re-raised as it is). Library users need none of this:
:func:`~transcalib.report.write_report` draws in the calling process.
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

__all__ = ["ReportWorker", "PendingReport", "ReportWorkerError", "warm_up"]


class ReportWorkerError(RuntimeError):
    """The report worker failed, died or timed out: ``report.html`` was not written."""


def warm_up() -> float:
    """Import matplotlib and draw a small figure to PNG (fonts, caches); returns seconds."""
    t0 = time.perf_counter()
    from .figures import draw_histogram, png

    import numpy as np

    png(draw_histogram({"edges": np.linspace(0, 1, 3), "inliers": np.ones(2), "outliers": np.zeros(2),
                        "n_in": 2, "n_out": 0, "s": 0.5}))
    return time.perf_counter() - t0


def _render(data, folder: str) -> tuple[list[str], float]:
    """In the worker: :func:`~transcalib.report.render_report`; returns the paths and seconds."""
    from . import render_report

    t0 = time.perf_counter()
    paths = render_report(data, folder)
    return [str(p) for p in paths], time.perf_counter() - t0


class PendingReport:
    """A report being drawn by the worker: :meth:`result` waits for its files."""

    def __init__(self, future, timeout_s: float):
        self._future, self._timeout_s = future, timeout_s
        self.worker_s = None  # seconds the worker spent drawing and writing, once done

    def result(self) -> list[Path]:
        """Wait for the worker; return ``report.html`` and the PNG paths.

        Raises
        ------
        ReportWorkerError
            The drawing raised, the worker process died, or it took over ``timeout_s``.
        OSError
            Writing a file failed (disk full, folder removed meanwhile).
        """
        try:
            paths, self.worker_s = self._future.result(timeout=self._timeout_s)
        except FutureTimeout:
            raise ReportWorkerError(f"the report worker did not finish within {self._timeout_s:g} s; "
                                    "report.html was not written") from None
        except BrokenProcessPool as exc:
            raise ReportWorkerError("the report worker process stopped unexpectedly (killed, or out of memory); "
                                    "report.html was not written") from exc
        except OSError:
            raise
        except Exception as exc:
            raise ReportWorkerError(f"the report worker failed ({type(exc).__name__}: {exc}); "
                                    "report.html was not written") from exc
        return [Path(p) for p in paths]


class ReportWorker:
    """One worker process for one report; use as a context manager or :meth:`close` it.

    Parameters
    ----------
    timeout_s : float
        Longest wait in :meth:`PendingReport.result` (the figures take about a second).
    """

    def __init__(self, timeout_s: float = 300.0):
        import multiprocessing

        self.timeout_s = timeout_s
        self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))
        self._pool.submit(warm_up)  # starts the process now; its failure shows in the real job

    def submit(self, data, folder) -> PendingReport:
        """Draw ``data`` (a :class:`~transcalib.report.ReportData`) into ``folder`` in the worker."""
        return PendingReport(self._pool.submit(_render, data, str(folder)), self.timeout_s)

    def close(self) -> None:
        """Stop the worker (without waiting for a job still running)."""
        self._pool.shutdown(wait=False, cancel_futures=True)

    def __enter__(self) -> "ReportWorker":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
