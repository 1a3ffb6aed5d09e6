"""Linking across orientations (placeholder: concatenation)."""

from __future__ import annotations

import numpy as np

__all__ = ["link_groups"]


def link_groups(grey, feats, groups, labels, per, opts, rng, report):
    n = len(grey)
    blocks = []
    for views, uv in zip(groups, per):
        if uv is None:
            continue
        full = np.full((n, uv.shape[1], 2), np.nan)
        full[views] = uv
        blocks.append(full)
    uv = np.concatenate(blocks, axis=1) if blocks else np.zeros((n, 0, 2))
    return uv, []
