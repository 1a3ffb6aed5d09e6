"""The ``transcalib`` command: one module per subcommand, registered from :data:`COMMANDS`.

Exit status: 0 success, 1 an internal failure (a bug, or the report's worker process
failed: one line, no traceback), 2 bad input (one line naming the option, no traceback),
3 degenerate data, 4 warnings with ``--strict``, 130 interrupted (Ctrl-C or SIGTERM; no
output folder is left half-written). With ``--json`` every outcome, argparse's usage
errors included, is one JSON document on stdout. Adding a subcommand is
one line: a module with ``add_parser(sub)`` and ``run(args)`` named in ``COMMANDS``.
"""

from __future__ import annotations

import ctypes
import gc
import importlib
import os
import sys

from .. import __version__
from .common import EXIT_INPUT, INTERRUPT_REPORTED, Parser, UsageError, fail, interrupted, run_guarded, wants_json

#: Subcommand modules of this package, in ``--help`` order.
COMMANDS = ("calibrate", "extract", "simulate", "track", "show", "undistort", "plan", "validate", "dense")


def build_parser(argv: list[str] | None = None) -> Parser:
    """The command line's parser. Given ``argv``, only the command it names gets its
    options; the others are listed by name and help line, all ``transcalib --help``
    shows (every command's options took 0.02 s of each run)."""
    named = next((a for a in argv or () if not a.startswith("-")), None)
    p = Parser(prog="transcalib",
               description="Camera calibration and metric reconstruction from known robot translations.",
               epilog="Exit status: 0 success, 1 internal failure, 2 bad input, 3 degenerate data, 4 warnings with "
                      "--strict, 130 interrupted. 'transcalib COMMAND -h' explains every option of a command.")
    p.add_argument("--version", action="version", version=f"transcalib {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)
    for name in COMMANDS:
        module = importlib.import_module(f".{name}", __package__)
        if named == name or named not in COMMANDS:
            module.add_parser(sub)
        else:
            sub.add_parser(module.NAME, help=module.HELP)
    return p


def keep_freed_memory() -> bool:
    """Ask glibc's allocator to keep freed memory for reuse (arrays up to 32 MiB from the
    heap, which is trimmed only beyond 1 GiB, grown 64 MiB at a time) instead of handing
    it back to the system and faulting it in again at the next array: the numerics
    allocate many megabyte-sized temporaries, and fresh pages cost a third of their time
    at 10^5 points on a virtual machine. Only the command does this (the process is
    ours); False where the C library is not glibc."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3  # malloc.h
    settings = ((m_mmap_threshold, 32 << 20), (m_trim_threshold, 1 << 30), (m_top_pad, 64 << 20))
    return all(mallopt(option, value) == 1 for option, value in settings)


#: Environment variables that set the thread count of a BLAS library.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def quiet_blas_threads() -> bool:
    """Run BLAS on one thread in this process and in those it starts (the report
    worker), unless the user chose a thread count (:data:`BLAS_THREAD_VARIABLES`).

    The command's products are skinny (``(3, 3) @ (3, n)``, ``(p, 3n) @ (3n, p)``) and
    its parallel parts run on threads of their own; after each product OpenBLAS's
    threads spin for a while on the cores those threads need (a tenth of the CPU time
    of a 10^5-point run on two cores). Returns whether the limit was set."""
    if any(name in os.environ for name in BLAS_THREAD_VARIABLES):
        return False
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # BLAS libraries loaded from now on, child processes
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")  # those already loaded (numpy's)
    return True


#: Container objects allocated between two runs of the cyclic garbage collector's
#: youngest generation (Python's default 700).
GC_THRESHOLD = 10_000


def tune_process() -> None:
    """Settings for the command's own process, never for the library's callers: glibc
    keeps freed memory (:func:`keep_freed_memory`), Arrow allocates from glibc too (its
    default mimalloc pool hands freed pages back and faults them in again, as huge
    pages that are zeroed whole: about 15 % of a 10^5-point run's CPU time), BLAS
    runs on one thread (:func:`quiet_blas_threads`), and the garbage collector runs
    every :data:`GC_THRESHOLD` new objects: the imports create some 10^5 objects that
    live for the whole run, which at Python's default meant ~100 collections, one of
    them full (0.05 s with the GIL held, four images of 800 x 600; now 7, none full:
    0.03 s). A user's own ``ARROW_DEFAULT_MEMORY_POOL`` or BLAS thread count is kept."""
    keep_freed_memory()
    gc.set_threshold(GC_THRESHOLD, *gc.get_threshold()[1:])
    os.environ.setdefault("ARROW_DEFAULT_MEMORY_POOL", "system")  # read when pyarrow is first used
    quiet_blas_threads()


def main(argv: list[str] | None = None) -> int:
    """Run the command line ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    INTERRUPT_REPORTED.clear()
    try:
        return _main(argv)
    except KeyboardInterrupt:  # before the command ran, or a second Ctrl-C while the first was reported
        return interrupted(wants_json(argv))


def _main(argv: list[str]) -> int:
    for stream in (sys.stdout, sys.stderr):  # "±" and "→" on a terminal that is not UTF-8
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="replace")
    try:
        args = build_parser(argv).parse_args(argv)
    except UsageError as exc:  # before any option is known: --json looked up by hand
        return fail(EXIT_INPUT, str(exc), wants_json(argv))
    except SystemExit as exc:  # --help, --version
        return exc.code if isinstance(exc.code, int) else EXIT_INPUT
    return run_guarded(args.func, args)


def entry() -> None:
    """The console script (and ``python -m transcalib``, ``python -m transcalib.cli``):
    :func:`main` in a process tuned for it (:func:`tune_process`), then an immediate
    exit with its status. Every file is written and closed and the report worker
    stopped by then; the interpreter's teardown would free every array and module one
    by one (a tenth of a second after a large run) for a process that ends anyway."""
    tune_process()
    code = main()
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    os._exit(code)


if __name__ == "__main__":
    entry()
