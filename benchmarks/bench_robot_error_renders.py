"""The robot's pose error on rendered images, through the command line (issue 22).

Each trial renders :func:`transcalib.synth.robot.robot_scene` (eye-in-hand, 640 x 480, the
realistic camera effects, JPEG 90) at the **true** flange poses ``R_i exp([delta_i]x)``,
``T_i + eps_i`` (``robot_scene(pose_error=...)``; per view and axis ``delta ~ N(0,
sigma_rot)``, ``eps ~ N(0, sigma_pos)``, drawn afresh every trial) while ``poses.csv``
keeps the **reported** ones, and calibrates with the default command
``transcalib calibrate --images ... --poses poses.csv --json`` (tracking, RANSAC, the lens
chosen from the data, the robot error's scales estimated by default). Two layouts:

- ``one session``: 12 views of 3-D pure translation (one orientation: rotation and
  position errors fold into the camera's, ``sigma_pos_eff^2 ~ sigma_pos^2 + (2/3)
  sigma_rot^2 |t_X|^2``; the hand-eye translation is not observable);
- ``session + singles``: a session of 6 views and 6 single views turned 15-45 deg.

Per case and parameter (fx, cx, the camera rotation ``w`` with ``R_est R_true^T =
exp([w]x)`` in degrees, and with single views t_X): ``ratio`` = RMS reported std /
empirical std (RMS error about zero, the truth), ``cover`` = share of trials with
``|error| < 1.96 reported std`` (nominal 95 %), and the median estimated scales. With N
trials a ratio is itself uncertain by about ``1 / sqrt(2 N)`` (N = 30: 13 %) and a
coverage by ``sqrt(0.95 * 0.05 / N)`` (N = 30: 4 points).

Run ``nice python benchmarks/bench_robot_error_renders.py --trials N --jobs J`` (default 20
trials per case, 1 process; 20-45 s a trial on one core). ``--read-noise DN`` and ``--blur PX``
render a noisier camera (the preset's read noise is 1.2 grey levels, no optics blur), whose
tracks' pixel noise is nearer a user's: is the perfect robot's shortfall a fixed floor of
the tracker that noisier tracks drown? (It is not: docs/uncertainty.md section 6.3.)
Recorded in ``..._nDN_bPX.jsonl``; ``--layout`` runs one layout only.
Each finished trial is appended
to ``benchmarks/results/robot_error_renders.jsonl`` and a run continues from the trials
found there (the same seeds), so the Monte Carlo grows over several runs; the table,
``benchmarks/results/robot_error_renders.md``, is rewritten from every trial recorded
after each round of trials. ``--supersample 4`` renders 4 x 4 samples per pixel instead
of 2 x 2 (the render twice as costly, a trial ~1.7 x), recorded in
``robot_error_renders_ss4.jsonl`` / ``.md``: at 2 x 2 the renderer's texture blur steps
along lines that move between views, which left the perfect-robot rows a floor
(docs/uncertainty.md section 6). ``--paired-with EARLIER.jsonl`` adds to the table the
trials of an earlier run on the same seeds, before -> now (after a change of the code).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from transcalib.estimate.robot_error import sample_errors
from transcalib.geometry.rotation import matrix_to_rotvec
from transcalib.io import write_poses_csv
from transcalib.synth.robot import robot_scene
from transcalib.synth.robot_layout import preset_degradations

OUT = Path(__file__).resolve().parent / "results" / "robot_error_renders.md"
TRIALS = OUT.with_suffix(".jsonl")  # one finished trial per line: the Monte Carlo so far
JPEG_QUALITY = 90
#: (sigma_rot deg, sigma_pos mm)
CASES = ((0.0, 0.0), (0.1, 1.0), (0.2, 2.0))
LAYOUTS = {"one session": dict(session_views=12, single_views=0),
           "session + singles": dict(session_views=6, single_views=6)}
FIRST_SEED = 22500
#: The renders' size (``robot_scene``'s default).
IMAGE_SIZE = (640, 480)


def trial(layout: str, s_rot: float, s_pos: float, seed: int, supersample: int = 2, camera=None) -> dict:
    """Render, write, calibrate through the CLI: errors and reported std per parameter,
    the robot error found, or ``{"failed": why}``. ``camera``: ``(read noise DN, blur
    px)`` instead of the preset's (:func:`noisier`)."""
    degrade, blur = (True, 0.0) if camera is None else noisier(*camera)
    out = calibrate_render(layout, s_rot, s_pos, seed, supersample, degrade=degrade, blur_sigma=blur)
    return out if isinstance(out, dict) else _row(*out, layout)


def noisier(read_noise_dn: float, blur_px: float) -> tuple:
    """``(degrade, blur_sigma)`` of :func:`calibrate_render`: the preset's camera effects
    with ``read_noise_dn`` grey levels of read noise and ``blur_px`` of optics blur."""
    return replace(preset_degradations(IMAGE_SIZE), read_noise_dn=float(read_noise_dn)), float(blur_px)


def calibrate_render(layout: str, s_rot: float, s_pos: float, seed: int, supersample: int = 2, degrade=True,
                     image_ext: str = "jpg", blur_sigma: float = 0.0):
    """Render (``supersample`` x ``supersample`` samples per pixel; ``degrade`` and
    ``blur_sigma`` as :func:`~transcalib.synth.robot.robot_scene` takes them), write
    (``image_ext`` ``jpg`` at :data:`JPEG_QUALITY` or ``png``), calibrate through the CLI:
    ``(robot scene, --json summary, hand_eye.json)`` or ``{"failed": why}``."""
    opts = LAYOUTS[layout]
    n_views = opts["session_views"] + opts["single_views"]
    err = sample_errors(n_views, s_rot, s_pos, rng=seed + 7)
    r = robot_scene("eye-in-hand", rng=seed, pose_error=err, supersample=supersample, degrade=degrade,
                    blur_sigma=blur_sigma, **opts)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        names = [f"view{i:02d}.{image_ext}" for i in range(n_views)]
        for name, img in zip(names, r.images):
            cv2.imwrite(str(folder / name), img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if image_ext == "jpg" else [])
        write_poses_csv(folder / "poses.csv", r.T, R=r.R, images=names)  # the reported poses
        out = folder / "out"
        run = subprocess.run([sys.executable, "-m", "transcalib", "calibrate", "--images",
                              *[str(folder / n) for n in names], "--poses", str(folder / "poses.csv"), "--unit", "mm",
                              "--out", str(out), "--formats", "json", "--json", "--quiet"],
                             capture_output=True, text=True)
        try:
            s = json.loads(run.stdout)
            he = json.loads((out / "hand_eye.json").read_text())
        except (json.JSONDecodeError, FileNotFoundError):
            return {"failed": (run.stderr.strip().splitlines() or ["?"])[-1]}
    return r, s, he


def _row(r, s: dict, he: dict, layout: str) -> dict:
    """``{param: (error, reported std)}`` and the robot error of one calibration."""
    K, std = np.array(s["K"]), s["std"]
    w = np.degrees(matrix_to_rotvec(np.array(s["R_cam_world"]) @ r.R_X))  # R_est R_true^T, R_true = R_X^T
    row = {"fx": (K[0, 0] - r.K[0, 0], std.get("fx", std.get("f"))), "cx": (K[0, 2] - r.K[0, 2], std["cx"])}
    for a, k in enumerate(("rx", "ry", "rz")):
        row[k] = (w[a], std[k])
    if layout != "one session":
        t, t_std = np.array(he["t_flange_camera"]), np.array(he["t_flange_camera_std"])
        for a, k in enumerate(("t_x", "t_y", "t_z")):
            row[k] = (t[a] - r.t_X[a], t_std[a])
    re = s["robot_error"]
    row["robot"] = (re["sigma_rot_deg"], re["sigma_pos"], re["source"]["rot"], re["source"]["pos"])
    checks = [v for v in re["consistency_p"].values() if v is not None and np.isfinite(v)]
    row["check_p"] = min(checks) if checks else None  # the misfit check's lowest p-value
    row["dist_model"] = s["dist_model"]
    row["sigma_px"] = s["sigma_px"]
    vf = (s.get("uncertainty") or {}).get("view_field")
    if vf is not None:  # each view's error field (docs/uncertainty.md section 7.1): RMS px, p-value, in the std
        row["view_field"] = (vf["rms_px"], vf["p_value"], vf["included"])
    row["codes"] = [d["code"] for d in s["diagnostics"]]
    row["stages"] = s["stages"]
    return row


def _summary(rows: list, key: str):
    """(ratio RMS std / RMS error, coverage) of one parameter."""
    e = np.array([r[key][0] for r in rows])
    sd = np.array([r[key][1] for r in rows])
    return float(np.sqrt(np.mean(sd**2)) / np.sqrt(np.mean(e**2))), float(np.mean(np.abs(e) < 1.96 * sd))


def table(results: dict, trials: int, elapsed: float, log_name: str = TRIALS.name, options: str = "") -> str:
    """The Monte Carlo's table; ``options``: the command's other options, as shown."""
    lines = ["# Robot pose error on renders, through the CLI (issue 22)", "",
             f"`nice python benchmarks/bench_robot_error_renders.py --trials {trials}{options}`: the trials recorded in "
             f"{log_name} over one or more runs (the last {elapsed:.0f} s). "
             "Eye-in-hand renders of `robot_scene` (640 x 480, realistic camera effects, JPEG 90; the samples per "
             "pixel: see the file's name, ss4 = 4 x 4, else 2 x 2; _nDN_bPX: read noise DN grey levels and optics "
             "blur PX px instead of the preset's 1.2 and none) at the true "
             "flange poses, `poses.csv` with the reported ones; `transcalib calibrate --images --poses --json` with "
             "default options (the robot error's scales estimated). ratio = RMS reported std / RMS error against "
             f"the truth (its own uncertainty ~1/sqrt(2N) = {1 / np.sqrt(2 * trials):.0%} at N = {trials}); cover = "
             "share with |error| < 1.96 std (nominal 95 %; +-" f"{100 * np.sqrt(0.0475 / trials):.0f} points at N). "
             "sigma est: median estimated scale (rot deg, pos mm) and how often each component was switched on. "
             "misfit: share of trials with a component left out as a misfit (in brackets: of the trials recorded "
             "with their stages, the share where a misfit on the way had the tracks judged again at held scales); "
             "check p: the misfit check's lowest "
             "p-value, its median and shares below 0.01 and 0.001 (the verdict's level). field: each view's error "
             "field (docs/uncertainty.md section 7.1), the share of trials where its test found it and the median "
             "RMS found (of the trials recorded with it). sigma_px: the median pixel noise estimated (of the trials recorded "
             "with it).", ""]
    for layout in LAYOUTS:
        keys = ["fx", "cx", "rx", "ry", "rz"] + (["t_x", "t_y", "t_z"] if layout != "one session" else [])
        head = ("| sigma_rot deg | sigma_pos mm | N | fails | " + " | ".join(f"{k} ratio / cover" for k in keys)
                + " | sigma_rot est (on) | sigma_pos est (on) | misfit | check p | field | lens | sigma_px |")
        lines += [f"## {layout}", "", head, "|" + "---|" * (head.count("|") - 1)]
        for (sr, sp) in CASES:
            chunk = results.get((layout, sr, sp), [])
            ok = [r for r in chunk if "failed" not in r]
            if not ok:
                continue
            cells = [f"{a:.2f} / {100 * b:.0f} %" for a, b in (_summary(ok, k) for k in keys)]
            rob = np.array([r["robot"][:2] for r in ok])
            on = [np.mean([r["robot"][2 + c] == "estimated" for r in ok]) for c in (0, 1)]
            lens = ", ".join(f"{m} {sum(r['dist_model'] == m for r in ok)}" for m in sorted({r["dist_model"] for r in ok}))
            lines.append(f"| {sr} | {sp} | {len(chunk)} | {len(chunk) - len(ok)} | " + " | ".join(cells)
                         + f" | {np.median(rob[:, 0]):.3f} ({100 * on[0]:.0f} %) | {np.median(rob[:, 1]):.2f} "
                           f"({100 * on[1]:.0f} %) | {_checks(ok)} | {_fields(ok)} | {lens} | {_sigma_px(ok)} |")
        fails = [r["failed"] for c, rows in results.items() if c[0] == layout for r in rows if "failed" in r]
        lines += [""] + ([f"Failures: {'; '.join(sorted(set(fails)))}", ""] if fails else [])
    return "\n".join(lines) + "\n"


def _checks(rows: list) -> str:
    """The misfit check: share of trials with a component left out as a misfit (and of
    those recorded with their stages, the share whose tracks were judged again at held
    scales after a misfit on the way) | median and shares below 1e-2 and 1e-3 (the
    verdict's level) of its lowest p-value (trials recorded with it)."""
    misfit = np.mean(["robot_error_misfit" in r["codes"] for r in rows])
    staged = [r["stages"] for r in rows if "stages" in r]
    held = (f" ({100 * np.mean(['refine (scales estimated)' in s for s in staged]):.0f} % of {len(staged)} "
            "judged again)" if staged else "")
    p = np.array([r["check_p"] for r in rows if r.get("check_p") is not None])
    low = (f"{np.median(p):.2f}; {100 * np.mean(p < 1e-2):.0f} / {100 * np.mean(p < 1e-3):.0f} % below 0.01 / "
           f"0.001 (of {len(p)})" if len(p) else "-")
    return f"{100 * misfit:.0f} %{held} | {low}"


def _sigma_px(rows: list) -> str:
    """Median estimated pixel noise (px) of the trials recorded with it."""
    s = [r["sigma_px"] for r in rows if "sigma_px" in r]
    return f"{np.median(s):.3f}" if s else "-"


def _fields(rows: list) -> str:
    """Each view's error field: share found and median RMS found (px), of the trials recorded with it."""
    vf = [r["view_field"] for r in rows if "view_field" in r]
    found = [v[0] for v in vf if v[2]]
    return f"{100 * len(found) / len(vf):.0f} %, {np.median(found) if found else 0:.4f} px (of {len(vf)})" if vf else "-"


def paired_table(log: Path, before: Path) -> str:
    """The trials of ``log`` and of an earlier run ``before`` on the same seeds, per case
    and parameter: std ratio and coverage before -> now, and RMS error now / before (the
    change the code made, free of the seeds' own scatter)."""
    runs = [{(r["layout"], r["sigma_rot"], r["sigma_pos"], r["seed"]): _row_of(r["row"]) for r in _recorded(path)}
            for path in (before, log)]
    lines = [f"## Paired with {before.name}", "",
             f"The trials of both runs on the same seeds: std ratio (coverage) {before.name} -> {log.name}, and "
             "the RMS error's ratio now / before.", "",
             "| layout | sigma_rot deg | sigma_pos mm | N | " + " | ".join(PAIRED_KEYS) + " |",
             "|---|---|---|---|" + "---|" * len(PAIRED_KEYS)]
    for layout in LAYOUTS:
        for sr, sp in CASES:
            seeds = sorted(c[3] for c in runs[1] if c[:3] == (layout, sr, sp) and c in runs[0]
                           and "failed" not in runs[0][c] and "failed" not in runs[1][c])
            if not seeds:
                continue
            pairs = [[run[(layout, sr, sp, k)] for k in seeds] for run in runs]
            cells = []
            for key in PAIRED_KEYS:
                if key not in pairs[0][0]:
                    cells.append("-")
                    continue
                (r0, c0), (r1, c1) = (_summary(rows, key) for rows in pairs)
                rms = [np.sqrt(np.mean([r[key][0] ** 2 for r in rows])) for rows in pairs]
                cells.append(f"{r0:.2f} ({100 * c0:.0f} %) -> {r1:.2f} ({100 * c1:.0f} %); x{rms[1] / rms[0]:.2f}")
            lines.append(f"| {layout} | {sr} | {sp} | {len(seeds)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


#: Parameters of :func:`paired_table`.
PAIRED_KEYS = ("fx", "cx", "rx", "ry", "rz", "t_x", "t_y", "t_z")


def _case_trial(case: tuple) -> dict:
    """One trial of ``(layout, sigma_rot, sigma_pos, seed, supersample, camera, code)`` as a
    JSON-able record (``code``: :func:`_code_version`)."""
    layout, sr, sp, seed, supersample, camera, code = case
    row = trial(layout, sr, sp, seed, supersample, camera)
    plain = {k: (list(map(_plain, v)) if isinstance(v, tuple) else _plain(v)) for k, v in row.items()}
    return {"layout": layout, "sigma_rot": sr, "sigma_pos": sp, "seed": seed, "code": code, "row": plain}


def _code_version() -> str | None:
    """The commit of the checkout the calibrations run from (``+changes`` when its files
    differ from it), or None outside a git checkout: recorded with every trial, since a
    Monte Carlo of many sessions may span several versions."""
    import transcalib

    src = Path(transcalib.__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=src, capture_output=True, text=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "."], cwd=src, capture_output=True, text=True)
    except OSError:
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")


def _plain(v):
    return v if v is None or isinstance(v, (str, list)) else float(v)


def _recorded(path: Path) -> list:
    """The trials recorded so far (none without the file)."""
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=20, help="trials per case, those recorded included")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--out", type=Path, default=None, help=f"table (default {OUT.name}; with --supersample N "
                   "other than 2, robot_error_renders_ssN.md)")
    p.add_argument("--supersample", type=int, default=2, help="samples per pixel along each axis of the renders")
    p.add_argument("--paired-with", type=Path, default=None, metavar="JSONL",
                   help="an earlier run's trials: the table gains their comparison on the same seeds")
    p.add_argument("--read-noise", type=float, default=None, metavar="DN",
                   help="read noise in grey levels instead of the preset's 1.2 (with --blur: a noisier camera)")
    p.add_argument("--blur", type=float, default=0.0, metavar="PX", help="optics blur, Gaussian std in pixels")
    p.add_argument("--layout", choices=tuple(LAYOUTS), action="append", default=None,
                   help="run this layout only (repeatable; default both)")
    a = p.parse_args(argv)
    if a.paired_with is not None and not a.paired_with.is_file():
        p.error(f"--paired-with: no such file {a.paired_with}")
    if (a.read_noise is not None and a.read_noise < 0) or a.blur < 0:
        p.error("--read-noise and --blur must be >= 0")
    camera = None
    if a.read_noise is not None or a.blur > 0:
        camera = (preset_degradations(IMAGE_SIZE).read_noise_dn if a.read_noise is None else a.read_noise, a.blur)
    if a.out is None:
        a.out = OUT if a.supersample == 2 else OUT.with_name(f"{OUT.stem}_ss{a.supersample}.md")
        if camera is not None:
            a.out = a.out.with_name(f"{a.out.stem}_n{camera[0]:g}_b{camera[1]:g}.md")
    log = a.out.with_suffix(".jsonl")
    done = {(r["layout"], r["sigma_rot"], r["sigma_pos"], r["seed"]) for r in _recorded(log)}
    code = _code_version()
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs) as pool:
        for k in range(a.trials):  # trials interleaved over the cases: a run cut short stays balanced
            todo = [(layout, sr, sp, FIRST_SEED + 1000 * g + k) for layout in a.layout or LAYOUTS
                    for g, (sr, sp) in enumerate(CASES)]
            todo = [(*c, a.supersample, camera, code) for c in todo if c not in done]
            if not todo:
                continue
            with log.open("a") as f:
                for record in pool.map(_case_trial, todo):
                    f.write(json.dumps(record) + "\n")
                    f.flush()
            _write_table(log, a.out, time.perf_counter() - t0, a.paired_with, _shown(a))
            print(f"trial {k + 1}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    if log.exists():  # (also: --trials 0 rewrites the table of what is recorded)
        sys.stdout.write(_write_table(log, a.out, time.perf_counter() - t0, a.paired_with, _shown(a)))


def _shown(a: argparse.Namespace) -> str:
    """The options of a run that change its trials, as its table shows the command."""
    shown = [f"--supersample {a.supersample}"] if a.supersample != 2 else []
    if a.read_noise is not None:
        shown.append(f"--read-noise {a.read_noise:g}")
    if a.blur:
        shown.append(f"--blur {a.blur:g}")
    return "".join(" " + o for o in shown)


def _write_table(log: Path, out: Path, elapsed: float, paired_with: Path | None = None, options: str = "") -> str:
    """The table of every trial recorded in ``log`` (and its comparison with the run
    ``paired_with`` on the same seeds), written to ``out``."""
    results = {}
    for r in _recorded(log):
        results.setdefault((r["layout"], r["sigma_rot"], r["sigma_pos"]), []).append(_row_of(r["row"]))
    text = table(results, min(len(v) for v in results.values()), elapsed, log.name, options)
    if paired_with is not None:
        text += "\n" + paired_table(log, paired_with)
    out.write_text(text)
    return text


def _row_of(plain: dict) -> dict:
    """A recorded row with its pairs as tuples again (what :func:`table` reads)."""
    return {k: (tuple(v) if isinstance(v, list) and k != "codes" else v) for k, v in plain.items()}


if __name__ == "__main__":
    main()
