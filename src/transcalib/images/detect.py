"""Detection and descriptor matching: each image is read and detected once, on two threads.

Per image (:func:`detect_all`): SIFT keypoints and descriptors (what fixes the epipoles
and links orientations: distinctive, invariant to scale and rotation; found on a copy
no larger than ``sift_max_side`` pixels, positions scaled back, since the tracks'
positions come from Lucas-Kanade later) and Shi-Tomasi corners refined by ``cv2.cornerSubPix`` (the points tracked: the
Lucas-Kanade criterion itself, also on repetitive textures such as checkerboards, whose
X-corners make unbiased templates only when the window is centred on them).
OpenCV releases the GIL, so two images are decoded and detected at once.

Matching (:func:`match_pair`): exact nearest neighbours of the descriptors (squared
distances from one matrix product), Lowe's ratio test and a mutual check.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Features", "DetectOptions", "detect_all", "match_pair", "to_u8", "n_threads"]


@dataclass(frozen=True)
class DetectOptions:
    """What :func:`detect_all` finds in each image.

    Attributes
    ----------
    max_features : int
        SIFT keypoints per image, at most.
    max_corners : int
        Shi-Tomasi corners per image, at most (0: none).
    corner_quality : float
        ``qualityLevel`` of ``cv2.goodFeaturesToTrack``.
    min_corner_distance_px : float
        ``minDistance`` between corners.
    sift_max_side_px : int
        SIFT runs on the image reduced (by an integer factor) to at most this side.
    """

    max_features: int = 2000
    max_corners: int = 2000
    corner_quality: float = 0.02
    min_corner_distance_px: float = 6.0
    sift_max_side_px: int = 640


@dataclass(frozen=True, eq=False)
class Features:
    """What was found in one image.

    Attributes
    ----------
    keypoints : (n, 2) float
        SIFT keypoint positions (px, full resolution).
    descriptors : (n, 128) float32
    corners : (m, 2) float
        Shi-Tomasi corners, strongest first (px).
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    corners: np.ndarray

    @property
    def n_keypoints(self) -> int:
        return len(self.keypoints)


def n_threads() -> int:
    """Worker threads for per-image work: 2 (the machines this runs on), 1 on one core."""
    return max(1, min(2, os.cpu_count() or 1))


def to_u8(g: np.ndarray) -> np.ndarray:
    """A grey image (float 0..255) as uint8."""
    return g if g.dtype == np.uint8 else np.clip(np.rint(g), 0, 255).astype(np.uint8)


def detect(grey: np.ndarray, options: DetectOptions) -> Features:
    """:class:`Features` of one grey image ``(h, w)`` (uint8 or float 0..255)."""
    u8 = to_u8(grey)
    h, w = u8.shape
    f = max(1, int(np.ceil(max(h, w) / options.sift_max_side_px)))
    small = u8 if f == 1 else cv2.resize(u8, (w // f, h // f), interpolation=cv2.INTER_AREA)
    sift = cv2.SIFT_create(nfeatures=options.max_features, contrastThreshold=0.02)
    kps, desc = sift.detectAndCompute(small, None)
    pts = np.array([k.pt for k in kps], float).reshape(-1, 2)
    pts = (pts + 0.5) * f - 0.5  # pixel centres of the reduced image -> full resolution
    if desc is None:
        desc = np.zeros((0, 128), np.float32)
    corners = np.zeros((0, 2))
    if options.max_corners > 0:
        c = cv2.goodFeaturesToTrack(u8, maxCorners=options.max_corners, qualityLevel=options.corner_quality,
                                    minDistance=options.min_corner_distance_px, blockSize=5)
        if c is not None:  # the seed is the track's reference: at the corner itself (X-corners of checkers)
            c = cv2.cornerSubPix(np.asarray(grey, np.float32), c.astype(np.float32), (4, 4), (-1, -1),
                                 (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-3))
            corners = c.reshape(-1, 2).astype(float)
    return Features(keypoints=pts, descriptors=np.ascontiguousarray(desc, np.float32), corners=corners)


def detect_all(grey: list, options: DetectOptions, report=None) -> list[Features]:
    """:func:`detect` of every image, on :func:`n_threads` threads, in order; ``report``
    (``(stage, done, total)``, optional) after each image."""
    feats = []
    with ThreadPoolExecutor(n_threads()) as pool:
        for f in pool.map(lambda g: detect(g, options), grey):
            feats.append(f)
            if report is not None:
                report("detect", len(feats), len(grey))
    return feats


def match_pair(d1: np.ndarray, d2: np.ndarray, ratio: float) -> np.ndarray:
    """Mutual nearest neighbours passing the ratio test: index pairs ``(k, 2)``.

    Exact (brute force): squared distances ``|a|^2 + |b|^2 - 2 a.b`` from one matrix
    product, whose row and column minima give both matching directions. SIFT's
    descriptors are integers up to 255, so every sum here is an integer below 2^24: exact
    in float32, in any order, and never negative.
    """
    if len(d1) < 2 or len(d2) < 2:
        return np.zeros((0, 2), int)
    a = np.ascontiguousarray(d1, np.float32)
    b = np.ascontiguousarray(d2, np.float32)
    D = a @ (-2.0 * b).T  # filled in place: no n1 x n2 temporary
    D += (b * b).sum(1)[None]
    D += (a * a).sum(1)[:, None]
    r2 = np.float32(ratio * ratio)
    Dt = cv2.transpose(D)  # the columns as rows: numpy's argmin down columns is 5 x slower
    ja, ok_a = _nearest_passing_ratio(D, r2)
    ib, ok_b = _nearest_passing_ratio(Dt, r2)
    i = np.flatnonzero(ok_a)
    j = ja[i]
    mutual = ok_b[j] & (ib[j] == i)
    return np.column_stack([i[mutual], j[mutual]])


def _nearest_passing_ratio(D: np.ndarray, r2: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Per row of the squared distances ``D (n1, n2)`` (overwritten): the nearest column
    and whether it passes the ratio test (nearer than ``r2`` times the second nearest)."""
    arg = D.argmin(1)
    rows = np.arange(len(D))
    best = D[rows, arg]
    D[rows, arg] = np.inf
    return arg, best < r2 * D.min(1)
