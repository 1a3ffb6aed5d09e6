"""Benchmark of the sessions model (issue 11): accuracy vs the CRLB, and three routes compared.

(a) Monte Carlo: fixed geometry (``transcalib.handeye.simulate.session_scene``: a
    table-top scene ~0.5 m below the camera, 60 points, 6 views per session, the wrist
    tilted 25 deg between sessions), fresh 0.5 px noise per trial. Empirical std of fx,
    fy, cx, cy, the rotation ``w`` of ``R_X^T`` (``R_est R_true^T = exp([w]x)``, degrees)
    and ``t_X`` beside the Cramér-Rao bound (``transcalib.handeye.observability.sessions_crlb``).
    Target: within 10 %.
(b) The table of ``docs/hand-eye.md``: on the same poses and noise, (1) the single-session
    method (paper + ML refinement on session 0 only; ``R_X = R_0^T R^T``, no ``t_X``),
    (2) the multi-session method (``calibrate_sessions``), (3) the target-based route: a
    9 x 6 checkerboard (25 mm) on the table seen from the same poses, OpenCV
    ``calibrateCamera`` (pinhole, no distortion, as the truth) then a hand-eye solve
    ``AX = XB`` over all view pairs: ``cv2.calibrateHandEye`` (Park) when the installed
    OpenCV has it, else Park & Martin's closed form written out below (the same method;
    the OpenCV 5.0 wheels lack the function). RMS errors over the trials.

Run ``python benchmarks/bench_handeye.py`` (``--quick``: few trials). Writes
``benchmarks/results/handeye.md``.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from transcalib.errors import DegenerateError, TranscalibError
from transcalib.estimate.linear import estimate_linear
from transcalib.estimate.refine import refine
from transcalib.geometry.camera import project
from transcalib.geometry.rotation import matrix_to_rotvec, rotation_angle_deg, rotvec_to_matrix
from transcalib.handeye import calibrate_sessions
from transcalib.handeye.observability import offset_observability, sessions_crlb
from transcalib.handeye.simulate import session_scene

HERE = Path(__file__).resolve().parent
SCENES = {
    "3 sessions, 3-D moves": dict(n_sessions=3, moves="3d"),
    "3 sessions, 2-axis (xy) moves": dict(n_sessions=3, moves="xy"),
    "2 sessions, 2-axis (xy) moves": dict(n_sessions=2, moves="xy"),
}
NOISE_PX = 0.5


def _noisy(base, rng):
    """The scene ``base`` with fresh pixel noise (same visibility)."""
    uv = base.uv_true + rng.normal(0.0, NOISE_PX, base.uv_true.shape)
    uv[~np.isfinite(base.uv)] = np.nan
    return replace(base, uv=uv, noise_px=NOISE_PX)


def _determined_basis(sc):
    """Directions of t_X the (noise-free) problem determines, from the Fisher information."""
    from transcalib.handeye.sessions import group_sessions
    g = group_sessions(sc.R)
    obs = offset_observability(sc.K, np.zeros(5), sc.R_X.T, sc.t_X, sc.X, sc.uv_true, sc.T,
                               np.transpose(sc.R, (0, 2, 1)), g.rotations, g.labels)
    return obs.determined


def monte_carlo(name, kw, trials, seed=0) -> list[str]:
    base = session_scene(seed, n_points=60, **kw)
    B = _determined_basis(base)
    full = B.shape[1] == 3
    bound = sessions_crlb(replace(base, noise_px=NOISE_PX), t_basis=None if full else B)
    t_names = ["t_x", "t_y", "t_z"] if full else [f"t_{k}" for k in range(B.shape[1])]
    names = ["fx", "fy", "cx", "cy", "rx", "ry", "rz", *t_names]
    rng = np.random.default_rng(seed + 1)
    rows, fails = [], 0
    for _ in range(trials):
        sc = _noisy(base, rng)
        try:
            he = calibrate_sessions(sc.uv, sc.T, sc.R)
        except TranscalibError:
            fails += 1
            continue
        K = he.K
        w = np.degrees(matrix_to_rotvec(he.R_flange_camera.T @ base.R_X))  # R_est R_true^T, R = R_X^T
        t = he.t_flange_camera if full else B.T @ he.t_flange_camera
        rows.append([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *w, *t])
    est = np.array(rows)
    std = est.std(axis=0, ddof=1)
    out = [f"**{name}** ({len(rows)} trials, {fails} failed, noise {NOISE_PX} px"
           + ("" if full else f"; t_X free along {np.round(_free(B), 3).tolist()}, t_k along the determined basis")
           + ")", "", "| parameter | empirical std | CRLB | ratio |", "|---|---|---|---|"]
    for k, nm in enumerate(names):
        unit = "deg" if nm.startswith("r") else ("mm" if nm.startswith("t") else "px")
        out.append(f"| {nm} ({unit}) | {std[k]:.4g} | {bound[nm]:.4g} | {std[k] / bound[nm]:.3f} |")
    return out + [""]


def _free(B):
    U = np.linalg.svd(B, full_matrices=True)[0]
    return U[:, B.shape[1]:].T


# ------------------------------------------------------------------------- target route


def _board():
    g = np.mgrid[0:9, 0:6].reshape(2, -1).T * 25.0
    return np.c_[g - g.mean(axis=0), np.zeros(len(g))]


def _park_martin(Rg, tg, Rc, tc):
    """``X = T_gripper_camera`` from ``T_base_gripper_i X T_camera_target_i = const``:
    ``cv2.calibrateHandEye`` (Park) when available, else Park & Martin here. Both need
    gripper rotations about two axes at least: data whose relative rotations share one
    axis are refused here first (OpenCV 5 returns a meaningless transform for them)."""
    alphas, betas, pairs = [], [], []
    n = len(Rg)
    for i in range(n):
        for j in range(i + 1, n):
            RA = Rg[j].T @ Rg[i]
            tA = Rg[j].T @ (tg[i] - tg[j])
            RB = Rc[j] @ Rc[i].T
            tB = tc[j] - RB @ tc[i]
            pairs.append((RA, tA, RB, tB))
            if rotation_angle_deg(RA) > 1.0:
                alphas.append(matrix_to_rotvec(RA))
                betas.append(matrix_to_rotvec(RB))
    M = sum((np.outer(b, a) for a, b in zip(alphas, betas)), np.zeros((3, 3)))
    w, V = np.linalg.eigh(M.T @ M)
    if len(alphas) == 0 or w[1] <= 1e-9 * w[-1]:
        raise DegenerateError("hand-eye AX = XB: the gripper rotations are all about one axis; R_X undetermined")
    try:
        import cv2
        if hasattr(cv2, "calibrateHandEye"):
            R, t = cv2.calibrateHandEye(list(Rg), list(tg), list(Rc), list(tc), method=cv2.CALIB_HAND_EYE_PARK)
            return R, t.ravel()
    except ImportError:
        pass
    RX = V @ np.diag(w ** -0.5) @ V.T @ M.T
    A_rows = [RA - np.eye(3) for RA, _, _, _ in pairs]
    b_rows = [RX @ tB - tA for _, tA, _, tB in pairs]
    tX = np.linalg.lstsq(np.concatenate(A_rows), np.concatenate(b_rows), rcond=None)[0]
    return RX, tX


def target_route(sc, rng):
    import cv2
    Xb = _board()
    Rc = sc.camera_rotations()
    C = sc.camera_centres()
    obj, img = [], []
    for i in range(len(sc.T)):
        uv = project(sc.K, Rc[i], Xb, C[i:i + 1])[0] + rng.normal(0.0, NOISE_PX, (len(Xb), 2))
        obj.append(Xb.astype(np.float32))
        img.append(uv.astype(np.float32).reshape(-1, 1, 2))
    flags = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
    _, K, _, rvecs, tvecs = cv2.calibrateCamera(obj, img, sc.image_size, None, None, flags=flags)
    R_ct = np.stack([rotvec_to_matrix(np.ravel(r)) for r in rvecs])
    t_ct = np.stack([np.ravel(t) for t in tvecs]).astype(float)
    RX, tX = _park_martin(sc.R, sc.T, R_ct, t_ct)
    return K, RX, tX


def single_session(sc):
    v = sc.session_of_view == 0
    cal = refine(sc.uv[v], sc.T[v], estimate_linear(sc.uv[v], sc.T[v]))
    return cal.K, sc.R[v][0].T @ cal.R.T, None


def comparison(trials, seed=100) -> list[str]:
    out = ["| data | method | fx err % | fy err % | cx err px | cy err px | R_X err deg | t_X err mm |",
           "|---|---|---|---|---|---|---|---|"]
    for name, kw in SCENES.items():
        base = session_scene(seed, n_points=60, **kw)
        B = _determined_basis(base)
        rng = np.random.default_rng(seed + 7)
        errs = {m: [] for m in ("single-session (paper + ML)", "multi-session (this)", "target + hand-eye")}
        fails = dict.fromkeys(errs, 0)
        for _ in range(trials):
            sc = _noisy(base, rng)
            runs = {"single-session (paper + ML)": lambda: single_session(sc),
                    "multi-session (this)": lambda: _he(sc), "target + hand-eye": lambda: target_route(sc, rng)}
            for m, run in runs.items():
                try:
                    K, RX, tX = run()
                except TranscalibError:
                    fails[m] += 1
                    continue
                dt = np.nan if tX is None else np.linalg.norm(B.T @ (tX - base.t_X)) if m.startswith("multi") \
                    else np.linalg.norm(tX - base.t_X)
                errs[m].append([100 * (K[0, 0] / base.K[0, 0] - 1), 100 * (K[1, 1] / base.K[1, 1] - 1),
                                K[0, 2] - base.K[0, 2], K[1, 2] - base.K[1, 2],
                                rotation_angle_deg(RX.T @ base.R_X), dt])
        for m, e in errs.items():
            if not e:
                out.append(f"| {name} | {m} | fails ({fails[m]}/{trials}: degenerate) | | | | | |")
                continue
            e = np.array(e, float)
            r = np.sqrt(np.mean(e ** 2, axis=0))  # NaN column: t_X not available
            t_txt = "n/a (not observable)" if np.isnan(r[5]) else f"{r[5]:.3f}"
            if m.startswith("multi") and B.shape[1] < 3:
                t_txt += f" ({B.shape[1]} of 3 components)"
            if fails[m]:
                t_txt += f"; {fails[m]}/{trials} failed"
            out.append(f"| {name} | {m} | {r[0]:.3f} | {r[1]:.3f} | {r[2]:.2f} | {r[3]:.2f} | {r[4]:.4f} | {t_txt} |")
    return out


def _he(sc):
    he = calibrate_sessions(sc.uv, sc.T, sc.R)
    return he.K, he.R_flange_camera, he.t_flange_camera


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="few trials (smoke run)")
    parser.add_argument("--trials", type=int, default=None, help="Monte-Carlo trials (default 300; quick: 20)")
    args = parser.parse_args(argv)
    trials = args.trials or (20 if args.quick else 300)
    lines = ["# Sessions model: accuracy (benchmarks/bench_handeye.py)", "",
             f"`python benchmarks/bench_handeye.py{' --quick' if args.quick else ''}`; RMS over trials, "
             f"{NOISE_PX} px noise, 60 points (board: 54 corners), 6 views per session, ~0.5 m working distance.",
             "", "## (a) Monte-Carlo std vs the Cramér-Rao bound", ""]
    for name, kw in SCENES.items():
        lines += monte_carlo(name, kw, trials)
    lines += ["## (b) Single-session, multi-session and target-based routes on the same data", ""]
    lines += comparison(max(trials // 3, 10))
    text = "\n".join(lines) + "\n"
    print(text)
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "handeye.md").write_text(text)


if __name__ == "__main__":
    main(sys.argv[1:])
