"""Output folders that are complete or absent: a run's files appear all at once or not at all.

A command writes its outputs into a temporary folder beside ``--out``
(``.<name>.tmp-<random>``), then, once every file is written, a ``manifest.json``
listing them (path, bytes, SHA-256), and renames the folder into place. An interrupted or
failed run removes its temporary folder and leaves ``--out`` as it was. The rule for an
existing ``--out``:

- absent, or an empty folder: written;
- a folder holding an earlier transcalib run (its ``manifest.json`` says so): replaced
  whole (the new run's files only, nothing of the old run left);
- anything else (a file, or a folder of other files): refused with a message saying
  which, unless ``force`` (then replaced whole as well).

:func:`check_output_folder` applies the rule before any long work; :func:`output_folder`
is the context manager that writes. The replacement renames the old folder aside
(``.<name>.old-<random>``), renames the new one into place and then deletes the old one.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ..errors import InputError
from .files import check_writable_dir, software_version, write_json

__all__ = ["MANIFEST", "OutputFolder", "check_output_folder", "output_folder", "read_manifest",
           "terminate_as_interrupt"]

#: Name of the manifest in every output folder.
MANIFEST = "manifest.json"
_KIND = "transcalib run"


def read_manifest(folder) -> dict | None:
    """The manifest of an earlier transcalib run in ``folder``, or None (no manifest, or a
    file of that name that is not one)."""
    path = Path(folder) / MANIFEST
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("kind") == _KIND else None


def check_output_folder(out, *, force: bool = False, inputs=(), option: str = "--out") -> Path:
    """Check ``out`` against the rule (module docstring) before any work; create nothing.

    Parameters
    ----------
    out : path-like
    force : bool
        Replace a folder that holds something other than a transcalib run.
    inputs : sequence of path-like
        The run's input files and folders: ``out`` may not be one of them, nor hold one
        (replacing it would delete the input).
    option : str
        The option's name, for messages.

    Raises
    ------
    InputError
        ``out`` is a file; holds foreign files (without ``force``); is or holds an input;
        its parent folder cannot be written.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{option} {str(out)!r} is an existing file, not a folder; give a folder name")
    target = out.resolve()
    for item in inputs:
        p = Path(item).resolve()
        if p == target or target in p.parents:
            raise InputError(f"{option} {str(out)!r} holds the input {str(item)!r}; replacing it would delete it: "
                             "give another folder")
    if out.is_dir() and any(out.iterdir()) and read_manifest(out) is None and not force:
        raise InputError(f"{option} {str(out)!r} holds files that are not a transcalib run (no {MANIFEST}); give a "
                         "new or empty folder, or add --force to replace it whole")
    check_writable_dir(out.parent if str(out.parent) else Path("."), option=option)
    return out


@dataclass(frozen=True)
class OutputFolder:
    """Where a run writes: ``path`` is the temporary folder; files go to
    ``folder.file(name)``; ``final`` is ``--out``."""

    path: Path
    final: Path

    def file(self, name: str) -> Path:
        """Path of output ``name`` (relative, ``/``-separated) in the temporary folder,
        its parent folders made."""
        p = self.path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        return p


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _write_manifest(folder: Path, command: str, extra: dict) -> None:
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    entries = [{"path": p.relative_to(folder).as_posix(), "bytes": p.stat().st_size, "sha256": _digest(p)}
               for p in files]
    write_json(folder / MANIFEST, {"kind": _KIND, "command": command, "software": "transcalib",
                                   "version": software_version(),
                                   "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                                   **extra, "files": entries})


def _remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


@contextmanager
def output_folder(out, *, command: str, force: bool = False, inputs=(), info: dict | None = None):
    """Write a run's outputs so that ``out`` is complete or absent (module docstring).

    Parameters
    ----------
    out : path-like
        The final folder (``--out``).
    command : str
        The command's name, recorded in the manifest.
    force, inputs
        As in :func:`check_output_folder` (checked again here).
    info : dict, optional
        More fields for the manifest (JSON values).

    Yields
    ------
    OutputFolder
        Write every file under ``folder.path`` (``folder.file(name)``).
    """
    out = check_output_folder(out, force=force, inputs=inputs)
    parent = out.parent if str(out.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=parent))
    try:
        yield OutputFolder(path=tmp, final=out)
        _write_manifest(tmp, command, info or {})
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700
        _swap_into_place(tmp, out)
    except BaseException:
        _remove(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _swap_into_place(tmp: Path, out: Path) -> None:
    """Rename ``tmp`` to ``out``; an existing ``out`` is renamed aside first and deleted
    after (if the second rename fails, the old folder is put back)."""
    if not out.exists():
        os.replace(tmp, out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
    old.rmdir()
    os.replace(out, old)
    try:
        os.replace(tmp, out)
    except BaseException:
        os.replace(old, out)
        raise
    _remove(old)


@contextmanager
def terminate_as_interrupt():
    """Within the block, SIGTERM (``kill``) raises ``KeyboardInterrupt`` like Ctrl-C, so
    that :func:`output_folder` removes its temporary folder (main thread only; elsewhere
    nothing changes)."""
    def handler(signum, frame):
        raise KeyboardInterrupt

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
