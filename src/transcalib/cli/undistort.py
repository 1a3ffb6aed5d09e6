"""``transcalib undistort``: images as the calibrated camera without distortion would take them."""

from __future__ import annotations

from pathlib import Path

from .common import OptionError, Progress, existing_file, print_json

NAME = "undistort"
HELP = "write undistorted copies of images with a saved calibration"


def add_parser(sub) -> None:
    u = sub.add_parser(NAME, help=HELP, description=HELP)
    u.add_argument("images", nargs="+", metavar="IMAGE")
    u.add_argument("--calibration", required=True, metavar="DIR", help="the --out folder of calibrate")
    u.add_argument("--out", required=True, metavar="DIR", help="folder for the undistorted images")
    u.add_argument("--json", action="store_true", help="print a machine-readable summary on stdout")
    u.add_argument("--quiet", action="store_true")
    u.set_defaults(func=run)


def run(args) -> int:
    import cv2

    from ..io import atomic_write, check_writable_dir
    from ..io.calibration_file import load_calibration

    out = check_writable_dir(args.out, "--out")
    images = [existing_file("IMAGE", p) for p in args.images]
    clash = [p for p in images if (out / p.name).resolve() == p.resolve()]
    if clash:
        raise OptionError("--out", f"would overwrite the input image {str(clash[0])!r}; give another folder")
    names = [p.name for p in images]
    if len(set(names)) != len(names):
        raise OptionError("IMAGE", "two images have the same file name; they would overwrite each other in --out")
    camera = load_calibration(args.calibration).camera
    progress = args._progress = Progress(args.quiet)
    written = []
    for k, path in enumerate(images):
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise OptionError("IMAGE", f"{str(path)!r} is not an image OpenCV can read")
        if camera.image_size is not None and (img.shape[1], img.shape[0]) != tuple(camera.image_size):
            raise OptionError("IMAGE", f"{str(path)!r} is {img.shape[1]}x{img.shape[0]} px but the camera was "
                              f"calibrated at {camera.image_size[0]}x{camera.image_size[1]}")
        ok, data = cv2.imencode(Path(path).suffix or ".png", camera.undistort_image(img))
        if not ok:
            raise OptionError("IMAGE", f"cannot encode {str(path)!r} in its format")
        with atomic_write(out / path.name, "wb") as fh:
            fh.write(data.tobytes())
        written.append(out / path.name)
        progress.step("undistort", k + 1, len(images))
    if args.json:
        print_json({"status": "ok", "exit_code": 0, "outputs": [str(p) for p in written]})
    else:
        print(f"Wrote {len(written)} undistorted image(s) to {out}")
    return 0
