"""Per-frame poses of an se3 fit: the CVS pose (PnP at the fitted intrinsics) beside the Vicon
reference of eq. (1), as the table every error statistic reads (:func:`apply_se3`), and the
pieces the rig solve shares with it (:func:`pose_columns`, :func:`tracks_from_params`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow.board import board_object_points
from cvsflow.geometry import project_points
from cvsflow.geometry import transforms as tf
from cvsflow.optimise.body_tracks import CAMERA_MOVING_SMOOTH_S, BodyTrack
from cvsflow.optimise.se3_start import corner_arrays, solve_pnp_frames


def pose_columns(prefix, T):
    """Columns of a per-frame pose table: position, quaternion (rvec for ``cvs_``), Euler.

    Parameters
    ----------
    prefix : str
        ``"cvs_"`` (with ``cvs_rvec_0..2``) or ``"ref_"``.
    T : ndarray, shape (F, 4, 4)
        Poses, m.

    Returns
    -------
    columns : dict
        ``{prefix}x_m, y_m, z_m, qx, qy, qz, qw`` (, ``cvs_rvec_0..2``), ``roll_rad, pitch_rad,
        yaw_rad`` -> ndarray (F,).
    """
    out = {}
    q = tf.quat_from_R(T[:, :3, :3])
    rpy = tf.euler_from_R(T[:, :3, :3]).reshape(-1, 3)
    for j, ax in enumerate("xyz"):
        out[f"{prefix}{ax}_m"] = T[:, j, 3]
    for j, ax in enumerate(("qx", "qy", "qz", "qw")):
        out[f"{prefix}{ax}"] = q[:, j]
    if prefix == "cvs_":
        rv = tf.rvec_from_R(T[:, :3, :3]).reshape(-1, 3)
        for j in range(3):
            out[f"cvs_rvec_{j}"] = rv[:, j]
    for j, ax in enumerate(("roll", "pitch", "yaw")):
        out[f"{prefix}{ax}_rad"] = rpy[:, j]
    return out


def tracks_from_params(params, bodies, share=None):
    """The camera-marker and board-marker tracks with a fit's smoothing options.

    Parameters
    ----------
    params : dict
        Optional ``camera_smooth_s``, ``board_smooth_s`` (s, default 0), ``camera_static_tol``
        ((m, rad), default None), ``camera_moving_smooth_s`` (s, default
        ``CAMERA_MOVING_SMOOTH_S``), as in a ``result.yaml``.
    bodies : DataFrame
        bodies.parquet.
    share : cvsflow.optimise.se3_share.Se3Share, optional
        Tracks made once for the session's fits (of these ``bodies``).

    Returns
    -------
    cam, brd : BodyTrack
    """
    board_smooth_s = float(params.get("board_smooth_s", 0.0))
    moving_smooth_s = params.get("camera_moving_smooth_s")
    make = (lambda body, **o: BodyTrack.from_bodies(bodies, body, **o)) if share is None else share.track
    cam = make(
        "camera",
        smooth_s=float(params.get("camera_smooth_s", 0.0)),
        static_tol=params.get("camera_static_tol"),
        moving_smooth_s=CAMERA_MOVING_SMOOTH_S if moving_smooth_s is None else float(moving_smooth_s),
    )
    brd = make("board", smooth_s=board_smooth_s)
    return cam, brd


def apply_se3(params, corners, bodies, board, frames=None, *, share=None):
    """Per-frame CVS pose (PnP at the fitted intrinsics) and Vicon reference pose (eq. 1).

    Parameters
    ----------
    params : dict
        ``K`` (3x3, px), ``dist`` (5), ``T_Cm_C``, ``T_Bm_B`` (4x4, m), ``dt_offset_s`` (s),
        optional ``camera_smooth_s``, ``board_smooth_s`` (s, default 0),
        ``camera_static_tol`` ((m, rad), default None), ``camera_moving_smooth_s`` (s,
        default ``CAMERA_MOVING_SMOOTH_S``) and ``line_delay_s`` (s per row, default 0); e.g.
        ``optimise_se3(...).result``.
    corners : DataFrame
        corners.parquet (``frame, t_s, found, corner, u_px, v_px``).
    bodies : DataFrame
        bodies.parquet (see :func:`cvsflow.mocap.body_poses`).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    frames : array_like of int, optional
        Frames to evaluate (e.g. a held-out block); default all complete found frames.
    share : cvsflow.optimise.se3_share.Se3Share, optional
        Corner arrays, tracks and PnP poses made once for the session's fits (of these
        ``corners``, ``bodies`` and ``board``); the table is the same with and without it.

    Returns
    -------
    frames : DataFrame
        One row per frame with corners (``corner_arrays``), a PnP solution and valid Vicon poses at
        t + dt (+ line_delay_s times the mean image row of the frame's corners: the PnP pose of
        a rolling-shutter image is, to first order, the board's pose when that row was read):
        ``frame, t_s, t_vicon_s``; CVS pose T_C_B ``cvs_x_m, cvs_y_m, cvs_z_m,
        cvs_qx, cvs_qy, cvs_qz, cvs_qw, cvs_rvec_0..2, cvs_roll_rad, cvs_pitch_rad,
        cvs_yaw_rad``; reference T_C_B from the Vicon with ``ref_`` prefix, same columns
        (no rvec); ``reproj_rms_px`` (PnP reprojection RMS at the fitted intrinsics).
    """
    if share is None:
        p_B = board_object_points(board)
        frame, t_video, uv = corner_arrays(corners, len(p_B))
    else:
        share.check(corners, bodies, board)
        p_B, frame, t_video, uv = share.p_B, share.frame, share.t_video, share.uv
    rows = np.arange(len(frame))
    if frames is not None:
        sel = np.isin(frame, np.asarray(frames))
        frame, t_video, uv, rows = frame[sel], t_video[sel], uv[sel], rows[sel]
    K = np.asarray(params["K"], float)
    dist = np.asarray(params["dist"], float)
    T_Cm_C = np.asarray(params["T_Cm_C"], float)
    T_Bm_B = np.asarray(params["T_Bm_B"], float)
    dt = float(params["dt_offset_s"])
    cam, brd = tracks_from_params(params, bodies, share)
    tq = t_video + dt
    ld = float(params.get("line_delay_s", 0.0) or 0.0)
    if ld != 0.0:
        tq = tq + ld * np.nanmean(uv[..., 1], axis=1)
    ok_vicon = cam.ok(tq) & brd.ok(tq)
    T_ref = tf.invert_T(cam(tq) @ T_Cm_C) @ brd(tq) @ T_Bm_B  # eq. (1)
    T_cvs, ok_pnp = solve_pnp_frames(uv, p_B, K, dist) if share is None else share.pnp(rows, K, dist)
    keep = ok_vicon & ok_pnp
    T_ref, T_cvs = T_ref[keep], T_cvs[keep]
    p_C = np.einsum("fij,pj->fpi", T_cvs[:, :3, :3], p_B) + T_cvs[:, None, :3, 3]
    err2 = np.sum((project_points(p_C, K, dist) - uv[keep]) ** 2, axis=-1)  # NaN where unseen
    rms = np.sqrt(np.nanmean(err2, axis=1))
    out = {"frame": frame[keep], "t_s": t_video[keep], "t_vicon_s": tq[keep]}
    out.update(pose_columns("cvs_", T_cvs))
    out.update(pose_columns("ref_", T_ref))
    out["reproj_rms_px"] = rms
    return pd.DataFrame(out)
