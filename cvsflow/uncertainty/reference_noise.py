"""The reference's own noise from a moving camera body, per held-out frame.

A static camera body is replaced by its mean pose over the take (se3's ``camera_static``),
so its marker noise averages away. A moving camera's body pose is the local quadratic of
its track (``CAMERA_MOVING_SMOOTH_S``) at each frame's time, and its rotation noise moves the
reference board by the lever of the board's distance: on a 720p hand-held-camera render
(the board 0.7-2 m away) the within-session fits put a floor of 0.6 mm / 0.6 mrad under the
errors, where the model fitted on static cameras has 0.08 mm / 0.12 mrad, and 49-55 % of the
x and y errors fell inside its 95 % band. The noise is measured from the track itself (the
raw samples about their local quadratic), so it needs no marker layout and holds for a
mocap system's own body poses too.
"""

from __future__ import annotations

import numpy as np

from cvsflow.geometry import transforms as tf
from cvsflow.metrics import ERROR_DIMS, pose_errors
from cvsflow.mocap import body_poses
from cvsflow.optimise import CAMERA_MOVING_SMOOTH_S, smooth_track_local
from cvsflow.uncertainty.propagation import _numeric_jacobian

#: Median of chi-square with one degree of freedom: a per-axis variance from the median of
#: squared residuals (robust to a marker swap or a dropout's edge).
_CHI2_1_MEDIAN = 0.454936423119572


def _centre_variance_factor(n):
    """Variance of a centred local quadratic's value over ``n`` iid samples, per sample's."""
    return 3.0 * (3.0 * n * n - 7.0) / (4.0 * n * (n * n - 4.0))


def moving_body_noise(bodies, body="camera", window_s=CAMERA_MOVING_SMOOTH_S):
    """Per-axis standard deviation of a moving body's smoothed pose, from its own track.

    Parameters
    ----------
    bodies : DataFrame
        bodies.parquet (native rate).
    body : str
        Body name.
    window_s : float
        Window of the local quadratic the reference uses (se3's moving-camera smoothing).

    Returns
    -------
    sigma_rot_rad, sigma_pos_m : float
        Of the smoothed track, per axis (isotropic): the raw samples' scatter about the
        local quadratic gives the per-sample noise s^2 (1 - g), the smoothed value carries
        s^2 g, g the centre variance factor of a quadratic over the window's samples.
    """
    t, T, valid = body_poses(bodies, body, invalid="identity", min_valid=2, track=True)
    T_s = smooth_track_local(t, T, valid, window_s)
    rate = (len(t) - 1) / (t[-1] - t[0])
    n = 2 * int(round(0.5 * window_s * rate)) + 1
    g = _centre_variance_factor(max(n, 5))
    d_rot = tf.rvec_from_R(np.swapaxes(T_s[valid, :3, :3], 1, 2) @ T[valid, :3, :3])
    d_pos = T[valid, :3, 3] - T_s[valid, :3, 3]
    var_rot = np.median(d_rot**2) / _CHI2_1_MEDIAN / (1.0 - g) * g
    var_pos = np.median(d_pos**2) / _CHI2_1_MEDIAN / (1.0 - g) * g
    return float(np.sqrt(var_rot)), float(np.sqrt(var_pos))


def camera_body_error_cov(rvec_C_B, tvec_C_B, sigma_rot_rad, sigma_pos_m, frame="C", h=1e-6):
    """Covariance of the pose error [x, y, z, roll, pitch, yaw] that the camera body's noise
    puts into the reference, per frame.

    The camera body turned by a small d_theta and moved by d_p turns and moves the reference
    board pose T_C_B the other way, about the body's origin; taken at C's origin (the optical
    centre is a few cm from the body's, the board metres away), that is the left perturbation
    T_C_B <- exp([-R d_theta, -R d_p]) T_C_B, whose rotation about C moves the board by the
    lever of its distance. With isotropic noise (``sigma_rot_rad``, ``sigma_pos_m`` per axis,
    :func:`moving_body_noise`) the perturbation's covariance is diag(s_r^2 I, s_p^2 I); it is
    pushed through :func:`cvsflow.metrics.errors.pose_errors` by central differences.

    Parameters
    ----------
    rvec_C_B, tvec_C_B : ndarray, shape (N, 3)
        The poses the errors are linearised at (rad, m).
    sigma_rot_rad, sigma_pos_m : float
    frame : {"C", "B"}
        Error frame.
    h : float
        Central-difference step.

    Returns
    -------
    cov : ndarray, shape (N, 6, 6)
        SI (m^2, m rad, rad^2), in the order of ``ERROR_DIMS``.
    """
    rvec = np.atleast_2d(np.asarray(rvec_C_B, float))
    tvec = np.atleast_2d(np.asarray(tvec_C_B, float))
    T0 = tf.T_from_rvec_tvec(rvec, tvec)
    # [rotation, translation] of the left perturbation
    S = np.diag(np.r_[np.full(3, sigma_rot_rad**2), np.full(3, sigma_pos_m**2)])
    cols = [f"err_{d}" for d in ERROR_DIMS]

    def err(rot, trans):
        return pose_errors(tf.make_T(tf.R_from_rvec(rot), trans) @ T0, T0, frame=frame)[cols].to_numpy()

    zero = np.zeros((len(T0), 3))
    G = _numeric_jacobian(err, zero, zero, h)
    return G @ S @ np.swapaxes(G, 1, 2)
