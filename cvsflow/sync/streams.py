"""The angular-speed streams of the video and Vicon, and the checks on their spans (rule ``sync``).

The board's angular speed is the same in both streams whatever the unknown marker offsets are
(:mod:`cvsflow.sync.offset`): ``angular_speed_cvs`` from the PnP rotations R_C_B (jumps masked),
``angular_speed_vicon`` from R_Cm_Bm = R_W_Cm^T R_W_Bm, and ``check_take_covers_video`` that
the take spans the video for a candidate offset.
"""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import InputError
from cvsflow.geometry import R_from_rvec, interpolate_T, invert_T, rotation_angle, sample_period
from cvsflow.mocap import body_poses

# --------------------------------------------------------------------------- streams


def _cvs_rotations(poses_raw):
    """Sorted video times (s), R_C_B (N, 3, 3) (identity where invalid) and validity."""
    p = poses_raw.sort_values("frame", kind="stable")
    rvec = p[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
    valid = p["valid"].to_numpy(bool) & np.isfinite(rvec).all(axis=1)
    rvec = np.where(valid[:, None], p[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float), 0.0)
    return p["t_s"].to_numpy(float), R_from_rvec(rvec), valid


def _vicon_relative(bodies, camera="camera", board="board"):
    """Vicon times (s), T_Cm_Bm (N, 4, 4) (NaN where either body is invalid) and validity."""
    t_c, T_W_Cm, v_c = body_poses(bodies, camera)
    t_b, T_W_Bm, v_b = body_poses(bodies, board)
    if len(t_c) != len(t_b) or not np.allclose(t_c, t_b):
        raise InputError("bodies table: camera and board samples are not on the same times")
    valid = v_c & v_b
    T = invert_T(np.where(valid[:, None, None], T_W_Cm, np.eye(4))) @ np.where(
        valid[:, None, None], T_W_Bm, np.eye(4)
    )
    T[~valid] = np.nan
    return t_b, T, valid


def _jump_outliers(t_s, R, valid, max_speed_rad_s, max_frames=5):
    """Frames of short runs set apart by rotation jumps faster than any real motion.

    A pose whose rotation differs from its neighbour's by more than ``max_speed_rad_s`` times
    their time difference is a jump (typically PnP's flip ambiguity of a nearly fronto-parallel
    board). Consecutive valid frames without a jump form runs. First, runs of at most
    ``max_frames`` frames with a jump at both ends are outliers; then, those left out, runs
    of at most ``max_frames`` with a jump at one end (the other end a missing pose or the end
    of the video). A longer run is taken as the truth.

    Returns
    -------
    outlier : ndarray of bool, shape (N,)
    """
    n = len(t_s)
    out = np.zeros(n, dtype=bool)
    if n < 2:
        return out
    for both_ends in (True, False):
        ok = valid & ~out
        pair = ok[:-1] & ok[1:]
        speed = np.zeros(n - 1)
        speed[pair] = rotation_angle(np.swapaxes(R[:-1][pair], 1, 2) @ R[1:][pair]) / np.diff(t_s)[pair]
        jump = pair & (speed > max_speed_rad_s)
        brk = ~pair | jump  # run boundaries between frame k and k + 1
        starts = np.concatenate([[0], np.flatnonzero(brk) + 1])
        ends = np.concatenate([np.flatnonzero(brk), [n - 1]])
        for a, b in zip(starts, ends, strict=True):
            if not ok[a] or b - a + 1 > max_frames:
                continue
            j0, j1 = a > 0 and jump[a - 1], b < n - 1 and jump[b]
            if (j0 and j1) if both_ends else (j0 or j1):
                out[a : b + 1] = True
    return out


def _frame_list(poses_raw, mask, at_most=10):
    """The frame numbers where mask is true (sorted by frame), at most ``at_most`` of them."""
    frames = np.sort(poses_raw["frame"].to_numpy())[mask]
    more = f" and {len(frames) - at_most} more" if len(frames) > at_most else ""
    return ", ".join(str(int(f)) for f in frames[:at_most]) + more


def angular_speed_cvs(poses_raw):
    """Board angular speed seen by the camera, from consecutive video frames.

    Parameters
    ----------
    poses_raw : DataFrame
        ``poses_raw.parquet`` table (``frame, t_s, valid, rvec_0..2``; rvec_C_B).

    Returns
    -------
    t_mid_s : ndarray, shape (N - 1,)
        Mid-times of consecutive frames, video clock, s.
    omega_rad_s : ndarray, shape (N - 1,)
        |omega| = angle(R_C_B(i)^T R_C_B(i+1)) / (t_{i+1} - t_i), rad/s; NaN where either
        frame has no valid pose (masked, not interpolated).
    """
    t, R, valid = _cvs_rotations(poses_raw)
    ang = rotation_angle(np.swapaxes(R[:-1], 1, 2) @ R[1:])
    omega = ang / np.diff(t)
    omega[~(valid[:-1] & valid[1:])] = np.nan
    return 0.5 * (t[:-1] + t[1:]), omega


def _omega_vicon_between(t_v, T_v, valid_v, t0, t1):
    """Angular speed (rad/s) of the Vicon relative rotation between times t0 and t1 (SLERP)."""
    T0, ok0, _ = interpolate_T(t_v, T_v, valid_v, t0)
    T1, ok1, _ = interpolate_T(t_v, T_v, valid_v, t1)
    ok = ok0 & ok1
    R0 = np.where(ok[:, None, None], T0[:, :3, :3], np.eye(3))
    R1 = np.where(ok[:, None, None], T1[:, :3, :3], np.eye(3))
    omega = rotation_angle(np.swapaxes(R0, 1, 2) @ R1) / (t1 - t0)
    omega[~ok] = np.nan
    return omega


def angular_speed_vicon(bodies, window_s, t_grid_s=None, camera="camera", board="board"):
    """Board angular speed relative to the camera body from the Vicon, over a window.

    Parameters
    ----------
    bodies : DataFrame
        Native-rate bodies table.
    window_s : float
        Time between the two rotations compared, s: the video frame interval, so that both
        streams average the true angular speed over the same span.
    t_grid_s : ndarray, optional
        Centre times on the Vicon clock, s; default every native sample.

    Returns
    -------
    t_s : ndarray, shape (K,)
    omega_rad_s : ndarray, shape (K,)
        NaN where the Vicon relative pose is invalid at either end of the window.
    """
    t_v, T_v, valid_v = _vicon_relative(bodies, camera, board)
    t = t_v if t_grid_s is None else np.asarray(t_grid_s, dtype=float)
    return t, _omega_vicon_between(t_v, T_v, valid_v, t - window_s / 2, t + window_s / 2)


def angular_speed_streams(poses_raw, bodies, camera="camera", board="board"):
    """Both angular-speed streams as plotted by :func:`cvsflow.plots.mocap.plot_sync`.

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet (``t_s`` video clock, ``valid``, ``rvec_0..2`` of R_C_B).
    bodies : DataFrame
        Native-rate bodies.parquet (T_W_Cm and T_W_Bm).
    camera, board : str
        Body names of the camera-marker and board-marker bodies.

    Returns
    -------
    streams : dict
        ``t_cvs_s``, ``omega_cvs_rad_s`` (video clock) and ``t_vicon_s``,
        ``omega_vicon_rad_s`` (Vicon clock, native samples, same window as the video).
    """
    t_c, w_c = angular_speed_cvs(poses_raw)
    h = sample_period(poses_raw["t_s"].to_numpy(float))
    t_v, w_v = angular_speed_vicon(bodies, h, camera=camera, board=board)
    return {"t_cvs_s": t_c, "omega_cvs_rad_s": w_c, "t_vicon_s": t_v, "omega_vicon_rad_s": w_v}


# --------------------------------------------------------------------------- checks


def _spans(poses_raw, bodies):
    t_video = poses_raw["t_s"].to_numpy(float)
    t_vicon = bodies["t_s"].to_numpy(float)
    return (float(t_video.min()), float(t_video.max())), (float(t_vicon.min()), float(t_vicon.max()))


def check_take_covers_video(video_span_s, take_span_s, dt_offset_s=None, tol_s=1e-9, min_share=1.0):
    """Raise InputError when the Vicon take is shorter than the video (or misses part of it).

    With ``min_share`` < 1 and no offset, the take need only last ``min_share`` of the video
    (a partial overlap is used for what it covers: :func:`cvsflow.plausibility.checks.check_overlap`).

    Parameters
    ----------
    video_span_s : (float, float)
        First and last video frame times, video clock, s.
    take_span_s : (float, float)
        First and last Vicon sample times, Vicon clock, s.
    dt_offset_s : float, optional
        Known offset; with it, the video span mapped to the Vicon clock must lie in the take.
    tol_s : float
        Slack at each end, s.
    min_share : float
        Share of the video the take must last when no offset is given, in (0, 1].

    Returns
    -------
    None

    Raises
    ------
    InputError
        The take is too short, or the mapped video span falls outside it.
    """
    v0, v1 = video_span_s
    k0, k1 = take_span_s
    if dt_offset_s is None:
        if (k1 - k0) + tol_s < min_share * (v1 - v0):
            raise InputError(
                f"Vicon take is shorter than the video: take spans {k0:.3f}..{k1:.3f} s "
                f"({k1 - k0:.3f} s), video spans {v0:.3f}..{v1:.3f} s ({v1 - v0:.3f} s); "
                f"expected it to last at least {100 * min_share:.0f} % of the video"
            )
        return
    m0, m1 = v0 + dt_offset_s, v1 + dt_offset_s
    if m0 < k0 - tol_s or m1 > k1 + tol_s:
        raise InputError(
            f"Vicon take does not cover the video: video frames span {v0:.3f}..{v1:.3f} s, i.e. "
            f"{m0:.3f}..{m1:.3f} s on the Vicon clock (dt_offset_s = {dt_offset_s:.4f}), but the "
            f"take spans {k0:.3f}..{k1:.3f} s"
        )
