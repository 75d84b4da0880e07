"""The reference's uncertainty on a flight: its covariance per frame and its propagation.

``Sigma_ref`` (N, 6, 6) is the covariance of the reference's error ``[dt, dtheta]`` on T_C_B,
with ``t_meas = t_true + dt`` (metres, in C) and ``R_meas = Exp(dtheta) R_true`` (radians,
left perturbation, in C). Models: a distance-only stand-in
(:func:`reference_covariance_model`), the corner noise through PnP
(:func:`reference_covariance_from_pnp`) and the se3 stage's model (T) with the planar PnP's
flip ambiguity (:func:`reference_covariance_transfer`, :func:`pnp_flip_term`).
"""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow import uncertainty as un
from cvsflow.exceptions import InputError
from cvsflow.geometry import INTRINSIC_NAMES, euler_from_R, euler_jacobian, invert_T, wrap_angle
from cvsflow.geometry import skew as skew_matrix
from cvsflow.optimise import DEFAULT_INTRINSIC_STD
from cvsflow.uncertainty import composed_error_jacobian, pnp_covariance, propagated_pose_covariance

# --------------------------------------------------------------------------------------------
# Reference uncertainty
# --------------------------------------------------------------------------------------------


def reference_covariance_model(
    T_C_B, f_px: float = 700.0, board_m: float = 0.5, sigma_px: float = 0.3, n_corners: int = 20
) -> np.ndarray:
    """A simple distance-dependent covariance of a PnP board pose (stand-in for se3's model).

    Lateral position error ~ d sigma_px / (f sqrt(n)); depth error ~ d^2 sigma_px /
    (f L sqrt(n)); tilt (about the camera's x, y) ~ d sigma_px / (f L) and in-plane rotation
    (about z) ~ d sigma_px / (f L sqrt(n)), with d the board distance and L its size.

    Parameters
    ----------
    T_C_B : ndarray, shape (N, 4, 4)
        Board poses in the camera frame, metres.
    f_px, board_m, sigma_px, n_corners : float
        Focal length (px), board size (m), corner noise (px), number of corners.

    Returns
    -------
    Sigma : ndarray, shape (N, 6, 6)
        Diagonal covariance of ``[dt (m, in C), dtheta (rad, in C)]`` (module docstring).
    """
    d = np.linalg.norm(np.asarray(T_C_B, float)[:, :3, 3], axis=1)
    rn = np.sqrt(n_corners)
    s_lat = d * sigma_px / (f_px * rn)
    s_depth = d**2 * sigma_px / (f_px * board_m * rn)
    s_tilt = d * sigma_px / (f_px * board_m)
    s_roll = s_tilt / rn
    sig = np.column_stack([s_lat, s_lat, s_depth, s_tilt, s_tilt, s_roll])
    Sigma = np.zeros((len(d), 6, 6))
    idx = np.arange(6)
    Sigma[:, idx, idx] = sig**2
    return Sigma


def propagate_reference_sigma(Sigma_C_B, T_C_B, T_Q_B, R_C_L, flip=None) -> np.ndarray:
    """Per-axis standard deviations of the reference body pose in the error axes of L.

    Linear in the pose error, except for the planar PnP's flip (``flip``): its 10-40 deg
    jumps are far outside the Euler angles' linear range (on the rendered PnP flights the
    linearised share overstated roll's spread by ~10 %), so its share ``w delta delta^T``
    of ``Sigma_C_B`` is replaced by ``w D D^T`` with ``D`` the exact difference, in the error
    axes, between the measured pose and the other solution.

    Parameters
    ----------
    Sigma_C_B : ndarray, shape (N, 6, 6)
        Covariance of the board pose error [dt, dtheta] in C (module docstring).
    T_C_B : ndarray, shape (N, 4, 4)
        Measured board poses.
    T_Q_B : ndarray, shape (4, 4)
        Board mounting on the body.
    R_C_L : ndarray, shape (3, 3)
        Rotation of the alignment.
    flip : ndarray, shape (N, 7), optional
        ``[delta, w]`` per frame (:func:`reference_covariance_transfer` with
        ``return_terms=True``): measured minus the other solution ``[dt, dtheta]`` in C and
        its weight in ``Sigma_C_B``; NaN or w = 0 where there is none.

    Returns
    -------
    sigma : ndarray, shape (N, 6)
        Standard deviations of x, y, z (m, axes of L) and roll, pitch, yaw (rad of R_L_Q).
    """
    T_B_Q = invert_T(T_Q_B)
    T_C_Q = T_C_B @ T_B_Q
    lever = T_C_B[:, :3, :3] @ T_B_Q[:3, 3]  # R_C_B t_B_Q
    J = np.zeros((len(T_C_B), 6, 6))
    R_L_C = R_C_L.T
    J[:, :3, :3] = R_L_C
    J[:, :3, 3:] = -R_L_C @ skew_matrix(lever)  # dp = dt - [lever]x dtheta
    # a left perturbation in C is one in L by R_L_C; the Euler angles are of R_L_Q
    J[:, 3:, 3:] = euler_jacobian(R_L_C @ T_C_Q[:, :3, :3], side="left") @ R_L_C
    Sigma_C_B = np.asarray(Sigma_C_B, float)
    if flip is not None:
        flip = np.asarray(flip, float)
        delta, w = flip[:, :6], flip[:, 6]
        has = np.isfinite(flip).all(axis=1) & (w > 0)
        if has.any():
            Sigma_C_B = Sigma_C_B.copy()
            Sigma_C_B[has] -= w[has, None, None] * delta[has, :, None] * delta[has, None, :]
    S = J @ Sigma_C_B @ np.swapaxes(J, -1, -2)
    if flip is not None and has.any():
        D = _flip_axis_difference(T_C_B[has], T_B_Q, R_L_C, delta[has])
        S[has] += w[has, None, None] * D[:, :, None] * D[:, None, :]
    return np.sqrt(np.clip(np.diagonal(S, axis1=1, axis2=2), 0, None))


def _flip_axis_difference(T_C_B, T_B_Q, R_L_C, delta):
    """Measured minus the other PnP solution in the error axes of L: body position (m) and
    the wrapped Euler angles of R_L_Q (rad), exact."""
    R_meas = T_C_B[:, :3, :3]
    # delta = [t_meas - t_alt, rotvec(R_meas R_alt^T)]
    R_alt = np.swapaxes(Rotation.from_rotvec(delta[:, 3:]).as_matrix(), -1, -2) @ R_meas
    t_alt = T_C_B[:, :3, 3] - delta[:, :3]
    p_meas = T_C_B[:, :3, 3] + R_meas @ T_B_Q[:3, 3]
    p_alt = t_alt + R_alt @ T_B_Q[:3, 3]
    rpy_meas = euler_from_R(R_L_C @ R_meas @ T_B_Q[:3, :3])
    rpy_alt = euler_from_R(R_L_C @ R_alt @ T_B_Q[:3, :3])
    return np.column_stack([(p_meas - p_alt) @ R_L_C.T, wrap_angle(rpy_meas - rpy_alt)])


def sigma_columns(Sigma):
    """Flatten (N, 6, 6) covariances into a DataFrame of columns ``S00 .. S55`` (SI).

    Parameters
    ----------
    Sigma : array_like, shape (N, 6, 6)
        Covariances of ``[dt (m), dtheta (rad)]`` in C (module docstring).

    Returns
    -------
    DataFrame
        N rows, 36 columns ``S{i}{j}`` (row-major), in m^2, m rad and rad^2.
    """
    Sigma = np.asarray(Sigma, float)
    columns = [f"S{i}{j}" for i in range(6) for j in range(6)]
    return pd.DataFrame(Sigma.reshape(len(Sigma), 36), columns=columns)


def sigma_from_columns(df):
    """Inverse of :func:`sigma_columns`: (N, 6, 6) from columns ``S00 .. S55``.

    Parameters
    ----------
    df : DataFrame
        A table with the 36 columns ``S00 .. S55`` (e.g. ``reference.parquet``).

    Returns
    -------
    Sigma : ndarray, shape (N, 6, 6)
        Covariances of ``[dt (m), dtheta (rad)]`` in C.

    Raises
    ------
    InputError
        A column is missing.
    """
    cols = [f"S{i}{j}" for i in range(6) for j in range(6)]
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise InputError(f"reference covariance table lacks columns {missing[:3]}...")
    return df[cols].to_numpy(float).reshape(len(df), 6, 6)


def corner_noise_per_axis(reproj_rms_px, n_corners):
    """Corner noise per image axis (px) from PnP's 2-D reprojection RMS over ``n_corners``:
    the RMS of the residual length over sqrt(2), corrected for the 6 pose parameters fitted.

    Parameters
    ----------
    reproj_rms_px : float
        RMS over the corners of the reprojection residual length, px.
    n_corners : int
        Corners in the PnP fit.

    Returns
    -------
    float
        ``reproj_rms_px / sqrt(2) * sqrt(2n / (2n - 6))``, px per axis.
    """
    n_res = 2 * int(n_corners)
    return float(reproj_rms_px) / np.sqrt(2.0) * np.sqrt(n_res / max(n_res - 6, 1))


def reference_covariance_from_pnp(poses_raw, p_B, K, dist, sigma_px):
    """Reference covariance per frame of a real flight, propagated from the corner noise.

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet of the flight's video (``valid``, ``rvec_0..2``, ``x_m..z_m``).
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    K, dist : array_like
        Intrinsics (the se3 calibration's where available), px.
    sigma_px : float
        Corner noise per axis, px (the se3 fit's ``sigma_px``).

    Returns
    -------
    Sigma_ref : ndarray, shape (N, 6, 6)
        ``[dt, dtheta]`` in C (module docstring) per row of ``poses_raw``; NaN where not valid.
    """

    valid = poses_raw["valid"].to_numpy(bool)
    Sigma = np.full((len(poses_raw), 6, 6), np.nan)
    if valid.any():
        rv = poses_raw.loc[valid, ["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
        tv = poses_raw.loc[valid, ["x_m", "y_m", "z_m"]].to_numpy(float)
        cov_rt = pnp_covariance(rv, tv, p_B, np.asarray(K, float), np.asarray(dist, float), sigma_px)
        Sigma[valid] = propagated_pose_covariance(rv, tv, cov_rt, frame="C")
    return Sigma


def _intrinsics_std(calib):
    """1-sigma of [fx, fy, cx, cy, k1, k2, p1, p2, k3] from an se3 result or a camera.yaml."""

    sd = dict(DEFAULT_INTRINSIC_STD)
    std = calib.get("std") if isinstance(calib.get("std"), dict) else {}
    sd.update({k: float(v) for k, v in std.items() if k in sd and v is not None})
    fixed = calib.get("fixed_intrinsics") or {}
    sd.update(dict(zip(fixed.get("names", []), map(float, fixed.get("std", [])), strict=False)))
    se = calib.get("std_errors") or {}
    sd.update({k: float(v) for k, v in se.items() if k in sd})
    return np.array([sd[n] for n in INTRINSIC_NAMES])


def pnp_flip_term(uv_px, rvec, tvec, p_B, K, dist):
    """The other solution of each frame's planar PnP and how much worse it fits its corners.

    :func:`cvsflow.uncertainty.ambiguity.pnp_alternatives`, with the difference as a
    translation in C and a rotation vector about C's axes (the flight's error coordinates).

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Observed corners, NaN where unseen.
    rvec, tvec : ndarray, shape (N, 3)
        The measured poses T_C_B.
    p_B : ndarray, shape (P, 3)
    K, dist : ndarray
        The intrinsics of the PnP.

    Returns
    -------
    delta : ndarray, shape (N, 6)
        Measured minus alternative, ``[dt m, dtheta rad]`` in C (module docstring); 0 where
        the two solutions coincide.
    d_ssr : ndarray, shape (N,)
        Sum of squared reprojection residuals of the alternative minus the measured pose's,
        px^2 (inf where there is no distinct alternative).
    """
    rvec, tvec = np.asarray(rvec, np.float64), np.asarray(tvec, np.float64)
    r_alt, t_alt, d_ssr = un.pnp_alternatives(uv_px, rvec, tvec, p_B, K, dist)
    delta = np.zeros((len(uv_px), 6))
    has = np.isfinite(r_alt).all(axis=1)
    if has.any():
        delta[has, :3] = tvec[has] - t_alt[has]
        delta[has, 3:] = (Rotation.from_rotvec(rvec[has])
                          * Rotation.from_rotvec(r_alt[has]).inv()).as_rotvec()
    return delta, d_ssr


def correct_rolling_shutter(poses_raw, corners, p_B, calib):
    """Poses with a rolling shutter's shear taken out, and the shear that was taken out.

    Under a rolling shutter each corner is seen at its own row's time, so a moving board's
    corners are displaced from one instant's by their image velocity times the line delay
    times their row after the frame's mean row
    (:func:`cvsflow.uncertainty.rolling_shutter.shear_displacement`; the frame is timed at that
    row, :func:`cvsflow.flight.trajectory.reference_from_poses`), and PnP turns the
    displacement into a pose error (:func:`cvsflow.uncertainty.frame_noise_terms`).
    It is a bias the corners' velocities predict, shared by neighbouring frames: on a rendered
    rolling-shutter flight (480 rows in 24 ms) 9-10 mrad about C's x and y axes, followed by the
    measured error with slope -0.99 and a residual at the corner-noise level; stated as a
    variance instead, it moved the flight's alignment and left roll at 3.4 times its sigma
    (docs/findings.md, 2026-12-05). The reprojection RMS is recomputed from the corners with
    their displacement taken out, so the corner noise is not read from the shear.

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet of the video (``frame``, ``valid``, ``rvec_0..2``, ``x_m..z_m``,
        ``reproj_rms_px``).
    corners : DataFrame
        corners.parquet of the same video (the corners' rows and velocities).
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    calib : dict
        ``K``, ``dist`` and ``line_delay_s`` (s per row; an se3 result's).

    Returns
    -------
    poses : DataFrame
        A copy of ``poses_raw``: the poses PnP gives the unsheared corners and their
        ``reproj_rms_px`` (:func:`cvsflow.uncertainty.rolling_shutter.unsheared_pnp`); as given with no
        line delay.
    shear : ndarray, shape (N, 6)
        The shear's pose error as first order predicts it (measured minus unsheared,
        ``[dt, dtheta]`` in C) per row; 0 where a corner velocity is unknown or with no line
        delay, NaN where not valid.
    """
    out = poses_raw.copy()
    valid = out["valid"].to_numpy(bool)
    shear = np.full((len(out), 6), np.nan)
    shear[valid] = 0.0
    ld = float(calib.get("line_delay_s") or 0.0)
    if not ld or not valid.any():
        return out, shear
    K = np.asarray(calib["K"], float)
    dist = np.asarray(calib["dist"], float).ravel()
    rcols, tcols = ["rvec_0", "rvec_1", "rvec_2"], ["x_m", "y_m", "z_m"]
    rows = out[valid]
    rv = np.array(rows[rcols], dtype=float)
    tv = np.array(rows[tcols], dtype=float)
    uv, _, vel = un.seen_corners(corners, rows["frame"].to_numpy(), len(p_B))
    _, shear[valid] = un.frame_noise_terms(uv, vel, rv, tv, p_B, K, dist, ld, frame="C")
    rv_c, tv_c, reproj = un.unsheared_pnp(uv, vel, rv, tv, p_B, K, dist, ld)
    out.loc[valid, rcols] = rv_c
    out.loc[valid, tcols] = tv_c
    out.loc[valid, "reproj_rms_px"] = reproj
    return out, shear


def reference_covariance_transfer(poses_raw, corners, p_B, calib, model=None, flips=True,
                                  inter_coded=False, return_terms=False, shear_corrected=False):
    """Reference covariance per frame of a flight from the error model (T) of the se3 stage.

    The camera reference of a flight is the PnP pose of the board: its error is what model (T)
    (:func:`cvsflow.uncertainty.fit_transfer_model`) predicts for the CVS side, without the
    Vicon's floor and mountings (a flight has no Vicon): the corner noise from each frame's
    image speed and reprojection RMS through the PnP of the corners it saw, the calibration's
    intrinsics uncertainty through PnP (one draw for the whole flight: correlated; the principal
    point's is left out, the alignment absorbs it), and, with a
    rolling shutter (``calib["line_delay_s"]``), the outer product of the pose error its shear
    predicts (where the reference does not correct it; with ``shear_corrected``, poses from
    :func:`correct_rolling_shutter`, only the prediction's own error, the model's ``r_rs``
    times it), and (``flips``) the planar PnP's two-fold
    ambiguity: ``w delta delta^T`` with ``delta`` the measured pose minus the other IPPE
    solution (:func:`pnp_flip_term`) and ``w = 1 / (1 + exp(d_ssr / (2 sigma_px^2)))`` the
    chance that the other one is the true pose given how much worse it fits the corners (the
    covariance of the two-solution mixture about the measured pose); from a motion-compensated
    video (``inter_coded``) also the still board's codec term of a model with ``s_still`` (a
    hovering body's board is coded as a copy of the last frame's,
    :func:`cvsflow.uncertainty.still_board_weight`).

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet of the flight's video (``frame``, ``valid``, ``rvec_0..2``,
        ``x_m..z_m``, ``reproj_rms_px``).
    corners : DataFrame
        corners.parquet of the flight's video.
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    calib : dict
        The se3 result (``K``, ``dist``, ``std_errors``, ``fixed_intrinsics``,
        ``line_delay_s``) or a camera.yaml (``K``, ``dist``, ``std``); intrinsics without a
        standard deviation take ``DEFAULT_INTRINSIC_STD``; their correlations are left out.
    model : dict, optional
        Model (T) (:func:`cvsflow.uncertainty.fit_transfer_model`'s dict, e.g. the validation
        session's, :func:`session_error_model`); default
        :data:`cvsflow.uncertainty.RENDERED_TRANSFER_MODEL`.
    flips : bool
        Add the PnP ambiguity term.
    inter_coded : bool
        The flight's video is motion-compensated (its corners_summary.yaml ``inter_coded``).
    return_terms : bool
        Also return the flip term's parts and the calibration's factor, for
        :func:`cvsflow.flight.evaluate_flight`.
    shear_corrected : bool
        ``poses_raw`` are already corrected for the rolling shutter's shear
        (:func:`correct_rolling_shutter`).

    Returns
    -------
    Sigma_ref : ndarray, shape (N, 6, 6)
        ``[dt, dtheta]`` in C per row of ``poses_raw``; NaN where not valid.
    flip : ndarray, shape (N, 7)
        With ``return_terms``: ``[delta, w]`` per row (measured minus the other solution, its
        weight in ``Sigma_ref``); NaN where not valid, w = 0 without ``flips``.
    cal_factor : ndarray, shape (N, 6, 9)
        With ``return_terms``: the calibration's share of ``Sigma_ref`` is
        ``cal_factor cal_factor^T``, the error per standard deviation of each intrinsic, one
        draw common to every frame; NaN where not valid.
    """

    model = un.RENDERED_TRANSFER_MODEL if model is None else model
    valid = poses_raw["valid"].to_numpy(bool)
    Sigma = np.full((len(poses_raw), 6, 6), np.nan)
    flip = np.full((len(poses_raw), 7), np.nan)
    cal_factor = np.full((len(poses_raw), 6, len(INTRINSIC_NAMES)), np.nan)
    if not valid.any():
        return (Sigma, flip, cal_factor) if return_terms else Sigma
    rows = poses_raw[valid]
    rv = rows[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
    tv = rows[["x_m", "y_m", "z_m"]].to_numpy(float)
    K = np.asarray(calib["K"], float)
    dist = np.asarray(calib["dist"], float).ravel()
    uv, speed, vel = un.seen_corners(corners, rows["frame"].to_numpy(), len(p_B))
    ld = float(calib.get("line_delay_s") or 0.0)
    unit, shear = un.frame_noise_terms(uv, vel, rv, tv, p_B, K, dist, ld, frame="C")
    n_seen = np.isfinite(uv).all(axis=-1).sum(axis=1)
    reproj = un.corner_noise_from_reproj(rows["reproj_rms_px"].to_numpy(float), n_seen)
    if model.get("k_shrink") is not None:
        # the model's shrinkage option: toward the flight's own pooled corner noise
        pool = un.corner_noise_pool(rows["reproj_rms_px"].to_numpy(float), n_seen)
        reproj = un.shrink_corner_noise(reproj, n_seen, pool, model["k_shrink"])
    var_px = (model["s0_px"] ** 2 + (model["s_speed"] * speed) ** 2
              + (model["s_reproj"] * reproj) ** 2)  # fmt: skip
    # intrinsics through PnP: d(rvec, tvec)/d(intrinsics) = -(J^T J)^-1 J^T J_K
    sd = _intrinsics_std(calib)
    # a principal-point error is to first order a turn of C about its origin, which the
    # flight's alignment (R_C_L) absorbs: only focal lengths and distortion stay
    sd[2:4] = 0.0
    seen = np.isfinite(uv).all(axis=-1)
    cov_rt = np.empty((len(rows), 6, 6))
    fac_rt = np.empty((len(rows), 6, len(sd)))
    obj = np.asarray(p_B, np.float64)
    for i in range(len(rows)):
        _, jac = cv2.projectPoints(obj[seen[i]].reshape(-1, 1, 3), rv[i], tv[i], K, dist)
        Jp, JK = jac[:, :6], jac[:, 6:15]
        A = -np.linalg.lstsq(Jp.T @ Jp, Jp.T @ JK, rcond=None)[0]
        cov_rt[i] = (A * sd**2) @ A.T
        fac_rt[i] = A * sd

    G_err = composed_error_jacobian(rv, tv, frame="C")
    cal = G_err @ cov_rt @ np.swapaxes(G_err, 1, 2)  # propagated_pose_covariance, G_err kept
    # the shear is a predicted bias: stated whole where it stays in the pose, and by the
    # prediction's relative error r_rs where it was taken out
    shear_share = float(model.get("r_rs") or 0.0) ** 2 if shear_corrected else 1.0
    S = (var_px[:, None, None] * unit + model["c_cal"] ** 2 * cal
         + shear_share * shear[:, :, None] * shear[:, None, :])  # fmt: skip
    s_still = float(model.get("s_still") or 0.0)
    if s_still and inter_coded:
        still = un.still_board_weight(n_seen, speed, 1.0)
        S = S + (s_still**2 * var_px * still)[:, None, None] * unit
    delta, w = np.zeros((len(rows), 6)), np.zeros(len(rows))
    if flips:
        delta, d_ssr = pnp_flip_term(uv, rv, tv, p_B, K, dist)
        w = un.flip_weight(d_ssr, var_px)
        S = S + w[:, None, None] * delta[:, :, None] * delta[:, None, :]
    Sigma[valid] = S
    if not return_terms:
        return Sigma
    flip[valid] = np.column_stack([delta, w])
    cal_factor[valid] = model["c_cal"] * (G_err @ fac_rt)
    return Sigma, flip, cal_factor


def flip_columns(flip):
    """The flip term's parts as columns ``flip_{dim}`` (m, rad) and ``flip_w``.

    Parameters
    ----------
    flip : array_like, shape (N, 7)
        :func:`reference_covariance_transfer`'s ``flip``.

    Returns
    -------
    DataFrame
    """
    cols = [f"flip_{d}" for d in ("dx_m", "dy_m", "dz_m", "drx_rad", "dry_rad", "drz_rad")]
    return pd.DataFrame(np.asarray(flip, float).reshape(-1, 7), columns=cols + ["flip_w"])


def factor_columns(G):
    """A per-frame factor (N, 6, k) as columns ``G{i}_{c}`` (row i of the error, cause c).

    Parameters
    ----------
    G : array_like, shape (N, 6, k)

    Returns
    -------
    DataFrame
    """
    G = np.asarray(G, float)
    cols = [f"G{i}_{c}" for i in range(6) for c in range(G.shape[2])]
    return pd.DataFrame(G.reshape(len(G), -1), columns=cols)


def factor_from_columns(df):
    """Inverse of :func:`factor_columns`; None when the table has no ``G0_0`` column.

    Parameters
    ----------
    df : DataFrame

    Returns
    -------
    ndarray, shape (N, 6, k), or None
    """
    k = sum(1 for c in df.columns if c.startswith("G0_"))
    if k == 0:
        return None
    cols = [f"G{i}_{c}" for i in range(6) for c in range(k)]
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise InputError(f"reference table: calibration factor columns {missing[:3]} missing")
    return df[cols].to_numpy(float).reshape(len(df), 6, k)


def flip_from_columns(df):
    """Inverse of :func:`flip_columns`; None when the table has no flip columns.

    Parameters
    ----------
    df : DataFrame

    Returns
    -------
    ndarray, shape (N, 7), or None
    """
    cols = list(flip_columns(np.zeros((0, 7))).columns)
    if not set(cols) <= set(df.columns):
        return None
    return df[cols].to_numpy(float)


def session_error_model(comparison, path="comparison.yaml"):
    """The model (T) a validation session fitted on all its frames, for its flights.

    Parameters
    ----------
    comparison : dict
        The session's comparison.yaml.
    path : str
        Its file name, for the error message.

    Returns
    -------
    dict
        Its ``error_model_fit`` (:func:`cvsflow.uncertainty.fit_transfer_model`'s dict).

    Raises
    ------
    InputError
        The comparison has no fitted model (written by an older cvsflow), or it is not a
        model (T).
    """

    model = comparison.get("error_model_fit")
    if not isinstance(model, dict):
        raise InputError(f"{path}: no error_model_fit (a comparison from an older cvsflow); rerun "
                         "its compare stage (snakemake --forcerun compare) or set the flight's "
                         "error_model: rendered")  # fmt: skip
    missing = [k for k in ("s0_px", "s_speed", "s_reproj", "c_cal", "nu") if k not in model]
    if missing or model.get("kind") != "T":
        raise InputError(f"{path}: error_model_fit is not a model (T) (kind {model.get('kind')!r}, "
                         f"missing {missing})")  # fmt: skip
    return model
