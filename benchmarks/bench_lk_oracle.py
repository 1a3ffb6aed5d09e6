"""The sub-pixel alignment against an exact oracle: where its error comes from.

    python benchmarks/bench_lk_oracle.py [--points N] [--noise L,...] [--quick]

:func:`transcalib.images.refine.lk_affine` (the tracker's sub-pixel stage) aligns
windows of a band-limited texture (a sum of cosines below 0.35 cycles per px, so the
image is exact at any sub-pixel position: no renderer, no noise, no interpolation in
the data) into a second image whose content is moved by a known warp ``W``: the second
image is ``I(W^-1(x))`` evaluated exactly, the start is the truth plus 0.2 px of noise
and the warp's exact Jacobian. Per case, over the converged points: ``rms`` the error per
coordinate, ``pull`` the norm of the mean error (alike over the image: what the
calibration absorbs, as a few thousandths of a pixel over a view's ~1000 points weigh on
fx like the pixel noise of every point), ``field`` the RMS over a 4 x 4 grid of
image cells of the cells' mean errors (a smooth error pattern over the image) and
``scale`` the errors' isotropic scale about the image centre (``sum e.r / sum r.r``: a
view's tracks scaled by a few 1e-6 lean a session's fx, docs/uncertainty.md section 6),
each beside what independent errors of the same spread would give. ``--noise`` adds
white noise of those grey levels to both images (independent draws): does the noise
bias the alignment, beyond scattering it?

Cases (640 x 480, f = 660 px, as ``robot_scene``):

- ``shift``: content moved by a sub-pixel amount: OpenCV's bicubic kernel (``a =
  -0.75``, which ``lk_affine`` samples with) does not reproduce a linear ramp; it bends
  every sample by up to 0.048 grey levels per unit gradient with the position's fraction
  of a pixel, so the error depends on the fractions of template and target;
- ``scale 1.06``: a session's view pair (the scale change of a move along the axis);
- ``turn 15 / 30 / 45 deg``: the homography ``K R K^-1`` of a view turned about an axis
  in the image plane (a single view linked to a session): the affine warp leaves the
  homography's curvature to the window's centre, ``-M E_w[o o^T] g`` with ``g`` the
  homography's projective row about the point;
- ``lens, shift 60 px`` and ``lens, turn 30 deg``: the same moves seen through the
  preset's radial lens (k1 -0.06, k2 0.02): the lens's curvature differs where the
  point is seen.

Writes ``benchmarks/results/lk_oracle.md`` (``--quick``: 300 points, a scratch folder).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import md_table, results_dir  # noqa: E402

W, H = 640, 480
K = np.array([[660.0, 0, 320], [0, 660, 240], [0, 0, 1]])
DIST = np.array([-0.06, 0.02, 0.0, 0.0, 0.0])  # robot_scene's preset lens


def band_limited(rng, n: int = 60):
    """``I(x, y)`` exact at any position: cosines below 0.35 cycles/px, grey ~128 +- 40."""
    f = rng.uniform(-0.35, 0.35, (n, 2))
    amp = rng.normal(0, 1, n) * np.exp(-(f**2).sum(1) / (2 * 0.12**2))
    phase = rng.uniform(0, 2 * np.pi, n)

    def texture(x, y):
        out = np.zeros(np.shape(x))
        for (u, v), a, p in zip(f, amp, phase):
            out += a * np.cos(2 * np.pi * (u * x + v * y) + p)
        return (128 + 25 * out).astype(np.float32)
    return texture


def homography(axis, deg: float) -> np.ndarray:
    """``K R K^-1`` turned by ``deg`` about ``axis``, moved so that the image centre stays."""
    Hm = K @ cv2.Rodrigues(np.radians(deg) * np.asarray(axis, float) / np.linalg.norm(axis))[0] @ np.linalg.inv(K)
    c = Hm @ [W / 2, H / 2, 1.0]
    return np.array([[1, 0, W / 2 - c[0] / c[2]], [0, 1, H / 2 - c[1] / c[2]], [0, 0, 1]]) @ Hm


def apply_h(Hm):
    def f(x, y):
        q = np.einsum("ij,j...->i...", Hm, np.stack([x, y, np.ones_like(x)]))
        return q[0] / q[2], q[1] / q[2]
    return f


def through_lens(Hm):
    """The homography ``Hm`` (of undistorted pixels) seen through :data:`DIST`:
    ``W = D(Hm U(x))`` and its inverse ``D(Hm^-1 U(x))``."""
    from transcalib.geometry.camera import pixels_to_rays, project

    def make(A):
        def f(x, y):
            rays = pixels_to_rays(K, np.stack([np.ravel(x), np.ravel(y)], -1), DIST)  # (n, 3), z = 1
            rays = rays @ (np.linalg.inv(K) @ A @ K).T
            uv = project(K, np.eye(3), rays / rays[:, 2:], np.zeros((1, 3)), DIST)[0]
            return uv[:, 0].reshape(np.shape(x)), uv[:, 1].reshape(np.shape(y))
        return f
    return make(Hm), make(np.linalg.inv(Hm))


def jacobian(warp, x, y, h: float = 0.5):
    """``(m, 2, 2)`` central-difference Jacobian of ``warp`` at the points."""
    cols = []
    for dx, dy in ((h, 0.0), (0.0, h)):
        a = np.column_stack(warp(x + dx, y + dy))
        b = np.column_stack(warp(x - dx, y - dy))
        cols.append((a - b) / (2 * h))
    return np.stack(cols, axis=-1)


def run_case(texture, warp, inverse, n_points: int, rng, noise: float = 0.0):
    """Errors ``(m, 2)`` and target positions of the converged points (``noise``: std of
    white noise added to each image, grey levels)."""
    from transcalib.images.refine import SmoothedImages, lk_affine

    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    xs, ys = inverse(xx, yy)
    images = [texture(xx, yy), texture(xs, ys)]
    if noise > 0:
        images = [im + rng.normal(0.0, noise, im.shape) for im in images]
    sm = SmoothedImages(images)
    pts = np.column_stack([rng.uniform(40, W - 40, 4 * n_points), rng.uniform(40, H - 40, 4 * n_points)])
    truth = np.column_stack(warp(pts[:, 0], pts[:, 1]))
    inside = (truth[:, 0] > 40) & (truth[:, 0] < W - 40) & (truth[:, 1] > 40) & (truth[:, 1] < H - 40)
    pts, truth = pts[inside][:n_points], truth[inside][:n_points]
    M0 = jacobian(warp, pts[:, 0], pts[:, 1])
    start = truth + rng.normal(0, 0.2, truth.shape)
    p, _, _, _, conv = lk_affine(sm.plain(0), sm[1], pts, start, M0, 8, 24)
    return (p - truth)[conv], truth[conv]


def field_rms(err, at, cells: int = 4) -> tuple[float, float]:
    """RMS over a ``cells x cells`` grid of the cells' mean errors (cells with >= 10
    points), and what independent errors of the same RMS would give (``rms / sqrt(n)``)."""
    ci = (np.clip((at[:, 0] / W * cells).astype(int), 0, cells - 1) * cells
          + np.clip((at[:, 1] / H * cells).astype(int), 0, cells - 1))
    groups = [err[ci == c] for c in range(cells * cells) if (ci == c).sum() >= 10]
    means = np.array([g.mean(0) for g in groups])
    white = np.mean([np.sum(g.var(0)) / len(g) for g in groups])
    return float(np.sqrt(np.mean(np.sum(means**2, axis=1)))), float(np.sqrt(white))


def scale_about_centre(err, at) -> tuple[float, float]:
    """The errors' isotropic scale about the image centre, ``sum e.r / sum r.r`` (``r`` the
    position from the centre), and its std under independent errors of the same spread."""
    r = at - [(W - 1) / 2, (H - 1) / 2]
    rr = np.sum(r * r)
    return float(np.sum(err * r) / rr), float(np.sqrt(np.sum(err.var(0) * np.sum(r * r, axis=0))) / rr)


def cases():
    shift = np.array([3.37, -1.71])
    out = {"shift (3.37, -1.71) px": ((lambda x, y: (x + shift[0], y + shift[1])),
                                      (lambda x, y: (x - shift[0], y - shift[1]))),
           "scale 1.06": ((lambda x, y: (W / 2 + 1.06 * (x - W / 2), H / 2 + 1.06 * (y - H / 2))),
                          (lambda x, y: (W / 2 + (x - W / 2) / 1.06, H / 2 + (y - H / 2) / 1.06)))}
    for deg in (15, 30, 45):
        Hm = homography((0.8, 0.6, 0.0), deg)
        out[f"turn {deg} deg"] = (apply_h(Hm), apply_h(np.linalg.inv(Hm)))
    out["lens, shift 60 px"] = through_lens(np.array([[1, 0, 48.0], [0, 1, 36.0], [0, 0, 1]]))
    out["lens, turn 30 deg"] = through_lens(homography((0.8, 0.6, 0.0), 30))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1500, help="points per case")
    ap.add_argument("--noise", default="0", help="white noise added to both images, grey levels (comma-separated)")
    ap.add_argument("--quick", action="store_true", help="300 points per case, written to a scratch folder")
    a = ap.parse_args(argv)
    if a.quick:
        a.points = 300
    try:
        levels = [float(v) for v in a.noise.split(",")]
    except ValueError:
        ap.error(f"--noise: comma-separated grey levels, got {a.noise!r}")
    if any(v < 0 for v in levels):
        ap.error(f"--noise: levels must be >= 0, got {a.noise!r}")
    t0 = time.perf_counter()
    rows = []
    for name, (warp, inverse) in cases().items():
        for noise in levels:
            rng = np.random.default_rng(0)
            texture = band_limited(rng)
            err, at = run_case(texture, warp, inverse, a.points, rng, noise)
            rms = np.sqrt((err**2).mean(0))
            field, white = field_rms(err, at)
            kappa, kappa_white = scale_about_centre(err, at)
            rows.append([name, noise, len(err), float(rms[0]), float(rms[1]), float(np.linalg.norm(err.mean(0))),
                         float(np.sqrt(np.sum(err.var(0)) / len(err))), field, white, f"{kappa * 1e6:+.2f}",
                         f"{kappa_white * 1e6:.2f}"])
    text = "\n".join([
        "# The sub-pixel alignment against an exact oracle", "",
        f"`python benchmarks/bench_lk_oracle.py --points {a.points} --noise {a.noise}` "
        f"({time.perf_counter() - t0:.0f} s). "
        "`lk_affine` (17 x 17 window, the tracker's settings) on a band-limited texture moved by an exact warp "
        "(no renderer; noise: white noise of that std, grey levels, added to both images); errors against the "
        "truth over the converged points. pull: norm of the mean error (alike over the image); field: RMS of "
        "the mean errors of a 4 x 4 grid of image cells; scale: the errors' isotropic scale about the image "
        "centre (1e-6); (white): what independent errors of the same spread would give each.", "",
        md_table(["case", "noise", "points", "rms x px", "rms y px", "pull px", "pull (white) px", "field px",
                  "field (white) px", "scale 1e-6", "scale (white) 1e-6"], rows), ""])
    out = results_dir(a.quick) / "lk_oracle.md"
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
