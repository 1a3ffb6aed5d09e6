"""Image front-end benchmark: time of each stage for 5 views of 800 x 600.

Run alone (``python benchmarks/bench_tracks.py``) or through ``benchmarks/run.py``,
which calls :func:`main`.
"""

from __future__ import annotations

import time

import numpy as np

from transcalib import render, target, tracks


def _errors(r, tr):
    uv = tr.uv
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    X = np.full((uv.shape[1], 3), np.nan)
    ghost = np.zeros(uv.shape[1], bool)
    for v in range(uv.shape[0]):
        X[ref == v] = r.backproject(v, uv[v, ref == v])
        ghost[ref == v] = r.near_occlusion(v, uv[v, ref == v])
    err = np.linalg.norm(r.project(X) - uv, axis=-1)
    other = seen & (np.arange(uv.shape[0])[:, None] != ref[None]) & ~ghost[None]
    return err[other]


def main(n_views: int = 5, image_size=(800, 600)) -> list[dict]:
    """Print a table: per scene, the time of render, detect, match, verify, refine and
    the whole tracking, with the number of tracks and their accuracy (px)."""
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
        rows.append({"scene": kind, "render": t_render, "detect": ts["detect"], "match": ts["match"],
                     "verify": ts["verify"] + ts.get("chain", 0.0), "refine": ts["refine"] + ts.get("final", 0.0),
                     "track": t_track, "points": tr.n_points, "median": float(np.median(e)),
                     "p90": float(np.percentile(e, 90))})
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
    return rows


if __name__ == "__main__":
    main()
