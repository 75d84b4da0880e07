"""Rendered flight demo: trajectories of a quadcopter seen by the ground camera (no images).

The truth is a smooth flight between 3 and 20 m from the camera in the estimator's local
frame L (NED, z down), body Q (FRD), the board B mounted on the back of the body (its face
towards the camera). From it:

- the on-board estimate ``T_L_Q`` with bias, drift (random walk), white noise, sampled on
  its own clock: ``t_ref_s = dt_offset_s + (1 + skew) * t_log_s``;
- the camera reference ``T_C_B`` at the video frames (camera clock = true time). With
  ``reference="pnp"`` it is measured as the CVS measures it: the board's corners projected
  with the camera model, corner noise added, the CVS's PnP (:func:`cvsflow.pose.estimate_poses`)
  with a calibration that is off the true lens by a draw of its stated std; its stated
  covariance is model (T)'s (:func:`cvsflow.flight.reference_covariance_transfer`), so the
  truth check tests that model and not the noise it drew. ``reference="model"`` (the
  default, the demo flight's; or a given ``Sigma_ref``) draws the noise from a covariance
  instead (the distance model :func:`cvsflow.flight.reference_covariance_model`, or the given
  array), which the truth check then only echoes;
- the injected error, i.e. what a perfect reference would measure at each video frame.

Every random choice comes from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.calibration import board_object_points, board_pattern
from cvsflow.errors import ConfigError
from cvsflow.flight.clock import Clock
from cvsflow.flight.metrics import ERR_COLS
from cvsflow.flight.reference import reference_covariance_model, reference_covariance_transfer
from cvsflow.flight.trajectory import interpolate_trajectory, traj_from_T
from cvsflow.geometry.camera import INTRINSIC_NAMES, project_points
from cvsflow.optimise.se3_model import K_from_intrinsics
from cvsflow.pose import estimate_poses
from cvsflow.stereo import (
    board_pose_starts,
    fused_board_pose_best,
    rig_calibration_covariance,
    stereo_extrinsics,
)
from cvsflow.synth.camera import Board as SynthBoard
from cvsflow.synth.stereo import shared_view_poses
from cvsflow.transforms import R_from_euler, euler_from_R, invert_T, make_T, wrap_angle

# Board mounting: board x = body right (y_Q), board y = body down (z_Q), board z (into the
# board) = body forward (x_Q); the board hangs behind the body, its origin at an inner corner.
R_Q_B_DEFAULT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
T_Q_B_DEFAULT = make_T(R_Q_B_DEFAULT, [-0.15, -0.2, -0.15])


MIN_HEIGHT_M = 0.5  # the body never flies lower above the ground (metres)

#: The demo's camera (its lens, bench/uncertainty_sessions.yaml u_demo), 640 x 480 px.
CAMERA_DEMO = {"fx_px": 702.0, "fy_px": 698.0, "cx_px": 331.5, "cy_px": 247.0,
               "dist": [-0.12, 0.09, 0.0009, -0.0007, -0.02], "width_px": 640, "height_px": 480}
#: The board on the body: 6 x 5 squares of 12.5 cm, 20 inner corners over 0.5 x 0.375 m (the
#: distance model's 0.5 m and 20 corners).
BOARD_DEFAULT = {"squares_x": 6, "squares_y": 5, "square_m": 0.125}
#: 1-sigma of the flight camera's calibration (a camera.yaml ``std``: fx fy cx cy px, k1..k3);
#: the reference's PnP uses a calibration off the true lens by one draw of it per flight.
CALIB_STD_DEFAULT = {"fx": 0.5, "fy": 0.5, "cx": 0.5, "cy": 0.5, "k1": 0.002, "k2": 0.01,
                     "p1": 1e-4, "p2": 1e-4, "k3": 0.02}  # fmt: skip
#: Corners nearer the image border than this are not detected (px).
BORDER_PX = 2.0


@dataclass
class FlightDemo:
    """A rendered flight: inputs of :func:`cvsflow.flight.evaluate_flight` and their truth.

    Attributes
    ----------
    reference : DataFrame
        ``frame`` + common form of the measured T_C_B (camera clock, s); missed frames invalid.
    Sigma_ref : ndarray, shape (N_frames, 6, 6)
        Reference covariance per frame ([dt m, dtheta rad] in C).
    onboard : DataFrame
        Common form of the on-board T_L_Q (log clock, s).
    truth : DataFrame
        Common form of the true T_L_Q at the video frames (camera clock).
    injected : DataFrame
        ``frame, t_s, ex_m .. eyaw_rad``: the on-board error at the video frames (the log
        interpolated at the true log times of the frames, minus the truth), axes of L.
    T_L_C, T_Q_B : ndarray, shape (4, 4)
        Camera in L; board mounting on the body.
    clock : Clock
        The true log clock.
    """

    reference: pd.DataFrame
    Sigma_ref: np.ndarray
    onboard: pd.DataFrame
    truth: pd.DataFrame
    injected: pd.DataFrame
    T_L_C: np.ndarray
    T_Q_B: np.ndarray
    clock: Clock


def _sines(rng, n_terms, f_lo, f_hi, amp):
    """A random smooth signal: a function of time (s) with standard deviation about ``amp``."""
    f = rng.uniform(f_lo, f_hi, n_terms)
    ph = rng.uniform(0, 2 * np.pi, n_terms)
    a = amp * np.sqrt(2.0 / n_terms) * np.ones(n_terms)
    return lambda t: np.sum(a * np.sin(2 * np.pi * f * np.asarray(t)[:, None] + ph), axis=1)


def _K_dist(camera):
    K = np.array([[camera["fx_px"], 0.0, camera["cx_px"]], [0.0, camera["fy_px"], camera["cy_px"]],
                  [0.0, 0.0, 1.0]])  # fmt: skip
    return K, np.asarray(camera["dist"], float).ravel()


def corner_noise(rng, n_frames, board, sigma_px, shared_px=0.0, shared_squares=1.0):
    """Detection error of every corner of ``n_frames`` frames, px, shape (n_frames, P, 2).

    Per image axis: iid N(0, sigma_px^2) plus a field shared by neighbouring corners, with
    covariance ``shared_px^2 exp(-g^2 / (2 shared_squares^2))`` between corners ``g`` squares
    apart on the board (a detector's error is partly common to nearby corners: the same blur,
    the same pixel grid phase, overlapping refinement windows).

    Parameters
    ----------
    rng : numpy.random.Generator
        The seeded generator.
    n_frames : int
        Number of frames.
    board : dict
        Board config; P = nx * ny inner corners, corner k at square (k % nx, k // nx).
    sigma_px : float
        Standard deviation of the independent part per axis, px.
    shared_px : float, default 0.0
        Standard deviation of the shared field per axis, px; 0 for none.
    shared_squares : float, default 1.0
        Correlation length of the shared field, board squares.

    Returns
    -------
    ndarray, shape (n_frames, P, 2)
        The error (du, dv) of every corner, px.
    """

    nx, ny = board_pattern(board)
    k = np.arange(nx * ny)
    g = np.column_stack([k % nx, k // nx]).astype(float)
    out = sigma_px * rng.standard_normal((n_frames, len(k), 2))
    if shared_px > 0:
        d2 = np.sum((g[:, None] - g[None]) ** 2, axis=-1)
        C = shared_px**2 * np.exp(-d2 / (2.0 * shared_squares**2))
        L = np.linalg.cholesky(C + 1e-12 * np.eye(len(k)))
        out += np.einsum("pq,nqa->npa", L, rng.standard_normal((n_frames, len(k), 2)))
    return out


def measure_reference(T_C_B, t_s, seen, rng, camera=None, board=None, sigma_px=0.3,
                      shared_px=0.0, shared_squares=1.0, calib_std=None):
    """The camera reference of a flight as the CVS measures it, at corner level.

    The board's corners are projected with the true camera (``camera``), those inside the
    image (``BORDER_PX``) on frames ``seen`` are detected with :func:`corner_noise`, and the
    CVS's PnP (:func:`cvsflow.pose.estimate_poses`, RANSAC + LM) solves them with a
    calibration drawn once about the true lens from ``calib_std``. The covariance stated is
    :func:`cvsflow.flight.reference_covariance_transfer` with that calibration and its std.

    Parameters
    ----------
    T_C_B : ndarray, shape (N, 4, 4)
        True board poses in the camera, m.
    t_s : ndarray, shape (N,)
        Frame times, s.
    seen : ndarray of bool, shape (N,)
        Frames on which the detector finds the board (if enough corners are in the image).
    rng : numpy.random.Generator
    camera : dict, optional
        ``fx_px, fy_px, cx_px, cy_px, dist, width_px, height_px``; default ``CAMERA_DEMO``.
    board : dict, optional
        ``squares_x, squares_y, square_m``; default ``BOARD_DEFAULT``.
    sigma_px, shared_px, shared_squares : float
        Corner noise (:func:`corner_noise`).
    calib_std : dict, optional
        1-sigma of fx, fy, cx, cy, k1, k2, p1, p2, k3; default ``CALIB_STD_DEFAULT``.

    Returns
    -------
    T_meas : ndarray, shape (N, 4, 4)
        Measured T_C_B, NaN where not valid.
    valid : ndarray of bool, shape (N,)
    Sigma_ref : ndarray, shape (N, 6, 6)
        Stated covariance ([dt m, dtheta rad] in C), NaN where not valid.
    poses, corners : DataFrame
        The poses_raw and corners tables of the measurement.
    """

    camera = CAMERA_DEMO if camera is None else camera
    board = BOARD_DEFAULT if board is None else board
    calib_std = CALIB_STD_DEFAULT if calib_std is None else calib_std
    K, dist = _K_dist(camera)
    p_B = board_object_points(board)
    p_C = np.einsum("nij,pj->npi", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
    uv = project_points(p_C, K, dist) + corner_noise(rng, len(T_C_B), board, sigma_px,
                                                     shared_px, shared_squares)
    w, h = float(camera.get("width_px", 640)), float(camera.get("height_px", 480))
    inside = ((p_C[..., 2] > 0) & (uv[..., 0] >= BORDER_PX) & (uv[..., 0] <= w - 1 - BORDER_PX)
              & (uv[..., 1] >= BORDER_PX) & (uv[..., 1] <= h - 1 - BORDER_PX))  # fmt: skip
    found = np.asarray(seen, bool) & (inside.sum(axis=1) >= 6)
    # the calibration the CVS uses: the true lens plus one draw of its stated error
    true_intr = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist]
    sd = np.array([float(calib_std.get(n, 0.0)) for n in INTRINSIC_NAMES])
    intr = true_intr + sd * rng.standard_normal(len(sd))
    K_cal, dist_cal = K_from_intrinsics(*intr[:4]), intr[4:]
    fr, ci = np.nonzero(found[:, None] & inside)
    rows = [pd.DataFrame({"frame": fr, "t_s": np.asarray(t_s, float)[fr], "found": True,
                          "corner": ci, "u_px": uv[fr, ci, 0], "v_px": uv[fr, ci, 1]})]
    lost = np.flatnonzero(~found)
    rows.append(pd.DataFrame({"frame": lost, "t_s": np.asarray(t_s, float)[lost], "found": False,
                              "corner": -1, "u_px": np.nan, "v_px": np.nan}))
    corners = pd.concat(rows).sort_values(["frame", "corner"], kind="stable").reset_index(drop=True)
    corners = corners.astype({"frame": np.int64, "corner": np.int64, "found": bool})
    poses = estimate_poses(corners, K_cal, dist_cal, board)
    valid = poses["valid"].to_numpy(bool)
    T_meas = np.full_like(np.asarray(T_C_B, float), np.nan)
    rv = poses[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
    T_meas[valid] = make_T(Rotation.from_rotvec(rv[valid]).as_matrix(),
                           poses.loc[valid, ["x_m", "y_m", "z_m"]].to_numpy(float))
    calib = {"K": K_cal.tolist(), "dist": dist_cal.tolist(),
             "std": {n: float(v) for n, v in zip(INTRINSIC_NAMES, sd, strict=True)}}
    Sigma = reference_covariance_transfer(poses, corners, p_B, calib)
    return T_meas, valid, Sigma, poses, corners


def stereo_rig(baseline_m: float, cross_m: float = 10.0) -> list:
    """``T_Ci_C0`` of a two-camera rig: camera 1 ``baseline_m`` to the right of camera 0,
    turned in so that the optical axes cross ``cross_m`` ahead.

    Parameters
    ----------
    baseline_m : float
        Distance between the camera centres along camera 0's x axis, m (> 0).
    cross_m : float
        Distance ahead of camera 0 where the axes cross, m (> 0).

    Returns
    -------
    list of ndarray, shape (4, 4)
        ``[I, T_C1_C0]``: a point in C0 maps to Ci.
    """
    if not (baseline_m > 0 and cross_m > 0):
        raise ConfigError(f"flight demo: rig baseline_m={baseline_m}, cross_m={cross_m}; both must be > 0")
    T_C0_C1 = make_T(R_from_euler([0.0, -np.arctan2(baseline_m, cross_m), 0.0]), [baseline_m, 0.0, 0.0])
    return [np.eye(4), invert_T(T_C0_C1)]


def observe_rig(T_C0_B, T_Ci_C0, p_B, cameras, noise_px=None):
    """Each rig camera's image of the board's corners, and which of them it detects.

    Parameters
    ----------
    T_C0_B : ndarray, shape (F, 4, 4)
        Board poses in camera 0, m.
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        Each camera's pose from camera 0.
    p_B : ndarray, shape (N, 3)
        The corners in B, m.
    cameras : sequence of dict
        Each camera as ``CAMERA_DEMO`` (``fx_px .. dist, width_px, height_px``).
    noise_px : ndarray, shape (F, C, N, 2), optional
        Detection error added to the projections, px.

    Returns
    -------
    uv : ndarray, shape (F, C, N, 2)
        Corner k in camera c on frame f, px.
    seen : ndarray of bool, shape (F, C, N)
        Corners in front of the camera and at least ``BORDER_PX`` inside its image, on frames
        where the camera has at least 6 of them (fewer: it does not find the board).
    """
    uv = np.zeros((len(T_C0_B), len(T_Ci_C0), len(p_B), 2))
    seen = np.zeros(uv.shape[:3], bool)
    for c, (T, camera) in enumerate(zip(T_Ci_C0, cameras, strict=True)):
        K, dist = _K_dist(camera)
        w, h = float(camera.get("width_px", 640)), float(camera.get("height_px", 480))
        T_C_B = np.asarray(T, float) @ T_C0_B
        p_C = np.einsum("fij,nj->fni", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
        uv[:, c] = project_points(p_C, K, dist)
        if noise_px is not None:
            uv[:, c] += noise_px[:, c]
        inside = ((p_C[..., 2] > 0) & (uv[:, c, :, 0] >= BORDER_PX) & (uv[:, c, :, 0] <= w - 1 - BORDER_PX)
                  & (uv[:, c, :, 1] >= BORDER_PX) & (uv[:, c, :, 1] <= h - 1 - BORDER_PX))  # fmt: skip
        seen[:, c] = inside & (inside.sum(axis=1) >= 6)[:, None]
    return uv, seen


def calibrate_rig_views(rng, T_Ci_C0, cameras, cameras_cal, calib_std, board, n_views=20, sigma_px=0.1):
    """The rig's relative poses as a user finds them: from shared views, with the drawn lens.

    ``n_views`` board poses that every camera sees whole (:func:`cvsflow.synth.stereo.
    shared_view_poses`, at 1.5-4 m or 1.5-4 baselines), their corners projected with the
    true cameras plus ``sigma_px`` of noise, solved by :func:`cvsflow.stereo.stereo_extrinsics`
    with the calibration the CVS uses (``cameras_cal``, stated ``calib_std``). The fitted
    poses take up part of the intrinsics' error, as a real rig calibration does.

    Parameters
    ----------
    rng : numpy.random.Generator
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        The true rig.
    cameras : sequence of dict
        The true cameras (``CAMERA_DEMO`` form).
    cameras_cal : sequence of (K, dist)
        The calibration used.
    calib_std : dict
        Its stated 1-sigma, the same for every camera.
    board : dict
        The board of the views.
    n_views : int
        Shared views.
    sigma_px : float
        Corner noise of the views (sharp stills), px.

    Returns
    -------
    dict
        :func:`cvsflow.stereo.stereo_extrinsics`' result.
    """
    b_m = max(float(np.linalg.norm(invert_T(np.asarray(T, float))[:3, 3])) for T in T_Ci_C0)
    sboard = SynthBoard(int(board["squares_x"]), int(board["squares_y"]), float(board["square_m"]))
    true = [(*_K_dist(c), (int(c.get("width_px", 640)), int(c.get("height_px", 480)))) for c in cameras]
    depth_m = (max(1.5, 1.5 * b_m), max(4.0, 4.0 * b_m))
    T_C0_V = shared_view_poses(rng, n_views, true, T_Ci_C0, sboard, depth_m=depth_m, min_square_px=10.0)
    p_B = board_object_points(board)
    noise = sigma_px * rng.standard_normal((n_views, len(T_Ci_C0), len(p_B), 2))
    uv, seen = observe_rig(T_C0_V, T_Ci_C0, p_B, cameras, noise)
    tables = []
    for c in range(len(T_Ci_C0)):
        v, k = np.nonzero(seen[:, c])
        tables.append(pd.DataFrame({"image": [f"shared_{x:03d}" for x in v], "corner": k,
                                    "u_px": uv[v, c, k, 0], "v_px": uv[v, c, k, 1],
                                    "X_m": p_B[k, 0], "Y_m": p_B[k, 1]}))  # fmt: skip
    cal = [{"K": np.asarray(K).tolist(), "dist": np.asarray(d).tolist(), "std": dict(calib_std),
            "width": w, "height": h}
           for (K, d), (_, _, (w, h)) in zip(cameras_cal, true, strict=True)]  # fmt: skip
    return stereo_extrinsics(tables, cal)


def measure_reference_rig(T_C0_B, seen, rng, T_Ci_C0, cameras=None, board=None, sigma_px=0.3,
                          shared_px=0.0, shared_squares=1.0, calib_std=None, n_views=20, view_sigma_px=0.1):
    """The camera reference of a flight measured by a rig of cameras exposed together.

    Every camera detects the board's corners (:func:`observe_rig`, :func:`corner_noise`). The
    rig's calibration is what a user gets: each camera's intrinsics the truth off by one draw
    of ``calib_std``, the relative poses fitted with them on shared views
    (:func:`calibrate_rig_views`). The board pose is fused from all corners
    (:func:`cvsflow.stereo.fused_board_pose_best`, started from both IPPE solutions of every
    camera's own view, with the mirrored solution's flip term). Its stated covariance is the
    corner noise's plus the calibration's, with the intrinsics' cross-covariance with the
    fitted poses (:func:`cvsflow.stereo.rig_calibration_covariance`).

    Parameters
    ----------
    T_C0_B : ndarray, shape (N, 4, 4)
        True board poses in camera 0, m.
    seen : ndarray of bool, shape (N,) or (N, C)
        Frames on which each camera's detector works (if enough corners are in its image).
    rng : numpy.random.Generator
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        The true rig (:func:`stereo_rig`), identity first.
    cameras : sequence of dict, optional
        Each camera as ``CAMERA_DEMO`` (the default for all).
    board : dict, optional
        ``BOARD_DEFAULT`` by default (also the rig calibration's board).
    sigma_px, shared_px, shared_squares : float
        Corner noise (:func:`corner_noise`), the same for every camera.
    calib_std : dict, optional
        Each camera's calibration 1-sigma; default ``CALIB_STD_DEFAULT``.
    n_views, view_sigma_px : int, float
        The rig calibration's shared views and their corner noise (:func:`calibrate_rig_views`).

    Returns
    -------
    T_meas : ndarray, shape (N, 4, 4)
        Measured T_C0_B, NaN where not valid.
    valid : ndarray of bool, shape (N,)
    Sigma_ref : ndarray, shape (N, 6, 6)
        Stated covariance ([dt m, dtheta rad] in C0, rotation perturbed on the left), NaN
        where not valid.
    rig : dict
        The rig calibration (:func:`cvsflow.stereo.stereo_extrinsics`).

    Notes
    -----
    The stated corner noise is ``sqrt(sigma_px^2 + shared_px^2)`` per corner, treated as
    independent: a shared part makes that optimistic.
    """
    n_cam = len(T_Ci_C0)
    cameras = [CAMERA_DEMO] * n_cam if cameras is None else list(cameras)
    board = BOARD_DEFAULT if board is None else board
    calib_std = CALIB_STD_DEFAULT if calib_std is None else calib_std
    if len(cameras) != n_cam or n_cam < 2:
        raise ConfigError(f"flight demo: {len(cameras)} cameras for a rig of {n_cam} (2 or more)")
    T_C0_B = np.asarray(T_C0_B, float)
    p_B = board_object_points(board)
    noise = np.stack([corner_noise(rng, len(T_C0_B), board, sigma_px, shared_px, shared_squares)
                      for _ in range(n_cam)], axis=1)  # fmt: skip
    uv, det = observe_rig(T_C0_B, T_Ci_C0, p_B, cameras, noise)
    det &= np.broadcast_to(np.asarray(seen, bool).reshape(len(T_C0_B), -1), det.shape[:2])[..., None]
    # the calibration the CVS uses: the truth plus one draw of its stated error, then the rig
    sd = np.array([float(calib_std.get(n, 0.0)) for n in INTRINSIC_NAMES])
    cams_cal = []
    for camera in cameras:
        K, dist = _K_dist(camera)
        intr = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist] + sd * rng.standard_normal(len(sd))
        cams_cal.append((K_from_intrinsics(*intr[:4]), intr[4:]))
    rig = calibrate_rig_views(rng, T_Ci_C0, cameras, cams_cal, calib_std, board, n_views, view_sigma_px)
    T_cal = [np.eye(4)] + [np.asarray(c["T_Ci_C0"], float) for c in rig["cameras"]]
    n_det = det.sum(axis=2)
    starts = board_pose_starts(uv, det, p_B, cams_cal, T_cal)
    sigma_eff = float(np.hypot(sigma_px, shared_px))
    T_meas, Sigma, _ = fused_board_pose_best(uv, det, p_B, cams_cal, T_cal, starts, sigma_px=sigma_eff,
                                             flip_term=True)  # fmt: skip
    valid = np.isfinite(T_meas[:, 0, 0]) & (n_det.max(axis=1) >= 6)
    ext_cov = [c["covariance"] for c in rig["cameras"]]
    ext_sens = [c["intrinsics_sensitivity"] for c in rig["cameras"]]
    Sigma[valid] += rig_calibration_covariance(uv[valid], det[valid], p_B, cams_cal, T_cal, T_meas[valid],
                                               sigma_eff, [calib_std] * n_cam, ext_cov, ext_sens)  # fmt: skip
    T_meas[~valid], Sigma[~valid] = np.nan, np.nan
    return T_meas, valid, Sigma, rig


def camera_pose(height_m: float = 1.0, tilt_up_rad: float = np.deg2rad(8.0)) -> np.ndarray:
    """T_L_C of a camera on a tripod ``height_m`` above the ground, looking north, tilted up.

    Optical axes in NED: z_C north, x_C east, y_C down, then pitched up by ``tilt_up_rad``.

    Parameters
    ----------
    height_m : float, default 1.0
        Height of the optical centre above the ground, m (z = -height_m in NED).
    tilt_up_rad : float, default 8 deg
        Upward tilt of the optical axis, rad.

    Returns
    -------
    T_L_C : ndarray, shape (4, 4)
        Camera pose in the estimator's world frame L (NED), m.
    """
    R_level = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns x_C y_C z_C
    R_tilt = Rotation.from_rotvec([tilt_up_rad, 0.0, 0.0]).as_matrix()  # about x_C: z_C goes up
    return make_T(R_level @ R_tilt, [0.0, 0.0, -height_m])


def true_flight(seed: int, duration_s: float, range_m=(3.0, 20.0), T_L_C=None):
    """The true body trajectory as a function ``f(t_s) -> T_L_Q`` (N, 4, 4) (seeded).

    The body stays in front of the camera: range from the camera between ``range_m``, bearing
    and elevation wobbling a few degrees around its optical axis (and above
    ``MIN_HEIGHT_M``), with sinusoidal roll, pitch and yaw of some degrees.

    Parameters
    ----------
    seed : int
        Seed of the random sinusoid amplitudes, frequencies and phases.
    duration_s : float
        Flight length, s; the range sweeps out and back once over it.
    range_m : (float, float), default (3.0, 20.0)
        Nearest and farthest distance from the camera centre, m.
    T_L_C : ndarray, shape (4, 4), optional
        Camera pose in L; default :func:`camera_pose`.

    Returns
    -------
    callable
        ``f(t_s)``: array of times (N,) in s -> T_L_Q, shape (N, 4, 4), m (L NED, Q FRD).
    """
    rng = np.random.default_rng(seed)
    T_L_C = camera_pose() if T_L_C is None else T_L_C
    r_lo, r_hi = range_m
    bearing = _sines(rng, 4, 0.02, 0.15, np.deg2rad(8.0))
    elev = _sines(rng, 4, 0.02, 0.15, np.deg2rad(4.0))
    r_wobble = _sines(rng, 3, 0.05, 0.3, 0.3)
    roll = _sines(rng, 6, 0.1, 1.5, np.deg2rad(6.0))
    pitch = _sines(rng, 6, 0.1, 1.5, np.deg2rad(6.0))
    yaw = _sines(rng, 5, 0.05, 1.0, np.deg2rad(10.0))
    c = T_L_C[:3, 3]

    def f(t_s):
        t = np.asarray(t_s, float)
        ph = np.clip(t / duration_s, 0.0, 1.0)
        r = r_lo + 0.3 + (r_hi - r_lo - 0.6) * 0.5 * (1 - np.cos(2 * np.pi * ph)) + r_wobble(t)
        r = np.clip(r, r_lo, r_hi)
        a = bearing(t)
        b = np.deg2rad(5.0) + elev(t)  # above the horizon through the lens
        b = np.maximum(
            b, np.arcsin(np.clip((MIN_HEIGHT_M + c[2]) / r, -1.0, 1.0))
        )  # off the ground
        p = c + r[:, None] * np.column_stack(
            [np.cos(b) * np.cos(a), np.cos(b) * np.sin(a), -np.sin(b)]
        )
        rpy = np.column_stack([roll(t), pitch(t), a + yaw(t)])
        return make_T(R_from_euler(rpy), p)

    return f


def render_flight(
    seed: int = 0,
    duration_s: float = 60.0,
    fps: float = 30.0,
    log_rate_hz: float = 100.0,
    range_m=(3.0, 20.0),
    dt_offset_s: float = -17.25,
    skew: float = 2e-4,
    log_margin_s: float = 5.0,
    pos_bias_m=(0.06, -0.04, 0.08),
    pos_rw_m_sqrt_s: float = 0.01,
    pos_noise_m: float = 0.01,
    att_bias_rad=(0.012, -0.009, 0.04),
    att_rw_rad_sqrt_s: float = 0.002,
    att_noise_rad: float = 0.003,
    f_px: float = 700.0,
    board_m: float = 0.5,
    sigma_px: float = 0.3,
    n_corners: int = 20,
    missed_frame_rate: float = 0.02,
    Sigma_ref=None,
    T_Q_B=None,
    reference: str = "model",
    camera=None,
    board=None,
    corner_shared_px: float = 0.0,
    corner_shared_squares: float = 1.0,
    calib_std=None,
    rig=None,
) -> FlightDemo:
    """Render a flight: truth, on-board estimate on its own clock, camera reference.

    Parameters
    ----------
    seed : int
        Seed of every random choice.
    duration_s, fps : float
        Video length (s) and frame rate (Hz); video frame k is at t = k / fps (true time).
    log_rate_hz : float
        On-board log rate, Hz (position and attitude logged together).
    range_m : (float, float)
        Closest and farthest distance of the body from the camera, metres.
    dt_offset_s, skew : float
        Log clock: ``t_ref_s = dt_offset_s + (1 + skew) t_log_s``.
    log_margin_s : float
        The log starts this long before the video and ends this long after, seconds.
    pos_bias_m, pos_rw_m_sqrt_s, pos_noise_m : on-board position error: constant bias (m, in
        L), random-walk intensity (m / sqrt(s)), white noise (m), per axis.
    att_bias_rad, att_rw_rad_sqrt_s, att_noise_rad : the same for roll, pitch, yaw (rad).
    f_px, board_m, n_corners : parameters of the distance model (``reference="model"``).
    sigma_px : float
        Corner noise per image axis, px: iid part of the detected corners (``"pnp"``), or of
        the distance model (``"model"``).
    missed_frame_rate : float
        Share of video frames where the board is not found (reference invalid).
    Sigma_ref : ndarray, shape (N_frames, 6, 6), optional
        Reference covariance per frame to draw the reference noise from (overrides
        ``reference``).
    T_Q_B : ndarray, shape (4, 4), optional
        Board mounting; default ``T_Q_B_DEFAULT``.
    reference : {"pnp", "stereo", "model"}
        ``"pnp"``: the reference is measured from noisy corners (:func:`measure_reference`)
        and states model (T)'s covariance; ``"stereo"``: measured by a rig of cameras
        exposed together (:func:`measure_reference_rig`, the board pose fused from every
        camera's corners), stating the fused pose's covariance; ``"model"``: its noise is
        drawn from the distance model, which it states.
    camera, board : dict, optional
        The reference camera (``CAMERA_DEMO``; with ``"stereo"`` every camera's) and the
        board on the body (``BOARD_DEFAULT``), ``"pnp"`` and ``"stereo"`` only.
    corner_shared_px, corner_shared_squares : float
        The part of the corner noise shared by neighbouring corners (:func:`corner_noise`).
    calib_std : dict, optional
        The calibration's 1-sigma (``CALIB_STD_DEFAULT``), ``"pnp"`` and ``"stereo"`` only.
    rig : dict, optional
        ``"stereo"`` only: ``baseline_m`` (default 1.0), ``cross_m`` (10.0) of
        :func:`stereo_rig`; ``n_views`` (20) and ``view_sigma_px`` (0.1) of the rig's
        calibration (:func:`calibrate_rig_views`). Camera 0 is the reference camera
        (``T_L_C``, the reference's frame C).

    Returns
    -------
    FlightDemo

    Raises
    ------
    ConfigError
        Non-positive durations or rates, a range outside (0, inf), skew of 1 % or more, an
        unknown ``reference``.
    """
    if duration_s <= 0 or fps <= 0 or log_rate_hz <= 0:
        raise ConfigError(
            f"flight demo: duration_s={duration_s}, fps={fps}, "
            f"log_rate_hz={log_rate_hz}; all must be > 0"
        )
    if not (0 < range_m[0] < range_m[1]):
        raise ConfigError(f"flight demo: range_m={range_m}; expected 0 < near < far (m)")
    if abs(skew) >= 1e-2:
        raise ConfigError(f"flight demo: skew={skew}; expected |skew| < 0.01")
    if reference not in ("pnp", "stereo", "model"):
        raise ConfigError(f"flight demo: reference={reference!r}; expected 'pnp', 'stereo' or 'model'")
    if rig is not None and reference != "stereo":
        raise ConfigError(f"flight demo: a rig is given with reference={reference!r}; it needs 'stereo'")
    rig = {} if rig is None else dict(rig)
    unknown = set(rig) - {"baseline_m", "cross_m", "n_views", "view_sigma_px"}
    if unknown:
        raise ConfigError(f"flight demo: unknown rig keys {sorted(unknown)}; expected baseline_m, "
                          "cross_m, n_views, view_sigma_px")  # fmt: skip
    rng = np.random.default_rng(seed)
    T_L_C = camera_pose()
    T_Q_B = T_Q_B_DEFAULT if T_Q_B is None else np.asarray(T_Q_B, float)
    f = true_flight(int(rng.integers(2**31)), duration_s, range_m, T_L_C)
    clock = Clock(dt_offset_s, skew)

    # camera reference at the video frames (true time)
    n_fr = int(round(duration_s * fps)) + 1
    frame = np.arange(n_fr)
    t_cam = frame / fps
    T_L_Q_cam = f(t_cam)
    T_C_B = invert_T(T_L_C) @ T_L_Q_cam @ T_Q_B
    if Sigma_ref is None and reference == "pnp":
        seen = rng.random(n_fr) >= missed_frame_rate
        T_meas, seen, Sigma_ref, _, _ = measure_reference(
            T_C_B, t_cam, seen, rng, camera, board, sigma_px, corner_shared_px,
            corner_shared_squares, calib_std)  # fmt: skip
    elif Sigma_ref is None and reference == "stereo":
        seen = rng.random(n_fr) >= missed_frame_rate
        T_Ci_C0 = stereo_rig(float(rig.get("baseline_m", 1.0)), float(rig.get("cross_m", 10.0)))
        T_meas, seen, Sigma_ref, _ = measure_reference_rig(
            T_C_B, seen, rng, T_Ci_C0, None if camera is None else [camera] * len(T_Ci_C0), board,
            sigma_px, corner_shared_px, corner_shared_squares, calib_std, int(rig.get("n_views", 20)),
            float(rig.get("view_sigma_px", 0.1)))  # fmt: skip
    else:
        if Sigma_ref is None:
            Sigma_ref = reference_covariance_model(T_C_B, f_px, board_m, sigma_px, n_corners)
        Sigma_ref = np.asarray(Sigma_ref, float)
        if Sigma_ref.shape != (n_fr, 6, 6):
            raise ConfigError(
                f"flight demo: Sigma_ref shape {Sigma_ref.shape}; expected ({n_fr}, 6, 6)"
            )
        L = np.linalg.cholesky(Sigma_ref + 1e-30 * np.eye(6))
        d = (L @ rng.standard_normal((n_fr, 6, 1)))[..., 0]
        T_meas = T_C_B.copy()
        T_meas[:, :3, 3] += d[:, :3]
        T_meas[:, :3, :3] = Rotation.from_rotvec(d[:, 3:]).as_matrix() @ T_C_B[:, :3, :3]
        seen = rng.random(n_fr) >= missed_frame_rate  # drawn after the noise (as it was)
        T_meas[~seen] = np.nan
    reference_df = traj_from_T(
        t_cam, T_meas, seen, seen, {"source": "flight_synth", "frames": "T_C_B"}
    )
    reference_df.insert(0, "frame", frame)

    # on-board log on its own clock
    t_log0 = clock.to_log(-log_margin_s)
    t_log1 = clock.to_log(duration_s + log_margin_s)
    t_log = t_log0 + np.arange(int((t_log1 - t_log0) * log_rate_hz) + 1) / log_rate_hz
    T_true_log = f(clock.to_ref(t_log))
    n = len(t_log)
    dt = 1.0 / log_rate_hz

    def process(bias, rw, noise):
        walk = np.cumsum(rng.standard_normal((n, 3)) * rw * np.sqrt(dt), axis=0)
        return np.asarray(bias, float) + walk + rng.standard_normal((n, 3)) * noise

    e_pos = process(pos_bias_m, pos_rw_m_sqrt_s, pos_noise_m)
    e_att = process(att_bias_rad, att_rw_rad_sqrt_s, att_noise_rad)
    rpy_est = euler_from_R(T_true_log[:, :3, :3]) + e_att
    T_est = make_T(R_from_euler(rpy_est), T_true_log[:, :3, 3] + e_pos)
    onboard = traj_from_T(
        t_log, T_est, attrs={"source": "flight_synth", "frames": "T_L_Q, NED/FRD"}
    )

    # injected error at the video frames, as a perfect reference would measure it
    est_cam = interpolate_trajectory(onboard, clock.to_log(t_cam), max_gap_s=2.0 / log_rate_hz)
    R_e = Rotation.from_quat(est_cam[["qx", "qy", "qz", "qw"]].to_numpy()).as_matrix()
    e = np.column_stack(
        [
            est_cam[["x_m", "y_m", "z_m"]].to_numpy() - T_L_Q_cam[:, :3, 3],
            wrap_angle(euler_from_R(R_e) - euler_from_R(T_L_Q_cam[:, :3, :3])),
        ]
    )
    injected = pd.DataFrame(e, columns=ERR_COLS)
    injected.insert(0, "t_s", t_cam)
    injected.insert(0, "frame", frame)
    truth = traj_from_T(t_cam, T_L_Q_cam, attrs={"frames": "T_L_Q (true)"})
    return FlightDemo(reference_df, Sigma_ref, onboard, truth, injected, T_L_C, T_Q_B, clock)
