"""Error classes and the :class:`Diagnostic` warning type: the bottom layer, imported by all."""

from __future__ import annotations

__all__ = ["TranscalibError", "InputError", "DegenerateError", "MirroredError", "Diagnostic"]


class TranscalibError(Exception):
    """Base class of every error transcalib raises on purpose."""


class InputError(TranscalibError, ValueError):
    """The input is malformed: wrong shape, non-finite values, bad file contents, ...

    The message says what was expected, what came, and what to do.
    """


class DegenerateError(TranscalibError, ValueError):
    """The input is well formed but does not determine the calibration.

    For example translations that do not span 3-D, or too few usable points. The
    message gives the reason and what to change in the data.
    """


class MirroredError(InputError, DegenerateError):
    """The data imply a mirrored (left-handed) camera: ``det(K R) < 0``.

    Usually the robot frame is left-handed, two robot axes are swapped, or the images
    are flipped. Both an :class:`InputError` and a :class:`DegenerateError`.
    """


class Diagnostic(str):
    """A human-readable warning (a ``str``) with a stable machine-readable ``code``.

    >>> d = Diagnostic("translations_coplanar", "translations are nearly coplanar ...")
    >>> d.code, str(d)
    ('translations_coplanar', 'translations are nearly coplanar ...')
    """

    code: str

    def __new__(cls, code: str, message: str) -> "Diagnostic":
        obj = super().__new__(cls, message)
        obj.code = code
        return obj

    def __reduce__(self):  # keep code when pickled / copied
        return (Diagnostic, (self.code, str(self)))
