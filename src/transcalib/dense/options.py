"""Options and results of dense reconstruction: frozen dataclasses.

:class:`DenseOptions` says how :func:`transcalib.dense` matches; :class:`DepthMap` is the
result for one reference view (depth, confidence, standard deviation on the view's
original pixel grid) and :class:`DenseResult` gathers the maps and the fused metric
point cloud in the robot frame.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from ..errors import InputError
from ..geometry.camera import Camera

__all__ = ["DenseOptions", "DepthStats", "DepthMap", "DenseResult", "default_best_k"]


def default_best_k(n_sources: int) -> int:
    """Views whose costs are summed at each pixel when ``best_k`` is None: half of the
    ``n_sources`` other views, rounded down, at least 1 (2 of 5): a pixel near an
    occluding edge or the image border is seen by about half of the views."""
    return max(1, n_sources // 2)


@dataclass(frozen=True)
class DenseOptions:
    """How :func:`transcalib.dense` matches (every field has a default).

    Attributes
    ----------
    n_depths : int
        Depth hypotheses, uniform in inverse depth between the depth limits (>= 3).
    window_px : int
        Side of the square matching window (odd, >= 3).
    best_k : int or None
        At each pixel and hypothesis, the costs of the ``best_k`` best-matching other
        views are summed (occlusions: a view that does not see the point is left out;
        Kang, Szeliski & Chai 2001). None: :func:`default_best_k`.
    min_texture : float
        A pixel whose window's grey-level standard deviation is below ``min_texture``
        times the image noise (estimated from the reference image) is untextured: left
        unknown.
    min_confidence : float
        Pixels whose confidence (0-1) is below this are left unknown.
    consistency_rel : float
        With several reference views: two depths agree when they differ by at most
        this fraction of the depth (the fused cloud keeps what no other reference view
        contradicts).
    threads : int or None
        Threads of the sweep (None: ``min(2, os.cpu_count())``).
    max_turn_deg : float or None
        Sources of a reference view: None, the other views of its session (one flange
        orientation); a number, every view whose camera is turned by at most this angle
        (degrees) against the reference's, whatever its session (a calibration from
        general motion, whose views each have an orientation of their own).
    """

    n_depths: int = 256
    window_px: int = 7
    best_k: int | None = None
    min_texture: float = 3.0
    min_confidence: float = 0.5
    consistency_rel: float = 0.01
    threads: int | None = None
    max_turn_deg: float | None = None

    def __post_init__(self):
        bad = []
        if not isinstance(self.n_depths, (int, np.integer)) or self.n_depths < 3:
            bad.append(f"n_depths must be an integer >= 3, got {self.n_depths!r}")
        if not isinstance(self.window_px, (int, np.integer)) or self.window_px < 3 or self.window_px % 2 == 0:
            bad.append(f"window_px must be an odd integer >= 3, got {self.window_px!r}")
        if self.best_k is not None and (not isinstance(self.best_k, (int, np.integer)) or self.best_k < 1):
            bad.append(f"best_k must be None or an integer >= 1, got {self.best_k!r}")
        if not (np.isfinite(self.min_texture) and self.min_texture >= 0):
            bad.append(f"min_texture must be a number >= 0, got {self.min_texture!r}")
        if not 0 <= self.min_confidence < 1:
            bad.append(f"min_confidence must be in [0, 1), got {self.min_confidence!r}")
        if not 0 < self.consistency_rel < 1:
            bad.append(f"consistency_rel must be in (0, 1), got {self.consistency_rel!r}")
        if self.threads is not None and (not isinstance(self.threads, (int, np.integer)) or self.threads < 1):
            bad.append(f"threads must be None or an integer >= 1, got {self.threads!r}")
        if self.max_turn_deg is not None and not (isinstance(self.max_turn_deg, (int, float, np.floating))
                                                  and 0 < self.max_turn_deg <= 45):
            bad.append(f"max_turn_deg must be None or a number of degrees in (0, 45], got {self.max_turn_deg!r}")
        if bad:
            raise InputError("DenseOptions: " + "; ".join(bad))

    def n_threads(self) -> int:
        return int(self.threads) if self.threads is not None else max(1, min(2, os.cpu_count() or 1))


def _frozen(a):
    if a is None:
        return None
    view = np.asarray(a).view()
    view.setflags(write=False)
    return view


@dataclass(frozen=True)
class DepthStats:
    """How the depth map of one reference view was obtained (:attr:`DepthMap.stats`).

    Attributes
    ----------
    known_fraction : float
        Pixels with a depth (0-1).
    textured_fraction : float
        Pixels whose window has texture (0-1).
    noise_dn : float
        Noise of the reference image (grey levels, 0-255 units).
    hypothesis_step_px : float
        Image motion between neighbouring hypotheses in the view with the longest
        baseline (pixels): above 1, minima can fall between hypotheses.
    exclusion : int
        Hypotheses on each side of the best that the distinctness ``c2`` skips.
    time_s : float
    """

    known_fraction: float
    textured_fraction: float
    noise_dn: float
    hypothesis_step_px: float
    exclusion: int
    time_s: float


@dataclass(frozen=True, eq=False)
class DepthMap:
    """Dense depth of one reference view on its original pixel grid.

    Attributes
    ----------
    view : str
        The reference view's id (as in the poses file).
    index : int
        Its index in the views given.
    depth : (height, width) float32
        Depth along the optical axis (camera z) of the scene point seen at each pixel's
        centre, robot units; NaN where unknown.
    confidence : (height, width) float32
        0-1: the best-k views' normalised correlation at the depth found times its
        distinctness (``1 - c_1 / c_2``, ``c_2`` the best cost away from the minimum);
        0 where unknown.
    depth_std : (height, width) float32
        Standard deviation of ``depth`` (robot units): from the matching cost's
        curvature, and the calibration's covariance where the calibration has one;
        NaN where unknown.
    depth_std_calibration : (height, width) float32 or None
        The calibration's part of ``depth_std`` (None without a covariance).
    camera : Camera
        The reference view's camera: ``K``, distortion and ``R`` (world -> camera).
    centre : (3,) float
        Its centre in the robot frame (relative to the camera centre at ``T = 0``).
    image : (height, width, 3) uint8
        The reference image (RGB), for the cloud's colours.
    sources : tuple of str
        Ids of the other views matched.
    depth_limits : (2,) float
        Near and far depth searched (robot units).
    best_k : int
        Views summed at each pixel.
    stats : DepthStats
        How it was obtained.
    """

    view: str
    index: int
    depth: np.ndarray
    confidence: np.ndarray
    depth_std: np.ndarray
    depth_std_calibration: np.ndarray | None
    camera: Camera
    centre: np.ndarray
    image: np.ndarray
    sources: tuple
    depth_limits: tuple
    best_k: int
    stats: DepthStats

    def __post_init__(self):
        for name in ("depth", "confidence", "depth_std", "depth_std_calibration", "centre", "image"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        object.__setattr__(self, "sources", tuple(self.sources))

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.depth.shape)

    def points(self, mask: np.ndarray | None = None) -> np.ndarray:
        """World points ``(n, 3)`` of the known pixels (row-major order), or of ``mask``:
        ``X = C + z R^T [x, y, 1]`` with ``[x, y, 1]`` the pixel's ray (lens included)."""
        mask = np.isfinite(self.depth) if mask is None else mask
        v, u = np.nonzero(mask)
        rays = self.camera.pixels_to_rays(np.column_stack([u, v]).astype(float))
        return self.centre + (rays * self.depth[v, u, None].astype(float)) @ self.camera.R


@dataclass(frozen=True, eq=False)
class DenseResult:
    """What :func:`transcalib.dense` returns.

    Attributes
    ----------
    maps : tuple of DepthMap
        One per reference view, in the order asked for.
    points : (n, 3) float
        The fused metric point cloud in the frame of the calibration's points (robot
        units; ``frame`` says which).
    colors : (n, 3) uint8
        RGB of each point (its reference image).
    point_view : (n,) int
        Index into ``maps`` of the map each point comes from.
    point_confidence, point_std : (n,) float32
        Confidence and depth standard deviation of each point.
    n_rejected : int
        Points left out of the cloud because another reference view contradicted them.
    unit : str or None
        Length unit of the robot positions: the poses' (``Poses.unit``), else the
        calibration's (``options.unit``); None when neither names one.
    options : DenseOptions
    frame : str
        The cloud's frame in words (:func:`~transcalib.dense.views.cloud_frame`).
    timings_s : mapping of str to float
    """

    maps: tuple
    points: np.ndarray
    colors: np.ndarray
    point_view: np.ndarray
    point_confidence: np.ndarray
    point_std: np.ndarray
    n_rejected: int
    unit: str | None
    options: DenseOptions
    frame: str = ""
    timings_s: Mapping = field(default_factory=dict)

    def __post_init__(self):
        for name in ("points", "colors", "point_view", "point_confidence", "point_std"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))
        object.__setattr__(self, "maps", tuple(self.maps))
        object.__setattr__(self, "timings_s", MappingProxyType(dict(self.timings_s)))

    def map(self, view) -> DepthMap:
        """The :class:`DepthMap` of reference view ``view`` (its id)."""
        for m in self.maps:
            if m.view == str(view):
                return m
        raise InputError(f"view {view!r} is not a reference view of this result; it has "
                         f"{', '.join(m.view for m in self.maps)}")
