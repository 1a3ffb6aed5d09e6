"""Textured rectangles of a rendered scene: planes, box faces and boards with exact corners.

A :class:`Surface` is ``origin + s * axis_s + t * axis_t`` with a procedural texture
(:mod:`.textures`) of its surface coordinates ``(s, t)``; :func:`plane`, :func:`box`,
:func:`paper_board` and :func:`checker_board` build them, the boards with the exact
world coordinates of their corners (the ground truth of the target mode).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .textures import Checker, Squares, _Framed

__all__ = ["Surface", "plane", "box", "paper_board", "checker_board"]


@dataclass(frozen=True, eq=False)
class Surface:
    """A textured rectangle ``origin + s * axis_s + t * axis_t``, ``0 <= s <= size[0]``,
    ``0 <= t <= size[1]``; ``axis_s``, ``axis_t`` orthonormal (world frame).

    Attributes
    ----------
    origin, axis_s, axis_t : (3,) float
    size : (2,) float
        Extent along ``axis_s`` and ``axis_t`` (world units).
    texture : callable ``(s, t, ws, wt) -> value in [0, 1]``
        ``ws, wt`` are the sample footprint widths for box filtering.
    name : str
    cull_back : bool
        Invisible from the side opposite its normal ``axis_s x axis_t`` (faces of a
        closed solid); skipped when the camera is behind it, to save time.
    """

    origin: np.ndarray
    axis_s: np.ndarray
    axis_t: np.ndarray
    size: tuple[float, float]
    texture: object
    name: str = ""
    cull_back: bool = False

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.axis_s, self.axis_t)

    def point(self, st: np.ndarray) -> np.ndarray:
        """World points ``(n, 3)`` of surface coordinates ``st`` ``(n, 2)``."""
        st = np.asarray(st, float)
        return self.origin + st[:, :1] * self.axis_s + st[:, 1:2] * self.axis_t

    def moved(self, R: np.ndarray, t: np.ndarray) -> "Surface":
        """The surface moved rigidly by ``x -> R x + t``: origin ``R o + t``, axes ``R a``;
        the same texture (in its own ``(s, t)``), size, name and culling.

        Parameters
        ----------
        R : (3, 3) float
            A rotation (det +1; not checked here: callers check their poses once).
        t : (3,) float
        """
        R, t = np.asarray(R, float), np.asarray(t, float)
        return replace(self, origin=R @ self.origin + t, axis_s=R @ self.axis_s, axis_t=R @ self.axis_t)


def plane(center, normal_rot, size, texture, name: str = "") -> Surface:
    """A rectangle centred at ``center`` (3,), with axes the first two columns of the
    rotation ``normal_rot`` (3, 3) (its third column is the normal), extent ``size``."""
    Rm = np.asarray(normal_rot, float)
    a, b = Rm[:, 0], Rm[:, 1]
    w, h = size
    origin = np.asarray(center, float) - 0.5 * w * a - 0.5 * h * b
    return Surface(origin, a, b, (float(w), float(h)), texture, name)


def box(center, rot, dims, textures, name: str = "box") -> list[Surface]:
    """The six faces of a box of ``dims`` (dx, dy, dz) centred at ``center``.

    ``rot`` (3, 3): box axes in the world; ``textures``: one texture or a list of six.
    """
    Rm = np.asarray(rot, float)
    c = np.asarray(center, float)
    d = np.asarray(dims, float)
    if not isinstance(textures, (list, tuple)):
        textures = [textures] * 6
    faces = []
    ex, ey, ez = Rm[:, 0], Rm[:, 1], Rm[:, 2]
    # (normal axis index, sign): face centre c + sign * d[k]/2 * e_k, face axes the other two
    axes = [ex, ey, ez]
    for f, (k, sign) in enumerate([(0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)]):
        i, j = [m for m in range(3) if m != k]
        a, b = axes[i], axes[j]
        if np.dot(np.cross(a, b), sign * axes[k]) < 0:
            b = -b  # outward normal, for back-face culling
        fr = np.column_stack([a, b, np.cross(a, b)])
        sf = plane(c + sign * 0.5 * d[k] * axes[k], fr, (d[i], d[j]), textures[f], f"{name}{f}")
        faces.append(Surface(sf.origin, sf.axis_s, sf.axis_t, sf.size, sf.texture, sf.name, cull_back=True))
    return faces


def paper_board(center, rot, square: float = 30.0, gap: float = 20.0, cols: int = 3, rows: int = 2,
                margin: float = 25.0, name: str = "board") -> tuple[Surface, np.ndarray]:
    """The paper's target: ``cols x rows`` black squares of side ``square`` on a white board.

    Returns
    -------
    surface : Surface
    corners : (4 * cols * rows, 3) float
        Exact world corners, square by square (row-major from the board's (s, t)
        origin), each square's corners in the order (s0,t0), (s1,t0), (s1,t1), (s0,t1).
    """
    pitch = square + gap
    W = 2 * margin + cols * square + (cols - 1) * gap
    H = 2 * margin + rows * square + (rows - 1) * gap
    rects, corners = [], []
    for r in range(rows):
        for c in range(cols):
            s0, t0 = margin + c * pitch, margin + r * pitch
            rects.append([s0, t0, s0 + square, t0 + square])
            corners += [[s0, t0], [s0 + square, t0], [s0 + square, t0 + square], [s0, t0 + square]]
    surf = plane(center, rot, (W, H), Squares(np.array(rects)), name)
    return surf, surf.point(np.array(corners))


def checker_board(center, rot, cell: float, cols: int, rows: int, margin: float = 0.0,
                  name: str = "checker") -> tuple[Surface, np.ndarray]:
    """A ``cols x rows``-cell checkerboard (with a light margin of ``margin`` cells).

    Returns the surface and its interior corners ``((cols-1)*(rows-1), 3)`` (world).
    """
    W, H = (cols + 2 * margin) * cell, (rows + 2 * margin) * cell
    inner = Checker(cell)
    if margin > 0:
        m = margin * cell
        tex = _Framed(inner, m, W - m, H - m)
    else:
        tex = inner
    surf = plane(center, rot, (W, H), tex, name)
    ii, jj = np.meshgrid(np.arange(1, cols), np.arange(1, rows))
    st = np.column_stack([ii.ravel(), jj.ravel()]) * cell + margin * cell
    return surf, surf.point(st)
