"""The one progress protocol: every long computation reports ``progress(ProgressEvent)``."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

@dataclass(frozen=True)
class ProgressEvent:
    """What a long computation reports to its ``progress`` callable, the one progress
    protocol of every stage: ``progress(event)``.

    Attributes
    ----------
    stage : str
        What is running, e.g. ``"robust"``, ``"refine: iteration"``, ``"track: detect"``.
    done, total : int or None
        Steps done so far of ``total`` (``total`` None: open-ended, e.g. iterations);
        both None: the stage has finished.
    info : mapping of str to value
        Figures of the stage (``rms_px``, ``inliers``, ``cost``, ...).
    """

    stage: str
    done: int | None = None
    total: int | None = None
    info: Mapping = field(default_factory=lambda: MappingProxyType({}))

    @property
    def finished(self) -> bool:
        return self.done is None and self.total is None


def report(progress, stage: str, done: int | None = None, total: int | None = None, **info) -> None:
    """Send ``progress`` (a callable or None) a :class:`ProgressEvent`."""
    if progress is not None:
        progress(ProgressEvent(stage, done, total, MappingProxyType(info)))
