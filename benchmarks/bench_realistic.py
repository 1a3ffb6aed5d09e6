"""Realistic images end to end: each camera degradation alone and all together.

    python benchmarks/bench_realistic.py [--quick]    (--quick: 480 x 360, 5 views)

Renders the ``mixed`` scene (the ``repetitive`` scene for that row) with 5 views of
640 x 480, one degradation of :mod:`transcalib.synth.degrade` at a time (``all``:
every one plus lens distortion, on the mixed and on the repetitive scene; rows ``+ T``
track with the robot translations, ``track(images, T=T)``), tracks with ``track()`` and calibrates with the **default**
options of ``calibrate(tracks.uv, T)``. Columns: relative error of fx, fy (%), error
of cx, cy (px), rotation error (deg), the distortion model chosen (``cal.dist_model``),
the number of tracks, how many of them do not move (the burnt-in overlay's; should be
0), how many come within two highlight radii of the specular highlight (scene points
that the highlight passes over; their errors are in the next columns), how many static
tracks the tracker dropped (``Tracks.info.n_static_dropped``), the median tracking error against the exact projection (px),
and the time of tracking plus calibration (s). The table is printed and written to
``benchmarks/results/realistic.md``.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from transcalib import calibrate, track
from transcalib.geometry.rotation import rotation_angle_deg
from transcalib.synth import render
from transcalib.synth.degrade import REALISTIC, Degradations

#: k1 = -0.12 (barrel), the lens of issue 9 item 6
DIST = np.array([-0.12, 0.03, 0.0, 0.0, 0.0])

#: name -> (scene kind, lens distortion, Degradations)
CASES = {
    "clean": ("mixed", (), Degradations()),
    "distortion": ("mixed", DIST, Degradations()),
    "vignetting": ("mixed", (), Degradations(vignetting=REALISTIC.vignetting)),
    "exposure": ("mixed", (), Degradations(exposure=REALISTIC.exposure)),
    "sensor noise": ("mixed", (), Degradations(full_well_e=REALISTIC.full_well_e,
                                               read_noise_dn=REALISTIC.read_noise_dn)),
    "jpeg": ("mixed", (), Degradations(jpeg_quality=REALISTIC.jpeg_quality)),
    "specular": ("mixed", (), Degradations(specular=REALISTIC.specular)),
    "repetitive": ("repetitive", (), Degradations()),
    "overlay": ("mixed", (), Degradations(overlay=REALISTIC.overlay)),
    "all": ("mixed", DIST, REALISTIC),
    "all, repetitive": ("repetitive", DIST, REALISTIC),
    "repetitive + T": ("repetitive", (), Degradations()),
    "all, repetitive + T": ("repetitive", DIST, REALISTIC),
}
#: rows named ``... + T`` give the tracker the robot translations: ``track(images, T=T)``


def static_left(uv, px: float = 1.0) -> int:
    """Number of tracks that move less than ``px`` in every view (the overlay's)."""
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    d = np.linalg.norm(uv - uv[ref, np.arange(uv.shape[1])][None], axis=-1)
    return int((np.max(np.where(seen, d, 0.0), axis=0) < px).sum())


def on_specular(rendered, uv, sigma_px: float) -> int:
    """Number of tracks with an observation within ``sigma_px`` of the highlight centre."""
    c = rendered.meta.get("specular_uv")
    if c is None or not np.all(np.isfinite(c)):
        return 0
    d = np.linalg.norm(uv - c[:, None, :], axis=-1)
    return int(np.nanmin(np.where(np.isfinite(d), d, np.inf), axis=0).__lt__(sigma_px).sum())


def track_error(rendered, uv) -> np.ndarray:
    """Pixel errors of non-reference observations against the exact projection of the
    3-D point seen at each track's first observation (occlusion ghosts left out)."""
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    X, ghost = rendered.track_truth(uv)
    err = np.linalg.norm(rendered.project(X) - uv, axis=-1)
    other = seen & (np.arange(uv.shape[0])[:, None] != ref[None]) & ~ghost[None]
    return err[other & np.isfinite(err)]


def run_case(name: str, *, image_size=(640, 480), n_views: int = 5, rng=0, track_with_T: bool = False,
             **calibrate_options) -> dict:
    """Render, track and calibrate one case of :data:`CASES`; a row of the table.

    ``track_with_T``: give the tracker the robot translations (``track(images, T=T)``)."""
    kind, dist, opt = CASES[name]
    track_with_T = track_with_T or name.endswith("+ T")
    if image_size[0] != 640:  # text scaled with the image
        opt = replace(opt, overlay_scale=opt.overlay_scale * image_size[0] / 640)
    rendered = render.render_scene(kind, n_views=n_views, image_size=image_size, dist=dist, degrade=opt,
                                   noise_std=0.0 if opt.active() else 1.0, rng=rng)
    t0 = time.perf_counter()
    tracks = track(rendered.images, T=rendered.T if track_with_T else None)
    cal = calibrate(tracks.uv, rendered.T, **calibrate_options)
    seconds = time.perf_counter() - t0
    K, Kt = cal.K, rendered.K
    err = track_error(rendered, tracks.uv)
    return {
        "case": name, "fx_pct": 100 * (K[0, 0] / Kt[0, 0] - 1), "fy_pct": 100 * (K[1, 1] / Kt[1, 1] - 1),
        "cx_px": K[0, 2] - Kt[0, 2], "cy_px": K[1, 2] - Kt[1, 2],
        "R_deg": rotation_angle_deg(cal.R @ rendered.R.T), "dist_model": cal.dist_model,
        "tracks": tracks.n_points, "static_left": static_left(tracks.uv),
        "specular": on_specular(rendered, tracks.uv, 2.0 * opt.specular_sigma_px),
        "static_dropped": tracks.info.n_static_dropped,
        "track_err_px": float(np.median(err)) if len(err) else float("nan"),
        "gross_pct": 100 * float(np.mean(err > 1.0)) if len(err) else float("nan"),
        "seconds": seconds, "cal": cal, "tracks_obj": tracks, "rendered": rendered,
    }


def table(rows: list[dict]) -> str:
    head = ("| case | fx err % | fy err % | cx err px | cy err px | R err deg | dist model | tracks | "
            "static left | near highlight | static dropped | track err px (median) | > 1 px % | time s |")
    lines = [head, "|" + "|".join(["---"] * (head.count("|") - 1)) + "|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['fx_pct']:+.3f} | {r['fy_pct']:+.3f} | {r['cx_px']:+.2f} | "
                     f"{r['cy_px']:+.2f} | {r['R_deg']:.3f} | {r['dist_model']} | {r['tracks']} | {r['static_left']} | "
                     f"{r['specular']} | {r['static_dropped']} | {r['track_err_px']:.3f} | {r['gross_pct']:.2f} | "
                     f"{r['seconds']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] = ()) -> list[dict]:
    quick = "--quick" in argv
    size = (480, 360) if quick else (640, 480)
    names = [a for a in argv if not a.startswith("-")] or list(CASES)
    rows = []
    for name in names:
        rows.append(run_case(name, image_size=size, rng=1))
        print(f"  {name}: {rows[-1]['seconds']:.1f} s", file=sys.stderr, flush=True)
    text = (f"Realistic renders, 5 views of {size[0]}x{size[1]}, scene `mixed` (`repetitive` where named), "
            "default `calibrate(track(images).uv, T)` (`+ T`: `track(images, T=T)`); "
            "`python benchmarks/bench_realistic.py`\n\n" + table(rows))
    print(text)
    if not quick:
        out = Path(__file__).resolve().parent / "results" / "realistic.md"
        out.parent.mkdir(exist_ok=True)
        out.write_text(text + "\n")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
