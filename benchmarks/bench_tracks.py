"""Images to calibration: time of each stage for 5 views of 800 x 600, and accuracy.

    python benchmarks/bench_tracks.py [--quick]      (--quick: 4 views of 640 x 480)

Tracking stages (detect, match, verify, refine) are those of ``track()``; then
``calibrate()`` on the tracks (robust, refine, diagnostics). ``end to end`` is tracking
plus calibration, the work of ``transcalib calibrate --images`` (rendering excluded).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from transcalib import calibrate
from transcalib import images as tracks
from transcalib.images import target
from transcalib.synth import render


def _errors(r, tr):
    uv = tr.uv
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    X, ghost = r.track_truth(uv)
    err = np.linalg.norm(r.project(X) - uv, axis=-1)
    other = seen & (np.arange(uv.shape[0])[:, None] != ref[None]) & ~ghost[None]
    return err[other]


def main(argv: list[str] = ()) -> list[dict]:
    """Print tables: per scene, the time of each tracking stage, the number of tracks and
    their accuracy (px); then the calibration stages, end-to-end time and K errors."""
    n_views, image_size = (4, (640, 480)) if "--quick" in argv else (5, (800, 600))
    rows = []
    for kind in ("natural", "checker", "mixed"):
        t0 = time.perf_counter()
        r = render.render_scene(kind, n_views=n_views, image_size=image_size, brightness=0.15, rng=11)
        t_render = time.perf_counter() - t0
        t0 = time.perf_counter()
        tr = tracks.track(r.images)
        t_track = time.perf_counter() - t0
        ts = tr.info["time_s"]
        e = _errors(r, tr)
        t0 = time.perf_counter()
        cal = calibrate(tr.uv, r.T)
        t_cal = time.perf_counter() - t0
        rows.append({"scene": kind, "render": t_render, "detect": ts["detect"], "match": ts["match"],
                     "verify": ts["verify"] + ts.get("chain", 0.0), "refine": ts["refine"] + ts.get("final", 0.0),
                     "track": t_track, "points": tr.n_points, "median": float(np.median(e)),
                     "p90": float(np.percentile(e, 90)), "cal": cal, "t_cal": t_cal, "K": r.K})
    # target mode on the paper board
    r = render.render_scene("board", n_views=n_views, image_size=image_size, rng=11)
    t0 = time.perf_counter()
    tt = target.track_squares(r.images)
    t_t = time.perf_counter() - t0
    P = r.project(r.corners)
    d = np.linalg.norm(tt.uv[:, :, None] - P[:, None], axis=-1)
    e = np.nanmin(np.where(np.isfinite(d), d, np.inf), axis=2)[np.isfinite(tt.uv[..., 0])]
    print(f"image front-end: {n_views} views of {image_size[0]}x{image_size[1]} (times in s, errors in px)")
    head = f"{'scene':<8} {'render':>7} {'detect':>7} {'match':>7} {'verify':>7} {'refine':>7} {'track':>7} " \
           f"{'points':>7} {'median':>7} {'p90':>7}"
    print(head)
    print("-" * len(head))
    for rw in rows:
        print(f"{rw['scene']:<8} {rw['render']:7.2f} {rw['detect']:7.2f} {rw['match']:7.2f} {rw['verify']:7.2f} "
              f"{rw['refine']:7.2f} {rw['track']:7.2f} {rw['points']:7d} {rw['median']:7.3f} {rw['p90']:7.3f}")
    print(f"{'squares':<8} {'':>7} {'':>7} {'':>7} {'':>7} {'':>7} {t_t:7.2f} {tt.n_points:7d} "
          f"{np.median(e):7.3f} {np.percentile(e, 90):7.3f}")
    rows.append({"scene": "squares", "track": t_t, "points": tt.n_points, "median": float(np.median(e)),
                 "p90": float(np.percentile(e, 90))})

    print("\ncalibrate() on those tracks (times in s; K errors in px; target: end to end <= 10 s)")
    head = f"{'scene':<8} {'robust':>7} {'refine':>7} {'diagn.':>7} {'end2end':>8} {'inliers':>8} " \
           f"{'fx err':>8} {'fy err':>8} {'cx err':>8} {'cy err':>8}"
    print(head)
    print("-" * len(head))
    for rw in rows[:-1]:
        cal, info, dK = rw["cal"], rw["cal"].stats.timings_s, rw["cal"].K - rw["K"]
        print(f"{rw['scene']:<8} {info.get('robust_s', 0):7.2f} {info.get('refine_s', 0):7.2f} "
              f"{info.get('diagnostics_s', 0):7.2f} {rw['track'] + rw['t_cal']:8.2f} "
              f"{int(cal.inliers.sum()):>8d} {dK[0, 0]:+8.3f} {dK[1, 1]:+8.3f} {dK[0, 2]:+8.3f} {dK[1, 2]:+8.3f}")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
