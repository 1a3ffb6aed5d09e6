"""``python -m transcalib.cli``: the command line."""

from .main import entry

entry()
