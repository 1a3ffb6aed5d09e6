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

__all__ = ["EXIT_OK", "EXIT_INPUT", "EXIT_DEGENERATE", "EXIT_WARNINGS", "EXIT_INTERRUPTED", "OptionError",
           "positive_int", "positive_float", "nonnegative_float", "fraction", "image_size", "existing_file",
           "cli_message", "exit_code", "Progress", "print_json", "Parser", "import_in_background"]

EXIT_OK = 0
EXIT_INPUT = 2
EXIT_DEGENERATE = 3
EXIT_WARNINGS = 4
EXIT_INTERRUPTED = 130

#: Python parameter -> the option a user types (messages from the library use the former).
OPTION_NAMES = {
    "sigma_T": "--robot-sigma",
    "robot_sigma_pos": "--robot-sigma",
    "robot_sigma_deg": "--robot-sigma-deg",
    "robot_error": "--robot-error",
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
    "robot_noise": "--robot-sigma",
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
    m = re.fullmatch(r"\s*(\d+)\s*[xX,]\s*(\d+)\s*", text)
    if not m or min(int(m.group(1)), int(m.group(2))) <= 0:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels such as 640x480, got {text!r}")
    return int(m.group(1)), int(m.group(2))


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


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line (``transcalib: error: ...``),
    exit 2."""

    def error(self, message: str):
        self.exit(EXIT_INPUT, f"transcalib: error: {message} (see {self.prog} --help)\n")


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


def run_guarded(func, args) -> int:
    """Run a subcommand: library errors become one line and an exit code."""
    import os

    progress = getattr(args, "_progress", None)
    try:
        return func(args)
    except TranscalibError as exc:
        if progress:
            progress.close()
        message = cli_message(exc)
        print(f"transcalib: error: {message}", file=sys.stderr)
        if getattr(args, "json", False):
            print_json({"status": "error", "exit_code": exit_code(exc), "error": message})
        return exit_code(exc)
    except BrokenPipeError:  # output piped into a command that stopped reading (head)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except OSError as exc:  # a write that failed despite the checks (disk full, vanished folder)
        print(f"transcalib: error: cannot write {exc.filename or 'a file'}: {exc.strerror or exc}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("transcalib: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
