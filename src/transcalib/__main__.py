"""``python -m transcalib``: the command line."""

from .cli.main import entry

entry()
