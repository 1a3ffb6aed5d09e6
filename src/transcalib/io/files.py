"""Atomic file writing: every output of transcalib goes through :func:`atomic_write`.

A file is written to a temporary file in the same folder and renamed onto its name only
once complete, so an interrupted or failed run never leaves a partial file and never
clobbers a good one. :func:`check_writable_dir` lets a command test an output folder
*before* it starts any computation.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from collections.abc import Mapping
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["atomic_write", "write_json", "jsonable", "check_writable_dir", "check_writable_file", "software_version"]


def software_version() -> str:
    """The installed transcalib's version (from the package metadata: io sits below the
    top-level package and does not import it)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("transcalib")
    except PackageNotFoundError:
        return "unknown"


@contextmanager
def atomic_write(path, mode: str = "w", **kwargs):
    """Open a temporary file beside ``path``; rename it to ``path`` only on success.

    Parameters
    ----------
    path : path-like
        Final file name; its folder is created if missing.
    mode : str
        ``"w"`` (text, give ``encoding``) or ``"wb"``.
    **kwargs
        Passed to :func:`os.fdopen` (``encoding``, ``newline``).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def jsonable(value):
    """Plain JSON values of numpy scalars and arrays (non-finite floats become null)."""
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (np.bool_, bool)):
        return bool(value)
    if isinstance(value, (np.floating, float)):
        v = float(value)
        return v if math.isfinite(v) else None  # JSON has no NaN: null
    if isinstance(value, np.integer):
        return int(value)
    return value


def write_json(path, data: dict) -> None:
    """Write ``data`` as indented JSON (NaN/inf become null), atomically, LF line endings."""
    with atomic_write(path, encoding="utf-8", newline="\n") as fh:
        json.dump(jsonable(data), fh, indent=2, allow_nan=False)
        fh.write("\n")


def check_writable_dir(path, option: str = "--out") -> Path:
    """Check that ``path`` is, or can be created as, a folder we may write into.

    Creates nothing. Raises :class:`InputError` naming ``option`` when ``path`` is an
    existing file, lies under a file, or is not writable (read-only folder, immutable
    attribute, read-only file system): tested by creating a temporary file in the nearest
    existing folder (unnamed where the system allows, so nothing is left there even if
    the check is interrupted).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {str(path)!r} is an existing file, not a folder; give a folder name")
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"{option} {str(path)!r}: {str(probe)!r} is a file, so the folder cannot be created")
    try:  # an unnamed file on Linux (O_TMPFILE): an interrupt cannot leave a probe behind
        with tempfile.TemporaryFile(dir=probe, prefix=".transcalib-probe."):
            pass
    except OSError as exc:
        raise InputError(f"{option} {str(path)!r} is not writable ({exc.strerror or exc}); "
                         "give a folder you can write to") from None
    return path


def check_writable_file(path, option: str) -> Path:
    """Like :func:`check_writable_dir` for an output *file* ``path``: an existing folder
    of that name, or a folder that cannot be written, raises :class:`InputError`."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {str(path)!r} is a folder; give a file name such as {str(path / 'tracks.csv')!r}")
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"{option} {str(path)!r} exists and is not writable")
    check_writable_dir(path.parent if str(path.parent) else Path("."), option=option)
    return path
