"""Diagnostics: checks that name the cause of a doubtful calibration and what to do."""

from .diagnostics import diagnose

__all__ = ["diagnose"]
