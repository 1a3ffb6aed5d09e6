"""The rotation test: are the views of a session pure translations of each other?

Under pure translation every view pair's fundamental matrix is ``F = [e]_x`` (2 degrees
of freedom, :mod:`.epipoles`); a rotation between the views gives a general ``F``
(7 degrees of freedom). For each view pair with enough moving descriptor matches:

1. a general ``F`` is fitted (USAC MAGSAC, the pair's epipolar threshold); the pair is
   **tested** only when ``F`` explains at least :data:`MIN_GENERAL_FRACTION` of its matches
   (a clean pair: on repetitive textures or planes a general ``F`` also fits families of
   mismatches, and nothing can be concluded);
2. the pure-translation model is fitted to **the same matches** (``F``'s inliers: an
   epipole by 2-match RANSAC), and the fraction of them it explains is measured as the
   distance from the epipolar lines alone, without the sign of the depth. Counting the
   translation's own inliers instead (its RANSAC on all matches, with cheirality and the
   depth checks) made the test refuse valid scenes: on a checkered floor, mismatches one
   period along the epipolar line fit a general ``F`` but have the wrong depth sign, so
   ``F`` "explained" more matches than the translation (issue 21's false refusal);
3. a match the translation does not explain is a **twin** when the second view, at the
   place the translation puts it (on its epipolar line, at the inverse depth of the
   explained matches around it), looks like its patch in the first view as much as its
   descriptor match does (normalised cross-correlation within :data:`TWIN_NCC_DROP`): on a
   texture of identical tiles the descriptor picked the next tile, and the translation
   explains the point as well. Twins count as explained (with the images given). Under a
   rotation the predicted place is a few pixels off the true one and its patch differs:
   measured, 0-22 % of the unexplained matches of rotated pairs are twins, 76-98 % of
   those of pure translations over identical tiles;
4. the pair is **flagged** when the explained fraction is below :data:`MIN_EXPLAINED`,
   also after undistorting both views by the best of a few radial terms
   (:data:`DISTORTION_GRID`: lens distortion bends the epipolar lines radially, which a
   general ``F`` absorbs better than ``[e]_x``; a rotation is not radial).

A rotated view breaks every pair it is in, so views are judged, not pairs: a view is
**rotated** when more than half of its tested pairs are flagged, and at least two of
them (one in a session of two views). One stray pair (a repetitive texture that fooled
both fits) refuses nothing. :func:`check_pure_translation`
raises :class:`RotatedViewsError` naming the views and their pairs.

Thresholds from ``benchmarks/bench_tracker_rotation.py`` (rendered scenes with large
moves, repetitive textures, curved objects, lens distortion, JPEG): the rates are in
``benchmarks/results/tracker_rotation.md``. Rotations too small to stop the tracker are
left to the calibration's own rotation test (:mod:`transcalib.check.rotation`), which
measures each view's rotation with the bundle adjuster.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import DegenerateError
from .epipoles import direction, epipole_ransac, residuals
from .local import local_linear

__all__ = ["RotatedViewsError", "RotationTest", "PairRotationTest", "check_pure_translation", "rotation_test",
           "general_inliers", "testable"]

#: A pair is tested when a general fundamental matrix explains at least this fraction of its matches.
MIN_GENERAL_FRACTION = 0.85
#: A tested pair is flagged when the pure translation explains less than this fraction of F's inliers.
MIN_EXPLAINED = 0.85
#: Fewest descriptor matches (and F inliers) of a tested pair.
MIN_TEST_MATCHES = 50
#: Radial terms (division model, radius in units of the matches' extent) tried on a pair
#: the straight lines do not explain: lens distortion (k1 from about -0.4 to 0.2 at common
#: fields of view, -0.3 tested) bends epipolar lines radially, a rotation does not.
DISTORTION_GRID = np.linspace(-0.3, 0.3, 25)
#: A pair whose matches move less than this (median, px) cannot show a rotation.
MIN_MOTION_PX = 2.0
#: An unexplained match is a twin (step 3) when the patch at its predicted place
#: correlates with its first-view patch at most this much less than its match's patch.
TWIN_NCC_DROP = 0.1
#: Half-size (px) of the patches compared; fewest explained matches to predict from.
TWIN_PATCH_RADIUS = 7
TWIN_MIN_EXPLAINED = 10


class RotatedViewsError(DegenerateError):
    """Some view pairs were taken with a rotation between them: the pure-translation
    tracker cannot track them (a :class:`DegenerateError`; the message names the views)."""


@dataclass(frozen=True)
class PairRotationTest:
    """The rotation test of one view pair (session view indices ``i < j``).

    Attributes
    ----------
    views : (int, int)
    n_matches : int
        Descriptor matches.
    n_general : int
        Matches a general fundamental matrix explains (0 when not fitted).
    explained : float
        Fraction of those the pure translation explains (NaN when not tested).
    tested : bool
    flagged : bool
    """

    views: tuple
    n_matches: int
    n_general: int = 0
    explained: float = float("nan")
    tested: bool = False
    flagged: bool = False


@dataclass(frozen=True)
class RotationTest:
    """The rotation test of a session: every pair, and the views found rotated.

    Attributes
    ----------
    pairs : tuple of PairRotationTest
        On the derotated matches when the rotations were estimated.
    rotated_views : tuple of int
        Views (session indices) with more than half of their tested pairs flagged (and at
        least 2 of them, 1 with 2 views), or turned beyond the session tolerance.
    angles_deg : tuple of float
        Each view's estimated rotation from the session's median orientation (degrees;
        empty when not estimated: no robot positions, or translations not spanning 3-D).
    tolerance_deg : float
        The session tolerance the angles were judged against (NaN when not estimated).
    image_pairs : tuple of PairRotationTest
        With estimated rotations, the pairs' test on the matches as imaged (not
        derotated); empty otherwise.
    """

    pairs: tuple
    rotated_views: tuple
    angles_deg: tuple = ()
    tolerance_deg: float = float("nan")
    image_pairs: tuple = ()

    @property
    def n_tested(self) -> int:
        return sum(p.tested for p in self.pairs)


def _general_inliers(x: np.ndarray, y: np.ndarray, threshold_px: float) -> np.ndarray | None:
    """Inliers ``(m,)`` of a general fundamental matrix (USAC MAGSAC), or None."""
    try:
        F, mask = cv2.findFundamentalMat(x.astype(np.float64), y.astype(np.float64), cv2.USAC_MAGSAC, threshold_px,
                                         0.999, 2000)
    except cv2.error:  # OpenCV's USAC can fail on degenerate samples
        return None
    if F is None or mask is None or F.shape != (3, 3):
        return None
    return mask.ravel().astype(bool)


def _explained(x: np.ndarray, y: np.ndarray, threshold_px: float, rng, images=None, to_image=None) -> float:
    """Fraction of the matches ``x -> y`` within ``threshold_px`` of the epipolar lines of
    the epipole fitted to them (2-match RANSAC), by distance alone; with ``images`` (the
    pair's two grey views) the twins (module docstring, step 3) count as explained
    (``to_image``: the two views' maps from the matches' pixels to the images')."""
    e, _, _ = epipole_ransac(x, y, threshold_px=threshold_px, rng=rng, max_trials=300)
    if e is None:
        return 0.0
    dist, rho = residuals(e, x, y)
    ok = dist < threshold_px
    if images is not None and ok.sum() >= TWIN_MIN_EXPLAINED and not ok.all():
        ok[~ok] = _twins(images, e, x[ok], rho[ok], x[~ok], y[~ok], to_image)
    return float(np.mean(ok))


def _twins(images, e: np.ndarray, x_ok, rho_ok, x, y, to_image=None) -> np.ndarray:
    """``(m,)`` bool: the unexplained matches ``x -> y`` whose translation-predicted place
    ``x + rho (e3 x - e_xy)`` (``rho`` of the explained matches ``x_ok`` around them)
    looks like them as much as ``y`` does (step 3); patches cut at ``to_image`` of them."""
    rho = np.nan_to_num(local_linear(x_ok, rho_ok, x, k=10), nan=0.0)
    predicted = x + rho[:, None] * direction(e, x)
    fi, fj = to_image or (lambda p: p, lambda p: p)
    first = _patches(images[0], fi(x))
    return _ncc(first, _patches(images[1], fj(predicted))) >= _ncc(first, _patches(images[1], fj(y))) - TWIN_NCC_DROP


def _patches(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Square patches ``(m, (2 r + 1)^2)`` of ``image`` centred on ``points`` (bilinear, border replicated)."""
    r = TWIN_PATCH_RADIUS
    offsets = np.arange(-r, r + 1, dtype=np.float32)
    gx, gy = np.meshgrid(offsets, offsets)
    map_x = (points[:, 0, None, None] + gx).astype(np.float32).reshape(len(points), -1)
    map_y = (points[:, 1, None, None] + gy).astype(np.float32).reshape(len(points), -1)
    return cv2.remap(np.asarray(image, np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normalised cross-correlation of the rows of ``a`` and ``b``."""
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    return (a * b).sum(axis=1) / np.sqrt((a * a).sum(axis=1) * (b * b).sum(axis=1) + 1e-12)


def _undistort(x: np.ndarray, centre: np.ndarray, scale: float, lam: float) -> np.ndarray:
    """One-parameter division model: ``c + (x - c) / (1 + lam r^2)``, ``r = |x - c| / scale``."""
    d = x - centre
    return centre + d / (1.0 + lam * (d * d).sum(1, keepdims=True) / scale**2)


def testable(x: np.ndarray, y: np.ndarray) -> bool:
    """Enough matches ``x -> y`` moving enough for a pair to show a rotation (step 1)."""
    return len(x) >= MIN_TEST_MATCHES and bool(np.median(np.linalg.norm(y - x, axis=1)) >= MIN_MOTION_PX)


def general_inliers(xy: dict, threshold_px: float) -> dict:
    """``{(i, j): (m,) bool}``: the matches of every :func:`testable` pair that a general
    fundamental matrix explains (USAC MAGSAC; pairs where it fails left out)."""
    out = {}
    for p, (x, y) in xy.items():
        S = _general_inliers(x, y, threshold_px) if testable(x, y) else None
        if S is not None:
            out[p] = S
    return out


def pair_test(x: np.ndarray, y: np.ndarray, threshold_px: float, rng, views=(0, 1), images=None, general=None,
              to_image=None) -> PairRotationTest:
    """The test of one pair of matches ``x -> y`` ``(m, 2)`` (module docstring, steps 1-4);
    ``images`` the two grey views (None: no twins), ``general`` the general ``F``'s
    inliers when known (a homography close to the identity applied to both views, such as
    the derotation, leaves them), ``to_image`` the views' maps to image pixels."""
    m = len(x)
    if not testable(x, y):
        return PairRotationTest(views=views, n_matches=m)
    S = _general_inliers(x, y, threshold_px) if general is None else general
    n_f = 0 if S is None else int(S.sum())
    if n_f < max(MIN_TEST_MATCHES, MIN_GENERAL_FRACTION * m):
        return PairRotationTest(views=views, n_matches=m, n_general=n_f)
    explained = _explained(x[S], y[S], threshold_px, rng, images, to_image)
    if explained < MIN_EXPLAINED:  # lens distortion bends the lines: undistorted by the best radial term
        c = x[S].mean(0)
        scale = max(float(np.abs(np.vstack([x[S], y[S]]) - c).max()), 1.0)
        for lam in DISTORTION_GRID:
            explained = max(explained, _explained(_undistort(x[S], c, scale, lam), _undistort(y[S], c, scale, lam),
                                                  threshold_px, rng))
    return PairRotationTest(views=views, n_matches=m, n_general=n_f, explained=explained, tested=True,
                            flagged=explained < MIN_EXPLAINED)


def rotation_test(xy: dict, n_views: int, threshold_px: float, rng, grey=None, general=None, derotation=None,
                  tolerance_deg: float = float("nan")) -> RotationTest:
    """The test of every pair of ``xy`` (``(i, j) -> (x (m, 2), y (m, 2))``) and the views
    with more than half of their tested pairs flagged, and at least 2 (1 with 2 views);
    ``grey`` the views (list of ``(h, w)`` arrays; None: no twins).

    With a ``derotation`` (:class:`~.derotate.Derotation`, estimated) ``xy`` are the
    derotated matches, ``general`` the general ``F``'s inliers of each pair; a view is
    rotated when the derotated pairs flag it (residuals the rotations do not explain), or
    when its estimated rotation exceeds ``tolerance_deg`` **and** the pairs as imaged
    flag it (an angle alone refuses nothing: on flat scenes seen from few views the fit
    can find rotations the matches do not show, measured on
    ``benchmarks/bench_tracker_rotation.py``'s scenes).
    """
    general = general or {}
    est = derotation is not None and derotation.estimated
    maps = (lambda p: None) if not est else (
        lambda p: (lambda x: derotation.to_image(p[0], x), lambda x: derotation.to_image(p[1], x)))

    def tests(matches, to_image):
        return tuple(pair_test(x, y, threshold_px, rng, views=p, general=general.get(p), to_image=to_image(p),
                               images=None if grey is None else (grey[p[0]], grey[p[1]]))
                     for p, (x, y) in matches.items())

    pairs = tests(xy, maps)
    image_pairs = tests(derotation.pairs_to_image(xy), lambda p: None) if est else ()
    angles = derotation.angles_deg() if est else None
    rotated = [v for v in range(n_views) if _flagged_view(pairs, v, n_views)
               or (est and angles[v] > tolerance_deg and _flagged_view(image_pairs, v, n_views))]
    return RotationTest(pairs=pairs, rotated_views=tuple(rotated),
                        angles_deg=() if angles is None else tuple(float(a) for a in angles),
                        tolerance_deg=float(tolerance_deg) if est else float("nan"), image_pairs=image_pairs)


def _flagged_view(pairs: tuple, v: int, n_views: int) -> bool:
    """More than half of view ``v``'s tested pairs flagged, and at least 2 (1 with 2 views)."""
    mine = [p for p in pairs if v in p.views and p.tested]
    n_flagged = sum(p.flagged for p in mine)
    return n_flagged >= min(2, n_views - 1) and n_flagged > len(mine) / 2


def check_pure_translation(xy: dict, n_views: int, threshold_px: float, rng, names=None, grey=None, general=None,
                           derotation=None, tolerance_deg: float = float("nan")) -> RotationTest:
    """:func:`rotation_test`, raising :class:`RotatedViewsError` when a view is rotated
    (the message names the views, their estimated angles and the pairs that show them)."""
    test = rotation_test(xy, n_views, threshold_px, rng, grey, general, derotation, tolerance_deg)
    if not test.rotated_views:
        return test
    name = (lambda i: str(i)) if names is None else (lambda i: str(names[i]))
    flagged = [p for p in test.pairs if p.flagged and set(p.views) & set(test.rotated_views)]
    detail = "; ".join(f"{name(p.views[0])}-{name(p.views[1])} (general epipolar geometry: {p.n_general} of "
                       f"{p.n_matches} matches, pure translation: {round(p.explained * p.n_general)} of them)"
                       for p in flagged[:6]) + ("; ..." if len(flagged) > 6 else "")
    views = ", ".join(name(v) + (f" ({test.angles_deg[v]:.2f} deg)" if test.angles_deg else "")
                      for v in test.rotated_views)
    turned = ("" if not test.angles_deg else
              f" (estimated rotation from the session's median orientation; the session tolerance is "
              f"{test.tolerance_deg:g} deg)")
    seen = f", seen in the pairs {detail}" if detail else ""
    raise RotatedViewsError(
        f"the views are not related by pure translations: the camera rotated at view(s) "
        f"{views}{turned}{seen}. The pure-translation "
        "tracker needs one camera orientation per session. If the robot turned the wrist between groups of "
        "views, give the flange orientations (a session per orientation): "
        "transcalib.images.track(images, T=T, rotations=R), or the poses file's orientation columns; "
        "otherwise check that the robot did not rotate. A robot whose orientation errs by ~0.2 deg per axis "
        "turns a view by up to ~1 deg: for angles just above the tolerance, a larger one takes such views in "
        f"({_wider_tolerance(test)})")


def _wider_tolerance(test: RotationTest) -> str:
    """The option that takes the rotated views of ``test`` in: the largest estimated
    angle plus a quarter degree, rounded up to half a degree."""
    if not test.angles_deg:
        return "--session-tolerance-deg, session_tolerance_deg"
    turned = max(test.angles_deg[v] for v in test.rotated_views)
    wider = np.ceil(2.0 * (turned + 0.25)) / 2.0
    return f"--session-tolerance-deg {wider:g}, session_tolerance_deg={wider:g}"
