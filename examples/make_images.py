"""Render the bundled image example: ``examples/images/``.

Five 800 x 600 views of a textured scene (a wall with natural texture, a checkerboard,
the paper's board of six black squares and a textured box) taken by a camera with
non-square pixels and an off-centre principal point, translated by a robot in mm.

Writes ``view0.png`` ... ``view4.png``, ``poses.csv`` (``view,x,y,z,image``: exact robot
translations in mm and the image file of each view) and ``truth.json``
(``Scene.truth_dict()``: K, R, dist, T_true, the 3-D corners of the checkerboard and the
board, image size, units). Deterministic: run it again to get the same files.

    python examples/make_images.py [OUT_DIR]
    python examples/make_images.py --realistic [OUT_DIR]

``--realistic`` renders the same scene through a real camera instead
(:data:`transcalib.synth.degrade.REALISTIC`: lens distortion k1 = -0.12, vignetting,
per-view exposure, shot + read noise, a specular highlight, a burnt-in timestamp) and
writes JPEG files (quality 85) ``view0.jpg`` ... to ``examples/images-realistic/`` by
default.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from dataclasses import replace

import cv2
import numpy as np

from transcalib.synth import render
from transcalib.synth.degrade import REALISTIC


def main(out: str | Path | None = None, realistic: bool = False) -> Path:
    here = Path(__file__).resolve().parent
    out = Path(out) if out is not None else here / ("images-realistic" if realistic else "images")
    out.mkdir(parents=True, exist_ok=True)
    if realistic:  # the JPEG is written by cv2.imwrite below, at the same quality
        r = render.render_scene("mixed", n_views=5, image_size=(800, 600), distance=1000.0, baseline=0.12,
                                noise_std=0.0, dist=np.array([-0.12, 0.03, 0.0, 0.0, 0.0]),
                                degrade=replace(REALISTIC, jpeg_quality=None), rng=2024)
    else:
        r = render.render_scene("mixed", n_views=5, image_size=(800, 600), distance=1000.0, baseline=0.12,
                                noise_std=1.0, brightness=0.1, rng=2024)
    names = []
    for i, img in enumerate(r.images):
        name = f"view{i}.jpg" if realistic else f"view{i}.png"
        params = [cv2.IMWRITE_JPEG_QUALITY, REALISTIC.jpeg_quality] if realistic else [cv2.IMWRITE_PNG_COMPRESSION, 9]
        if not cv2.imwrite(str(out / name), img, params):
            raise OSError(f"could not write {out / name}")
        names.append(name)
    rows = ["view,x,y,z,image"] + [f"{i},{t[0]:.6f},{t[1]:.6f},{t[2]:.6f},{n}" for i, (t, n) in enumerate(zip(r.T, names))]
    (out / "poses.csv").write_text("\n".join(rows) + "\n")
    truth = r.scene().truth_dict()
    truth["scene"] = "rendered: wall (natural texture), checkerboard, paper board, textured box"
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return out


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--realistic"]
    print(main(args[0] if args else None, realistic="--realistic" in sys.argv[1:]))
