"""What every subcommand shares: exit codes, checked argument types, one-line errors,
progress display and the ``--json`` output.

The rule of the command line: every option, input file and output path is checked
*before* any computation, and a bad one ends the run with one line naming the option
(exit 2, no traceback). Errors raised deeper down name Python parameters; :func:`cli_message`
puts the command-line option the user typed in their place.
"""

from __future__ import annotations

import argparse
import importlib
import json
import math
import re
import sys
import threading
from pathlib import Path

from ..errors import DegenerateError, InputError, TranscalibError

__all__ = ["EXIT_OK", "EXIT_FAILURE", "EXIT_INPUT", "EXIT_DEGENERATE", "EXIT_WARNINGS", "EXIT_INTERRUPTED", "OptionError",
           "positive_int", "positive_float", "nonnegative_float", "fraction", "image_size", "existing_file",
           "cli_message", "exit_code", "Progress", "print_json", "Parser", "UsageError", "GROUPS", "add_output_options",
           "fail", "interrupted", "wants_json", "run_guarded", "import_in_background", "range_pair"]

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_INPUT = 2
EXIT_DEGENERATE = 3
EXIT_WARNINGS = 4
EXIT_INTERRUPTED = 130

#: Python parameter -> the option a user types (messages from the library use the former).
OPTION_NAMES = {
    "sigma_T": "--robot-sigma",
    "threshold_px": "--threshold-px",
    "loss_scale_px": "--loss-scale-px",
    "inlier_threshold_px": "--inlier-threshold-px",
    "sigma_px": "--sigma-px",
    "estimate_skew": "--estimate-skew",
    "square_pixels": "--square-pixels",
    "refine=False": "--no-refine",
    "robust=False": "--no-robust",
    "max_trials": "--max-trials",
    "noise_px": "--noise-px",
    "robot_noise": "--robot-noise",
    "n_points": "--points",
    "n_views": "--views",
    "rotation_format": "--rotation-format",
}


class OptionError(InputError):
    """A bad command-line value; the message starts with the option's name."""

    def __init__(self, option: str, message: str):
        super().__init__(f"{option}: {message}")
        self.option = option


def cli_message(exc: BaseException) -> str:
    """The exception's message with Python parameter names replaced by CLI options."""
    text = str(exc).strip().replace("\n", " ")
    for name, option in OPTION_NAMES.items():
        text = re.sub(rf"(?<![\w-]){re.escape(name)}(?![\w])", option, text)
    return text


def exit_code(exc: BaseException) -> int:
    """2 for bad input, 3 for degenerate data (a mirrored scene included)."""
    return EXIT_DEGENERATE if isinstance(exc, DegenerateError) else EXIT_INPUT


# --------------------------------------------------------------------------------------
# argument types: argparse calls them while parsing, before any work
# --------------------------------------------------------------------------------------


def _number(text: str, kind=float):
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if kind is float and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def positive_int(text: str) -> int:
    value = _number(text, int)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return value


def positive_float(text: str) -> float:
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def nonnegative_float(text: str) -> float:
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a number >= 0, got {text!r}")
    return value


def fraction(text: str) -> float:
    value = _number(text)
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"must be a fraction in [0, 1), got {text!r}")
    return value


def image_size(text: str) -> tuple[int, int]:
    """``WxH`` or ``W,H`` (the one spelling of an image size in every subcommand), pixels."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", text)
    if not m or min(int(m.group(1)), int(m.group(2))) <= 0:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT or WIDTH,HEIGHT in pixels such as 640x480, got {text!r}")
    return int(m.group(1)), int(m.group(2))


def numbers(text: str, count: int | None = None) -> list[float]:
    """Comma-separated finite numbers (``count`` of them when given)."""
    parts = [t for t in text.replace(" ", "").split(",")]
    values = [_number(t) for t in parts]
    if count is not None and len(values) != count:
        raise argparse.ArgumentTypeError(f"expected {count} numbers separated by commas, got {len(values)} in {text!r}")
    return values


def range_pair(text: str) -> tuple[float, float]:
    """``MIN,MAX`` with ``MIN < MAX``: the one spelling of a range in every subcommand."""
    lo, hi = numbers(text, 2)
    if not lo < hi:
        raise argparse.ArgumentTypeError(f"expected MIN,MAX with MIN < MAX, got {text!r}")
    return lo, hi


def box(text: str) -> tuple[float, ...]:
    """``xmin,xmax,ymin,ymax,zmin,zmax``: three ranges (:func:`range_pair`), each of
    positive length."""
    v = numbers(text, 6)
    for axis, (lo, hi) in zip("xyz", (v[0:2], v[2:4], v[4:6])):
        if not lo < hi:
            raise argparse.ArgumentTypeError(f"{axis}min must be below {axis}max, got {lo:g} and {hi:g} in {text!r} "
                                              "(a box of positive size along x, y and z)")
    return tuple(v)


def existing_file(option: str, path) -> Path:
    """``path`` as a Path if it is a readable file, else :class:`OptionError`."""
    p = Path(path)
    if not p.exists():
        raise OptionError(option, f"{str(p)!r} does not exist")
    if not p.is_file():
        raise OptionError(option, f"{str(p)!r} is not a file")
    try:
        with open(p, "rb"):
            pass
    except OSError as exc:
        raise OptionError(option, f"{str(p)!r} cannot be read ({exc.strerror})") from None
    return p


class UsageError(Exception):
    """A command line argparse could not parse (raised by :meth:`Parser.error`)."""


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (``transcalib: error: ...``),
    exit 2: :meth:`error` raises :class:`UsageError`, which :func:`run_guarded` reports
    (with ``--json``, as a JSON document too). Option groups are titled as in
    :data:`GROUPS`."""

    def error(self, message: str):
        if message.startswith("argument "):  # "argument --box: ..." -> "--box: ...", as the checks say it
            message = message[len("argument "):]
        raise UsageError(f"{message} (see {self.prog} --help)")

    def groups(self) -> dict:
        """The titled option groups of :data:`GROUPS`, by key (``"inputs"``, ...)."""
        return {key: self.add_argument_group(title, text) for key, (title, text) in GROUPS.items()}


#: The option groups of every subcommand's ``--help``, in this order.
GROUPS = {
    "inputs": ("inputs", "what the command reads"),
    "model": ("model", "what is estimated and what is known"),
    "robust": ("robust", "outliers and noise"),
    "outputs": ("outputs", "what is written where; --json, --quiet"),
    "performance": ("performance", "speed and repeatability"),
}


def add_output_options(group, *, folder: bool = True, quiet: bool = True) -> None:
    """``--force`` (commands that write a folder), ``--json`` and ``--quiet``: the same
    words in every subcommand."""
    if folder:
        group.add_argument("--force", action="store_true",
                           help="replace an --out folder that holds files other than an earlier transcalib run "
                                "(one that holds a run is replaced without it)")
    group.add_argument("--json", action="store_true",
                       help="print one JSON document on stdout (also on failure: status, exit_code, error)")
    if quiet:
        group.add_argument("--quiet", action="store_true", help="no progress messages on stderr")


# --------------------------------------------------------------------------------------
# progress and output
# --------------------------------------------------------------------------------------


class Progress:
    """Progress on stderr: ``tqdm`` bars on a terminal, a few plain lines otherwise,
    nothing when quiet. A progress callable of the library (:class:`ProgressEvent`):
    a finished stage is one line with its figures, a step of a long loop with a known
    total a bar (or a few lines), an open-ended step (an iteration) nothing.
    """

    def __init__(self, quiet: bool = False, stream=None):
        self.quiet = quiet
        self.stream = stream or sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._bars = {}

    def log(self, message: str) -> None:
        if not self.quiet:
            self.close()  # a bar left open (a loop that ended early) ends its line first
            print(message, file=self.stream, flush=True)

    def __call__(self, event) -> None:
        if event.finished:
            self.stage(event.stage, event.info)
        elif event.total is not None:
            self.step(event.stage, event.done, event.total)

    def stage(self, name: str, info: dict) -> None:
        self.log(f"  {name}: " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                                           for k, v in info.items()))

    def step(self, name: str, done: int, total: int) -> None:
        if self.quiet:
            return
        if self.tty:
            from tqdm import tqdm

            bar = self._bars.get(name)
            if bar is None:
                self.close()  # one bar at a time: another stage's bar ends its line
                bar = self._bars[name] = tqdm(total=total, desc=f"  {name}", file=self.stream, leave=True)
            bar.update(done - bar.n)
            if done >= total:
                bar.close()
                self._bars.pop(name, None)
        elif done == total or done % -(-total // 4) == 0:  # about four lines per stage
            print(f"  {name}: {done}/{total}", file=self.stream, flush=True)

    def close(self) -> None:
        for bar in self._bars.values():
            bar.close()
        self._bars.clear()


def import_in_background(*modules: str) -> threading.Thread:
    """Import ``modules`` on a daemon thread while the main thread reads its inputs (the
    CSV parser releases the GIL): scipy's modules take a few tenths of a second that
    would otherwise come after the reading. A failed import is left for the main
    thread's own import of the module to report."""
    def work():
        for name in modules:
            try:
                importlib.import_module(name)
            except Exception:  # noqa: BLE001 - reported by the main thread's import
                return

    thread = threading.Thread(target=work, name="imports", daemon=True)
    thread.start()
    return thread


def print_json(data: dict) -> None:
    """One JSON document on stdout (non-finite floats as null)."""
    from ..io.files import jsonable

    print(json.dumps(jsonable(data), indent=2, allow_nan=False), flush=True)


def fail(code: int, message: str, json_mode: bool, progress=None) -> int:
    """Report a failure: one line on stderr, and with ``--json`` one JSON document on
    stdout; returns ``code``."""
    if progress is not None:
        progress.close()
    print(f"transcalib: error: {message}", file=sys.stderr, flush=True)
    if json_mode:
        print_json({"status": "error", "exit_code": code, "error": message})
    return code


#: Whether this run has reported an interrupt already (a second Ctrl-C while the first
#: is being reported must not print a second JSON document); reset by ``main``.
INTERRUPT_REPORTED = threading.Event()


def interrupted(json_mode: bool, progress=None) -> int:
    """Report Ctrl-C (or SIGTERM), once per run: one line on stderr, with ``--json`` one
    JSON document; returns 130."""
    if INTERRUPT_REPORTED.is_set():
        return EXIT_INTERRUPTED
    INTERRUPT_REPORTED.set()
    if progress is not None:
        progress.close()
    print("transcalib: interrupted; no output folder was left half-written", file=sys.stderr, flush=True)
    if json_mode:
        print_json({"status": "interrupted", "exit_code": EXIT_INTERRUPTED, "error": "interrupted"})
    return EXIT_INTERRUPTED


def wants_json(argv: list[str]) -> bool:
    """Whether ``--json`` is among the options of ``argv`` (before a ``--``): known before
    argparse has run, for its own errors."""
    return "--json" in (argv[:argv.index("--")] if "--" in argv else argv)


def run_guarded(func, args) -> int:
    """Run a subcommand: every failure becomes one line (and a JSON document with
    ``--json``) and an exit code, never a traceback. SIGTERM is handled as Ctrl-C, so an
    output folder being written is removed (:mod:`transcalib.io.folders`).

    A failure that is not the user's (an exception no check foresaw) exits 1 and says
    so; ``TRANSCALIB_TRACEBACK=1`` prints its traceback too.
    """
    import os

    from ..io.folders import terminate_as_interrupt

    json_mode = bool(getattr(args, "json", False))
    try:
        with terminate_as_interrupt():
            return func(args)
    except TranscalibError as exc:
        return fail(exit_code(exc), cli_message(exc), json_mode, getattr(args, "_progress", None))
    except BrokenPipeError:  # output piped into a command that stopped reading (head)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except OSError as exc:  # a write that failed despite the checks (disk full, vanished folder)
        message = f"cannot write {exc.filename or 'a file'}: {exc.strerror or exc}; nothing was written"
        return fail(EXIT_INPUT, message, json_mode, getattr(args, "_progress", None))
    except KeyboardInterrupt:
        return interrupted(json_mode, getattr(args, "_progress", None))
    except Exception as exc:  # noqa: BLE001 - a bug or a failure of a helper process: exit 1, no traceback
        if os.environ.get("TRANSCALIB_TRACEBACK"):
            import traceback

            traceback.print_exc()
        first = (str(exc).strip().splitlines() or [""])[0]
        message = (f"{type(exc).__name__}: {first} (an internal error, not your input; nothing was written; set "
                   "TRANSCALIB_TRACEBACK=1 for the traceback and please report it)")
        return fail(EXIT_FAILURE, message, json_mode, getattr(args, "_progress", None))
