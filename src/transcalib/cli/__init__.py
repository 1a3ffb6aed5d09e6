"""The ``transcalib`` command line: parse, call, print; no numerics here."""

from .main import main

__all__ = ["main"]
