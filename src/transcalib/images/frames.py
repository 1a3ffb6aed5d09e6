"""Images in, tracks out: the :class:`Tracks` container and image loading/checking.

Coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import os
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..types import InputError, report

__all__ = ["Tracks", "load_images"]


@dataclass(frozen=True, eq=False)
class Tracks:
    """Point tracks across views.

    Attributes
    ----------
    uv : (n_views, n_points, 2) float
        Pixels (OpenCV convention, centre of the top-left pixel = (0, 0)); NaN where a
        point is not seen.
    ids : (n_points,) int
        Point identifiers (written to the ``point`` column of ``tracks.csv``).
    colors : (n_points, 3) uint8 or None
        RGB colour of each point (from its reference view), when the images had colour.
    view_names : tuple of str
        Name of each view (file stem, or ``"0"``, ``"1"``, ... for arrays).
    info : dict
        Statistics: per-stage times ``time_s``, counts, epipoles.
    """

    uv: np.ndarray
    ids: np.ndarray
    colors: np.ndarray | None = None
    view_names: tuple = ()
    info: dict = field(default_factory=dict)

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
        path = Path(path)
        seen = np.isfinite(self.uv[..., 0])
        vi, pj = np.nonzero(seen)
        rows = [f"{v},{self.ids[p]},{self.uv[v, p, 0]:.6f},{self.uv[v, p, 1]:.6f}" for v, p in zip(vi, pj)]
        text = "view,point,u,v\n" + "\n".join(rows) + ("\n" if rows else "")
        d = path.parent if str(path.parent) else Path(".")
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=d)
        try:
            with os.fdopen(fd, "w", newline="") as f:
                f.write(text)
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise


# --------------------------------------------------------------------------- input
def load_images(images) -> tuple[list[np.ndarray], list[np.ndarray | None], tuple[str, ...]]:
    """Read and check images.

    Parameters
    ----------
    images : sequence of path or array, or array (n_views, h, w[, 3])
        File paths (read with OpenCV, colour converted to RGB) or arrays (2-D grey, or
        3-D ``(h, w, 3)`` taken as RGB), all of one size.

    Returns
    -------
    grey : list of (h, w) float32
        Intensities 0..255.
    rgb : list of (h, w, 3) uint8 or None
    names : tuple of str
    """
    if isinstance(images, (str, os.PathLike)):
        raise InputError("track: expected a sequence of images (paths or arrays), got a single path "
                         f"{str(images)!r}; pass a list such as [img0.png, img1.png, ...]")
    images = list(images)
    if len(images) < 2:
        raise InputError(f"track: need at least 2 images (4+ for calibration), got {len(images)}")
    grey, rgb, names = [], [], []
    for k, im in enumerate(images):
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
            names.append(p.stem)
        else:
            arr = np.asarray(im)
            names.append(str(k))
        if arr.ndim == 3 and arr.shape[2] == 1:
            arr = arr[..., 0]
        if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3) or min(arr.shape[:2]) < 16:
            raise InputError(f"track: image {names[-1]} has shape {arr.shape}; expected (h, w) grey or (h, w, 3) "
                             "colour with h, w >= 16")
        if not np.issubdtype(arr.dtype, np.number) or not np.all(np.isfinite(arr)):
            raise InputError(f"track: image {names[-1]} has non-numeric or non-finite pixels")
        scale = 1.0
        if arr.dtype == np.uint16:
            scale = 255.0 / 65535.0
        elif np.issubdtype(arr.dtype, np.floating) and arr.max() <= 1.0:
            scale = 255.0
        a = arr.astype(np.float32) * np.float32(scale)
        if a.ndim == 3:
            rgb.append(np.clip(np.rint(a), 0, 255).astype(np.uint8))
            a = a @ np.array([0.299, 0.587, 0.114], np.float32)
        else:
            rgb.append(None)
        grey.append(np.ascontiguousarray(a, dtype=np.float32))
    shapes = {g.shape for g in grey}
    if len(shapes) > 1:
        raise InputError("track: all images must have the same size (one camera); got sizes "
                         + ", ".join(f"{n}: {g.shape[1]}x{g.shape[0]}" for n, g in zip(names, grey)))
    return grey, rgb, tuple(names)



def _progress_fn(progress):
    """``step(stage, done, total)`` sending :class:`~transcalib.types.ProgressEvent` s to
    ``progress`` (a callable; ``True``: one line per step on stderr; None / False: off)."""
    if progress is None or progress is False:
        return lambda stage, done, total: None
    if progress is True:
        def progress(event):
            print(f"[track] {event.stage}: {event.done}/{event.total}", file=sys.stderr, flush=True)
    return lambda stage, done, total: report(progress, stage, done, total)
