"""``transcalib undistort``: images as the calibrated camera without distortion would take them."""

from __future__ import annotations

from pathlib import Path

from .common import OptionError, Progress, add_output_options, existing_file, print_json

NAME = "undistort"
HELP = "write undistorted copies of images with a saved calibration"


def add_parser(sub) -> None:
    u = sub.add_parser(NAME, help=HELP, description=HELP + ". The output folder is written whole or not at all.")
    g = u.groups()
    g["inputs"].add_argument("images", nargs="+", metavar="IMAGE",
                             help="images taken by the calibrated camera, at its calibrated size")
    g["inputs"].add_argument("--calibration", required=True, metavar="DIR",
                             help="the --out folder of calibrate (or its calibration.json)")
    g["outputs"].add_argument("--out", required=True, metavar="DIR",
                              help="folder for the undistorted images, same names and formats (written whole or "
                                   "not at all)")
    add_output_options(g["outputs"])
    u.set_defaults(func=run)


def _check(args) -> list[Path]:
    """The images, checked: readable, distinct names, none inside ``--out``."""
    images = [existing_file("IMAGE", p) for p in args.images]
    names = [p.name for p in images]
    if len(set(names)) != len(names):
        raise OptionError("IMAGE", "two images have the same file name; they would overwrite each other in --out")
    return images


def run(args) -> int:
    import cv2

    from ..io.calibration_file import load_calibration
    from ..io.folders import check_output_folder, output_folder

    inputs = [args.calibration, *args.images]
    out = check_output_folder(args.out, force=args.force, inputs=inputs)
    images = _check(args)
    camera = load_calibration(args.calibration).camera
    progress = args._progress = Progress(args.quiet)
    with output_folder(out, command=NAME, force=args.force, inputs=inputs) as folder:
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
            folder.file(path.name).write_bytes(data.tobytes())
            written.append(folder.path / path.name)
            progress.step("undistort", k + 1, len(images))
        written = folder.final_paths(written)
    if args.json:
        print_json({"status": "ok", "exit_code": 0, "outputs": [str(p) for p in written]})
    else:
        print(f"Wrote {len(written)} undistorted image(s) and manifest.json to {out}")
    return 0
