"""Images in, tracks out: the :class:`Tracks` container, its :class:`TrackInfo`, image loading.

Coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import os
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..types import InputError, report

__all__ = ["Tracks", "TrackInfo", "PairInfo", "GroupInfo", "LinkInfo", "load_images"]


@dataclass(frozen=True)
class PairInfo:
    """One view pair of a session, or of general motion (``views``, global indices, ``a < b``).

    Attributes
    ----------
    views : (int, int)
    n_matches : int
        Descriptor matches.
    n_verified : int
        Of them consistent with the pair's epipole (general motion: its fundamental matrix).
    source : str
        Where the epipole came from: ``"ransac"``, ``"repaired"``, ``"translations"``, ``"none"``;
        general motion ``"fundamental"`` (verified by ``F``) or ``"none"``.
    epipole : tuple of 3 float or None
        Unit epipole re-estimated from the refined tracks (signed as ``A (T_b - T_a)``).
    """

    views: tuple
    n_matches: int
    n_verified: int
    source: str
    epipole: tuple | None = None


@dataclass(frozen=True)
class GroupInfo:
    """A group of views of one camera orientation: a session (2+ views) or a single view.

    Attributes
    ----------
    label : str
    views : tuple of int
    n_tracks : int
        Tracks of the session alone (0 for a single view).
    rotations_deg : tuple of (float, float, float)
        A session's views' small rotations (the robot's orientation error), estimated from
        the images with the robot positions (:mod:`.derotate`): rotation vectors in
        degrees, robot base frame, from the session's median orientation, one per view of
        ``views``; empty when not estimated (a single view, no ``T``, translations not
        spanning 3-D).
    sigma_px : float
        Robust scale (px) of the derotated epipolar distances of the descriptor matches
        (NaN when the rotations were not estimated).
    """

    label: str
    views: tuple
    n_tracks: int
    rotations_deg: tuple = ()
    sigma_px: float = float("nan")

    @property
    def angles_deg(self) -> tuple:
        """Each view's rotation angle (degrees) from the session's median orientation."""
        return tuple(float(np.linalg.norm(w)) for w in self.rotations_deg)


@dataclass(frozen=True)
class LinkInfo:
    """Tracks linked between two groups of different orientation.

    Attributes
    ----------
    groups : (str, str)
        Labels.
    n_matches : int
        Descriptor matches consistent with the general epipolar geometry (both view pairs).
    n_links : int
        Points seen in both groups after linking.
    """

    groups: tuple
    n_matches: int
    n_links: int


@dataclass(frozen=True)
class TrackInfo:
    """How the tracks were found (:attr:`Tracks.info`).

    Attributes
    ----------
    method : str
        ``"features"``, ``"features (general motion)"`` (no two views at one orientation:
        :mod:`.multiview`), ``"squares"`` or ``"squares (auto: too few feature tracks)"``.
    time_s : dict str -> float
        Wall time of each stage (``load``, ``detect``, ``match``, ``verify``, ``chain``,
        ``refine``, ``checks``, ``extend``, ``link``), summed over sessions.
    pairs : tuple of PairInfo
        Every view pair inside a session (general motion: every view pair).
    n_observations : dict str -> int
        Observations (of tracks in 2+ views) after each stage, summed over sessions.
    n_static_dropped : int
        Tracks that did not move while the scene did.
    inconsistent_pairs, repaired_pairs, pairs_set_by_translations : tuple of (int, int)
        Pairs whose epipole disagreed with the others, those re-estimated on the line of
        consistent ones, and those set to ``A (T_b - T_a)`` of the robot translations.
    groups : tuple of GroupInfo
        The orientation groups (one when no rotations were given).
    links : tuple of LinkInfo
        Between groups.
    n_shared_points : int
        Points seen in two or more groups.
    squares_per_view : tuple of int
        Target mode: squares found in each view.
    rotation_tests : tuple of RotationTest
        Each session's rotation test (:mod:`.rotation`; session view indices).
    """

    method: str = "features"
    time_s: dict = field(default_factory=dict)
    pairs: tuple = ()
    n_observations: dict = field(default_factory=dict)
    n_static_dropped: int = 0
    inconsistent_pairs: tuple = ()
    repaired_pairs: tuple = ()
    pairs_set_by_translations: tuple = ()
    groups: tuple = ()
    links: tuple = ()
    n_shared_points: int = 0
    squares_per_view: tuple = ()
    rotation_tests: tuple = ()

    def pair(self, a: int, b: int) -> PairInfo | None:
        """The :class:`PairInfo` of views ``a``, ``b`` (either order), or None."""
        key = (min(a, b), max(a, b))
        return next((p for p in self.pairs if tuple(p.views) == key), None)

    def link(self, a: str, b: str) -> LinkInfo | None:
        """The :class:`LinkInfo` of groups ``a``, ``b`` (either order), or None."""
        return next((k for k in self.links if set(k.groups) == {a, b}), None)


@dataclass(frozen=True, eq=False)
class Tracks:
    """Point tracks across views.

    Attributes
    ----------
    uv : (n_views, n_points, 2) float
        Pixels (OpenCV convention, centre of the top-left pixel = (0, 0)); NaN where a
        point is not seen. A point keeps its index across every view it is seen in.
    ids : (n_points,) int
        Point identifiers (written to the ``point`` column of ``tracks.csv``).
    colors : (n_points, 3) uint8 or None
        RGB colour of each point (from its reference view), when the images had colour.
    view_names : tuple of str
        Name of each view (file stem, or ``"0"``, ``"1"``, ... for arrays).
    info : TrackInfo
        How they were found: times, counts, epipoles, groups and links.
    """

    uv: np.ndarray
    ids: np.ndarray
    colors: np.ndarray | None = None
    view_names: tuple = ()
    info: TrackInfo = field(default_factory=TrackInfo)

    @property
    def n_views(self) -> int:
        return int(self.uv.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.uv.shape[1])

    def to_csv(self, path) -> None:
        """Write ``view,point,u,v`` rows (one per observation), atomically.

        ``view`` is the view index ``0..n_views-1`` (the order of the images given to
        :func:`track`), ``point`` the id; ``u, v`` in pixels with 6 decimals.
        """
        seen = np.isfinite(self.uv[..., 0])
        vi, pj = np.nonzero(seen)
        rows = [f"{v},{self.ids[p]},{self.uv[v, p, 0]:.6f},{self.uv[v, p, 1]:.6f}" for v, p in zip(vi, pj)]
        text = "view,point,u,v\n" + "\n".join(rows) + ("\n" if rows else "")
        path = Path(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent if str(path.parent) else ".")
        try:
            with os.fdopen(fd, "w", newline="") as f:
                f.write(text)
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise


# --------------------------------------------------------------------------- input
def _read(k: int, im):
    """One image as ``(array, name)``: a file read with OpenCV (colour to RGB) or an array."""
    if isinstance(im, (str, os.PathLike)):
        p = Path(im)
        if not p.is_file():
            raise InputError(f"track: image file {str(p)!r} does not exist")
        arr = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if arr is None:
            raise InputError(f"track: cannot read image {str(p)!r} (not an image format OpenCV can decode)")
        if arr.ndim == 3 and arr.shape[2] == 4:
            arr = arr[..., :3]
        if arr.ndim == 3:
            arr = cv2.cvtColor(arr, cv2.COLOR_BGR2RGB)
        return arr, p.stem
    return np.asarray(im), str(k)


def _grey(arr: np.ndarray, name: str):
    """Checked ``(grey (h, w) float32 0..255, rgb (h, w, 3) uint8 or None)``."""
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3) or min(arr.shape[:2]) < 16:
        raise InputError(f"track: image {name} has shape {arr.shape}; expected (h, w) grey or (h, w, 3) "
                         "colour with h, w >= 16")
    if not np.issubdtype(arr.dtype, np.number) or (arr.dtype.kind == "f" and not np.all(np.isfinite(arr))):
        raise InputError(f"track: image {name} has non-numeric or non-finite pixels")
    if arr.dtype == np.uint8:
        if arr.ndim == 3:  # float conversion: no rounding of the weighted sum
            return cv2.cvtColor(arr.astype(np.float32), cv2.COLOR_RGB2GRAY), np.ascontiguousarray(arr)
        return arr.astype(np.float32), None
    scale = 1.0
    if arr.dtype == np.uint16:
        scale = 255.0 / 65535.0
    elif np.issubdtype(arr.dtype, np.floating) and arr.max() <= 1.0:
        scale = 255.0
    a = arr.astype(np.float32) * np.float32(scale)
    if a.ndim == 3:
        return np.ascontiguousarray(a @ np.array([0.299, 0.587, 0.114], np.float32)), \
            np.clip(np.rint(a), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(a), None


def load_images(images) -> tuple[list[np.ndarray], list[np.ndarray | None], tuple[str, ...]]:
    """Read and check images (files decoded on two threads).

    Parameters
    ----------
    images : sequence of path or array, or array (n_views, h, w[, 3])
        File paths (read with OpenCV, colour converted to RGB) or arrays (2-D grey, or
        3-D ``(h, w, 3)`` taken as RGB), all of one size.

    Returns
    -------
    grey : list of (h, w) float32
        Intensities 0..255 (0.299 R + 0.587 G + 0.114 B).
    rgb : list of (h, w, 3) uint8 or None
    names : tuple of str
    """
    if isinstance(images, (str, os.PathLike)):
        raise InputError("track: expected a sequence of images (paths or arrays), got a single path "
                         f"{str(images)!r}; pass a list such as [img0.png, img1.png, ...]")
    images = list(images)
    if len(images) < 2:
        raise InputError(f"track: need at least 2 images (4+ for calibration), got {len(images)}")
    with ThreadPoolExecutor(2) as pool:
        read = list(pool.map(lambda ki: _read(*ki), enumerate(images)))
        conv = list(pool.map(lambda an: _grey(*an), read))
    grey = [g for g, _ in conv]
    rgb = [c for _, c in conv]
    names = tuple(name for _, name in read)
    shapes = {g.shape for g in grey}
    if len(shapes) > 1:
        raise InputError("track: all images must have the same size (one camera); got sizes "
                         + ", ".join(f"{n}: {g.shape[1]}x{g.shape[0]}" for n, g in zip(names, grey)))
    return grey, rgb, names


def progress_fn(progress):
    """``step(stage, done, total)`` sending :class:`~transcalib.types.ProgressEvent` s to
    ``progress`` (a callable; ``True``: one line per step on stderr; None / False: off)."""
    if progress is None or progress is False:
        return lambda stage, done, total: None
    if progress is True:
        def progress(event):
            print(f"[track] {event.stage}: {event.done}/{event.total}", file=sys.stderr, flush=True)
    return lambda stage, done, total: report(progress, stage, done, total)
