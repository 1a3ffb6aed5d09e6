"""Draw docs/img/architecture.png: the packages of transcalib and how data flows.

Run ``python docs/make_architecture_diagram.py`` (matplotlib).
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyBboxPatch  # noqa: E402

BOXES = {  # name: (x, y, label, colour)
    "images": (0.6, 4.2, "images/\ntrack, target mode,\nsessions", "#dbe9f6"),
    "tracks": (3.1, 4.2, "Tracks\nuv (views, points, 2)\n+ T (views, 3)", "#f2f2f2"),
    "robust": (5.6, 4.2, "estimate/robust\n2-point minimal solver,\nnoise-adaptive rule", "#fde9d9"),
    "linear": (8.1, 4.2, "estimate/linear\npaper's TLS, O(n)\n(coplanar: known params)", "#fde9d9"),
    "refine": (8.1, 2.3, "estimate/refine\nthe one bundle adjuster,\ndistortion chosen, covariance", "#fde9d9"),
    "check": (5.6, 2.3, "check/\none module per\ndiagnostic", "#e4f1e1"),
    "cal": (3.1, 2.3, "Calibration\nCamera (K, dist, R),\nX, std, diagnostics", "#f2f2f2"),
    "io": (0.6, 2.3, "io/, report/\nfiles, exports", "#ece2f4"),
    "geometry": (3.1, 0.5, "geometry/  (used by every stage)\nthe camera model: projection + distortion, written once;\nrotations, triangulation", "#fff5cc"),
    "synth": (8.1, 0.5, "synth/ scenes, renderer\nplanning/, handeye/, dense/", "#f2f2f2"),
}
ARROWS = [("images", "tracks"), ("tracks", "robust"), ("robust", "linear"), ("linear", "refine"),
          ("refine", "check"), ("check", "cal"), ("cal", "io")]


def main() -> None:
    fig, ax = plt.subplots(figsize=(11, 5.6))
    for name, (x, y, label, colour) in BOXES.items():
        w = 4.7 if name == "geometry" else 2.2
        ax.add_patch(FancyBboxPatch((x - 1.1, y - 0.55), w, 1.1, boxstyle="round,pad=0.05", fc=colour, ec="#555"))
        ax.text(x - 1.1 + w / 2, y, label, ha="center", va="center", fontsize=9)
    for a, b in ARROWS:
        (xa, ya, *_), (xb, yb, *_) = BOXES[a], BOXES[b]
        if ya == yb:
            start, end = (xa + 1.15 * (1 if xb > xa else -1), ya), (xb - 1.15 * (1 if xb > xa else -1), yb)
        else:
            start, end = (xa, ya - 0.6), (xb, yb + 0.6)
        ax.annotate("", end, start, arrowprops=dict(arrowstyle="-|>", color="#333", lw=1.4))
    ax.text(5.6, 5.25, "calibrate()  (pipeline.py):  images / tracks  ->  robust  ->  linear  ->  refine  ->  "
            "diagnose  ->  Calibration", ha="center", fontsize=10, weight="bold")
    ax.text(5.6, -0.35, "layers: errors < geometry < types, validate < estimate < check < synth, images, handeye "
            "< planning, pipeline, dense < io, report < cli; no import cycles   (tests/test_architecture.py)", ha="center", fontsize=8.5)
    ax.set_xlim(-0.7, 9.6)
    ax.set_ylim(-0.6, 5.5)
    ax.axis("off")
    out = Path(__file__).resolve().parent / "img" / "architecture.png"
    fig.savefig(out, dpi=110, bbox_inches="tight")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
