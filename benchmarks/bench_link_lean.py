"""Single views' hand-eye translation: a lean of the estimator, or of the links?

    python benchmarks/bench_link_lean.py [--seeds N] [--render-seeds N] [--effects E,...] [--jobs J] [--quick]

The robot preset's layout with single views (``robot_scene``: a 6-view session and 6
views turned 15-45 deg, a perfect robot) in two ways:

- **exact tracks**: the scene's points projected exactly (``RobotRendered.exact_tracks``
  of 30 000 points drawn on its surfaces, the first 1500 seen twice or more), Gaussian
  noise of 0.05, 0.5 and 2 px added, ``transcalib.calibrate`` on the tracks: the
  estimator alone. Per noise level, over ``--seeds`` layouts: the mean and RMS of
  ``z = (t_X - truth) / reported std`` per axis, and fx's.
- **renders through the command** (2 x 2 samples per pixel, ``--render-seeds``
  layouts): ``clean`` (the lens and 1.2 grey levels of read noise) and ``full`` (every
  camera effect of the preset: vignetting, exposure, shot noise, JPEG 90, a highlight),
  the same layouts, and with ``--effects`` the clean renders plus one effect each;
  t_X's error (mm) and z per axis, and each paired difference from ``clean`` with its
  standard error.

A lean present in the renders and absent from the exact tracks is the tracker's (its
links), not the model's (docs/uncertainty.md section 6). Writes
``benchmarks/results/link_lean.md`` (``--quick``: 6 and 2 layouts, a scratch folder).
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import md_table, results_dir  # noqa: E402

FIRST_SEED = 22600
NOISE_PX = (0.05, 0.5, 2.0)
LAYOUT = dict(session_views=6, single_views=6)
AXES = ("t_x", "t_y", "t_z")


def exact_trial(seed: int, sigma: float) -> dict:
    """t_X and fx errors and reported std from exact projections plus ``sigma`` px of noise."""
    from transcalib import calibrate
    from transcalib.io import Poses
    from transcalib.synth.robot import robot_scene

    r = robot_scene("eye-in-hand", rng=seed, images=False, **LAYOUT)
    uv = r.exact_tracks(r.sample_points(30000, rng=seed + 1), margin_px=10)
    uv = uv[:, np.flatnonzero(np.isfinite(uv[..., 0]).sum(0) >= 2)[:1500]]
    uv = uv + np.random.default_rng(seed + 2).normal(0.0, sigma, uv.shape)
    cal = calibrate(uv, Poses.of(r.T, r.R), unit="mm", image_size=r.image_size, rng=0)
    he = cal.hand_eye
    return {"t_err": (np.asarray(he.t) - r.t_X).tolist(), "t_std": np.sqrt(np.diag(he.t_cov)).tolist(),
            "fx": [float(cal.K[0, 0] - r.K[0, 0]), float(cal.std["fx"])]}


#: ``--effects``: one camera effect of the preset added to the clean renders.
EFFECTS = {"vignetting": dict(vignetting=0.25), "exposure": dict(exposure=0.15), "shot noise": dict(full_well_e=6000.0),
           "jpeg": dict(jpeg_quality=90),
           "highlight": dict(specular=0.5, specular_sigma_px=12.0, specular_drift_px=25.0)}


def render_trial(seed: int, setting: str) -> dict:
    """The same through ``transcalib calibrate --images`` on renders: ``clean`` (the lens
    and read noise), ``full`` (every effect of the preset) or clean plus one of :data:`EFFECTS`."""
    from bench_robot_error_renders import calibrate_render
    from transcalib.synth.degrade import Degradations

    clean = dict(vignetting=0.0, exposure=0.0, full_well_e=None, read_noise_dn=1.2, jpeg_quality=None, specular=0.0)
    degrade = True if setting == "full" else Degradations(**{**clean, **EFFECTS.get(setting, {})})
    out = calibrate_render("session + singles", 0.0, 0.0, seed, 2, degrade=degrade, image_ext="png")
    if isinstance(out, dict):
        return out
    r, s, he = out
    return {"t_err": (np.array(he["t_flange_camera"]) - r.t_X).tolist(), "t_std": he["t_flange_camera_std"],
            "fx": [float(np.array(s["K"])[0, 0] - r.K[0, 0]), float(s["std"]["fx"])]}


def _z_row(label, rows) -> list:
    """Mean z and RMS z per axis of t_X, and fx's."""
    ok = [r for r in rows if "failed" not in r]
    z = np.array([np.array(r["t_err"]) / np.array(r["t_std"]) for r in ok]).reshape(-1, 3)
    fz = np.array([r["fx"][0] / r["fx"][1] for r in ok])
    cells = [f"{z[:, a].mean():+.2f} / {np.sqrt(np.mean(z[:, a] ** 2)):.2f}" for a in range(3)]
    return [label, len(ok), len(rows) - len(ok), *cells, f"{fz.mean():+.2f} / {np.sqrt(np.mean(fz ** 2)):.2f}"]


def main(argv=None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=None, help="layouts per noise level (exact tracks; default 40)")
    ap.add_argument("--render-seeds", type=int, default=None, help="rendered layouts (default 8)")
    ap.add_argument("--effects", default="", help=f"comma-separated, of {', '.join(EFFECTS)}: renders with one effect "
                    "each, paired with the clean ones")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    n_exact = a.seeds or (6 if a.quick else 40)
    n_render = a.render_seeds if a.render_seeds is not None else (2 if a.quick else 8)
    t0 = time.perf_counter()
    seeds = [FIRST_SEED + k for k in range(n_exact)]
    with ProcessPoolExecutor(a.jobs) as pool:
        exact = {s: list(pool.map(exact_trial, seeds, [s] * len(seeds))) for s in NOISE_PX}
        rseeds = [FIRST_SEED + k for k in range(n_render)]
        effects = [e.strip() for e in a.effects.split(",") if e.strip()]
        unknown = [e for e in effects if e not in EFFECTS]
        if unknown:
            ap.error(f"--effects: unknown {', '.join(unknown)} (known: {', '.join(EFFECTS)})")
        renders = {st: list(pool.map(render_trial, rseeds, [st] * len(rseeds))) for st in ("clean", "full", *effects)}
    head = ["case", "layouts", "failed", *[f"{ax} mean z / RMS z" for ax in AXES], "fx mean z / RMS z"]
    rows = [_z_row(f"exact tracks, {s} px", exact[s]) for s in NOISE_PX]
    rows += [_z_row(f"renders, {st}", renders[st]) for st in renders]
    mm = [["renders, mean t_X error (mm)", *[f"{np.mean([r['t_err'][k] for r in renders[st] if 'failed' not in r]):+.4f}"
                                              for k in range(3)], st] for st in renders]
    for st in [k for k in renders if k != "clean"]:
        pairs = [(c, f) for c, f in zip(renders["clean"], renders[st]) if "failed" not in c and "failed" not in f]
        if len(pairs) >= 2:
            d = np.array([np.array(f["t_err"]) - np.array(c["t_err"]) for c, f in pairs])
            se = d.std(0, ddof=1) / np.sqrt(len(d))
            mm.append([f"{st} - clean (paired)", *[f"{d[:, k].mean():+.4f} ± {se[k]:.4f}" for k in range(3)], len(d)])
    text = (f"# Single views' t_X: the estimator or the links\n\n`python benchmarks/bench_link_lean.py"
            f"{' --quick' if a.quick else ''}` ({time.perf_counter() - t0:.0f} s; seeds from {FIRST_SEED}; "
            "z = (estimate - truth) / reported std)\n\n" + md_table(head, rows) + "\n\n"
            + md_table(["renders", *[f"{ax} (mm)" for ax in AXES], "setting / pairs"], mm) + "\n")
    print(text)
    (results_dir(a.quick) / "link_lean.md").write_text(text)
    return text


if __name__ == "__main__":
    main(sys.argv[1:])
