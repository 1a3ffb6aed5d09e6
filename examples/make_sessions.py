"""Render the sessions examples: ``examples/sessions2/`` and ``examples/sessions3/``.

A camera on a robot flange (``R_X``, ``t_X`` of :mod:`transcalib.handeye.simulate`, K for
400 x 300 images) looks from ~0.5 m down at a table top (a textured table, a checkerboard
and two textured boxes, robot base frame, mm). Each session is one wrist orientation
(tilted 35 deg about base x, then y) with 2-axis moves (six points of a 120 x 120 mm square in the base
xy plane): no session alone determines K, together they do.

Writes ``view*.png``, ``poses.csv`` (``view,x,y,z,qx,qy,qz,qw,session,image``: flange
poses in the base frame, ROS quaternions, mm) and ``truth.json`` (K, R_X, t_X, image
size, units). Deterministic.

    python examples/make_sessions.py [OUT_ROOT]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

from transcalib.geometry.rotation import matrix_to_quaternion, rotvec_to_matrix
from transcalib.handeye.simulate import DEFAULT_R_X, DEFAULT_T_X, flange_rotations_looking
from transcalib.synth import render

K = np.array([[430.0, 0.0, 203.0], [0.0, 425.0, 147.0], [0.0, 0.0, 1.0]])
IMAGE_SIZE = (400, 300)
MOVES = np.array([[0, 0, 0], [120, 0, 0], [120, 120, 0], [0, 120, 0], [60, 60, 0], [60, 0, 0]], float) - [60, 60, 0]
TILT_DEG = 35.0
TILTS = [np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0])]


def surfaces(seed: int = 11):
    """The table-top scene (base frame, mm) and the checkerboard's inner corners."""
    up = np.eye(3)
    sf = [render.plane([0, 0, 0], up, (700, 600), render.Noise(1.6, (700, 600), seed), "table")]
    board, corners = render.checker_board([-60, 40, 0.5], up, 20.0, 8, 6, margin=0.5)
    sf.append(board)
    for b, (c, dims) in enumerate([([90, -60, 40], [70, 60, 80]), ([-110, -90, 25], [60, 80, 50])]):
        tex = [render.Noise(1.2, (100, 100), seed + 10 * b + f) for f in range(6)]
        sf += render.box(c, rotvec_to_matrix(np.radians([0, 0, 20.0 * (b + 1)])), dims, tex, f"box{b}")
    return sf, corners


def poses(n_sessions: int):
    """Flange rotations ``(n, 3, 3)``, positions ``(n, 3)`` and session of each view."""
    dirs = [rotvec_to_matrix(np.radians(TILT_DEG) * TILTS[s]) @ [0, 0, -1.0] for s in range(n_sessions)]
    Rs = flange_rotations_looking(np.array(dirs), DEFAULT_R_X)
    R, T, sess = [], [], []
    for s, Rf in enumerate(Rs):
        C0 = np.array([0.0, 0.0, 30.0]) - 500.0 * (Rf @ DEFAULT_R_X)[:, 2]
        for d in MOVES:
            R.append(Rf)
            T.append(C0 - Rf @ DEFAULT_T_X + d)
            sess.append(s)
    return np.array(R), np.array(T), np.array(sess)


def rendered_sessions(n_sessions: int, with_images: bool = True, rng=2026):
    """One :class:`transcalib.synth.render.Rendered` per session (images optional)."""
    sf, corners = surfaces()
    R, T, sess = poses(n_sessions)
    rng = np.random.default_rng(rng)
    out = []
    for s in range(n_sessions):
        v = sess == s
        Rc = (R[v][0] @ DEFAULT_R_X).T
        C = T[v] + R[v] @ DEFAULT_T_X
        images = (render.render(sf, K, Rc, C, IMAGE_SIZE, supersample=2, noise_std=1.0, rng=rng) if with_images
                  else np.zeros((int(v.sum()), 1, 1), np.uint8))
        out.append(render.Rendered(images=images, K=K, R=Rc, dist=np.zeros(0), T=C, surfaces=sf, corners=corners,
                                   corner_kind=np.array(["checker"] * len(corners), dtype=object),
                                   image_size=IMAGE_SIZE))
    return out


def main(root: str | Path | None = None) -> list[Path]:
    root = Path(root) if root is not None else Path(__file__).resolve().parent
    made = []
    for n in (2, 3):
        out = root / f"sessions{n}"
        out.mkdir(parents=True, exist_ok=True)
        R, T, sess = poses(n)
        rows, k = ["view,x,y,z,qx,qy,qz,qw,session,image"], 0
        for r in rendered_sessions(n):
            for img in r.images:
                name = f"view{k:02d}.png"
                if not cv2.imwrite(str(out / name), img, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
                    raise OSError(f"could not write {out / name}")
                q = matrix_to_quaternion(R[k])
                rows.append(f"{k},{T[k, 0]:.6f},{T[k, 1]:.6f},{T[k, 2]:.6f},{q[0]:.9f},{q[1]:.9f},{q[2]:.9f},"
                            f"{q[3]:.9f},{sess[k]},{name}")
                k += 1
        (out / "poses.csv").write_text("\n".join(rows) + "\n")
        truth = {"K": K.tolist(), "R_flange_camera": DEFAULT_R_X.tolist(), "t_flange_camera": DEFAULT_T_X.tolist(),
                 "dist": [], "image_size": list(IMAGE_SIZE), "unit": "mm", "n_sessions": n,
                 "scene": "table top: textured table, checkerboard (20 mm), two textured boxes; base frame z up",
                 "model": "x ~ K (R_i R_X)^T (X - T_i - R_i t_X); R_i, T_i the flange pose in the base frame"}
        (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
        made.append(out)
    return made


if __name__ == "__main__":
    for p in main(sys.argv[1] if len(sys.argv) > 1 else None):
        print(p)
