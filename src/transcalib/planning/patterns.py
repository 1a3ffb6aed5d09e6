"""Standard translation patterns fitted to the robot's box, for comparison with a plan.

Each pattern has a natural number of positions; with fewer views the first ones are
used, with more the pattern is repeated at half the size about the same anchor (then a
quarter, ...), never at a position already used: a repeated position adds no geometry,
and the linear (TLS) start of the calibration breaks down on exactly repeated positions.
Patterns that depend on a choice of corner come in variants (the mirror images of the
box); the comparison reports the best variant, so a plan is compared with the best a user
could have done with that pattern.

* ``tetrahedron`` — axis-aligned: a box corner and the full box edges from it along x, y, z.
* ``cube_corners`` — the 8 box corners, the two inscribed regular tetrahedra first.
* ``paper`` — the paper's §3 moves (three orthogonal equal moves, rotated 20° about the
  vertical), scaled to the largest copy that fits the box, centred.
* ``naive`` — what a user tries first: the box centre and small moves (10 % of the box)
  along +x, +y, +z, then -x, -y, -z; for more views the same moves twice as long, ...
"""

from __future__ import annotations

import itertools

import numpy as np

__all__ = ["PATTERNS", "pattern_variants"]

PATTERNS = ("tetrahedron", "cube_corners", "paper", "naive")
#: Size of the naive moves, as a fraction of the box extent on each axis.
NAIVE_FRACTION = 0.1

_SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))  # (8, 3) mirror images


def _cycle(P: np.ndarray, n_views: int, anchor: np.ndarray) -> np.ndarray:
    """The first ``n_views`` of ``P``, then of ``P`` shrunk about ``anchor`` by 1/2, 1/4, ...
    (positions already used are skipped)."""
    out, scale = [], 1.0
    while len(out) < n_views and scale > 1e-3:
        for p in anchor + (P - anchor) * scale:
            if len(out) < n_views and not any(np.allclose(p, q) for q in out):
                out.append(p)
        scale *= 0.5
    return np.array(out)


def _fit(unit: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Positions in ``[-1, 1]^3`` box coordinates -> robot coordinates of ``box (3, 2)``."""
    c, half = box.mean(axis=1), 0.5 * (box[:, 1] - box[:, 0])
    return c + unit * half


def pattern_variants(name: str, box: np.ndarray, n_views: int) -> np.ndarray:
    """Variants of a standard pattern inside ``box``.

    Parameters
    ----------
    name : one of :data:`PATTERNS`
    box : (3, 2) float
        ``[min, max]`` per robot axis.
    n_views : int

    Returns
    -------
    (n_variants, n_views, 3) float
        Robot translations.
    """
    if name == "tetrahedron":
        base = np.array([[-1, -1, -1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
        units = [base * s for s in _SIGNS]
    elif name == "cube_corners":
        tet_a = np.array([[-1, -1, -1], [1, 1, -1], [1, -1, 1], [-1, 1, 1]], float)
        units = [np.vstack([tet_a, -tet_a]), np.vstack([-tet_a, tet_a])]
    elif name == "paper":
        moves = np.array([[0, 0, 0], [40, 0, 0], [0, 40, 0], [0, 0, -40]], float)
        c, s = np.cos(np.radians(20.0)), np.sin(np.radians(20.0))
        moves = moves @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
        units = []
        for sg in _SIGNS:
            m = moves * sg
            lo, hi = m.min(axis=0), m.max(axis=0)
            units.append(2.0 * (m - lo) / np.max(hi - lo) - (hi - lo) / np.max(hi - lo))
        # same shape on every axis (a uniform scale) so it fits the box's smallest side
        half = 0.5 * (box[:, 1] - box[:, 0])
        k = np.min(np.where(half > 0, half, np.inf)) if np.any(half > 0) else 0.0
        c0 = box.mean(axis=1)
        k = np.minimum(k, half)  # a flat axis of the box stays flat
        return np.stack([_cycle(c0 + u * k, n_views, c0) for u in units])
    elif name == "naive":
        f = NAIVE_FRACTION * 2.0
        units = [np.vstack([np.zeros(3), f * np.eye(3), -f * np.eye(3)])]
        # more views: the same moves twice, three times as long, ... (a naive user's next guess)
        units = [np.vstack([units[0]] + [k * units[0][1:] for k in range(2, 1 + int(np.ceil(n_views / 6)))])]
    else:
        raise KeyError(name)
    # repeat about the pattern's first position (tetrahedron: its corner) or the centre
    anchor = {"tetrahedron": 0, "naive": 0}.get(name)
    return np.stack([_cycle(_fit(u, box), n_views, _fit(u[anchor] if anchor is not None else np.zeros(3), box))
                     for u in units])
