"""A view of another orientation resected against a session's affine structure.

A pure-translation session gives more than tracks: its infinite homography is the
identity, so its points have an **affine reconstruction** for free. With the view ``a``
of the session as reference, ``lambda_j x~_j = lambda_a x~_a - c_j e_aj`` (``e_aj`` the unit
epipole, ``c_j > 0``), so the point seen at ``x_a`` is ``X~ = (x_a, 1, w)`` with ``w``
its inverse depth in view ``a`` up to one scale: ``q_j = 1 / (1 / rho_j + e3) = c_j w``
(:func:`~.propagate.depth_scales`). Any other view ``b`` (any orientation) is then a
3 x 4 camera ``x~_b ~ P_b X~ = H x~_a + m w``: 11 degrees of freedom, fixed by 6 matches
(direct linear transform), found robustly on the project's one loop
(:func:`~transcalib.estimate.ransac.lo_ransac`) from descriptor matches whose ``w`` is
interpolated from the session's tracks. ``P_b`` then says where in ``b`` every point
of the session is - the prediction that makes tracking across 10-45 degrees reliable.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..estimate.noise import sigma_from_threshold
from ..estimate.ransac import lo_ransac
from .local import local_linear
from .propagate import depth_scales

__all__ = ["affine_structure", "resect", "project_structure", "interpolate_w", "session_camera", "infinite_homography"]


def affine_structure(uv: np.ndarray, epi: dict, a: int, sel: np.ndarray) -> np.ndarray:
    """Inverse depths ``w (m,)`` in view ``a`` (one common scale) of the session's tracks
    ``sel`` (seen in ``a``), NaN where unknown: the median of ``q_j / s_j`` over their views."""
    q, s, _ = depth_scales(uv, epi, a, sel)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmedian(q / s[:, None], axis=0)


def _normaliser(x: np.ndarray) -> np.ndarray:
    """Similarity ``(3, 3)`` moving ``x (m, 2)`` to zero mean, mean distance sqrt(2)."""
    c = x.mean(0)
    d = max(float(np.mean(np.linalg.norm(x - c, axis=1))), 1e-9)
    k = np.sqrt(2.0) / d
    return np.array([[k, 0, -k * c[0]], [0, k, -k * c[1]], [0, 0, 1.0]])


class _Resection:
    """The camera of view ``b`` as a :class:`~transcalib.estimate.ransac.RansacProblem`:
    6 matches per sample, the DLT's null vector as hypothesis, squared reprojection
    errors (px^2, 2 degrees of freedom)."""

    sample_size = 6

    def __init__(self, xa: np.ndarray, w: np.ndarray, xb: np.ndarray):
        self.Ha, self.Hb = _normaliser(xa), _normaliser(xb)
        self.ws = 1.0 / max(float(np.std(w)), 1e-12)
        self.wmean = float(np.mean(w))
        na = np.column_stack([xa, np.ones(len(xa))]) @ self.Ha.T
        self.X = np.column_stack([na, (w - self.wmean) * self.ws])  # (m, 4), normalised structure
        self.xb = xb
        nb = np.column_stack([xb, np.ones(len(xb))]) @ self.Hb.T
        u, v = nb[:, 0:1], nb[:, 1:2]
        z = np.zeros_like(self.X)
        self.rows = np.stack([np.hstack([self.X, z, -u * self.X]), np.hstack([z, self.X, -v * self.X])], axis=1)
        m = len(xa)
        self.dof = np.full(m, 2, np.intp)
        self.scorable = self.samplable = np.ones(m, bool)

    def sample(self, rng, size):
        return np.argpartition(rng.random((size, len(self.xb))), 6, axis=1)[:, :6]

    def _dlt(self, idx):
        A = self.rows[idx].reshape(idx.shape[0], -1, 12)
        P = np.linalg.svd(A, full_matrices=False)[2][:, -1]
        return P, np.all(np.isfinite(P), axis=1)

    def solve(self, samples):
        return self._dlt(samples)

    def refit(self, inliers):
        return self._dlt(np.flatnonzero(inliers)[None])

    def errors(self, P):
        x = np.einsum("hab,mb->hma", P.reshape(-1, 3, 4), self.X)
        x = np.einsum("ab,hmb->hma", np.linalg.inv(self.Hb), x)
        with np.errstate(divide="ignore", invalid="ignore"):
            p = x[..., :2] / x[..., 2:]
        e = ((p - self.xb[None]) ** 2).sum(-1)
        return np.where(np.isfinite(e) & (x[..., 2] * np.sign(np.median(x[..., 2], axis=1, keepdims=True)) > 0),
                        e, np.inf)

    def camera(self, P):
        """``P`` (12,) of normalised coordinates as ``(3, 4)`` on ``(x_a, 1, w)`` in pixels."""
        D = np.zeros((4, 4))
        D[:3, :3] = self.Ha
        D[3, 3] = self.ws
        D[3, 2] = -self.wmean * self.ws
        return np.linalg.inv(self.Hb) @ P.reshape(3, 4) @ D


class _ResectionWithHint(_Resection):
    """:class:`_Resection` with the infinite homography ``H`` known: ``P_b = [l H | m]``,
    4 unknowns up to scale (3 degrees of freedom), 2 matches per sample."""

    sample_size = 2

    def __init__(self, xa: np.ndarray, w: np.ndarray, xb: np.ndarray, H: np.ndarray):
        self.Hb = _normaliser(xb)
        self.xb = xb
        self.ws = 1.0 / max(float(np.std(w)), 1e-12)
        y = np.column_stack([xa, np.ones(len(xa))]) @ (self.Hb @ H).T
        n = np.linalg.norm(y, axis=1)  # each match's equation divided by it: same projective point
        y = y / n[:, None]
        self.Y, self.W = y, w * self.ws / n
        nb = np.column_stack([xb, np.ones(len(xb))]) @ self.Hb.T
        u, v, W, z = nb[:, 0], nb[:, 1], self.W, np.zeros(len(xb))
        self.rows = np.stack([np.column_stack([u * y[:, 2] - y[:, 0], -W, z, u * W]),
                              np.column_stack([v * y[:, 2] - y[:, 1], z, -W, v * W])], axis=1)
        self.H = H
        m = len(xa)
        self.dof = np.full(m, 2, np.intp)
        self.scorable = self.samplable = np.ones(m, bool)

    def sample(self, rng, size):
        return np.argpartition(rng.random((size, len(self.xb))), 2, axis=1)[:, :2]

    def _dlt(self, idx):
        A = self.rows[idx].reshape(idx.shape[0], -1, 4)
        p = np.linalg.svd(A, full_matrices=False)[2][:, -1]
        return p, np.all(np.isfinite(p), axis=1)

    def errors(self, p):
        x = p[:, None, :1] * self.Y[None] + p[:, None, 1:] * self.W[None, :, None]
        x = np.einsum("ab,hmb->hma", np.linalg.inv(self.Hb), x)
        with np.errstate(divide="ignore", invalid="ignore"):
            q = x[..., :2] / x[..., 2:]
        e = ((q - self.xb[None]) ** 2).sum(-1)
        return np.where(np.isfinite(e), e, np.inf)

    def camera(self, p):
        """``(3, 4)`` on ``(x_a, 1, w)`` in pixels: ``[l H | ws Hb^-1 m]``."""
        return np.column_stack([p[0] * self.H, self.ws * np.linalg.inv(self.Hb) @ p[1:]])


def resect(xa: np.ndarray, w: np.ndarray, xb: np.ndarray, threshold_px: float, rng, min_inliers: int = 12,
           H: np.ndarray | None = None):
    """Camera ``P_b (3, 4)`` with ``x~_b ~ P_b (x_a, 1, w)`` from matches ``xa -> xb`` of
    points of inverse depth ``w`` (module docstring), and its inliers; ``(None, inliers)``
    with fewer than ``min_inliers`` inliers. With ``H`` (the infinite homography a -> b,
    e.g. from the flange rotations) only ``P_b = [l H | m]`` is sought: well posed even
    when the matches lie on one plane or in a narrow range of depths."""
    ok = np.isfinite(w)
    inl = np.zeros(len(xa), bool)
    if ok.sum() < min_inliers:
        return None, inl
    prob = _Resection(xa[ok], w[ok], xb[ok]) if H is None else _ResectionWithHint(xa[ok], w[ok], xb[ok], H)
    best = lo_ransac(prob, max_trials=500, sigma=sigma_from_threshold(threshold_px, 0.01), rng=rng)
    if best.hypothesis is None or best.n_inliers < min_inliers:
        return None, inl
    inl[np.flatnonzero(ok)[best.inliers]] = True
    return prob.camera(best.hypothesis), inl


def project_structure(P: np.ndarray, xa: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``P (x_a, 1, w)`` in pixels ``(m, 2)`` (NaN where undefined)."""
    x = np.column_stack([xa, np.ones(len(xa)), w]) @ P.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return x[:, :2] / x[:, 2:]


def interpolate_w(track_x: np.ndarray, track_w: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Inverse depth at ``query`` points from the tracks' (:func:`~.local.local_linear`)."""
    ok = np.isfinite(track_w)
    return local_linear(track_x[ok], track_w[ok], query, k=10)


def session_camera(uv: np.ndarray, T: np.ndarray, rng=0):
    """The camera of a pure-translation session from its own tracks: ``(K, R, sign)`` of
    the robust linear estimate (:func:`transcalib.estimate.robust.estimate_robust`), or
    None when the session cannot give one (translations not spanning 3-D, too few tracks).

    ``sign`` is +1 when the camera moves with the robot (eye-in-hand), -1 when the scene
    does (eye-to-hand: an object carried by the flange in front of a fixed camera; the
    camera then sees the object translate by ``-T``); the other sign is refused as a
    mirrored camera."""
    from ..errors import DegenerateError, InputError, MirroredError
    from ..estimate.robust import estimate_robust

    for sign in (1.0, -1.0):
        try:
            est = estimate_robust(uv, sign * np.asarray(T, float), rng=rng)
        except MirroredError:
            continue
        except (DegenerateError, InputError, np.linalg.LinAlgError):
            return None
        return est.linear.K, est.linear.R, sign
    return None


def infinite_homography(camera, R_fa: np.ndarray, R_fb: np.ndarray) -> np.ndarray:
    """The infinite homography ``(3, 3)`` from a view of flange rotation ``R_fa`` (whose
    session's camera is ``camera = (K, R, sign)``, :func:`session_camera`) to a view of
    flange rotation ``R_fb``, under the robot model of the poses (DESIGN.md section 4):

    - eye-in-hand (``sign = +1``): ``R_b = (R_fb R_X)^T`` with ``R_X = R_fa^T R^T``, so
      ``H = K R R_fa R_fb^T R^T K^-1``;
    - eye-to-hand (``sign = -1``, ``R = R_bc^T``): the object turns by ``R_fb R_fa^T`` in
      the base frame, so ``H = K R R_fb R_fa^T R^T K^-1``.

    A hint (the flange rotations are measured, the camera's from the session's linear
    estimate): every prediction it gives is verified in the images.
    """
    K, R, sign = camera
    turn = R_fa @ R_fb.T if sign > 0 else R_fb @ R_fa.T
    return K @ R @ turn @ R.T @ np.linalg.inv(K)
