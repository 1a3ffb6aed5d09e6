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

__all__ = ["Surface", "Sphere", "plane", "box", "sphere", "paper_board", "checker_board"]


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


@dataclass(frozen=True, eq=False)
class Sphere:
    """A textured sphere: centre ``center``, radius ``radius``, texture in longitude and
    latitude arc lengths ``s = r (phi + pi)``, ``t = r theta`` about the axes ``frame``.

    In the frame's coordinates ``p = frame^T (X - center) / r``: ``phi = atan2(p_y, p_x)``,
    ``theta = arccos(p_z)``; the texture's seam (``phi = +-pi``) is on the side of
    ``-frame[:, 0]``, the poles along ``+-frame[:, 2]``. A curved surface for the tracker's
    tests (depth is not locally affine in the image, unlike on a plane).

    Attributes
    ----------
    center : (3,) float
    radius : float
    frame : (3, 3) float
        Rotation whose columns are the sphere's axes in the world.
    texture : callable ``(s, t, ws, wt) -> value in [0, 1]``
        Over ``[0, 2 pi r] x [0, pi r]``.
    name : str
    """

    center: np.ndarray
    radius: float
    frame: np.ndarray
    texture: object
    name: str = "sphere"
    cull_back: bool = False

    @property
    def size(self) -> tuple[float, float]:
        return (2.0 * np.pi * self.radius, np.pi * self.radius)

    def bounding_corners(self) -> np.ndarray:
        """The 8 corners ``(8, 3)`` of the axis-aligned cube around the sphere."""
        c = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
        return np.asarray(self.center, float) + self.radius * c

    def hits(self, d, C, sl=slice(None)):
        """Nearest intersection of the rays ``C + z d`` (three direction arrays): ``z`` (inf
        where the ray misses) and the texture coordinates ``s, t``; see
        :func:`transcalib.synth.raycast.surface_hits`. Solves ``|C + z d - c|^2 = r^2``."""
        dx, dy, dz = d[0][sl], d[1][sl], d[2][sl]
        o = np.asarray(C, float) - np.asarray(self.center, float)
        a = dx * dx + dy * dy + dz * dz
        b = dx * o[0] + dy * o[1] + dz * o[2]
        disc = b * b - a * (o @ o - self.radius**2)
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(disc >= 0, (-b - np.sqrt(np.maximum(disc, 0.0))) / a, np.inf)
        zf = np.where(np.isfinite(z), z, 0.0)
        F = np.asarray(self.frame, float)
        p = [(o[k] + zf * (dx, dy, dz)[k]) / self.radius for k in range(3)]
        q = [p[0] * F[0, k] + p[1] * F[1, k] + p[2] * F[2, k] for k in range(3)]
        s = self.radius * (np.arctan2(q[1], q[0]) + np.pi)
        t = self.radius * np.arccos(np.clip(q[2], -1.0, 1.0))
        return z, s, t

    def on(self, z, s, t) -> np.ndarray:
        """bool mask: the ray met the sphere in front of the camera."""
        return np.isfinite(z) & (z > 0)

    def moved(self, R: np.ndarray, t: np.ndarray) -> "Sphere":
        """The sphere moved rigidly by ``x -> R x + t`` (as :meth:`Surface.moved`): centre
        ``R c + t``, axes ``R frame``; the same texture, radius and name."""
        R, t = np.asarray(R, float), np.asarray(t, float)
        return replace(self, center=R @ np.asarray(self.center, float) + t, frame=R @ np.asarray(self.frame, float))

    def point(self, st: np.ndarray) -> np.ndarray:
        """World points ``(n, 3)`` of texture coordinates ``st`` ``(n, 2)``."""
        st = np.asarray(st, float)
        phi, theta = st[:, 0] / self.radius - np.pi, st[:, 1] / self.radius
        q = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        return np.asarray(self.center, float) + self.radius * q @ np.asarray(self.frame, float).T


def sphere(center, radius: float, texture, frame=None, name: str = "sphere") -> Sphere:
    """A :class:`Sphere` (``frame`` default: the world axes)."""
    F = np.eye(3) if frame is None else np.asarray(frame, float)
    return Sphere(np.asarray(center, float), float(radius), F, texture, name)


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
