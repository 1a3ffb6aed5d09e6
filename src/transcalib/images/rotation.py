"""The rotation test: are the views of a session pure translations of each other?

(Placeholder: today's test, to be replaced.)
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import DegenerateError

__all__ = ["RotatedViewsError", "check_pure_translation"]

ROTATION_MIN_F_FRACTION = 0.85
ROTATION_MAX_E_RATIO = 0.85


class RotatedViewsError(DegenerateError):
    """Some view pairs were taken with a rotation between them: the pure-translation
    tracker cannot track them (a :class:`DegenerateError`; the message names the pairs)."""


def check_pure_translation(xy: dict, geo: dict, threshold_px: float, names=None, min_matches: int = 50):
    """Raise :class:`RotatedViewsError` when some view pair was taken with a rotation."""
    rotated = []
    name = (lambda i: str(i)) if names is None else (lambda i: str(names[i]))
    for (i, j), (xi, xj) in xy.items():
        g = geo[(i, j)]
        if len(xi) < min_matches or np.median(np.linalg.norm(xj - xi, axis=1)) < 2.0:
            continue
        F, mask = cv2.findFundamentalMat(xi.astype(np.float64), xj.astype(np.float64), cv2.USAC_MAGSAC,
                                         threshold_px, 0.999, 2000)
        n_f = 0 if mask is None or F is None else int(mask.sum())
        n_e = g.n_inliers if g.e is not None else 0
        if n_f >= max(min_matches, ROTATION_MIN_F_FRACTION * len(xi)) and n_e < ROTATION_MAX_E_RATIO * n_f:
            rotated.append(f"{name(i)}-{name(j)} (general epipolar geometry: {n_f} of {len(xi)} matches, "
                           f"pure translation: {n_e})")
    if rotated:
        raise RotatedViewsError(
            "the views are not related by pure translations: the camera rotated between views "
            + "; ".join(rotated[:6]) + ("; ..." if len(rotated) > 6 else "")
            + ". The pure-translation tracker needs one camera orientation per session. If the robot turned "
            "the wrist between groups of views, give the flange orientations (a session per orientation): "
            "transcalib.images.track(images, T=T, rotations=R), or the poses file's orientation columns; "
            "otherwise check that the robot did not rotate")
