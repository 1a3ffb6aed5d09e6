"""The tf tree of a bag: transforms by edge, the chain between two frames, and the
pose along it at any times (translations linear, rotations slerp), vectorised over times.

A tf edge ``parent -> child`` holds ``(R, t)`` with ``p_parent = R p_child + t``
(metres). A frame has one parent; ``/tf_static`` edges hold at all times.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...geometry.rotation import matrix_to_rotvec, quaternion_to_matrix, rotvec_to_matrix
from .options import BagError

__all__ = ["Edge", "TfTree", "Chain", "clean_frame"]


def clean_frame(name: str) -> str:
    """A frame id without ROS 1's leading slash or surrounding spaces."""
    return name.strip().lstrip("/")


@dataclass(frozen=True, eq=False)
class Edge:
    """One tf edge's samples, in time order.

    Attributes
    ----------
    parent, child : str
    stamps_ns : (k,) int64
        ``header.stamp`` of each sample (a static edge: one sample, any stamp).
    t : (k, 3) float
        Translations ``t_parent_child``, metres.
    R : (k, 3, 3) float
        Rotations child -> parent.
    static : bool
    """

    parent: str
    child: str
    stamps_ns: np.ndarray
    t: np.ndarray
    R: np.ndarray
    static: bool

    def at(self, times_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(t (n, 3), R (n, 3, 3), valid (n,))`` at ``times_ns (n,)``: linear in t,
        slerp ``R_a exp(f log(R_a^T R_b))`` in R between the samples around each time;
        ``valid`` False outside the samples' time span (no extrapolation)."""
        n = len(times_ns)
        if self.static or len(self.stamps_ns) == 1:
            valid = np.ones(n, bool) if self.static else times_ns == self.stamps_ns[0]
            return np.broadcast_to(self.t[0], (n, 3)), np.broadcast_to(self.R[0], (n, 3, 3)), valid
        s = self.stamps_ns
        i = np.clip(np.searchsorted(s, times_ns, side="right") - 1, 0, len(s) - 2)
        f = np.clip((times_ns - s[i]) / (s[i + 1] - s[i]), 0.0, 1.0)
        t = self.t[i] + f[:, None] * (self.t[i + 1] - self.t[i])
        Ra = self.R[i]
        rel = matrix_to_rotvec(np.swapaxes(Ra, 1, 2) @ self.R[i + 1])
        R = Ra @ rotvec_to_matrix(f[:, None] * rel)
        return t, R, (times_ns >= s[0]) & (times_ns <= s[-1])


@dataclass(frozen=True, eq=False)
class Chain:
    """The path ``base -> ... -> flange`` in the tf tree: each step an edge, walked
    against its direction (``inverse``, going up from the base) or along it."""

    base: str
    flange: str
    steps: tuple  # of (Edge, inverse: bool)

    @property
    def dynamic(self) -> list[Edge]:
        return [e for e, _ in self.steps if not e.static]

    def span_ns(self) -> tuple[int, int] | None:
        """The time span in which every moving edge has samples (None: all static)."""
        dyn = self.dynamic
        if not dyn:
            return None
        return max(int(e.stamps_ns[0]) for e in dyn), min(int(e.stamps_ns[-1]) for e in dyn)

    def sample_times_ns(self) -> np.ndarray:
        """The union of the moving edges' stamps, sorted (empty: all static)."""
        dyn = self.dynamic
        return np.unique(np.concatenate([e.stamps_ns for e in dyn])) if dyn else np.zeros(0, np.int64)

    def pose_at(self, times_ns) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``T_base_flange`` at ``times_ns (n,)``: ``(T (n, 3) metres, R (n, 3, 3) flange ->
        base, valid (n,))``, composed ``T = T_1 ∘ T_2 ∘ ...`` along the steps (an inverse
        step ``(R^T, -R^T t)``); ``valid`` where every edge has samples around the time."""
        times_ns = np.asarray(times_ns, dtype=np.int64)
        n = len(times_ns)
        T, R, valid = np.zeros((n, 3)), np.broadcast_to(np.eye(3), (n, 3, 3)), np.ones(n, bool)
        for edge, inverse in self.steps:
            t_e, R_e, ok = edge.at(times_ns)
            if inverse:
                R_e = np.swapaxes(R_e, 1, 2)
                t_e = -np.einsum("nij,nj->ni", R_e, t_e)
            T = T + np.einsum("nij,nj->ni", R, t_e)
            R = R @ R_e
            valid &= ok
        return T, R, valid


class TfTree:
    """tf edges by child frame, gathered from ``TransformStamped`` messages."""

    def __init__(self):
        self._samples: dict[str, dict] = {}

    def add(self, transform, static: bool) -> None:
        """Add one ``geometry_msgs/TransformStamped``."""
        parent, child = clean_frame(transform.header.frame_id), clean_frame(transform.child_frame_id)
        entry = self._samples.setdefault(child, {"parent": parent, "static": static, "rows": []})
        if entry["parent"] != parent:
            raise BagError("tf", f"tf frame {child!r} has two parents, {entry['parent']!r} and {parent!r}; "
                                 "a tf tree gives each frame one parent")
        entry["static"] = entry["static"] and static
        st, tr, q = transform.header.stamp, transform.transform.translation, transform.transform.rotation
        entry["rows"].append((st.sec * 1_000_000_000 + st.nanosec, tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w))

    @property
    def frames(self) -> list[str]:
        """Every frame named in the tree, sorted."""
        return sorted(set(self._samples) | {e["parent"] for e in self._samples.values()})

    def edge(self, child: str) -> Edge:
        """The edge into ``child``: samples in stamp order (the last of equal stamps kept)."""
        entry = self._samples[child]
        rows = np.array(entry["rows"], dtype=float)
        stamps = np.array([r[0] for r in entry["rows"]], dtype=np.int64)  # exact: float64 loses ns
        order = np.argsort(stamps, kind="stable")
        stamps, rows = stamps[order], rows[order]
        keep = np.append(stamps[1:] != stamps[:-1], True)
        stamps, rows = stamps[keep], rows[keep]
        if entry["static"]:
            stamps, rows = stamps[-1:], rows[-1:]
        q = rows[:, 4:8]
        if np.any(np.linalg.norm(q, axis=1) < 0.5):
            raise BagError("tf", f"tf edge {entry['parent']!r} -> {child!r} has a quaternion far from unit norm")
        return Edge(entry["parent"], child, stamps, rows[:, 1:4], quaternion_to_matrix(q), entry["static"])

    def _ancestors(self, frame: str) -> list[str]:
        """``[frame, parent, grandparent, ...]`` up to the root."""
        path = [frame]
        while path[-1] in self._samples:
            parent = self._samples[path[-1]]["parent"]
            if parent in path:
                raise BagError("tf", f"the tf tree has a loop through {parent!r}")
            path.append(parent)
        return path

    def chain(self, base: str, flange: str) -> Chain:
        """The chain ``base -> flange``: up from ``base`` to the closest common ancestor,
        then down to ``flange``. :class:`BagError` names the frame that is missing
        (listing the tree's frames) or says the two are in separate trees."""
        base, flange = clean_frame(base), clean_frame(flange)
        frames = self.frames
        for name, frame in (("base_frame", base), ("flange_frame", flange)):
            if frame not in frames:
                raise BagError(name, f"frame {frame!r} is not in the tf tree; its frames: "
                               + (", ".join(frames) or "none (no /tf or /tf_static messages)"))
        up, down = self._ancestors(base), self._ancestors(flange)
        common = next((f for f in up if f in down), None)
        if common is None:
            raise BagError("flange_frame", f"no tf chain joins {base!r} and {flange!r}: they are in separate trees "
                           f"(roots {up[-1]!r} and {down[-1]!r})")
        steps = [(self.edge(f), True) for f in up[:up.index(common)]]
        steps += [(self.edge(f), False) for f in reversed(down[:down.index(common)])]
        return Chain(base, flange, tuple(steps))
