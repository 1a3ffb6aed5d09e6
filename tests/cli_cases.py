"""Bad and unusual command lines, one per case, across every subcommand (issue 24): the
exit status each must give and words its one-line message must hold.

Used by ``tests/test_cli_cases.py`` (in-process, with and without ``--json``) and by
``docs/make_cli_cases.py``, which runs each as a user would (a subprocess) and writes the
table of ``docs/cli-cases.md``. ``make_workspace(root)`` writes the files the cases name;
in a case, ``{name}`` is a path in that workspace.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Case:
    """``transcalib`` + ``line`` must exit ``code`` with ``words`` in its message."""

    line: str
    code: int
    words: tuple = ()

    def argv(self, root: Path) -> list[str]:
        return [w.format_map(_Paths(root)) for w in shlex.split(self.line)]


class _Paths(dict):
    def __init__(self, root: Path):
        super().__init__()
        self.root = root

    def __missing__(self, key):
        return str(self.root / key)


C = Case
S = "--tracks {scene}/tracks.csv --poses {scene}/poses.csv"  # a good tracks + poses pair
B = "--images {board}/v0.png {board}/v1.png {board}/v2.png {board}/v3.png {board}/v4.png --poses {board}/poses.csv"
P = "plan --image-size 640x480 --focal-px 800 --distance 1000"

CASES = [
    # --- the command itself
    C("", 2, ("required",)),
    C("calibrat --out x", 2, ("invalid choice", "calibrate")),
    C("calibrate", 2, ("required",)),
    # --- calibrate: inputs
    C(f"calibrate --tracks {{missing}}.csv --poses {{scene}}/poses.csv --out {{o}}", 2, ("--tracks", "does not exist")),
    C(f"calibrate --tracks {{scene}} --poses {{scene}}/poses.csv --out {{o}}", 2, ("--tracks", "not a file")),
    C(f"calibrate --tracks {{scene}}/tracks.csv --poses {{missing}}.csv --out {{o}}", 2, ("--poses", "does not exist")),
    C(f"calibrate {S} --images {{board}}/v0.png --out {{o}}", 2, ("--images", "not allowed with")),
    C(f"calibrate --tracks {{empty}}.csv --poses {{scene}}/poses.csv --out {{o}}", 2, ("empty",)),
    C(f"calibrate --tracks {{badheader}}.csv --poses {{scene}}/poses.csv --out {{o}}", 2, ("column",)),
    C(f"calibrate --tracks {{nan_uv}}.csv --poses {{scene}}/poses.csv --out {{o}}", 2, ("line",)),
    C(f"calibrate --tracks {{scene}}/tracks.csv --poses {{poses3}}.csv --out {{o}}", 2, ("view",)),
    C(f"calibrate --tracks {{scene}}/tracks.csv --poses {{poses_text}}.csv --out {{o}}", 2, ("line", "x")),
    C(f"calibrate --tracks {{scene}}/tracks.csv --poses {{empty}}.csv --out {{o}}", 2, ("empty",)),
    C(f"calibrate --tracks {{scene}}/tracks.csv --poses {{poses_dup}}.csv --out {{o}}", 2, ("view",)),
    C(f"calibrate --tracks {{scene}}/tracks.csv --poses {{poses_flat}}.csv --out {{o}}", 3, ("principal point",)),
    C(f"calibrate {S} --rotation-format quaternion --out {{o}}", 2, ("qx",)),
    C(f"calibrate {S} --truth {{missing}}.json --out {{o}}", 2, ("--truth", "does not exist")),
    C(f"calibrate {S} --truth {{scene}}/poses.csv --out {{o}}", 2, ("--truth", "not a truth.json")),
    C(f"calibrate {S} --image-size 100x100 --out {{o}}", 2, ("--image-size", "100x100", "tracks reach")),
    C(f"calibrate {S} --image-size 640 --out {{o}}", 2, ("--image-size", "WIDTHxHEIGHT")),
    C(f"calibrate {S} --image-size 0x480 --out {{o}}", 2, ("--image-size",)),
    C(f"calibrate {S} --target squares --out {{o}}", 2, ("--target", "--images")),
    C(f"calibrate {B} --image-size 640x480 --out {{o}}", 2, ("--image-size", "320x240")),
    C("calibrate --images {board}/v0.png {board}/v0.png {board}/v0.png {board}/v0.png --poses {board}/poses4.csv "
      "--out {o}", 2, ("--images", "same file")),
    C("calibrate --images {board}/v0.png {board}/copy0.png {board}/v2.png {board}/v3.png --poses {board}/poses4.csv "
      "--out {o}", 2, ("--images", "identical images")),
    C("calibrate --images {board}/v0.png {board}/v1.png {board}/v2.png {board}/v3.png --poses {board}/poses.csv "
      "--out {o}", 2, ("--images", "4 images but 5 poses")),
    C("calibrate --images {notimage}.png {board}/v1.png {board}/v2.png {board}/v3.png --poses {board}/poses4.csv "
      "--out {o}", 2, ("--images", "not an image")),
    # --- calibrate: model and robust options
    C(f"calibrate {S} --fix k1=0.1 --out {{o}}", 2, ("--fix", "k1", "--distortion")),
    C(f"calibrate {S} --fix k2=0.1 --distortion radial1 --out {{o}}", 2, ("--fix", "k2", "radial2")),
    C(f"calibrate {S} --fix cx=400,cx=410 --out {{o}}", 2, ("--fix", "cx", "twice")),
    C(f"calibrate {S} --fix cx=400,principal-point=centre --image-size 800x600 --out {{o}}", 2, ("--fix", "twice")),
    C(f"calibrate {S} --fix focal=800 --out {{o}}", 2, ("--fix", "unknown parameter")),
    C(f"calibrate {S} --fix cx --out {{o}}", 2, ("--fix", "NAME=VALUE")),
    C(f"calibrate {S} --fix cx=abc --out {{o}}", 2, ("--fix", "not a number")),
    C(f"calibrate {S} --fix fx=-5 --out {{o}}", 2, ("--fix", "fx")),
    C(f"calibrate {S} --fix principal-point=centre --out {{o}}", 2, ("--fix", "image size")),
    C(f"calibrate {S} --estimate-skew --fix skew=0 --out {{o}}", 2, ("--estimate-skew", "skew")),
    C(f"calibrate {S} --distortion fisheye --out {{o}}", 2, ("--distortion", "invalid choice")),
    C(f"calibrate {S} --no-refine --distortion radial2 --out {{o}}", 2, ("--no-refine",)),
    C(f"calibrate {S} --no-refine --robot-sigma 0.1 --out {{o}}", 2, ("--robot-sigma", "--no-refine")),
    C(f"calibrate {S} --robot-sigma -1 --out {{o}}", 2, ("--robot-sigma", ">= 0")),
    C(f"calibrate {S} --threshold-px -1 --out {{o}}", 2, ("--threshold-px", "positive")),
    C(f"calibrate {S} --threshold-px nan --out {{o}}", 2, ("--threshold-px", "finite")),
    C(f"calibrate {S} --session-tolerance-deg 0 --out {{o}}", 2, ("--session-tolerance-deg",)),
    C(f"calibrate {S} --setup sideways --out {{o}}", 2, ("--setup", "invalid choice")),
    C(f"calibrate {S} --subset-points 10 --out {{o}}", 2, ("--subset-points", "at least")),
    C(f"calibrate {S} --seed abc --out {{o}}", 2, ("--seed",)),
    C(f"calibrate {S} --robust --no-robust --out {{o}}", 2, ("--no-robust", "not allowed with")),
    C(f"calibrate {S} --formats json,pdf --out {{o}}", 2, ("--formats", "pdf")),
    C(f"calibrate {S} --out {{o}} --vebose", 2, ("unrecognized arguments", "--vebose")),
    # --- calibrate: the output folder
    C(f"calibrate {S} --out {{scene}}/tracks.csv", 2, ("--out", "existing file")),
    C(f"calibrate {S} --out {{scene}}/tracks.csv/sub", 2, ("--out", "is a file")),
    C(f"calibrate {S} --out {{foreign}}", 2, ("--out", "not a transcalib run", "--force")),
    C(f"calibrate {S} --out {{scene}}", 2, ("--out", "holds the input")),
    C(f"calibrate {S} --out {{oldstyle}}", 2, ("--out", "older transcalib", "--force")),
    # --- simulate
    C("simulate --points 100000 --out {o}", 2, ("--points", "--preset random")),
    C("simulate --preset random --views 3 --out {o}", 2, ("--views", "at least 4")),
    C("simulate --preset random --missing 1.5 --out {o}", 2, ("--missing", "[0, 1)")),
    C("simulate --noise-px -1 --out {o}", 2, ("--noise-px", ">= 0")),
    C("simulate --preset spiral --out {o}", 2, ("--preset", "invalid choice")),
    C("simulate --preset random --sessions 2 --out {o}", 2, ("--sessions", "--preset robot")),
    C("simulate --preset paper --robot-sigma-deg 0.1 --out {o}", 2, ("--robot-sigma-deg", "--preset robot")),
    C("simulate --preset random --points 1 --out {o}", 2, ("--points", "at least 2")),
    C("simulate --preset robot --sessions 0 --out {o}", 2, ("--sessions",)),
    C("simulate --out {scene}/tracks.csv", 2, ("--out", "existing file")),
    C("simulate --out {foreign}", 2, ("--out", "not a transcalib run")),
    C("simulate", 2, ("--out", "required")),
    # --- extract
    C("extract --out {o}", 2, ("--bag", "required")),
    C("extract --bag {missing}.mcap --image-topic /cam --base-frame base --flange-frame tool0 --out {o}", 2,
      ("--bag",)),
    C("extract --bag {empty}.csv --image-topic /cam --base-frame base --flange-frame tool0 --out {o}", 2, ("--bag",)),
    C("extract --bag {missing}.mcap --out {o}", 2, ("--image-topic", "required with --bag")),
    C("extract --bag {missing}.mcap --image-topic /cam --base-frame base --flange-frame tool0 --out {foreign}", 2,
      ("--out", "not a transcalib run")),
    # --- track
    C("track {board}/v0.png {board}/v0.png {board}/v0.png {board}/v0.png -o {o}.csv", 2, ("IMAGE", "same file")),
    C("track {board}/v0.png {board}/v1.png -o {scene}", 2, ("-o/--output", "is a folder")),
    C("track {board}/v0.png {board}/v1.png -o {o}.txt", 2, ("-o/--output", ".csv")),
    C("track {missing}.png {board}/v1.png -o {o}.csv", 2, ("IMAGE", "does not exist")),
    C("track {notimage}.png {board}/v1.png -o {o}.csv", 2, ("not an image",)),
    C("track {board}/v0.png -o {o}.csv", 2, ("at least 2",)),
    C("track {board}/v0.png {board}/v1.png -o {board}/v1.png", 2, ("-o/--output",)),
    # --- show
    C("show {missing}", 2, ("does not exist",)),
    C("show {foreign}", 2, ("calibration.json",)),
    C("show {corrupt}", 2, ("calibration.json",)),
    # --- undistort
    C("undistort {board}/v0.png --calibration {cal} --out {o}", 2, ("IMAGE", "calibrated at")),
    C("undistort {board}/v0.png --calibration {missing} --out {o}", 2, ("does not exist",)),
    C("undistort {notimage}.png --calibration {cal} --out {o}", 2, ("not an image",)),
    C("undistort {board}/v0.png --calibration {cal} --out {board}", 2, ("--out", "holds the input")),
    C("undistort {board}/v0.png {board}/v0.png --calibration {cal} --out {o}", 2, ("same file name",)),
    # --- validate
    C("validate --calibration {cal} --tracks {scene}/tracks.csv", 2, ("--poses", "required")),
    C("validate --calibration {missing} --tracks {scene}/tracks.csv --poses {scene}/poses.csv", 2,
      ("does not exist",)),
    C("validate --calibration {cal} --tracks {missing}.csv --poses {scene}/poses.csv", 2, ("does not exist",)),
    C("validate --calibration {cal} --tracks {scene}/tracks.csv --poses {poses_text}.csv", 2, ("line 3",)),
    C("dense --calibration {cal} --images {board}/v0.png --poses {board}/poses.csv --out {o}", 2,
      ("--images", "1 images but 5 poses")),
    C("dense --calibration {missing} " + B + " --out {o}", 2, ("--calibration",)),
    C("dense --calibration {cal} " + B + " --out {o} --depth-limits 900,100", 2, ("--depth-limits", "NEAR < FAR")),
    C("dense --calibration {cal} " + B + " --out {o} --reference-view 9", 2, ("--reference-view", "9 not in")),
    C("dense --calibration {cal} " + B + " --out {o}", 2, ("--images", "calibrated at 800x600")),
    # --- plan
    C(f"{P} --box 0,0,0,0,0,0 --views 6 --out {{o}}", 2, ("--box", "xmin must be below xmax")),
    C(f"{P} --box 1,2,3 --views 6 --out {{o}}", 2, ("--box", "6 numbers")),
    C(f"{P} --box -200,200,-200,200,0,x --views 6 --out {{o}}", 2, ("--box", "number")),
    C("plan --image-size 640 --focal-px 800 --distance 1000 --evaluate {scene}/poses.csv", 2, ("--image-size",)),
    C("plan --image-size 640x480 --focal-px -800 --distance 1000 --evaluate {scene}/poses.csv", 2,
      ("--focal-px", "positive")),
    C(f"{P} --box -200,200,-200,200,0,300 --views 3 --out {{o}}", 2, ("--views", "4..50")),
    C(f"{P} --views 6 --out {{o}}", 2, ("--box", "planning needs")),
    C(f"{P} --evaluate {{missing}}.csv", 2, ("--evaluate", "does not exist")),
    C(f"{P} --depth-range 5000 --evaluate {{scene}}/poses.csv", 2, ("--depth-range",)),
    C(f"{P} --dist-coeffs 0.1,0.2,0.3 --evaluate {{scene}}/poses.csv", 2, ("--dist-coeffs",)),
    C(f"{P} --view-direction up --evaluate {{scene}}/poses.csv", 2, ("--view-direction",)),
    C(f"{P} --min-visible 2 --evaluate {{scene}}/poses.csv", 2, ("--min-visible",)),
    C(f"{P} --box -200,200,-200,200,0,300 --views 6 --evaluate {{scene}}/poses.csv", 2,
      ("--views", "--evaluate")),
    C(f"{P} --box -200,200,-200,200,0,300 --views 6 --out {{foreign}}", 2, ("--out", "not a transcalib run")),
]


def make_workspace(root: Path) -> Path:
    """Write the files the cases name under ``root`` (a few hundred kilobytes, a second)."""
    import cv2

    from transcalib.cli.main import main
    from transcalib.synth import render

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    assert main(["simulate", "--preset", "random", "--points", "30", "--views", "5", "--noise-px", "0.3",
                 "--seed", "1", "--out", str(root / "scene"), "--json"]) == 0
    assert main(["calibrate", "--tracks", str(root / "scene/tracks.csv"), "--poses", str(root / "scene/poses.csv"),
                 "--formats", "json", "--image-size", "800x600", "--out", str(root / "cal"), "--quiet",
                 "--json"]) == 0
    board = root / "board"
    board.mkdir()
    r = render.render_scene("board", n_views=5, image_size=(320, 240), noise_std=1.0, supersample=1, rng=7)
    for i, img in enumerate(r.images):
        cv2.imwrite(str(board / f"v{i}.png"), img)
    (board / "copy0.png").write_bytes((board / "v0.png").read_bytes())
    rows = [f"{i},{float(t[0])!r},{float(t[1])!r},{float(t[2])!r}" for i, t in enumerate(r.T)]
    (board / "poses.csv").write_text("view,x,y,z\n" + "\n".join(rows) + "\n")
    (board / "poses4.csv").write_text("view,x,y,z\n" + "\n".join(rows[:4]) + "\n")
    poses = (root / "scene/poses.csv").read_text().splitlines()
    (root / "poses3.csv").write_text("\n".join(poses[:4]) + "\n")
    (root / "poses_text.csv").write_text("\n".join([poses[0], poses[1], "1,ten,0,0", *poses[3:]]) + "\n")
    (root / "poses_dup.csv").write_text("\n".join([*poses, poses[2]]) + "\n")
    flat = ["view,x,y,z"] + [f"{i},{x},{y},0" for i, (x, y) in enumerate([(0, 0), (50, 0), (0, 50), (50, 50), (25, 10)])]
    (root / "poses_flat.csv").write_text("\n".join(flat) + "\n")
    (root / "empty.csv").write_text("")
    (root / "badheader.csv").write_text("frame,id,x,y\n0,0,1,2\n")
    tracks = (root / "scene/tracks.csv").read_text().splitlines()
    (root / "nan_uv.csv").write_text("\n".join([tracks[0], tracks[1], "0,1,abc,3", *tracks[3:]]) + "\n")
    (root / "notimage.png").write_text("not an image\n")
    (root / "foreign").mkdir()
    (root / "foreign/notes.txt").write_text("mine\n")
    (root / "oldstyle").mkdir()
    (root / "oldstyle/calibration.json").write_text("{}\n")
    (root / "corrupt").mkdir()
    (root / "corrupt/calibration.json").write_text("{not json\n")
    return root
