"""Lens models of the calibration: OpenCV 5-term, 8-term rational, 4-term fisheye (Kannala-Brandt).

Every model is a pinhole core ``(fx, fy, cx, cy)`` (px) followed by its distortion terms, in
mrcal's intrinsics order (``theta``):

=============  ==========================================  ===============================
name           theta                                       OpenCV call
=============  ==========================================  ===============================
``opencv5``    fx fy cx cy k1 k2 p1 p2 k3                  calibrateCamera, flags 0
``opencv8``    fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6         calibrateCamera, RATIONAL_MODEL
``fisheye4``   fx fy cx cy k1 k2 k3 k4                     cv2.fisheye.calibrate (skew 0)
=============  ==========================================  ===============================

The projections are OpenCV's own (``cv2.projectPoints``, ``cv2.fisheye.projectPoints``), with
their analytic Jacobians, so a model fitted here is exactly the one OpenCV, ROS and Kalibr apply.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cvsflow.exceptions import ConfigError


@dataclass(frozen=True)
class LensModel:
    """One lens model: its name, the names of its intrinsics and the OpenCV flags that fit it.

    Attributes
    ----------
    name : str
        ``opencv5``, ``opencv8`` or ``fisheye4``.
    param_names : tuple of str
        Names of the intrinsics vector ``theta`` in order (px for the core, unitless terms).
    fisheye : bool
        True for the ``cv2.fisheye`` model.
    cv_flags : int
        Flags of ``cv2.calibrateCamera`` (or ``cv2.fisheye.calibrate``) fitting this model.
    """

    name: str
    param_names: tuple
    fisheye: bool
    cv_flags: int

    @property
    def n_params(self) -> int:
        """Number of intrinsics (core and distortion)."""
        return len(self.param_names)

    @property
    def n_dist(self) -> int:
        """Number of distortion terms."""
        return len(self.param_names) - 4


_CORE = ("fx", "fy", "cx", "cy")
LENS_MODELS = {
    "opencv5": LensModel("opencv5", _CORE + ("k1", "k2", "p1", "p2", "k3"), False, 0),
    "opencv8": LensModel("opencv8", _CORE + ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
                         False, cv2.CALIB_RATIONAL_MODEL),
    "fisheye4": LensModel("fisheye4", _CORE + ("k1", "k2", "k3", "k4"), True,
                          cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC | cv2.fisheye.CALIB_FIX_SKEW),
}


def lens_model(name: str) -> LensModel:
    """The lens model called ``name``.

    Parameters
    ----------
    name : str
        ``opencv5``, ``opencv8`` or ``fisheye4``.

    Returns
    -------
    LensModel

    Raises
    ------
    ConfigError
        An unknown name (the known ones listed).
    """
    try:
        return LENS_MODELS[name]
    except KeyError:
        raise ConfigError(f"lens model {name!r}: expected one of {sorted(LENS_MODELS)}") from None


def K_dist(theta: np.ndarray, model: LensModel) -> tuple[np.ndarray, np.ndarray]:
    """Camera matrix and distortion vector of an intrinsics vector.

    Parameters
    ----------
    theta : ndarray, shape (model.n_params,)
        ``fx fy cx cy`` (px), then the model's distortion terms.
    model : LensModel

    Returns
    -------
    K : ndarray, shape (3, 3)
        px.
    dist : ndarray, shape (model.n_dist,)
        OpenCV's order.
    """
    fx, fy, cx, cy = (float(v) for v in theta[:4])
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return K, np.asarray(theta[4:], dtype=np.float64).copy()


def theta_from(K: np.ndarray, dist: np.ndarray, model: LensModel) -> np.ndarray:
    """Intrinsics vector from OpenCV's camera matrix and distortion.

    Parameters
    ----------
    K : ndarray, shape (3, 3)
        px.
    dist : ndarray
        OpenCV's distortion terms (padded with zeros or cut to the model's).
    model : LensModel

    Returns
    -------
    theta : ndarray, shape (model.n_params,)
    """
    d = np.asarray(dist, dtype=np.float64).ravel()[: model.n_dist]
    d = np.r_[d, np.zeros(model.n_dist - len(d))]
    return np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], d]


def project(p_B: np.ndarray, rvec_C_B: np.ndarray, tvec_C_B: np.ndarray, theta: np.ndarray,
            model: LensModel, jacobians: bool = True):
    """Pixels of board points seen from one pose, with the Jacobians of the fit.

    Parameters
    ----------
    p_B : ndarray, shape (n, 3)
        Points in the board frame B, m.
    rvec_C_B, tvec_C_B : ndarray, shape (3,)
        Pose of B in the camera frame C (Rodrigues, rad; m): ``p_C = R p_B + t``.
    theta : ndarray, shape (model.n_params,)
        Intrinsics (``fx fy cx cy`` px, then the distortion terms).
    model : LensModel
    jacobians : bool
        Also return the Jacobians.

    Returns
    -------
    uv_px : ndarray, shape (n, 2)
    J_pose : ndarray, shape (n, 2, 6)
        d uv / d (rvec, tvec) (only with ``jacobians``).
    J_theta : ndarray, shape (n, 2, model.n_params)
        d uv / d theta (only with ``jacobians``).
    """
    K, dist = K_dist(theta, model)
    p = np.ascontiguousarray(p_B, dtype=np.float64).reshape(-1, 1, 3)
    r = np.ascontiguousarray(rvec_C_B, dtype=np.float64).reshape(3, 1)
    t = np.ascontiguousarray(tvec_C_B, dtype=np.float64).reshape(3, 1)
    n = len(p)
    if model.fisheye:
        uv, J = cv2.fisheye.projectPoints(p, r, t, K, dist)
        uv = uv.reshape(n, 2)
        if not jacobians:
            return uv
        J = J.reshape(n, 2, 15)
        J_theta = J[:, :, :8]
        J_pose = J[:, :, 8:14]
    else:
        uv, J = cv2.projectPoints(p, r, t, K, dist)
        uv = uv.reshape(n, 2)
        if not jacobians:
            return uv
        J = J.reshape(n, 2, -1)
        J_pose = J[:, :, :6]
        J_theta = J[:, :, 6: 6 + model.n_params]
    return uv, np.ascontiguousarray(J_pose), np.ascontiguousarray(J_theta)


def project_camera_points(p_C: np.ndarray, theta: np.ndarray, model: LensModel):
    """Pixels of camera-frame points with d uv / d p_C and d uv / d theta.

    Parameters
    ----------
    p_C : ndarray, shape (n, 3)
        Points in the camera frame, m (any scale at infinity: only the direction counts).
    theta : ndarray, shape (model.n_params,)
    model : LensModel

    Returns
    -------
    uv_px : ndarray, shape (n, 2)
    J_p : ndarray, shape (n, 2, 3)
        d uv / d p_C (px per m).
    J_theta : ndarray, shape (n, 2, model.n_params)
    """
    uv, J_pose, J_theta = project(p_C, np.zeros(3), np.zeros(3), theta, model)
    return uv, J_pose[:, :, 3:6], J_theta


def unproject(uv_px: np.ndarray, theta: np.ndarray, model: LensModel, newton_steps: int = 20
              ) -> np.ndarray:
    """Unit rays in the camera frame of distorted pixels (the inverse of `project`).

    Parameters
    ----------
    uv_px : ndarray, shape (n, 2)
    theta : ndarray, shape (model.n_params,)
    model : LensModel
    newton_steps : int
        Gauss-Newton steps polishing OpenCV's undistortion.

    Returns
    -------
    v_C : ndarray, shape (n, 3)
        Unit vectors (z > 0), frame C.

    Notes
    -----
    OpenCV's iterative undistortion (``undistortPointsIter``; the fisheye model's own), then
    Gauss-Newton on the forward projection (``newton_steps``): OpenCV's fixed-point iteration
    does not converge under strong distortion. Where the model does not invert (a polynomial
    folding back beyond the angles the boards covered) the result does not reproject to the
    pixel; callers check the round trip (:mod:`cvsflow.calibration.projection_uncertainty`).
    """
    K, dist = K_dist(theta, model)
    uv = np.asarray(uv_px, np.float64).reshape(-1, 2)
    pts = uv.reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    if model.fisheye:
        xy = cv2.fisheye.undistortPoints(pts, K, dist, criteria=crit).reshape(-1, 2)
    else:
        xy = cv2.undistortPointsIter(pts, K, dist, None, None, crit).reshape(-1, 2)
    xy = np.where(np.isfinite(xy), xy, 0.0)
    for _ in range(newton_steps):
        q, J_p, _ = project_camera_points(np.c_[xy, np.ones(len(xy))], theta, model)
        r = q - uv
        if np.all(np.abs(r) < 1e-10):
            break
        A = J_p[:, :, :2]  # d uv / d (x, y) at z = 1
        det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
        ok = np.abs(det) > 1e-12
        step = np.zeros_like(xy)
        step[ok, 0] = (A[ok, 1, 1] * r[ok, 0] - A[ok, 0, 1] * r[ok, 1]) / det[ok]
        step[ok, 1] = (-A[ok, 1, 0] * r[ok, 0] + A[ok, 0, 0] * r[ok, 1]) / det[ok]
        # Damped: never move more than the current radius (keeps the iteration on its branch).
        scale = np.minimum(1.0, (np.linalg.norm(xy, axis=1) + 0.1) /
                           np.maximum(np.linalg.norm(step, axis=1), 1e-300))
        xy = xy - step * scale[:, None]
    v = np.c_[xy, np.ones(len(xy))]
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def rotate_jacobian(rvec: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``R(rvec) p`` and its derivative by ``rvec`` (OpenCV's Rodrigues).

    Parameters
    ----------
    rvec : ndarray, shape (3,)
    p : ndarray, shape (n, 3)

    Returns
    -------
    Rp : ndarray, shape (n, 3)
    dRp_dr : ndarray, shape (n, 3, 3)
        ``dRp_dr[k, i, j] = d (R p_k)_i / d rvec_j``.
    """
    R, dR = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))
    # cv2.Rodrigues' Jacobian is (3, 9): d R.ravel() (row-major) / d rvec_j in row j.
    dR = dR.reshape(3, 3, 3)  # [j, row, col]
    p = np.asarray(p, np.float64).reshape(-1, 3)
    return p @ R.T, np.einsum("jrc,kc->krj", dR, p)
