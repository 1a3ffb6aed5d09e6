"""The ``transcalib`` command: one module per subcommand, registered from :data:`COMMANDS`.

Exit status: 0 success, 2 bad input (one line naming the option, no traceback),
3 degenerate data, 4 warnings with ``--strict``, 130 interrupted. Adding a subcommand is
one line: a module with ``add_parser(sub)`` and ``run(args)`` named in ``COMMANDS``.
"""

from __future__ import annotations

import importlib
import sys

from .. import __version__
from .common import Parser, run_guarded

#: Subcommand modules of this package, in ``--help`` order.
COMMANDS = ("calibrate", "simulate", "track", "show", "undistort", "plan")


def build_parser() -> Parser:
    p = Parser(prog="transcalib",
               description="Camera calibration and metric reconstruction from known robot translations.",
               epilog="Exit status: 0 success, 2 bad input, 3 degenerate data, 4 warnings with --strict.")
    p.add_argument("--version", action="version", version=f"transcalib {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=Parser)
    for name in COMMANDS:
        importlib.import_module(f".{name}", __package__).add_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    for stream in (sys.stdout, sys.stderr):  # "±" and "→" on a terminal that is not UTF-8
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="replace")
    args = build_parser().parse_args(argv)
    return run_guarded(args.func, args)


if __name__ == "__main__":
    sys.exit(main())
