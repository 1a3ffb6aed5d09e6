"""Studies beyond the paper: accuracy of fx and cx against pixel noise, number of points,
translation magnitude and number of views - linear (the paper's), refined and the
Cramer-Rao bound side by side - and transcalib against the target-based route.

Monte Carlo on simulated tracks (``transcalib.simulate``): one base scene per setting
(``random_scene`` with a fixed seed: 800 x 600, points 1 m away in a box 0.5 m deep,
translations ``baseline * 1 m``), ``trials`` noisy observations (``observe``, exact
translations so that the bound is the pixel-noise bound), each calibrated by
``transcalib.calibrate(robust=False, distortion="none")``. Errors are rms over the trials;
the bound is ``transcalib.crlb(scene, distortion="none")``. Default setting: 50 points,
4 views, 0.5 px, baseline 0.2; one factor varied at a time.

The target-based route: OpenCV ``calibrateCamera`` given the known scene on the same
observations - (a) the same non-coplanar points as a known 3-D object (Tsai's
non-coplanar case; OpenCV needs an initial guess for it: fx = fy = image width, principal
point at the centre), (b) a planar board seen from the same translated poses
(``random_scene(planar=True)``) with the principal point free and fixed at the image
centre, against transcalib on the same board tracks.

    python benchmarks/bench_studies.py [--quick]      (--quick: 12 trials instead of 60)

Writes ``benchmarks/results/studies.md`` and ``results/studies_*.png`` (``--quick``: to a scratch folder).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import transcalib  # noqa: E402
from transcalib import simulate  # noqa: E402
from _common import results_dir, md_table, plane_fit  # noqa: E402

BASE = dict(n_points=50, n_views=4, noise_px=0.5, baseline=0.2)
STUDIES = {
    "noise_px": [0.1, 0.3, 1.0, 3.0],
    "n_points": [10, 25, 50, 100, 200],
    "baseline": [0.05, 0.1, 0.2, 0.4],
    "n_views": [4, 6, 8, 12],
}
LABEL = {"noise_px": "pixel noise (px)", "n_points": "number of points", "baseline": "translation / distance",
         "n_views": "number of views"}
SEED = 5


def _cv_calibrate(obj_list, img_list, size, K0, flags):
    import cv2

    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    rms, K, *_ = cv2.calibrateCamera(obj_list, img_list, size, K0.copy(), np.zeros(5), flags=flags, criteria=crit)
    return K


def opencv_known(X, uv, size, planar_st=None, fix_pp=False):
    """OpenCV calibration with the known scene: ``X`` (n, 3) non-coplanar known points, or
    ``planar_st`` (n, 2) board coordinates. Returns K, or None if OpenCV refused."""
    import cv2

    w, h = size
    flags = cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    K0 = np.array([[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1]], float)
    if planar_st is None:
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS  # required by OpenCV for a non-planar object
        obj3 = X
    else:
        obj3 = np.column_stack([planar_st, np.zeros(len(planar_st))])
    if fix_pp:
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
    objs, imgs = [], []
    for i in range(uv.shape[0]):
        ok = np.isfinite(uv[i, :, 0])
        if ok.sum() >= 6:
            objs.append(obj3[ok].astype(np.float32))
            imgs.append(uv[i, ok].astype(np.float32).reshape(-1, 1, 2))
    try:
        return _cv_calibrate(objs, imgs, (w, h), K0, flags)
    except cv2.error:
        return None


def base_scene(planar=False, **kw):
    p = {**BASE, **kw}
    return simulate.random_scene(p["n_points"], p["n_views"], planar=planar, noise_px=p["noise_px"],
                                 baseline=p["baseline"], image_size=(800, 600), rng=SEED)


def run_setting(scene, trials, with_cv=True, planar=False):
    """rms errors of fx, cx over ``trials`` observations: linear, refined, OpenCV; CRLB."""
    K = scene.K
    errs = {m: [] for m in ("linear", "refined", "cv", "cv_fix")}
    failed = {m: 0 for m in errs}
    st = None
    if planar:
        c, V, _ = plane_fit(scene.X)
        st = (scene.X - c) @ V[:2].T
    for k in range(trials):
        obs = simulate.observe(scene, scene.noise_px, rng=10_000 + k)
        try:
            cal = transcalib.calibrate(obs.uv, obs.T, robust=False, distortion="none", check_rotation=False)
            errs["linear"].append([cal.linear.K[0, 0] - K[0, 0], cal.linear.K[0, 2] - K[0, 2]])
            errs["refined"].append([cal.K[0, 0] - K[0, 0], cal.K[0, 2] - K[0, 2]])
        except ValueError:
            failed["linear"] += 1
            failed["refined"] += 1
        if with_cv:
            for m, fix in (("cv", False), ("cv_fix", True)) if planar else (("cv", False),):
                Kc = opencv_known(scene.X, obs.uv, scene.image_size, planar_st=st, fix_pp=fix)
                if Kc is None or not np.all(np.isfinite(Kc)) or abs(Kc[0, 0] / K[0, 0] - 1) > 0.2:
                    failed[m] += 1  # refused or diverged (fx off by > 20 %): counted, not averaged
                else:
                    errs[m].append([Kc[0, 0] - K[0, 0], Kc[0, 2] - K[0, 2]])
    out = {}
    for m, e in errs.items():
        e = np.array(e).reshape(-1, 2)
        out[m] = (np.sqrt(np.mean(e**2, axis=0)) if len(e) else np.array([np.nan, np.nan]), failed[m])
    b = transcalib.crlb(scene, distortion="none")
    out["crlb"] = (np.array([b["fx"], b["cx"]]), 0)
    return out


def plot(name, xs, res, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(9, 3.4))
    for j, par in enumerate(("fx", "cx")):
        ax = axs[j]
        for m, style, lab in (("linear", "o-", "linear (paper)"), ("refined", "s-", "refined"),
                              ("crlb", "k--", "CRLB"), ("cv", "^:", "OpenCV, known 3-D points")):
            y = [r[m][0][j] for r in res]
            ax.plot(xs, y, style, label=lab, mfc="none")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(LABEL[name])
        ax.set_ylabel(f"rms error of {par} (px)")
        ax.grid(alpha=0.3, which="both")
    axs[0].legend(fontsize=7)
    fig.suptitle(f"fx and cx error against {LABEL[name]}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=()) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(list(argv))
    global RESULTS
    RESULTS = results_dir(args.quick)
    trials = 12 if args.quick else 60
    t_start = time.perf_counter()
    md = ["# Studies: accuracy against noise, points, translation, views; linear, refined, CRLB, OpenCV", "",
          f"Command: `python benchmarks/bench_studies.py{' --quick' if args.quick else ''}` ({trials} trials per "
          f"setting; base scene `random_scene(..., image_size=(800, 600), rng={SEED})`, defaults {BASE}, one factor "
          "varied at a time; exact translations). Entries: rms error of fx / cx in px over the trials; CRLB: the "
          "bound on their std; OpenCV: `calibrateCamera` given the true 3-D points (a known non-coplanar scene, an "
          "idealised Tsai calibration: it knows the scene exactly, which transcalib does not); runs where OpenCV's "
          "optimiser diverged from its generic start (fx off by > 20 %) are counted as failed, not averaged.",
          ""]
    allres = {}
    for name, xs in STUDIES.items():
        res = []
        for x in xs:
            sc = base_scene(**{name: x})
            res.append(run_setting(sc, trials))
        allres[name] = res
        plot(name, xs, res, RESULTS / f"studies_{name}.png")
        rows = []
        for x, r in zip(xs, res):
            row = [x]
            for m in ("linear", "refined", "crlb", "cv"):
                row.append(f"{r[m][0][0]:.3g} / {r[m][0][1]:.3g}" + (f" ({r[m][1]} failed)" if r[m][1] else ""))
            row.append(f"{r['refined'][0][0] / r['crlb'][0][0]:.2f} / {r['refined'][0][1] / r['crlb'][0][1]:.2f}")
            rows.append(row)
        md += [f"## Against {LABEL[name]}", "",
               md_table([LABEL[name], "linear", "refined", "CRLB", "OpenCV known 3-D", "refined / CRLB"], rows), "",
               f"Plot: `studies_{name}.png`.", ""]
    # the board route from the same translated poses
    rows = []
    for noise in (0.1, 0.5, 2.0):
        sc = base_scene(planar=True, noise_px=noise)
        r = run_setting(sc, trials, planar=True)
        rows.append([noise] + [f"{r[m][0][0]:.3g} / {r[m][0][1]:.3g}" + (f" ({r[m][1]} failed)" if r[m][1] else "")
                               for m in ("linear", "refined", "crlb", "cv", "cv_fix")])
    true_cx = base_scene(planar=True).K[0, 2]
    md += ["## Target-based route: a planar board seen from the same translated poses", "",
           md_table(["pixel noise (px)", "transcalib linear", "transcalib refined", "CRLB (transcalib model)",
                     "OpenCV board, pp free", "OpenCV board, pp fixed at centre"], rows), "",
           "rms error of fx / cx (px). Under pure translation the board has the same orientation in every view, so "
           "Zhang's constraints repeat and the board route cannot determine the principal point: free, it wanders "
           "(errors of tens to hundreds of px); fixed at the image centre, cx is off by the true offset "
           f"(|{true_cx:.1f} - {399.5}| = {abs(true_cx - 399.5):.1f} px) and fx absorbs part of it. transcalib uses the "
           "translations and needs no known scene. (The board route becomes well posed with tilted board views, "
           "which the robot here does not make.)", "",
           f"Total time {time.perf_counter() - t_start:.1f} s.", ""]
    (RESULTS / "studies.md").write_text("\n".join(md))
    print("\n".join(md))
    return allres


if __name__ == "__main__":
    main(sys.argv[1:])
