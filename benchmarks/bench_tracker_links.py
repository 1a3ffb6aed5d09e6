"""Long tracks and links across orientations, against the renderer's truth.

    python benchmarks/bench_tracker_links.py [--quick] [--seeds N]

Scenes from ``_tracker_scenes.orbit_scene``: a preset scene (``natural``, ``mixed``) seen
by a session of 6 translated views, a second session of 6 views whose camera orbits the
scene centre by 15, 30 or 45 degrees about a random axis, and one single view orbited by
0.7 x that angle; 640 x 480, 1 grey level of noise. ``track(images, T=T, rotations=R)``
with the exact flange poses (camera = flange). Reported per angle (``N`` seeds each):

- mean views per track within each 6-view session (long tracks: the bar is 4);
- for each pair of groups, the points visible in both (unoccluded, 12 px inside the
  image, in 2+ views of a session or in the single view), the share of them linked (seen
  in both groups), and the wrong links: linked points whose observations in the other
  group are more than 2 px from the truth's projection (``link_quality``);
- the tracker's wall time and its link stage.

Writes ``benchmarks/results/tracker_links.md`` (``--quick``: one seed, a scratch folder).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import md_table, results_dir  # noqa: E402
from _tracker_scenes import link_quality, orbit_scene  # noqa: E402

from transcalib.images import track  # noqa: E402

ANGLES = (15.0, 30.0, 45.0)
KINDS = ("natural", "mixed")


def one(angle: float, seed: int, kind: str):
    """Track one scene: (mean views per track in the sessions, link counts, wall s, link s)."""
    sc = orbit_scene(seed, kind=kind, angles_deg=(angle,), singles_deg=(0.7 * angle,), image_size=(640, 480))
    R_flange = np.transpose(sc.R, (0, 2, 1))  # camera -> world: the flange, with R_X = I
    t0 = time.perf_counter()
    tr = track(sc.images, T=sc.T, rotations=R_flange)
    wall = time.perf_counter() - t0
    groups = sc.config["groups"]
    seen = np.isfinite(tr.uv[..., 0])
    lengths = []
    for g in ("s0", "s1"):
        n = seen[[i for i, x in enumerate(groups) if x == g]].sum(0)
        lengths.append(float(n[n >= 2].mean()))
    return lengths, link_quality(sc, tr.uv, groups), wall, tr.info.time_s.get("link", 0.0)


def main(argv=()) -> str:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seeds", type=int, default=None)
    args = ap.parse_args(list(argv))
    n = args.seeds or (1 if args.quick else 3)
    load0 = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    rows = []
    for angle in ANGLES:
        lens, q, walls, links = [], {}, [], []
        for seed in range(n):
            for kind in KINDS:
                ln, quality, wall, link = one(angle, seed, kind)
                lens += ln
                walls.append(wall)
                links.append(link)
                for pair, counts in quality.items():
                    q[pair] = np.add(q.get(pair, 0), counts)
                print(angle, seed, kind, ln, quality, round(wall, 1), file=sys.stderr, flush=True)
        for (a, b), (vis, linked, wrong, linked_all) in q.items():
            rows.append([f"{angle:.0f}", f"{a}-{b}", float(np.mean(lens)), int(vis), int(linked),
                         100.0 * linked / max(vis, 1), int(wrong), 100.0 * wrong / max(linked_all, 1),
                         float(np.median(walls)), float(np.median(links))])
    load1 = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    text = ("# Long tracks and links across orientations\n\n"
            f"`python benchmarks/bench_tracker_links.py{' --quick' if args.quick else ''}`: {n} seed(s) x "
            f"{len(KINDS)} scenes ({', '.join(KINDS)}) per angle; s0, s1 sessions of 6 views, v2 one view; "
            f"load before: {load0}; after: {load1}\n\n"
            + md_table(["angle (deg)", "groups", "mean views per track (6-view sessions)", "visible in both",
                        "linked", "linked %", "wrong links", "wrong %", "track wall s (median)",
                        "link stage s (median)"], rows))
    print(text)
    (results_dir(args.quick) / "tracker_links.md").write_text(text + "\n")
    return text


if __name__ == "__main__":
    main(sys.argv[1:])
