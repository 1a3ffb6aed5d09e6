"""Output folders are complete or absent (``transcalib.io.folders``, issue 24): the rule for
an existing ``--out``, in Python and through every subcommand that writes a folder, and
``calibrate --images`` interrupted (a real SIGINT) at 23 moments, half of them while the
files are being written: each time ``--out`` is absent, the earlier run intact, or the
new run complete, and no temporary folder is left."""

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from transcalib.cli.main import main
from transcalib.errors import InputError
from transcalib.io.folders import MANIFEST, check_output_folder, output_folder, read_manifest


def default_sigint() -> None:
    """``preexec_fn`` of a command a test interrupts with Ctrl-C: SIGINT handled as a
    terminal's user meets it, even when the tests themselves run with it ignored (a shell
    starts a background job, ``make test &``, so)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def leftovers(out: Path) -> list[str]:
    """Temporary or set-aside folders of ``out`` still beside it."""
    return sorted(p.name for p in out.parent.glob(f".{out.name}.*"))


def assert_complete(out: Path, expect=()) -> dict:
    """``out`` holds exactly the files its manifest lists, with their sizes (and
    ``expect`` among them); returns the manifest."""
    doc = read_manifest(out)
    assert doc is not None, sorted(p.name for p in out.iterdir())
    listed = {f["path"]: f for f in doc["files"]}
    present = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()} - {MANIFEST}
    assert present == set(listed), (present ^ set(listed))
    for name, f in listed.items():
        assert (out / name).stat().st_size == f["bytes"], name
    assert set(expect) <= set(listed), set(expect) - set(listed)
    return doc


# --------------------------------------------------------------------------------------
# the rule, in Python
# --------------------------------------------------------------------------------------


def test_rule_in_python(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with output_folder(out, command="test") as f:
            f.file("a.txt").write_text("partial")
            raise RuntimeError("fails")
    assert not out.exists() and leftovers(out) == []
    with output_folder(out, command="test") as f:
        f.file("a.txt").write_text("one")
        f.file("sub/b.txt").write_text("two")
        assert f.final_paths([f.path / "sub/b.txt"]) == [out / "sub" / "b.txt"]
    assert assert_complete(out, ["a.txt", "sub/b.txt"])["command"] == "test"
    with output_folder(out, command="test") as f:  # an earlier run: replaced whole
        f.file("c.txt").write_text("three")
    assert_complete(out, ["c.txt"])
    assert not (out / "a.txt").exists()
    for exc in (RuntimeError, KeyboardInterrupt):  # the earlier run stays as it was
        with pytest.raises(exc):
            with output_folder(out, command="test") as f:
                f.file("d.txt").write_text("four")
                raise exc()
        assert_complete(out, ["c.txt"])
        assert leftovers(out) == []
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "mine.txt").write_text("keep")
    with pytest.raises(InputError, match="not a transcalib run.*mine.txt.*--force"):
        check_output_folder(foreign)
    with output_folder(foreign, command="test", force=True) as f:
        f.file("e.txt").write_text("five")
    assert_complete(foreign, ["e.txt"])
    with pytest.raises(InputError, match="holds the input"):
        check_output_folder(tmp_path, inputs=[foreign / "e.txt"])
    with pytest.raises(InputError, match="existing file"):
        check_output_folder(foreign / "e.txt", force=True)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert check_output_folder(empty) == empty


# --------------------------------------------------------------------------------------
# every subcommand that writes a folder
# --------------------------------------------------------------------------------------


def cli(*args, capsys=None):
    code = main([str(a) for a in args])
    return code if capsys is None else (code, capsys.readouterr())


def test_every_folder_command_follows_the_rule(tmp_path, capsys):
    scene, out = tmp_path / "scene", tmp_path / "out"
    assert cli("simulate", "--preset", "random", "--points", 30, "--views", 5, "--out", scene, "--json",
               capsys=capsys)[0] == 0
    assert_complete(scene, ["tracks.csv", "poses.csv", "truth.json"])
    calib = ["calibrate", "--tracks", scene / "tracks.csv", "--poses", scene / "poses.csv", "--quiet"]
    assert cli(*calib, "--out", out, "--formats", "json,csv,opencv") == 0
    assert_complete(out, ["calibration.json", "arrays.npz", "points.csv", "camera.yaml"])
    capsys.readouterr()
    code, io = cli(*calib[:-1], "--out", out, "--formats", "json", capsys=capsys)  # fewer formats: nothing stale
    assert code == 0 and "replacing the earlier transcalib run" in io.err
    assert_complete(out, ["calibration.json"])
    assert not (out / "points.csv").exists() and not (out / "camera.yaml").exists()
    img = cv2.GaussianBlur(np.random.default_rng(0).integers(0, 255, (60, 80), dtype=np.uint8), (5, 5), 2)
    cv2.imwrite(str(tmp_path / "a.png"), img)
    assert cli("undistort", tmp_path / "a.png", "--calibration", out, "--out", tmp_path / "und", "--quiet") == 0
    assert_complete(tmp_path / "und", ["a.png"])
    plan = ["plan", "--image-size", "640x480", "--focal-px", 800, "--distance", 1000]
    assert cli(*plan, "--evaluate", scene / "poses.csv", "--out", tmp_path / "ev") == 0
    assert_complete(tmp_path / "ev", ["evaluation.json"])
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    runs = [calib + ["--out", foreign], ["simulate", "--out", foreign],
            ["undistort", tmp_path / "a.png", "--calibration", out, "--out", foreign],
            plan + ["--evaluate", scene / "poses.csv", "--out", foreign]]
    capsys.readouterr()
    for args in runs:  # refused, untouched; then --force replaces it whole
        code, io = cli(*args, "--json", capsys=capsys)
        doc = json.loads(io.out)
        assert code == 2 and doc["exit_code"] == 2 and "not a transcalib run" in doc["error"] and "--force" in io.err
        assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]
    assert cli(*runs[1], "--force") == 0
    assert_complete(foreign, ["tracks.csv"]) and not (foreign / "notes.txt").exists()
    assert leftovers(out) == leftovers(scene) == leftovers(foreign) == []


def test_failed_image_run_leaves_nothing(tmp_path, capsys):
    """A run that fails after the tracking (too few tracks to calibrate) leaves no
    tracks.csv and no folder."""
    blank = np.full((120, 160), 128, np.uint8)
    images = []
    for k in range(4):
        img = blank.copy()
        cv2.circle(img, (40 + 20 * k, 60), 6, 0, -1)  # a single moving blob: nothing to calibrate
        images.append(tmp_path / f"v{k}.png")
        cv2.imwrite(str(images[-1]), img)
    (tmp_path / "poses.csv").write_text("view,x,y,z\n0,0,0,0\n1,10,0,0\n2,0,10,0\n3,0,0,10\n")
    out = tmp_path / "out"
    code, io = cli("calibrate", "--images", *images, "--poses", tmp_path / "poses.csv", "--out", out, "--quiet",
                   capsys=capsys)
    assert code in (2, 3) and "Traceback" not in io.err and io.err.startswith("transcalib: error:")
    assert not out.exists() and leftovers(out) == []


# --------------------------------------------------------------------------------------
# Ctrl-C at 23 moments of calibrate --images
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    """Five 320 x 240 views of the paper's board (target mode: tracked in a tenth of a second)."""
    from transcalib.synth import render

    d = tmp_path_factory.mktemp("board")
    r = render.render_scene("board", n_views=5, image_size=(320, 240), noise_std=1.0, supersample=1, rng=7)
    for i, img in enumerate(r.images):
        cv2.imwrite(str(d / f"v{i}.png"), img)
    (d / "poses.csv").write_text("view,x,y,z\n" + "".join(f"{i},{float(t[0])!r},{float(t[1])!r},{float(t[2])!r}\n"
                                                           for i, t in enumerate(r.T)))
    return ["calibrate", "--images", *sorted(d.glob("v*.png")), "--poses", d / "poses.csv", "--target", "squares",
            "--quiet"]


def _in_command(frame) -> bool:
    """Whether ``frame`` runs inside ``transcalib.cli.main.main``."""
    while frame is not None:
        if frame.f_code is main.__code__:
            return True
        frame = frame.f_back
    return False


class Interrupter:
    """Sends this process a real SIGINT once ``trigger(elapsed_s, n_files)`` holds,
    ``n_files`` being the files in ``out``'s temporary folder; records what the folder
    held at that moment. Signals after the run are ignored (never reach pytest)."""

    def __init__(self, out: Path, trigger):
        self.out, self.trigger, self.armed, self.at = out, trigger, True, None
        self.previous = signal.signal(signal.SIGINT, self._handler)
        self.t0 = time.perf_counter()
        self.thread = threading.Thread(target=self._watch, daemon=True)
        self.thread.start()

    def _files(self) -> int:
        try:
            return sum(1 for t in self.out.parent.glob(f".{self.out.name}.tmp-*") for p in t.rglob("*")
                       if p.is_file())
        except OSError:  # the folder is being renamed or removed as we look
            return 0

    def _watch(self):
        while self.armed:  # sent again until the command takes it
            if self.trigger(time.perf_counter() - self.t0, self._files()):
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.05)
            time.sleep(0.0005)

    def _handler(self, signum, frame):
        if self.armed and _in_command(frame):
            self.armed = False
            self.at = (time.perf_counter() - self.t0, self._files())
            raise KeyboardInterrupt

    def stop(self):
        self.armed = False
        self.thread.join()
        signal.signal(signal.SIGINT, self.previous)


def test_ctrl_c_while_the_temporary_folder_is_made_leaves_nothing(tmp_path, monkeypatch):
    """A Ctrl-C that arrives while the temporary folder is being created (deferred, raised
    once it exists) removes it: before, the folder was made but never named, so it stayed."""
    import transcalib.io.folders as folders

    made = []

    def mkdtemp_then_ctrl_c(**kw):
        made.append(real_mkdtemp(**kw))
        os.kill(os.getpid(), signal.SIGINT)
        return made[-1]

    real_mkdtemp = folders.tempfile.mkdtemp
    monkeypatch.setattr(folders.tempfile, "mkdtemp", mkdtemp_then_ctrl_c)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        with output_folder(out, command="test"):
            pytest.fail("the run must not start after the Ctrl-C")
    assert len(made) == 1 and not Path(made[0]).exists()
    assert leftovers(out) == [] and not out.exists()


#: (formats, trigger): 10 moments at fractions of an uninterrupted run's time (checks,
#: tracking, calibrating, the first files), 13 by the files already in the temporary
#: folder (the writing, the last part of every run); the last 3 with the report, drawn by
#: a second process.
NO_REPORT = "json,csv,opencv,ros,colmap,ply"
MOMENTS = ([(NO_REPORT, ("fraction", f)) for f in (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8)]
           + [(NO_REPORT, ("files", k)) for k in (1, 2, 3, 4, 5, 6, 7, 8, 9, 10)]
           + [("all", ("files", k)) for k in (1, 10, 15)])


def _trigger(kind, value, duration_s):
    if kind == "fraction":
        return lambda t, n: t >= value * duration_s
    return lambda t, n: n >= value


def _interrupted_run(board, out: Path, formats: str, trigger, capsys):
    """One run of ``board`` into ``out`` with a SIGINT once ``trigger`` holds; checks the
    outcome and returns ``(exit status, Interrupter.at)``."""
    replace = out.exists()
    before = read_manifest(out) if replace else None
    stopper = Interrupter(out, trigger)
    try:
        code = cli(*board, "--out", out, "--formats", formats, "--json")
    except KeyboardInterrupt:  # arrived after the command returned: it had finished
        code = 0
    finally:
        stopper.stop()
    io = capsys.readouterr()
    assert "Traceback" not in io.err
    assert code in (0, 130), (code, io.err)
    if code == 130:
        assert json.loads(io.out)["exit_code"] == 130
    assert leftovers(out) == [], leftovers(out)
    if not out.exists():
        assert not replace  # an earlier run is never lost
    else:  # complete: the new run, or the earlier one as it was
        doc = assert_complete(out, ["calibration.json"])
        if code == 130 and stopper.at is not None:  # interrupted before the folder was renamed
            assert doc == before
    return code, stopper.at


def test_interrupted_image_run_leaves_a_complete_folder_or_none(board, tmp_path, capsys):
    earlier = tmp_path / "earlier"
    assert cli(*board, "--out", earlier, "--formats", NO_REPORT) == 0  # the reference run (and warm-up)
    assert len(assert_complete(earlier, ["tracks.csv", "calibration.json", "colmap/points3D.txt"])["files"]) == 10
    t0 = time.perf_counter()
    assert cli(*board, "--out", tmp_path / "timed", "--formats", NO_REPORT) == 0
    duration_s = time.perf_counter() - t0
    capsys.readouterr()
    landed = []
    for k, (formats, (kind, value)) in enumerate(MOMENTS):
        out = tmp_path / f"run{k}"
        if k % 2 == 1:  # every other run replaces an earlier run
            os.rename(earlier, out)
        for _ in range(3):  # a moment the run beat (the machine's load varies): half as late
            code, at = _interrupted_run(board, out, formats, _trigger(kind, value, duration_s), capsys)
            if code == 130 or kind != "fraction":
                break
            value /= 2
        landed.append((code, at))
        if k % 2 == 1:  # the next replacing run starts from a complete earlier run again
            os.rename(out, earlier)
    interrupted = [at for code, at in landed if code == 130]
    writing = [at for at in interrupted if at is None or at[1] > 0]  # None: held during the rename
    print(f"uninterrupted run {duration_s:.3f} s; interrupts (exit, (s after start, files in the temporary "
          "folder)):", landed)
    assert len(interrupted) >= 20 and len(writing) >= 12, landed
    # with the report: interrupted once its files were among those written (more than
    # the 10 of the other formats), or while the complete folder was renamed into place
    assert any(code == 130 and (at is None or at[1] > 10) for code, at in landed[-3:]), landed[-3:]


def test_ctrl_c_of_the_command_in_a_terminal(board, tmp_path):
    """The command as a user runs it: Ctrl-C (SIGINT to the process group, the report
    worker included) while the files are written: exit 130, one JSON document, no
    folder, no worker left."""
    out = tmp_path / "out"
    for _ in range(5):  # a signal that lands after the last file (a loaded machine) is tried again
        shutil.rmtree(out, ignore_errors=True)
        p = subprocess.Popen([sys.executable, "-m", "transcalib", *map(str, board), "--out", str(out), "--json"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                             preexec_fn=default_sigint)
        deadline = time.monotonic() + 120
        while not any(f.is_file() for t in tmp_path.glob(".out.tmp-*") for f in t.rglob("*")):
            assert time.monotonic() < deadline and p.poll() is None, "never started writing"
            time.sleep(0.002)
        os.killpg(p.pid, signal.SIGINT)
        stdout, stderr = p.communicate(timeout=60)
        if p.returncode != 0:
            break
    assert p.returncode == 130, stderr
    assert json.loads(stdout) == {"status": "interrupted", "exit_code": 130, "error": "interrupted"}
    assert "Traceback" not in stderr and "interrupted" in stderr
    assert not out.exists() and leftovers(out) == []
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:  # the group empties: the worker was stopped with the command
        try:
            os.killpg(p.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        pytest.fail("a process of the command outlived it")
