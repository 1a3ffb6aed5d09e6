"""Output folders that are complete or absent: a run's files appear all at once or not at all.

Every command that writes a folder (``calibrate``, ``simulate``, ``undistort``, ``plan``,
``dense``) writes it through :func:`output_folder`:

1. :func:`check_output_folder` applies the rule below before any long work (creates
   nothing);
2. the files are written into a temporary folder beside ``--out``
   (``.<name>.tmp-<random>``, the same file system, so the last step is a rename);
3. once every file is there, ``manifest.json`` lists them (relative path and size in
   bytes) with the command, the version and the time. No digests: hashing the files
   again would cost about 1.5 s of a 10^6-point ``calibrate`` (600 MB at ~400 MB/s),
   and the folder's completeness comes from the rename, not from a checksum;
4. the folder is renamed into place. An existing ``--out`` is first renamed aside
   (``.<name>.old-<random>``) and deleted after; if the second rename fails the old
   folder is put back.

The rule for an existing ``--out``:

- absent, or an empty folder: written;
- a folder holding an earlier transcalib run (its ``manifest.json`` says so): replaced
  whole (the new run's files only, nothing of the old run left);
- anything else (a file, a folder of other files, an older transcalib output without a
  manifest): refused with a message saying which, unless ``force`` (then a folder is
  replaced whole as well; a file never is);
- a folder that is, or holds, one of the run's inputs: refused always.

An exception, Ctrl-C (``KeyboardInterrupt``) or, within :func:`terminate_as_interrupt`,
``kill`` removes the temporary folder and leaves ``--out`` as it was. The rename into
place and the removals run with Ctrl-C deferred to their end, so a second Ctrl-C cannot
leave half a folder either. Only ``kill -9`` (or a power cut) can leave a hidden
``.<name>.tmp-*`` folder behind; ``--out`` itself is never partial.

Using it (the whole API)::

    check_output_folder(args.out, force=args.force, inputs=[...])   # with the other checks
    with output_folder(args.out, command="calibrate", force=args.force, inputs=[...]) as folder:
        write_something(folder.file("points.csv"))                   # into the temporary folder
    # here args.out is complete; folder.final_paths(paths) names what was written
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import tempfile
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ..errors import InputError
from .files import check_writable_dir, software_version, write_json

__all__ = ["MANIFEST", "OutputFolder", "check_output_folder", "output_folder", "read_manifest", "replacing",
           "interrupts_deferred", "uninterrupted", "terminate_as_interrupt"]

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


def _foreign_message(out: Path, option: str) -> str:
    """Why ``out`` is refused: what it holds and what to do."""
    names = sorted(p.name for p in out.iterdir())
    shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
    older = " (an output of an older transcalib, written before manifests)" if "calibration.json" in names else ""
    return (f"{option} {str(out)!r} holds files that are not a transcalib run ({shown}; no {MANIFEST}){older}; "
            "give a new or empty folder, or add --force to replace it whole")


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

    Returns
    -------
    Path
        ``out``.

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
        raise InputError(_foreign_message(out, option))
    check_writable_dir(out, option=option)  # the nearest existing folder: out itself, or where it will be made
    if out.exists():  # replaced by a rename in its parent
        parent = out.parent if str(out.parent) else Path(".")
        try:
            check_writable_dir(parent, option=option)
        except InputError:
            raise InputError(f"{option} {str(out)!r} cannot be replaced: its folder {str(parent)!r} is not "
                             "writable; give a folder you can write to") from None
    return out


def replacing(out) -> str | None:
    """What an :func:`output_folder` on ``out`` will replace, in words (for a progress
    line), or None when ``out`` is absent or empty."""
    out = Path(out)
    if not out.is_dir() or not any(out.iterdir()):
        return None
    doc = read_manifest(out)
    if doc is None:
        return f"replacing {str(out)!r} whole (--force)"
    return (f"replacing the earlier transcalib run in {str(out)!r} ({doc.get('command', '?')}, "
            f"{doc.get('created', '?')}, {len(doc.get('files', []))} files)")


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

    def final_paths(self, paths) -> list[Path]:
        """Where ``paths`` (files under :attr:`path`) will be once the folder is in place."""
        return [self.final / Path(p).relative_to(self.path) for p in paths]


def _write_manifest(folder: Path, command: str, extra: dict) -> None:
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    entries = [{"path": p.relative_to(folder).as_posix(), "bytes": p.stat().st_size} for p in files]
    write_json(folder / MANIFEST, {"kind": _KIND, "command": command, "software": "transcalib",
                                   "version": software_version(),
                                   "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                                   **extra, "files": entries})


def _remove(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


@contextmanager
def interrupts_deferred():
    """Within the block Ctrl-C (SIGINT) and SIGTERM are held; one that came is raised as
    ``KeyboardInterrupt`` at its end (main thread only; elsewhere nothing changes). For
    cleanup that must finish, such as stopping a helper process that writes into the
    temporary folder before the folder is removed. A signal that comes while the handlers
    are being swapped may still raise before the block starts: :func:`uninterrupted`
    retries until the work is done."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = {}
    try:
        for s in (signal.SIGINT, signal.SIGTERM):
            previous[s] = signal.signal(s, lambda signum, frame: caught.append(signum))
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    if caught:
        raise KeyboardInterrupt


def uninterrupted(work):
    """``work()`` run to its end whatever Ctrl-C or SIGTERM comes meanwhile (each then
    raises ``KeyboardInterrupt`` once the work is done); returns its value. ``work`` is
    started again if an interrupt came before it started, never after."""
    interrupted, done, value = False, False, None
    while not done:
        try:
            with interrupts_deferred():
                value, done = work(), True
        except KeyboardInterrupt:
            interrupted = True
    if interrupted:
        raise KeyboardInterrupt
    return value


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
    made = []  # the temporary folder, recorded before a Ctrl-C deferred meanwhile is raised
    try:
        uninterrupted(lambda: made.append(Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=parent))))
        tmp = made[0]
        yield OutputFolder(path=tmp, final=out)
        _write_manifest(tmp, command, info or {})
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700
        uninterrupted(lambda: _swap_into_place(tmp, out))
    except BaseException:
        if made:
            uninterrupted(lambda: _remove(made[0]))
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
