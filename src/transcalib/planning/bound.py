"""Thin adapter to the Cramér-Rao bound of the estimation layer.

The planner's own evaluator (:mod:`.fisher`) is batched for speed; the reported figures
are checked against :func:`transcalib.crlb`, reached only through :func:`crlb` here so
that a move of that function is a one-line change.
"""

from __future__ import annotations

__all__ = ["crlb"]


def crlb(scene, *, distortion: str | None = None) -> dict:
    """``transcalib.crlb(scene, distortion=...)``: dict of std by parameter name (px, degrees)."""
    from ..estimate.covariance import crlb as _crlb

    return _crlb(scene, distortion=distortion)
