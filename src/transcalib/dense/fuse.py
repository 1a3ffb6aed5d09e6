"""The metric point cloud of one or several depth maps, with a consistency check.

Every known pixel of a reference view gives a point ``X = C + z R^T r`` in the robot
frame. With several reference views each point is checked against every other
reference view's depth map: projected there (depth ``z'``, nearest pixel, depth ``z_b``
seen there, margin ``m = max(tol z_b, 3 sqrt(s^2 + s_b^2))`` with ``s``, ``s_b`` the two
depth standard deviations), it **agrees** when ``|z' - z_b| <= m``, **conflicts** when
it lies in front of what that view sees (``z' < min z_b - m``, the least depth of the
3 x 3 pixels around, so that a point beside an occluding edge is not judged by the
surface behind it: the view would have seen it),
and is not judged when it is hidden behind that surface, outside the image, or the view
has no depth there. A point is kept unless it conflicts with more views than it agrees
with. (With two reference views a contradiction cannot say which of the two is wrong:
the point in front of the other's surface goes.)
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry.camera import project_camera_frame

__all__ = ["Cloud", "fuse"]


@dataclass(frozen=True, eq=False)
class Cloud:
    """Points ``(n, 3)``, colours ``(n, 3)`` uint8, source map index ``view``,
    ``confidence`` and ``std`` ``(n,)`` of a fused cloud, and the points rejected."""

    points: np.ndarray
    colors: np.ndarray
    view: np.ndarray
    confidence: np.ndarray
    std: np.ndarray
    n_rejected: int


#: Standard deviations of two depths that still agree.
N_SIGMA = 3.0


def _votes(points: np.ndarray, std: np.ndarray, other, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(agree, conflict)`` bool ``(n,)`` of world ``points`` (depth std ``std (n,)``)
    against depth map ``other``."""
    cam = other.camera
    xc = cam.R @ (points - other.centre).T  # (3, n)
    z = xc[2]
    front = z > 0
    uv = project_camera_frame(cam.intrinsics, cam.dist5, xc, valid=front).pred
    h, w = other.depth.shape
    u, v = np.rint(uv[0]), np.rint(uv[1])
    inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    zb, sb, zmin = (np.full(len(z), np.nan) for _ in range(3))
    vi, ui = v[inside].astype(int), u[inside].astype(int)
    nearest = cv2.erode(np.where(np.isfinite(other.depth), other.depth, np.inf).astype(np.float32),
                        np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
    zb[inside], sb[inside], zmin[inside] = other.depth[vi, ui], other.depth_std[vi, ui], nearest[vi, ui]
    with np.errstate(invalid="ignore"):
        margin = np.maximum(tol * zb, N_SIGMA * np.hypot(std, sb))
        agree = np.abs(z - zb) <= margin
        conflict = z < zmin - margin
    return agree, conflict


def fuse(maps, tol: float) -> Cloud:
    """The cloud of ``maps`` (a sequence of :class:`~transcalib.dense.options.DepthMap`),
    each point checked against the other maps (module docstring)."""
    parts = []
    rejected = 0
    for a, m in enumerate(maps):  # a loop over the few reference views
        known = np.isfinite(m.depth)
        X = m.points(known)
        std = m.depth_std[known].astype(float)
        agree, conflict = np.zeros(len(X), int), np.zeros(len(X), int)
        for b, other in enumerate(maps):
            if b != a:
                ag, co = _votes(X, std, other, tol)
                agree += ag
                conflict += co
        keep = conflict <= agree
        rejected += int(np.sum(~keep))
        v, u = np.nonzero(known)
        parts.append((X[keep], m.image[v[keep], u[keep]], np.full(int(keep.sum()), a, np.int32),
                      m.confidence[v[keep], u[keep]], m.depth_std[v[keep], u[keep]]))
    cat = [np.concatenate([p[k] for p in parts]) for k in range(5)]
    return Cloud(cat[0], cat[1].astype(np.uint8), cat[2], cat[3].astype(np.float32), cat[4].astype(np.float32),
                 rejected)
