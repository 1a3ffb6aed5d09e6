"""Helpers shared by the paper benchmarks (not a benchmark itself: ``run.py`` runs ``bench_*.py``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def results_dir(quick: bool) -> Path:
    """Where a run writes: ``benchmarks/results`` for full runs; a scratch folder for
    ``--quick`` runs, so that quick numbers never overwrite the published tables."""
    import tempfile

    d = Path(tempfile.gettempdir()) / "transcalib-bench-quick" if quick else RESULTS
    d.mkdir(parents=True, exist_ok=True)
    return d


def k5(K) -> dict:
    """fx, fy, skew, cx, cy of ``K``."""
    K = np.asarray(K, float)
    return {"fx": K[0, 0], "fy": K[1, 1], "skew": K[0, 1], "cx": K[0, 2], "cy": K[1, 2]}


def md_table(header, rows) -> str:
    """A markdown table: ``header`` list of str, ``rows`` lists of cells (str or number)."""
    def cell(x):
        if isinstance(x, str):
            return x
        if x is None or (isinstance(x, float) and not np.isfinite(x)):
            return "-"
        if isinstance(x, (int, np.integer)):
            return str(x)
        ax = abs(x)
        return f"{x:.3g}" if ax < 0.01 and ax > 0 else (f"{x:.1f}" if ax >= 100 else f"{x:.3f}" if ax < 10 else f"{x:.2f}")
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def plane_fit(X):
    """Best plane of points ``X`` (n, 3): centroid, orthonormal axes (3, 3) (rows: in-plane
    s, in-plane t, normal) and the signed residuals (n,) along the normal."""
    X = np.asarray(X, float)
    c = X.mean(0)
    _, _, Vt = np.linalg.svd(X - c)
    return c, Vt, (X - c) @ Vt[2]


def relabel(uv, uv_true):
    """Order tracked points ``uv`` (n_views, n, 2) like the true projections ``uv_true``
    (n_views, m, 2): for each true point the track nearest to it in the view where that
    track is first seen. Returns ``(n_views, m, 2)`` (NaN where no track within 3 px)."""
    out = np.full(uv_true.shape, np.nan)
    seen = np.isfinite(uv[..., 0])
    ref = np.argmax(seen, axis=0)
    for j in range(uv.shape[1]):
        r = ref[j]
        d = np.linalg.norm(uv_true[r] - uv[r, j], axis=1)
        k = int(np.argmin(d))
        if d[k] < 3.0:
            out[:, k] = uv[:, j]
    return out


def opencv_board(obj_st, uv, image_size, fix_pp: bool):
    """OpenCV ``calibrateCameraExtended`` with the board's known geometry.

    obj_st : (m, 2) board coordinates of the corners (z = 0), uv : (n_views, m, 2)
    (NaN: unseen). No distortion (the rendered lens has none): k1..k3 and tangential
    fixed at zero. ``fix_pp``: principal point fixed at the image centre (as Tsai's
    coplanar method assumes), else free. Returns dict fx..cy, std of each, rms.
    """
    import cv2

    w, h = image_size
    obj, img = [], []
    for i in range(uv.shape[0]):
        ok = np.isfinite(uv[i, :, 0])
        if ok.sum() < 6:
            continue
        obj.append(np.column_stack([obj_st[ok], np.zeros(ok.sum())]).astype(np.float32))
        img.append(uv[i, ok].astype(np.float32).reshape(-1, 1, 2))
    flags = cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    if fix_pp:
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
    K0 = np.array([[w, 0, (w - 1) / 2], [0, w, (h - 1) / 2], [0, 0, 1]], float)
    if not fix_pp:
        flags |= 0
    rms, K, dist, rv, tv, std_in, _, _ = cv2.calibrateCameraExtended(
        obj, img, (w, h), K0, np.zeros(5), flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    s = np.asarray(std_in).ravel()
    return {**k5(K), "std": {"fx": s[0], "fy": s[1], "cx": s[2], "cy": s[3]}, "rms": rms, "K": K,
            "rvecs": rv, "tvecs": tv}


def rigid_align(X, Y, scale: bool = False):
    """``X`` (n, 3) moved onto ``Y`` by the best rotation + translation (+ scale): returns
    the moved ``X`` and the scale (1 without ``scale``). NaN rows are ignored in the fit."""
    ok = np.isfinite(X).all(1) & np.isfinite(Y).all(1)
    mx, my = X[ok].mean(0), Y[ok].mean(0)
    A, B = X[ok] - mx, Y[ok] - my
    U, S, Vt = np.linalg.svd(A.T @ B)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    Rm = U @ D @ Vt  # X -> Y: x @ Rm
    k = float((S * np.diag(D)).sum() / (A**2).sum()) if scale else 1.0
    return (X - mx) @ Rm * k + my, k
