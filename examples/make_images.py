"""Render the bundled image example: ``examples/images/``.

Five 800 x 600 views of a textured scene (a wall with natural texture, a checkerboard,
the paper's board of six black squares and a textured box) taken by a camera with
non-square pixels and an off-centre principal point, translated by a robot in mm.

Writes ``view0.png`` ... ``view4.png``, ``poses.csv`` (``view,x,y,z,image``: exact robot
translations in mm and the image file of each view) and ``truth.json``
(``Scene.truth_dict()``: K, R, dist, T_true, the 3-D corners of the checkerboard and the
board, image size, units). Deterministic: run it again to get the same files.

    python examples/make_images.py [OUT_DIR]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2

from transcalib.synth import render


def main(out: str | Path | None = None) -> Path:
    out = Path(out) if out is not None else Path(__file__).resolve().parent / "images"
    out.mkdir(parents=True, exist_ok=True)
    r = render.render_scene("mixed", n_views=5, image_size=(800, 600), distance=1000.0, baseline=0.12,
                            noise_std=1.0, brightness=0.1, rng=2024)
    names = []
    for i, img in enumerate(r.images):
        name = f"view{i}.png"
        if not cv2.imwrite(str(out / name), img, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
            raise OSError(f"could not write {out / name}")
        names.append(name)
    rows = ["view,x,y,z,image"] + [f"{i},{t[0]:.6f},{t[1]:.6f},{t[2]:.6f},{n}" for i, (t, n) in enumerate(zip(r.T, names))]
    (out / "poses.csv").write_text("\n".join(rows) + "\n")
    truth = r.scene().truth_dict()
    truth["scene"] = "rendered: wall (natural texture), checkerboard, paper board, textured box"
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return out


if __name__ == "__main__":
    print(main(sys.argv[1] if len(sys.argv) > 1 else None))
