"""Where the renders' perfect-robot floor comes from: the tracker's errors against the truth.

    python benchmarks/bench_render_floor.py [--seeds N] [--supersample S] [--variants V,...] [--jobs J] [--quick]
                                            [--name NAME]

On renders with a perfect robot the reported std of fx falls short of its scatter (one
session: ratio 0.49, benchmarks/results/robot_error_renders.md), though the pixel noise is
only 0.02-0.04 px. This study takes the one-session perfect-robot renders of
``bench_robot_error_renders.py`` (``robot_scene`` eye-in-hand, 12 views of 3-D pure
translation, JPEG 90 files, ``--supersample`` samples per pixel as the Monte Carlo's
``--supersample``), with the camera effects on (``default``: vignetting, exposure,
sensor noise, a highlight, lens distortion), off (``clean``: none of them, no lens
distortion), all off but the lens and read noise (``lens+noise``), those plus one effect
(``lens+noise+exposure``, the effects of ``bench_link_lean.py``), or every effect with
more read noise (``noisy``: does the floor matter once the tracks are noisier?), tracks the files as
the command does (:func:`transcalib.images.track` with the translations) and compares
every tracked observation with the exact projection of the 3-D point its first
observation shows (:meth:`RobotRendered.track_truth`):

- ``err`` the tracker's error per coordinate (px, RMS) against ``sigma_px``, the
  calibration's pixel noise: what the fit absorbs (errors shared by a track's
  observations move its 3-D point) and what it leaves;
- ``shift`` the RMS over views of each view's mean error (first observations left out),
  against ``err / sqrt(n)`` (n: observations per view), what white errors would give: an
  error shared by the points of a view does not average down with their number, so a
  few thousandths of a pixel weigh on fx as much as the pixel noise of every point;
- ``view field`` the RMS of each view's quadratic error field over the image (a few
  thousandths of a pixel: 5 % of the error's energy, yet alike over the ~1000 points of a
  view and absorbed by the intrinsics, it moved fx as much as the pixel noise of every
  point did), and fx's z with it removed from the tracked positions. It came from the
  alignment's brightness model: with gain and offset alone a brightness gradient across
  the window that differs between the views (shading, vignetting) pulled the alignment;
  the ramp in :func:`transcalib.images.refine.lk_affine` took fx's std / RMS error from
  0.56 to 0.82 on the 16 seeds of ``default``;
- ``along`` the error along each observation's displacement from its first view, as a
  fraction of that displacement (a tracker that falls short of the motion would scale
  the parallax and with it fx), and ``radial`` each view's radial error at 300 px from
  the principal point (a pattern that scales the image);
- fx's error, its reported std and which std the calibration reported (``model`` or the
  point-clustered sandwich ``robust``, docs/uncertainty.md §7) and z = error / std, for
  the tracked positions and for the exact projections with white noise of the tracker's
  RMS error (``exact+noise``: what the model's std promises);
- in the summary, fx from the exact projections plus one component of the tracker's
  error: ``along`` the motion (each observation's error along its displacement from the
  track's first view) or ``across`` it (the rest), tracks next to another surface left
  out (T-junctions): which component carries fx's lean; and fx from the exact
  projections plus the tracker's errors rearranged (:func:`_rearranged`): ``tracks
  permuted`` (each track's error vector given to another track with the same views: the
  errors' correlation along a track kept, their tie to its place and its neighbours
  gone) and ``views shuffled`` (each view's errors shuffled among its tracks: their
  correlation along a track gone): which structure of the errors the std misses; and
  ``tracked, one noise``: the tracked positions judged with one noise for every track
  (``RansacOptions(noise_spread=False)``, the rule before 2026-12-05), whose choice of the
  tracks followed the fit's error (docs/robust-and-diagnostics.md §2).

Writes ``benchmarks/results/NAME.md`` (default ``render_floor``; ``--quick``: 2 seeds, a scratch folder).
"""

from __future__ import annotations

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import md_table, results_dir  # noqa: E402
from bench_link_lean import EFFECTS  # noqa: E402  (one camera effect each)
from bench_robot_error_renders import FIRST_SEED, JPEG_QUALITY  # noqa: E402  (its perfect-robot seeds)

VARIANTS = ("default", "clean", "lens+noise", "noisy")
#: Read noise (grey levels) of the ``noisy`` variant: every effect, tracks of a few hundredths
#: of a pixel more noise (the preset's read noise is 1.2).
NOISY_READ_DN = 8.0
#: The calibrations of each render (the summary's rows).
CALIBRATIONS = ("tracked", "tracked, one noise", "tracked - view field", "exact+noise", "exact+along", "exact+across",
                "tracks permuted", "views shuffled")


def _degrade(variant: str):
    """``robot_scene``'s ``degrade`` of a variant: every effect, none (nor the lens), the
    lens and the preset's read noise alone, those plus one effect (``lens+noise+jpeg``),
    or every effect with :data:`NOISY_READ_DN` of read noise (``noisy``)."""
    from dataclasses import replace

    from transcalib.synth.robot_layout import preset_degradations

    if variant == "noisy":
        return replace(preset_degradations((640, 480)), read_noise_dn=NOISY_READ_DN)
    if not variant.startswith("lens+noise"):
        return variant == "default"
    off = dict(vignetting=0.0, exposure=0.0, full_well_e=None, jpeg_quality=None, specular=0.0)
    return replace(preset_degradations((640, 480)), **{**off, **EFFECTS.get(variant[len("lens+noise+"):], {})})


def _tracked(r, folder: Path) -> np.ndarray:
    """``uv`` of the renders written as JPEG files and tracked as the command tracks them."""
    from transcalib.images import track

    paths = [folder / f"view{i:02d}.jpg" for i in range(len(r.images))]
    for path, im in zip(paths, r.images):
        cv2.imwrite(str(path), im, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    return track(paths, T=r.T).uv


def trial(job: tuple) -> dict:
    """One render of ``(variant, seed, supersample)``: the tracker's errors and the calibrations."""
    import tempfile

    from transcalib import Poses, RansacOptions, calibrate
    from transcalib.synth.robot import robot_scene

    variant, seed, supersample = job
    r = robot_scene("eye-in-hand", rng=seed, degrade=_degrade(variant), session_views=12, single_views=0,
                    supersample=supersample)
    with tempfile.TemporaryDirectory() as tmp:
        uv = _tracked(r, Path(tmp))
    X, junction = r.track_truth(uv)
    keep = np.all(np.isfinite(X), axis=1) & ~junction  # a T-junction has no fixed 3-D point
    uv, X = uv[:, keep], X[keep]
    exact = r.project(X)
    seen = np.isfinite(uv[..., 0])
    err = np.where(seen[..., None], uv - exact, np.nan)
    rms = float(np.sqrt(np.nanmean(err**2)))
    out = {"variant": variant, "seed": seed, "err": rms, "n_obs": int(seen.sum()), **_shift(err, seen),
           "along": _along(err, exact, seen), "radial": _radial(err, uv, seen, r.K)}
    noisy = exact + np.random.default_rng(seed).normal(0.0, rms, exact.shape)
    field = _view_field(err, exact, seen, r.K)
    out["field"] = float(np.sqrt(np.nanmean(field**2)))
    along = _along_part(err, exact, seen)
    # NaN where unseen stays there: a track's errors go only to tracks with the same views
    permuted, shuffled = (exact + e for e in _rearranged(err, seen, np.random.default_rng(seed + 1)))
    for name, u in zip(CALIBRATIONS, (uv, uv, uv - field, np.where(seen[..., None], noisy, np.nan),
                                      exact + along, exact + (err - along), permuted, shuffled)):
        ransac = RansacOptions(noise_spread=name != "tracked, one noise")
        cal = calibrate(u, Poses.of(r.T, r.R), image_size=r.image_size, ransac=ransac, rng=0)
        e = cal.K[0, 0] - r.K[0, 0]
        reported = cal.uncertainty.reported["fx"] if cal.uncertainty is not None else "model"
        out[name] = {"fx_err": float(e), "fx_std": float(cal.std["fx"]), "sigma_px": float(cal.sigma_px),
                     "reported": reported}
    return out


def _rearranged(err, seen, rng) -> tuple:
    """The tracker's errors ``err`` rearranged: ``(tracks permuted, views shuffled)``.
    Tracks permuted: each track takes the whole error vector of another track with the
    same views and reference view (its errors' correlation across the views kept, their
    tie to the track's place and to its neighbours' errors gone); views shuffled: within
    each view the errors of its non-reference observations shuffled among its tracks
    (each view's errors and their spread kept, their correlation along a track gone)."""
    ref = np.argmax(seen, axis=0)
    permuted, shuffled = err.copy(), err.copy()
    _, group = np.unique(np.c_[seen.T, ref], axis=0, return_inverse=True)
    for g in np.unique(group):
        idx = np.flatnonzero(group == g)
        permuted[:, idx] = err[:, rng.permutation(idx)]
    is_ref = np.zeros_like(seen)
    is_ref[ref, np.arange(seen.shape[1])] = True
    for v in range(seen.shape[0]):
        idx = np.flatnonzero(seen[v] & ~is_ref[v])
        shuffled[v, idx] = err[v, rng.permutation(idx)]
    return permuted, shuffled


def _shift(err, seen) -> dict:
    """RMS over views and coordinates of each view's mean error (first observations left
    out: zero by construction), and what white errors of the same RMS would give."""
    first = np.argmax(seen, axis=0)
    means, counts = [], []
    for v in range(err.shape[0]):
        m = seen[v] & (first != v)
        if m.sum() >= 10:
            means.append(err[v, m].mean(axis=0))
            counts.append(m.sum())
    rms = float(np.sqrt(np.nanmean(err**2)))
    return {"shift": float(np.sqrt(np.mean(np.square(means)))), "shift_white": rms / float(np.sqrt(np.mean(counts)))}


def _view_field(err, exact, seen, K, degree: int = 2) -> np.ndarray:
    """Each view's smooth error field: the least-squares polynomial of ``degree`` in the
    image position (about the principal point, in units of 320 px) fitted to its errors
    (first observations left out: zero by construction); ``(n_views, n_points, 2)``, NaN
    where unseen. An error alike over a view does not average down with its points, and
    the intrinsics absorb it: the residuals do not show it."""
    first = np.argmax(seen, axis=0)
    out = np.full(err.shape, np.nan)
    for v in range(err.shape[0]):
        m = seen[v] & (first != v)
        out[v, seen[v]] = 0.0
        if m.sum() < 20:
            continue
        x = (exact[v] - K[:2, 2]) / 320.0
        powers = [(i - j, j) for i in range(degree + 1) for j in range(i + 1)]
        A = np.column_stack([x[:, 0] ** a * x[:, 1] ** b for a, b in powers])
        coef = np.linalg.lstsq(A[m], err[v, m], rcond=None)[0]
        out[v, m] = A[m] @ coef
    return out


def _displacements(exact, seen) -> np.ndarray:
    """Each observation's displacement from its track's first view ``(n_views, n_points, 2)``."""
    first = np.argmax(seen, axis=0)
    return exact - exact[first, np.arange(exact.shape[1])][None]


def _along_part(err, exact, seen) -> np.ndarray:
    """The component of each observation's error along its displacement from its track's
    first view ``(n_views, n_points, 2)`` (0 where it has not moved; NaN where unseen)."""
    d = _displacements(exact, seen)
    dn = np.linalg.norm(d, axis=2, keepdims=True)
    u = np.divide(d, dn, out=np.zeros_like(d), where=dn > 1e-9)
    return np.sum(err * u, axis=2, keepdims=True) * u


def _along(err, exact, seen) -> float:
    """Least-squares slope of the error along each observation's displacement from its
    track's first view against that displacement (px per px)."""
    d = _displacements(exact, seen)
    dn = np.linalg.norm(d, axis=2)
    m = seen & (dn > 1.0)
    along = np.sum(err * d, axis=2)[m] / dn[m]
    return float(np.sum(along * dn[m]) / np.sum(dn[m] ** 2))


def _radial(err, uv, seen, K) -> float:
    """Median over views of the radial error at 300 px from the principal point (px) of
    a fit ``e_radial = k r`` per view (first observations left out: zero by construction)."""
    first = np.argmax(seen, axis=0)
    out = []
    for v in range(uv.shape[0]):
        m = seen[v] & (first != v)
        if m.sum() < 10:
            continue
        d = uv[v, m] - K[:2, 2]
        r = np.linalg.norm(d, axis=1)
        radial = np.sum(err[v, m] * d / r[:, None], axis=1)
        out.append(300.0 * np.sum(radial * r) / np.sum(r * r))
    return float(np.median(out))


def table(rows: list, elapsed: float, seeds: int, supersample: int, command: str = "") -> str:
    head = ["variant", "seed", "err px", "shift px (white)", "view field px", "along", "radial px @300",
            "sigma_px tracked", "fx err (tracked)", "fx std (reported)", "z tracked", "z without the view field",
            "fx err (exact+noise)", "z exact+noise"]
    body = []
    for r in rows:
        t, x, f = r["tracked"], r["exact+noise"], r["tracked - view field"]
        body.append([r["variant"], r["seed"], r["err"], f"{r['shift']:.4f} ({r['shift_white']:.4f})", r["field"],
                     r["along"], r["radial"], t["sigma_px"], t["fx_err"], f"{t['fx_std']:.4f} ({t['reported']})",
                     t["fx_err"] / t["fx_std"], f["fx_err"] / f["fx_std"], x["fx_err"], x["fx_err"] / x["fx_std"]])
    summary = []
    for v in dict.fromkeys(r["variant"] for r in rows):
        mine = [r for r in rows if r["variant"] == v]
        for name in CALIBRATIONS:
            z = np.array([r[name]["fx_err"] / r[name]["fx_std"] for r in mine])
            e = np.array([r[name]["fx_err"] for r in mine])
            sd = np.array([r[name]["fx_std"] for r in mine])
            shift = np.sqrt(np.mean([r["shift"] ** 2 for r in mine]))
            summary.append(f"- {v}, {name}: fx std ratio {np.sqrt(np.mean(sd**2) / np.mean(e**2)):.2f}, mean z "
                           f"{z.mean():+.2f}, RMS z {np.sqrt(np.mean(z**2)):.2f}, mean error {e.mean():+.4f} px "
                           f"(N = {len(mine)})"
                           + (f"; views' mean error {shift:.4f} px RMS" if name == "tracked" else ""))
    return "\n".join([
        "# The renders' perfect-robot floor: the tracker against the truth", "",
        f"`python benchmarks/bench_render_floor.py --seeds {seeds} --supersample {supersample}{command}` "
        f"({elapsed:.0f} s). "
        f"One-session perfect-robot renders ({supersample} x {supersample} samples per pixel, 12 views, JPEG 90 "
        "files; seeds of bench_robot_error_renders.py), tracked as the command tracks them. err: the tracker's "
        "RMS error per coordinate against the exact projection of the point its first observation shows; shift: "
        "RMS of the views' mean errors (in brackets: what white errors of that RMS would give); view field: RMS of "
        "each view's quadratic error field over the image, and z without it (the tracked positions less that "
        "field); along: "
        "the error along the displacement from the first view per px of displacement; radial: median per-view "
        "radial error at 300 px; z = fx error / reported std (tracked) and for the exact projections with white "
        "noise of the tracker's RMS error (exact+noise), and in the summary for the exact projections plus the "
        "tracker's error along the motion or across it (exact+along, exact+across), or all of it rearranged: each "
        "track's error vector given to another track with the same views (tracks permuted: the correlation along "
        "a track kept, that with its place and its neighbours gone) or each view's errors shuffled among its "
        "tracks (views shuffled: each view's errors kept, their correlation along a track gone). Ratio = RMS std / RMS error "
        "(1 when the std is right; its own uncertainty ~1/sqrt(2N)).", "", md_table(head, body), "", *summary, ""])


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--supersample", type=int, default=2, help="samples per pixel and axis (the Monte Carlo's: 4)")
    p.add_argument("--variants", default=",".join(VARIANTS),
                   help=f"comma-separated, of {', '.join(VARIANTS)} and lens+noise+E, E one of {', '.join(EFFECTS)}")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--name", default="render_floor", help="results file name, without .md")
    a = p.parse_args(argv)
    variants = [v.strip() for v in a.variants.split(",") if v.strip()]
    known = set(VARIANTS) | {f"lens+noise+{e}" for e in EFFECTS}
    if not variants or set(variants) - known:
        p.error(f"--variants: give some of {', '.join(sorted(known))}, got {a.variants!r}")
    if a.supersample < 1:
        p.error(f"--supersample must be >= 1, got {a.supersample}")
    seeds = 2 if a.quick else a.seeds
    jobs = [(v, FIRST_SEED + k, a.supersample) for k in range(seeds) for v in variants]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(a.jobs) as pool:
        rows = list(pool.map(trial, jobs))
    command = (f" --variants {','.join(variants)}" if variants != list(VARIANTS) else "") + \
        (f" --name {a.name}" if a.name != "render_floor" else "")
    text = table(rows, time.perf_counter() - t0, seeds, a.supersample, command)
    (results_dir(a.quick) / f"{a.name}.md").write_text(text)
    sys.stdout.write(text)


if __name__ == "__main__":
    main()
