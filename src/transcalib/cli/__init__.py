"""The ``transcalib`` command line: parse, call, print; no numerics here."""

from .main import entry, main

__all__ = ["main", "entry"]
