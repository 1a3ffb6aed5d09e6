"""Assemble docs/results.md: the hand-written readings of ``results_doc.template.md``, the
tables of ``benchmarks/results/*.md`` and the printed tables of a ``make bench`` log.

    make bench | tee bench.log; python benchmarks/make_results_doc.py bench.log [more.log ...]
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
R = ROOT / "benchmarks" / "results"
log = "\n".join(Path(a).read_text() for a in sys.argv[1:])
times = dict(re.findall(r"\((bench_\w+): ([\d.]+) s\)", log))


def include(name):
    text = (R / name).read_text().strip().splitlines()
    out = []
    for line in text[1:]:  # drop the file's title
        if line.startswith("#"):
            line = "#" + line
        out.append(line.replace("`paper1_", "`../benchmarks/results/paper1_"))
    return "\n".join(out)


def printed(stem):
    m = re.search(rf"=== {stem} ===\n(.*?)\n\({stem}: [\d.]+ s\)", log, re.S)
    body = m.group(1) if m else "(not in the log)"
    body = "\n".join(l for l in body.splitlines() if not re.match(r"^[IWE]\d{8} ", l))
    return "```\n" + body.strip() + "\n```"


def img(name, alt):
    return f"![{alt}](../benchmarks/results/{name})"


PROSE = (ROOT / "benchmarks" / "results_doc.template.md").read_text()
total = sum(float(v) for v in times.values())
ctx = {f"time_{k}": f"{float(v):.0f}" for k, v in times.items()}
ctx["total"] = f"{total:.0f}"
ctx["total_min"] = f"{total / 60:.1f}"
for f in R.glob("*.md"):
    ctx[f"inc_{f.stem}"] = include(f.name)
for stem in ("bench_linear", "bench_refine", "bench_robust", "bench_rotation_test", "bench_tracks", "bench_report"):
    ctx[f"out_{stem}"] = printed(stem)
doc = PROSE
for k, v in ctx.items():
    doc = doc.replace("{{" + k + "}}", v)
doc = re.sub(r"\{\{img:([^|}]+)\|([^}]+)\}\}", lambda m: img(m.group(1), m.group(2)), doc)
left = re.findall(r"\{\{[^}]+\}\}", doc)
if left:
    print("unfilled:", left)
(ROOT / "docs" / "results.md").write_text(doc)
print("written", len(doc))
