"""Small helpers shared by the checks: formatting of vectors and index lists."""

from __future__ import annotations

import numpy as np


def fmt_vec(v) -> str:
    return "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"


def fmt_list(idx, limit: int = 10) -> str:
    idx = [int(i) for i in idx]
    s = ", ".join(map(str, idx[:limit]))
    return s + (f", ... ({len(idx)} in all)" if len(idx) > limit else "")


def depths(R, X, T):
    """Camera z of every point in every view (n_views, n_points)."""
    return (X @ R[2])[None, :] - (T @ R[2])[:, None]


def squared_norms(res: np.ndarray) -> np.ndarray:
    """``|r|^2`` of each residual ``res (..., 2)`` (NaN where the residual is), in one pass."""
    return np.einsum("...k,...k->...", res, res)
