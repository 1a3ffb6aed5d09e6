"""Observations grouped by view, the form in which the bundle adjuster reads them.

``build_data`` gathers, for each view, the used points it sees and their pixels; views that
see most points (at least :data:`DENSE_FRACTION` of them) also keep full arrays over every
used point with a mask, so that the assembly reads them contiguously instead of gathering
and scattering per accumulated quantity.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Views seeing at least this fraction of the used points are kept as full arrays too.
DENSE_FRACTION = 0.5


@dataclass
class Data:
    """Observations grouped by view: ``pts[i]`` indexes the used points seen in view i.

    Views seeing most points are also kept as full arrays over *all* used points with a
    mask (``full_uv``, ``full_seen``): contiguous arrays instead of a gather/scatter per
    accumulated quantity.
    """

    pts: list  # of (n_i,) int
    uv: list  # of (2, n_i) float
    T_meas: np.ndarray  # (n_views, 3)
    t_weight: np.ndarray  # (n_views,) sigma_px / sigma_T_i for free translations (else 0)
    n_points: int  # used points
    full_uv: list  # of (2, n) float (0 where unseen) or None
    full_seen: list  # of (n,) bool or None
    robot_weight: np.ndarray = field(default_factory=lambda: np.zeros(2))  # sigma_px / (sigma_rot, sigma_pos), 0 off

    @property
    def n_obs(self) -> int:
        return int(sum(len(p) for p in self.pts))

    def points(self, lo: int, hi: int) -> "Data":
        """The observations of the used points ``lo <= j < hi`` (renumbered from 0)."""
        cuts = [np.searchsorted(p, (lo, hi)) for p in self.pts]
        return Data(pts=[p[a:b] - lo for p, (a, b) in zip(self.pts, cuts)],
                    uv=[u[:, a:b] for u, (a, b) in zip(self.uv, cuts)], T_meas=self.T_meas, t_weight=self.t_weight,
                    n_points=hi - lo, full_uv=[None if f is None else f[:, lo:hi] for f in self.full_uv],
                    full_seen=[None if f is None else f[lo:hi] for f in self.full_seen], robot_weight=self.robot_weight)

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """Every view's observations over all points: ``uv (2, n_views, n)`` (0 where
        unseen) and ``seen (n_views, n)`` bool."""
        uv, seen = np.zeros((2, len(self.pts), self.n_points)), np.zeros((len(self.pts), self.n_points), bool)
        for i, (pts, obs, full) in enumerate(zip(self.pts, self.uv, self.full_uv)):
            if full is not None:
                uv[:, i], seen[i] = full, self.full_seen[i]
            else:
                uv[:, i, pts], seen[i, pts] = obs, True
        return uv, seen

    def dense_weights(self, weights: list) -> np.ndarray:
        """Per-view weights over the observations ``(n_i,)`` as ``(n_views, n)`` (0 where unseen)."""
        out = np.zeros((len(self.pts), self.n_points))
        for i, (pts, w) in enumerate(zip(self.pts, weights)):
            out[i, pts] = w
        return out


def build_data(uv, seen, used_idx, T_meas, t_weight, robot_weight=(0.0, 0.0)) -> Data:
    """Group the observations ``seen (V, n_all)`` of the points ``used_idx`` by view;
    ``robot_weight``: the priors' weights ``sigma_px / sigma_rot``, ``sigma_px / sigma_pos``
    of the robot pose errors (:mod:`transcalib.estimate.robot_error`)."""
    pts, obs, full_uv, full_seen = [], [], [], []
    n = len(used_idx)
    for i in range(uv.shape[0]):
        mask = seen[i, used_idx]
        sel = np.flatnonzero(mask)
        pts.append(sel)
        dense = DENSE_FRACTION * n <= len(sel)
        if dense:  # one gather of the view; a second one only when some points are unseen
            full = np.where(mask, uv[i, used_idx].T, 0.0)  # (2, n)
            obs.append(full if len(sel) == n else full[:, sel])
        else:
            obs.append(np.ascontiguousarray(uv[i, used_idx[sel]].T))  # (2, n_i)
        partial = dense and len(sel) < n
        full_uv.append(full if partial else None)
        full_seen.append(mask if partial else None)
    return Data(pts=pts, uv=obs, T_meas=T_meas, t_weight=t_weight, n_points=n, full_uv=full_uv,
                full_seen=full_seen, robot_weight=np.asarray(robot_weight, float))
