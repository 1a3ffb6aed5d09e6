"""transcalib against COLMAP's self-calibrating structure from motion (``pycolmap``).

COLMAP is the targetless tool users try first. On the same rendered images: SIFT feature
extraction, exhaustive matching, incremental mapping, with one shared camera
(``CameraMode.SINGLE``) of COLMAP's default model (SIMPLE_RADIAL) and of OPENCV; the
initial focal length is COLMAP's default guess (1.2 x the larger image side, no EXIF).
Scenes:

* ``board``: the experiment-1 images (``bench_paper1``: six black squares, four views);
* ``textured``: ``render.render_scene("natural")`` (textured wall and boxes) seen by the
  same 752 x 582 camera (fx 1744, fy 1807) from six purely translated positions.

Reported: whether a model was built and with how many images/points, the recovered
intrinsics against the truth, the scale (COLMAP has none: the best similarity fit of
its camera centres to the true ones, and the residual of that fit), and the time;
transcalib (``track`` / ``track_squares`` + ``calibrate``) on the same images beside it.
Pure translation is a critical motion for self-calibration (the images determine the
scene only up to an affine transformation, so the focal lengths are not observable
from them): COLMAP is expected to keep a wrong focal length.

Without ``pycolmap`` the benchmark writes a note and skips. ``pip install pycolmap``
(the ``bench`` extra of ``pyproject.toml``).

    python benchmarks/bench_colmap.py [--quick]     (--quick writes to a scratch folder)
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import transcalib  # noqa: E402
from transcalib import render  # noqa: E402
from _common import results_dir, k5, md_table, rigid_align  # noqa: E402

SIZE = (752, 582)


def scenes(quick: bool):
    import bench_paper1

    K, R, T, surf, corners, st = bench_paper1.setup()
    board = render.render([surf], K, R, T, SIZE, supersample=2, background=0.35, blur_sigma=0.8, noise_std=1.0,
                          rng=1000)
    n = 4 if quick else 6
    tex = render.render_scene("natural", n_views=n, image_size=SIZE, K=K, distance=600.0, baseline=0.1,
                              noise_std=1.0, supersample=1 if quick else 2, rng=3)
    return {"board": (board, K, T, "target"), "textured": (tex.images, K, tex.T, "features")}


def run_colmap(images, model: str, workdir: Path):
    import cv2
    import pycolmap

    img_dir = workdir / "images"
    img_dir.mkdir(parents=True, exist_ok=True)
    names = []
    for i, im in enumerate(images):
        name = f"view{i}.png"
        cv2.imwrite(str(img_dir / name), im)
        names.append(name)
    db = workdir / "database.db"
    if db.exists():
        db.unlink()
    t0 = time.perf_counter()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = model
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = 2
    pycolmap.extract_features(db, img_dir, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              extraction_options=ext, device=pycolmap.Device.cpu)
    mopt = pycolmap.FeatureMatchingOptions()
    mopt.num_threads = 2
    pycolmap.match_exhaustive(db, matching_options=mopt, device=pycolmap.Device.cpu)
    out = workdir / f"sparse_{model}"
    out.mkdir(exist_ok=True)
    popt = pycolmap.IncrementalPipelineOptions()
    popt.num_threads = 2
    recs = pycolmap.incremental_mapping(db, img_dir, out, options=popt)
    dt = time.perf_counter() - t0
    if not recs:
        return {"ok": False, "time": dt}
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    cam = next(iter(rec.cameras.values()))
    centres = {}
    for img in rec.images.values():
        pose = img.cam_from_world() if callable(img.cam_from_world) else img.cam_from_world
        Rm = pose.rotation.matrix()
        centres[names.index(img.name)] = -Rm.T @ pose.translation
    return {"ok": True, "time": dt, "n_images": rec.num_reg_images(), "n_points": rec.num_points3D(),
            "model": cam.model.name, "params": np.asarray(cam.params, float), "param_info": cam.params_info,
            "centres": centres, "n_models": len(recs)}


def colmap_k(res):
    p, model = res["params"], res["model"]
    if model in ("SIMPLE_RADIAL", "SIMPLE_PINHOLE", "RADIAL"):
        return {"fx": p[0], "fy": p[0], "cx": p[1], "cy": p[2]}
    return {"fx": p[0], "fy": p[1], "cx": p[2], "cy": p[3]}


def run_transcalib(images, T, mode):
    t0 = time.perf_counter()
    tr = transcalib.track_squares(images) if mode == "target" else transcalib.track(images)
    cal = transcalib.calibrate(tr.uv, T, image_size=SIZE, unit="mm", rng=0)
    return cal, time.perf_counter() - t0, tr.n_points


def main(argv=()) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(list(argv))
    global RESULTS
    RESULTS = results_dir(args.quick)
    OUT = RESULTS / "colmap.md"
    cmd = f"`python benchmarks/bench_colmap.py{' --quick' if args.quick else ''}`"
    try:
        import pycolmap
    except ImportError:
        OUT.write_text(f"# transcalib against COLMAP\n\nCommand: {cmd}\n\nSkipped: `pycolmap` is not installed "
                       "(`pip install -e '.[bench]'`).\n")
        print("bench_colmap: pycolmap not installed - skipped")
        return {}
    pycolmap.logging.minloglevel = 2  # warnings and errors only
    pycolmap.logging.stderrthreshold = 2
    rows, notes = [], []
    for name, (images, K, T, mode) in scenes(args.quick).items():
        truth = k5(K)
        rows.append([name, "ground truth", "", truth["fx"], truth["fy"], truth["cx"], truth["cy"], "", "", ""])
        cal, t_tc, n_tr = run_transcalib(images, T, mode)
        e = k5(cal.K)
        rows.append([name, f"transcalib ({'track_squares' if mode == 'target' else 'track'} + calibrate)",
                     f"{len(T)}/{len(T)} views, {n_tr} tracks", e["fx"], e["fy"], e["cx"], e["cy"],
                     "metric (robot units)", "", t_tc])
        for model in ("SIMPLE_RADIAL", "OPENCV"):
            with tempfile.TemporaryDirectory() as tmp:
                try:
                    res = run_colmap(images, model, Path(tmp))
                except Exception as exc:  # a failing external tool is a result, reported
                    res = {"ok": False, "time": float("nan"), "error": f"{type(exc).__name__}: {exc}"}
            label = f"COLMAP {model}{' (default)' if model == 'SIMPLE_RADIAL' else ''}"
            if not res["ok"]:
                rows.append([name, label, "no model" + (f" ({res['error'][:80]})" if "error" in res else ""),
                             "-", "-", "-", "-", "-", "-", res["time"]])
                continue
            ck = colmap_k(res)
            idx = sorted(res["centres"])
            C = np.array([res["centres"][i] for i in idx])
            if len(idx) >= 3:
                moved, s = rigid_align(C, T[idx], scale=True)
                fit = float(np.sqrt(np.mean(np.sum((moved - T[idx]) ** 2, axis=1))))
                scale_txt, fit_txt = f"{s:.4g} (mm per unit)", f"{fit:.2f} mm"
            else:
                scale_txt, fit_txt = "-", "-"
            rows.append([name, label, f"{res['n_images']}/{len(T)} images, {res['n_points']} points"
                         + (f", {res['n_models']} models" if res["n_models"] > 1 else ""),
                         ck["fx"], ck["fy"], ck["cx"], ck["cy"], scale_txt, fit_txt, res["time"]])
            notes.append(f"{name}, {model}: fx error {ck['fx'] - truth['fx']:+.0f} px "
                         f"({100 * (ck['fx'] / truth['fx'] - 1):+.0f} %), fy error {ck['fy'] - truth['fy']:+.0f} px; "
                         f"params {np.round(res['params'], 4).tolist()}")
    md = [
        "# transcalib against COLMAP's self-calibrating SfM (pycolmap)", "",
        f"Command: {cmd} (pycolmap {pycolmap.__version__}, CPU, 2 threads; one shared camera per run, COLMAP's "
        "default initial focal length 1.2 x 752 = 902 px; COLMAP's default keeps the principal point at the image "
        "centre). transcalib is given the exact translations here (no robot noise) and its defaults "
        "(robust, refinement, distortion `auto`).", "",
        md_table(["scene", "method", "registered", "fx", "fy", "cx", "cy", "scale (similarity fit)",
                  "fit residual of camera centres", "time (s)"], rows), "",
        "Errors: " + "; ".join(notes) if notes else "COLMAP built no model on any scene.", "",
        "Reading: under pure translation the images alone fix the scene only up to an affine transformation, so "
        "COLMAP's bundle adjustment has no information on the focal length (a critical motion for "
        "self-calibration) and the scale is arbitrary; the similarity fit of its camera centres gives the scale "
        "after the fact only because the true centres are known. transcalib gets K and the metric scale from the "
        "known translations.", ""]
    OUT.write_text("\n".join(md))
    print("\n".join(md))
    return {"rows": rows}


if __name__ == "__main__":
    main(sys.argv[1:])
