"""The renders' robot-error Monte Carlo without the tracker: exact projections of its scenes.

    python benchmarks/bench_robot_error_oracle.py [--trials N] [--layouts L,...] [--cases C,...]
                                                  [--variants V,...] [--noise-px S] [--field-px F]
                                                  [--no-view-field] [--jobs J] [--name NAME] [--quick]

On renders through the command (``bench_robot_error_renders.py``) some robot-error rows
report fx's std at 0.74-0.8 of its scatter, where the simulation (``bench_robot_error.py``)
reaches 0.94-1.11. This study takes the same scenes and the same robot errors (the
Monte Carlo's seeds: ``robot_scene`` eye-in-hand at the true flange poses, the reported
ones given to the fit) without rendering: points on the scene's surfaces (random pixels
of the first view, ray-cast), their exact projections at the true poses with the lens,
inside the image, plus

- ``white``: white pixel noise of ``--noise-px`` (default 0.02 px, the tracker's
  ``sigma_px`` on the 4 x 4 renders);
- ``white+quadratic``: that plus each view's own smooth error field, quadratic over the
  image (``x^2, xy, y^2`` about the principal point, random coefficients per view and
  coordinate) of ``--field-px`` RMS per coordinate (default 0.0025 px: the tracker's
  per-view fields on renders, ``bench_render_floor.py``, docs/uncertainty.md section 6.4);
- ``white+linear``: white noise plus each view's linear field (scale, rotation, shear
  about the principal point) of the same RMS,

calibrated in process with the defaults (:func:`transcalib.calibrate`: the lens chosen,
the robot error's scales estimated). Per case and variant as in the renders' table:
``ratio`` = RMS reported std / RMS error against the truth, ``cover`` the share within
1.96 std; and, paired on the same seeds, the renders' own ratio (from
``benchmarks/results/robot_error_renders_ss4.jsonl`` when present): where the white
variant holds and the field variant falls to the renders' ratio, an error field alike
over a view's points is what the renders' tracks add that the model does not hold.

Writes ``benchmarks/results/NAME.md`` (default ``robot_error_oracle``; ``--quick``: 6
trials, one layout and case, a scratch folder). A trial takes 3 s (one session) to 5 s (single views) on one core.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import md_table, results_dir  # noqa: E402
from bench_robot_error_renders import CASES, FIRST_SEED, LAYOUTS, _fields, _summary  # noqa: E402  (its scenes, seeds, ratios)

VARIANTS = ("white", "white+quadratic", "white+linear")
#: The field bases (columns over the offsets ``q = (x - c) / 300 px``) of the variants.
FIELD_BASES = {"quadratic": lambda q: np.stack([q[..., 0]**2, q[..., 0] * q[..., 1], q[..., 1]**2], -1),
               "linear": lambda q: q}
RENDERS = Path(__file__).resolve().parent / "results" / "robot_error_renders_ss4.jsonl"
#: Points per scene (the renders' tracks: 1200-1500).
N_POINTS = 1000


def trial(job: tuple) -> dict:
    """One scene of ``(layout, sigma_rot, sigma_pos, seed, variant, noise_px, field_px)``:
    ``{param: (error, reported std)}`` as the renders' Monte Carlo records them."""
    from transcalib import Poses, calibrate
    from transcalib.estimate.robot_error import sample_errors
    from transcalib.geometry.camera import project
    from transcalib.geometry.rotation import matrix_to_rotvec
    from transcalib.synth.robot import robot_scene
    from transcalib.synth.robot_layout import camera_poses

    from transcalib.types import RefineOptions

    layout, s_rot, s_pos, seed, variant, noise_px, field_px, view_field = job
    opts = LAYOUTS[layout]
    n_views = opts["session_views"] + opts["single_views"]
    err = sample_errors(n_views, s_rot, s_pos, rng=seed + 7)  # as the renders draw them
    r = robot_scene("eye-in-hand", rng=seed, pose_error=err, images=False, **opts)
    rng = np.random.default_rng(seed + 99)
    w, h = r.image_size
    X = r.backproject(0, rng.uniform([20, 20], [w - 20, h - 20], (2 * N_POINTS, 2)))
    X = X[np.all(np.isfinite(X), axis=1)][:N_POINTS]
    Q, c = camera_poses(r.meta["true_R"], r.meta["true_T"], r.R_X, r.t_X, r.setup)
    exact = project(r.K, Q, X, c, r.dist)
    inside = (exact[..., 0] > 5) & (exact[..., 0] < w - 5) & (exact[..., 1] > 5) & (exact[..., 1] < h - 5)
    uv = exact + rng.normal(0.0, noise_px, exact.shape) + _view_fields(exact, inside, r.K, variant, field_px, rng)
    cal = calibrate(np.where(inside[..., None], uv, np.nan), Poses.of(r.T, r.R), image_size=r.image_size, rng=0,
                    refinement=RefineOptions(view_field=view_field))
    row = {"fx": (cal.K[0, 0] - r.K[0, 0], cal.std["fx"]), "cx": (cal.K[0, 2] - r.K[0, 2], cal.std["cx"])}
    for a, k in enumerate(("rx", "ry", "rz")):  # R_est R_true^T = exp([w]x), degrees
        row[k] = (np.degrees(matrix_to_rotvec(cal.R @ r.R_X))[a], cal.std[k])
    if opts["single_views"]:
        he = cal.hand_eye
        for a, k in enumerate(("t_x", "t_y", "t_z")):
            row[k] = (he.t[a] - r.t_X[a], float(np.sqrt(he.t_cov[a, a])))
    vf = cal.uncertainty.view_field
    if vf is not None:  # each view's error field the test found (docs/uncertainty.md section 7.1)
        row["view_field"] = (vf.rms_px, vf.p_value, vf.included)
    return {"layout": layout, "sigma_rot": s_rot, "sigma_pos": s_pos, "seed": seed, "variant": variant,
            "row": {k: [float(v) for v in p] for k, p in row.items()}}


def _view_fields(exact: np.ndarray, inside: np.ndarray, K: np.ndarray, variant: str, field_px: float,
                 rng) -> np.ndarray:
    """Each view's error field ``(n_views, n, 2)`` of ``variant`` (zero for ``white``):
    random coefficients per view and coordinate on :data:`FIELD_BASES`, scaled to
    ``field_px`` RMS per coordinate over the observations ``inside (n_views, n)`` the image."""
    kind = variant.partition("+")[2]
    if not kind:
        return np.zeros_like(exact)
    B = FIELD_BASES[kind]((exact - K[:2, 2]) / 300.0)  # (n_views, n, k)
    scale = field_px / np.sqrt(np.mean(np.sum(B[inside] ** 2, axis=-1)))  # E|field coord|^2 = coef^2 E|B|^2
    return np.einsum("vnb,vbc->vnc", B, rng.normal(0.0, scale, (len(exact), B.shape[-1], 2)))


def _renders() -> dict:
    """The renders' recorded rows by ``(layout, sigma_rot, sigma_pos, seed)`` (none without the file)."""
    if not RENDERS.exists():
        return {}
    out = {}
    for line in RENDERS.read_text().splitlines():
        r = json.loads(line)
        if "failed" not in r["row"]:
            out[(r["layout"], r["sigma_rot"], r["sigma_pos"], r["seed"])] = r["row"]
    return out


def table(records: list, args, elapsed: float) -> str:
    renders = _renders()
    lines = ["# The renders' robot-error Monte Carlo without the tracker (issue 22)", "",
             f"`python benchmarks/bench_robot_error_oracle.py {args}` ({elapsed:.0f} s): the scenes and robot "
             "errors of `bench_robot_error_renders.py` (same seeds), exact projections of "
             f"{N_POINTS} surface points at the true poses plus the variant's errors, calibrated with the reported "
             "poses and default options. ratio = RMS reported std / RMS error (its own uncertainty ~1/sqrt(2N)); "
             "cover = share within 1.96 std. renders: the renders' Monte Carlo on the same seeds (the tracker's "
             "tracks through the command). field: each view's error field (docs/uncertainty.md section 7.1), the "
             "share of trials where its test found it and the median RMS found; with --no-view-field not tested "
             "(-) and not in the std.", ""]
    groups = {}
    for rec in records:
        groups.setdefault((rec["layout"], rec["sigma_rot"], rec["sigma_pos"]), {}).setdefault(
            rec["variant"], []).append(rec)
    for layout in LAYOUTS:
        keys = ["fx", "cx", "rx", "ry", "rz"] + (["t_x", "t_y", "t_z"] if LAYOUTS[layout]["single_views"] else [])
        rows = []
        for (lay, sr, sp), by_variant in sorted(groups.items()):
            if lay != layout:
                continue
            seeds = sorted({r["seed"] for recs in by_variant.values() for r in recs})
            paired = [renders[(lay, sr, sp, s)] for s in seeds if (lay, sr, sp, s) in renders]
            for name, recs in [(v, [r["row"] for r in by_variant[v]]) for v in VARIANTS if v in by_variant] + \
                    ([("renders", paired)] if paired else []):
                rows.append([sr, sp, name, len(recs)] + [f"{a:.2f} / {100 * b:.0f} %"
                                                         for a, b in (_summary(recs, k) for k in keys)]
                            + [_fields(recs)])
        if rows:
            lines += [f"## {layout}", "", md_table(["sigma_rot deg", "sigma_pos mm", "tracks", "N"]
                                                   + [f"{k} ratio / cover" for k in keys] + ["field"], rows), ""]
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=100, help="trials per layout, case and variant")
    p.add_argument("--layouts", default=",".join(LAYOUTS), help="some of: " + ", ".join(LAYOUTS))
    p.add_argument("--cases", default=",".join(f"{r}/{s}" for r, s in CASES),
                   help="sigma_rot/sigma_pos pairs of the renders' cases (default all: "
                        + ", ".join(f"{r}/{s}" for r, s in CASES) + ")")
    p.add_argument("--variants", default=",".join(VARIANTS), help="some of: " + ", ".join(VARIANTS))
    p.add_argument("--noise-px", type=float, default=0.02, help="white pixel noise (px)")
    p.add_argument("--field-px", type=float, default=0.0025, help="RMS per coordinate of each view's field (px)")
    p.add_argument("--no-view-field", action="store_true",
                   help="calibrate without the per-view error field's share of the std (docs/uncertainty.md 7.1)")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--name", default="robot_error_oracle", help="the table's file name, without .md")
    p.add_argument("--quick", action="store_true", help="6 trials of one session at 0.1 deg / 1 mm, scratch folder")
    a = p.parse_args(argv)
    layouts = [s.strip() for s in a.layouts.split(",") if s.strip()]
    variants = [s.strip() for s in a.variants.split(",") if s.strip()]
    known = {f"{r}/{s}": (r, s) for r, s in CASES}
    cases = [known.get(s.strip()) for s in a.cases.split(",") if s.strip()]
    for what, given, allowed in (("--layouts", layouts, LAYOUTS), ("--variants", variants, VARIANTS)):
        if not given or set(given) - set(allowed):
            p.error(f"{what}: give some of {', '.join(allowed)}")
    if not cases or None in cases:
        p.error(f"--cases: give some of {', '.join(known)}")
    if a.quick:
        a.trials, layouts, cases = 6, ["one session"], [(0.1, 1.0)]
    jobs = [(lay, sr, sp, FIRST_SEED + 1000 * CASES.index((sr, sp)) + k, v, a.noise_px, a.field_px, not a.no_view_field)
            for k in range(a.trials) for lay in layouts for sr, sp in cases for v in variants]
    t0 = time.perf_counter()
    records = []
    with ProcessPoolExecutor(a.jobs) as pool:
        for record in pool.map(trial, jobs, chunksize=4):
            records.append(record)
            if len(records) % 50 == 0:
                print(f"{len(records)} of {len(jobs)} trials: {time.perf_counter() - t0:.0f} s", file=sys.stderr,
                      flush=True)
    args = shlex.join(argv if argv is not None else sys.argv[1:])
    text = table(records, args, time.perf_counter() - t0)
    (results_dir(a.quick) / f"{a.name}.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
