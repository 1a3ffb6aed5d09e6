"""Result types and error classes shared by every stage.

Conventions (see ``docs/conventions.md``):

* ``uv``  ``(n_views, n_points, 2)`` pixels, NaN where a point is not seen; the centre of
  the top-left pixel is (0, 0) (OpenCV).
* ``T``   ``(n_views, 3)`` robot translations in the world (robot) frame, user units.
* ``R``   world -> camera rotation (``R_cam_world``), det +1; camera x right, y down,
  z forward.
* ``K``   ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``; ``A = K R``.
* ``X``   ``(n_points, 3)`` scene points in world axes relative to the camera centre at
  robot position ``T = 0``.

Projection (paper eq. 2): ``lam_ij * [u_ij, v_ij, 1] = A (X_j - T_i)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "TranscalibError",
    "InputError",
    "DegenerateError",
    "MirroredError",
    "Diagnostic",
    "LinearEstimate",
    "Calibration",
]


from .errors import DegenerateError, Diagnostic, InputError, MirroredError, TranscalibError  # noqa: E402


@dataclass(frozen=True, eq=False)
class LinearEstimate:
    """The paper's linear (total-least-squares) estimate.

    Attributes
    ----------
    K : (3, 3) float
        Intrinsics, positive diagonal, ``K[2, 2] = 1``.
    R : (3, 3) float
        Rotation world -> camera, ``det R = +1``.
    A : (3, 3) float
        ``A = K R`` scaled so that ``||A[2]|| = 1`` (then ``depth`` is camera z).
    X : (n_points, 3) float
        Scene points (world axes, user units, relative to the camera centre at ``T = 0``),
        triangulated from all views with ``A`` and the known translations. NaN for
        points that were not used (seen in fewer than 2 views).
    depth : (n_views, n_points) float
        Projective depths lambda of the TLS solution (paper eq. 3), equal to the camera
        z-coordinate for exact data; NaN where a point is not seen or not used.
    singular_values : (k,) float
        The smallest singular values of the normalised system ``C b = 0``, ascending.
        Their ratio ``s[0] / s[1]`` measures how well the solution is determined
        (near 1: ill-conditioned).
    n_used_points : int
        Number of points that entered the estimate.
    used : (n_points,) bool
        Which points entered the estimate.
    method : str
        ``"fast"`` (O(n) block elimination) or ``"dense"`` (SVD of the whole system).
    """

    K: np.ndarray
    R: np.ndarray
    A: np.ndarray
    X: np.ndarray
    depth: np.ndarray
    singular_values: np.ndarray
    n_used_points: int
    used: np.ndarray
    method: str = "fast"


@dataclass(frozen=True, eq=False)
class Calibration:
    """A complete calibration: what :func:`transcalib.calibrate` returns.

    Attributes
    ----------
    K : (3, 3) float
        Intrinsic matrix.
    R : (3, 3) float
        Rotation world (robot) -> camera, det +1.
    X : (n_points, 3) float
        Scene points in world axes and user units; NaN for unused points.
    dist : (k,) float
        Lens distortion coefficients of the model in OpenCV order (``k1, k2, p1, p2, k3``
        truncated to the model: empty for "none", ``k1, k2`` for "radial2");
        :attr:`dist_opencv` pads them to the five values OpenCV functions take.
    dist_model : str
        ``"none"``, ``"radial2"`` or ``"opencv5"``.
    residuals_px : (n_views, n_points, 2) float
        Observed minus predicted pixel positions; NaN where a point is not seen or not used.
    rms_px : float
        ``sqrt(mean(du**2 + dv**2))`` over the used observations (OpenCV's RMS convention).
    diagnostics : list of Diagnostic
        Human-readable warnings, each naming the cause and what to do. Empty when the
        data look healthy.
    T : (n_views, 3) float
        The translations used (the measured ones, or their refined values when the
        robot noise was modelled).
    linear : LinearEstimate or None
        The linear estimate the result started from.
    cov : (p, p) float or None
        Covariance of the parameters named by ``param_names`` (refined results only).
    std : dict of str to float
        Standard deviations by parameter name (rotation angles in degrees).
    param_names : tuple of str
        Names of the parameters in ``cov``.
    X_std : (n_points, 3) float or None
        Standard deviation of each scene point coordinate.
    inliers : (n_points,) bool or None
        Points classified as inliers (robust estimation), else None (all used).
    info : dict
        How the result was obtained: stages run, iterations, final cost, stop reason...
    """

    K: np.ndarray
    R: np.ndarray
    X: np.ndarray
    dist: np.ndarray
    residuals_px: np.ndarray
    rms_px: float
    diagnostics: list = field(default_factory=list)
    dist_model: str = "none"
    T: np.ndarray | None = None
    linear: LinearEstimate | None = None
    cov: np.ndarray | None = None
    std: dict = field(default_factory=dict)
    param_names: tuple = ()
    X_std: np.ndarray | None = None
    inliers: np.ndarray | None = None
    info: dict = field(default_factory=dict)

    @property
    def A(self) -> np.ndarray:
        """``K @ R`` (3, 3)."""
        return self.K @ self.R

    @property
    def dist_opencv(self) -> np.ndarray:
        """The five OpenCV coefficients ``k1, k2, p1, p2, k3`` (zeros beyond the model),
        ready for ``cv2.undistort`` / ``cv2.projectPoints``."""
        out = np.zeros(5)
        out[: self.dist.size] = self.dist
        return out

    @property
    def n_views(self) -> int:
        return int(self.residuals_px.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.residuals_px.shape[1])
