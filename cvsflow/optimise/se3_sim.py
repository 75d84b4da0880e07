"""Corner-level synthetic sessions with known truth for the ``se3`` method (no rendering).

For tests and bench scripts: the corners and bodies tables of a session whose intrinsics,
marker mountings, time offset and line delay are known, without the renderer of
:mod:`cvsflow.synth`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow.board import board_object_points
from cvsflow.geometry import fit_rigid, project_points
from cvsflow.geometry import transforms as tf
from cvsflow.optimise.se3_model import K_from_intrinsics


def simulate_session(
    seed,
    duration_s=20.0,
    fps=30.0,
    vicon_rate_hz=300.0,
    pixel_noise_px=0.3,
    marker_noise_m=0.0003,
    dt_offset_s=2.37,
    camera_motion_m=0.0,
    board=None,
    max_tilt_rad=0.7,
    line_delay_s=0.0,
    speed=1.0,
    focal_px=700.0,
    handheld_camera=False,
):
    """Corner-level synthetic session with known truth (no rendering): for tests and bench.

    Parameters
    ----------
    seed : int
        Seed of every random choice.
    duration_s : float
        Video length, s.
    fps : float
        Video frame rate, Hz.
    vicon_rate_hz : float
        Vicon sample rate, Hz.
    pixel_noise_px : float
        Standard deviation of the corner noise per axis, px.
    marker_noise_m : float
        Standard deviation of each Vicon marker position per axis, m; the body poses are
        rigid fits of four noisy markers.
    dt_offset_s : float
        True offset, t_vicon = t_video + dt_offset_s.
    camera_motion_m : float
        Amplitude of a slow sway of the camera body (0: static camera).
    handheld_camera : bool
        The camera is hand-held around a fixed board: the board stands still in W (where it
        is at t = 0) and the whole relative motion T_C_B(t) is the camera's,
        T_W_Cm(t) = T_W_B inv(T_C_B(t)) inv(T_Cm_C) (with ``camera_motion_m``'s sway on top
        of the board's fixed pose, if any).
    board : dict, optional
        Board geometry; default 6 x 5 squares of 0.09 m (20 inner corners).
    max_tilt_rad : float
        Largest board roll/pitch/yaw about its facing pose, rad.
    line_delay_s : float
        Rolling shutter: image row v is read ``v * line_delay_s`` after row 0 (whose time is
        the frame time); each corner is where the board was when its row was read.
    speed : float
        Factor on the frequencies of the hand motion (2: twice as fast, same path).
    focal_px : float
        Nominal focal length (px) of the 640 x 480 camera (each of fx, fy drawn about it).

    Returns
    -------
    session : dict
        ``corners`` (corners.parquet table), ``bodies`` (bodies.parquet table),
        ``camera`` (K, dist: the truth), ``board``, ``truth`` (``K, dist, T_Cm_C, T_Bm_B,
        dt_offset_s``, ``T_C_B`` (F, 4, 4) true board poses at the video frames,
        ``frame``, ``t_s``, ``uv_true_px`` (F, P, 2), ``t_corner_s`` (F, P) the time each
        corner was seen, ``line_delay_s``, ``T_W_Cm`` (F, 4, 4) the true camera-marker body at
        the video frames).
    """
    rng = np.random.default_rng(seed)
    if board is None:
        board = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
    p_B = board_object_points(board)
    centre_B = p_B.mean(axis=0)
    K = K_from_intrinsics(
        focal_px + rng.normal(0, 5), focal_px + rng.normal(0, 5), 320 + rng.normal(0, 5),
        240 + rng.normal(0, 5),
    )  # fmt: skip
    dist = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02]) * (1 + 0.1 * rng.normal(size=5))
    T_Cm_C = tf.T_from_pose6(
        [0.03, -0.02, 0.05, -np.pi / 2, 0.0, -np.pi / 2] + rng.normal(0, [0.005] * 3 + [0.03] * 3)
    )
    T_Bm_B = tf.T_from_pose6(
        [0.1, 0.07, -0.004, np.pi, 0.0, 0.0] + rng.normal(0, [0.005] * 3 + [0.03] * 3)
    )
    T_W_Cm0 = tf.T_from_pose6([-1.0, 0.5, 1.2, 0.05, -0.1, 0.3])

    T_C_B_at = hand_motion(rng, centre_B, speed, max_tilt_rad)

    def sway_at(t):
        t = np.atleast_1d(np.asarray(t, float))
        T = np.repeat(T_W_Cm0[None], len(t), axis=0)
        if camera_motion_m > 0:
            sway = camera_motion_m * np.stack(
                [np.sin(0.2 * t), np.sin(0.13 * t + 1), np.sin(0.17 * t + 2)], axis=1
            )
            T[:, :3, 3] += sway
            T[:, :3, :3] = T[:, :3, :3] @ tf.R_from_euler(2.0 * sway)
        return T

    if handheld_camera:  # the board (Bm) still where it is at t = 0; the camera carries the motion
        T_W_Bm_fixed = T_W_Cm0 @ T_Cm_C @ T_C_B_at(0.0)[0] @ tf.invert_T(T_Bm_B)

        def T_W_Cm_at(t):
            T_W_Bm = sway_at(t) @ tf.invert_T(T_W_Cm0) @ T_W_Bm_fixed
            return T_W_Bm @ T_Bm_B @ tf.invert_T(T_C_B_at(t)) @ tf.invert_T(T_Cm_C)
    else:
        T_W_Cm_at = sway_at

    # video frames and corners
    n_frames = int(round(duration_s * fps))
    t_video = np.arange(n_frames) / fps
    T_C_B = T_C_B_at(t_video)
    p_C = np.einsum("fij,pj->fpi", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
    uv_true = project_points(p_C, K, dist)
    t_corner = np.repeat(t_video[:, None], len(p_B), axis=1)
    for _ in range(4 if line_delay_s > 0 else 0):  # fixed point: the row read when the corner is
        t_corner = t_video[:, None] + np.clip(uv_true[..., 1], 0, None) * line_delay_s
        T_k = T_C_B_at(t_corner.ravel()).reshape(t_corner.shape + (4, 4))
        p_k = np.einsum("fpij,pj->fpi", T_k[..., :3, :3], p_B) + T_k[..., :3, 3]
        uv_true = project_points(p_k, K, dist)
    uv_obs = uv_true + rng.normal(0, pixel_noise_px, uv_true.shape)
    P = len(p_B)
    corners = pd.DataFrame(
        {
            "frame": np.repeat(np.arange(n_frames), P),
            "t_s": np.repeat(t_video, P),
            "found": True,
            "corner": np.tile(np.arange(P), n_frames),
            "u_px": uv_obs[..., 0].ravel(),
            "v_px": uv_obs[..., 1].ravel(),
        }
    )

    # Vicon: t_vicon = t_video + dt, covering the video with margins; rigid fits of noisy markers
    t_vicon = np.arange(0.0, duration_s + dt_offset_s + 1.0, 1.0 / vicon_rate_hz)
    t_vid_of_vicon = t_vicon - dt_offset_s
    T_W_Cm = T_W_Cm_at(t_vid_of_vicon)
    T_W_Bm = T_W_Cm @ T_Cm_C @ T_C_B_at(t_vid_of_vicon) @ tf.invert_T(T_Bm_B)
    bodies = mocap_bodies(rng, t_vicon, T_W_Cm, T_W_Bm, marker_noise_m)
    truth = {
        "K": K,
        "dist": dist,
        "T_Cm_C": T_Cm_C,
        "T_Bm_B": T_Bm_B,
        "dt_offset_s": float(dt_offset_s),
        "frame": np.arange(n_frames),
        "t_s": t_video,
        "T_C_B": T_C_B,
        "uv_true_px": uv_true,
        "t_corner_s": t_corner,
        "line_delay_s": float(line_delay_s),
        "T_W_Cm": T_W_Cm_at(t_video),
    }
    return {
        "corners": corners,
        "bodies": bodies,
        "camera": {"K": K.tolist(), "dist": dist.tolist()},
        "board": board,
        "truth": truth,
    }


def hand_motion(rng, centre_B, speed=1.0, max_tilt_rad=0.7):
    """A smooth hand-held board motion T_C_B(t): sums of sines per channel, drawn from rng.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the frequencies, phases and amplitudes (12 channels x 6 sines).
    centre_B : ndarray, shape (3,)
        The board's centre in B, m (the point the motion keeps in view).
    speed : float
        Factor on the frequencies.
    max_tilt_rad : float
        Largest roll/pitch/yaw about the facing pose, rad.

    Returns
    -------
    T_C_B_at : callable
        t (s, array) -> board poses in the camera, (len(t), 4, 4), m; the centre 1.2-3.8 m
        ahead.
    """

    # sums of sines per channel (board centre in C, tilt angles)
    def sines(n, f_lo, f_hi):
        f = speed * rng.uniform(f_lo, f_hi, (n, 3))
        ph = rng.uniform(0, 2 * np.pi, (n, 3))
        a = rng.uniform(0.5, 1.0, (n, 3))
        a /= a.sum(axis=1, keepdims=True)
        return lambda t: np.sum(
            a[:, None, :] * np.sin(2 * np.pi * f[:, None, :] * np.asarray(t)[None, :, None]
                                   + ph[:, None, :]), axis=0,
        )  # fmt: skip

    s_pos = sines(6, 0.03, 0.4)
    s_rot = sines(6, 0.05, 0.6)

    def T_C_B_at(t):
        t = np.atleast_1d(np.asarray(t, float))
        s = s_pos(t).T  # (t,) per channel
        z = 2.5 + 1.3 * s[2]
        x = z * 0.22 * s[0]
        y = z * 0.16 * s[1]
        rpy = max_tilt_rad * s_rot(t)
        R = tf.R_from_euler(rpy)
        centre_C = np.stack([x, y, z], axis=1)
        t_C_B = centre_C - (R @ centre_B)
        return tf.make_T(R, t_C_B)

    return T_C_B_at


def mocap_bodies(rng, t_vicon, T_W_Cm, T_W_Bm, marker_noise_m):
    """A bodies table (``camera``, ``board``) from true body poses: rigid fits of 4 noisy markers.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the marker noise (camera first, then board).
    t_vicon : ndarray, shape (N,)
        Vicon times, s.
    T_W_Cm, T_W_Bm : ndarray, shape (N, 4, 4)
        True camera-marker and board-marker body poses, m.
    marker_noise_m : float
        Standard deviation of each marker position per axis, m.

    Returns
    -------
    bodies : DataFrame
        bodies.parquet table (docs/contracts.md).
    """
    layout = {
        "camera": np.array([[0, 0, 0], [0, 0.16, 0], [0, 0, 0.12], [0, 0.11, 0.17]], float),
        "board": np.array([[0, 0, 0], [0.76, 0, 0], [0, 0.52, 0], [0.58, 0.5, 0]], float),
    }
    rows = []
    for body, T_true in (("camera", T_W_Cm), ("board", T_W_Bm)):
        L = layout[body]
        m_W = np.einsum("nij,kj->nki", T_true[:, :3, :3], L) + T_true[:, None, :3, 3]
        m_W = m_W + rng.normal(0, marker_noise_m, m_W.shape)
        T_fit = fit_rigid(L, m_W)[0]  # bit-identical here to the Kabsch copy se3 had
        q = tf.quat_from_R(T_fit[:, :3, :3])
        rows.append(
            pd.DataFrame(
                {
                    "frame": np.arange(len(t_vicon)),
                    "t_s": t_vicon,
                    "body": body,
                    "valid": True,
                    "x_m": T_fit[:, 0, 3],
                    "y_m": T_fit[:, 1, 3],
                    "z_m": T_fit[:, 2, 3],
                    "qx": q[:, 0],
                    "qy": q[:, 1],
                    "qz": q[:, 2],
                    "qw": q[:, 3],
                }
            )
        )
    return pd.concat(rows, ignore_index=True)


def _rig_camera_pose(i, baseline_m, rng, aim_depth_m=2.5):
    """T_C0_Ci of camera i: at x = 0, +b, -b, +2b, ... in C0, toed in to a point aim_depth_m ahead."""
    x = baseline_m * ((i + 1) // 2) * (1 if i % 2 else -1)
    if i == 0:
        return np.eye(4)
    # turn about y so that Ci's optical axis passes through (0, 0, aim_depth_m) of C0
    R = tf.R_from_euler([0.0, np.arctan2(-x, aim_depth_m), 0.0]) @ tf.R_from_euler(
        rng.normal(0, 0.03, 3)
    )
    return tf.make_T(R, [x, rng.normal(0, 0.01), rng.normal(0, 0.01)])


def _hidden_frames(rng, t, share, n_intervals=3):
    """Frames at times t (s) inside n_intervals random intervals covering ``share`` of the take."""
    hidden = np.zeros(len(t), bool)
    if share <= 0 or len(t) < 2:
        return hidden
    span = t[-1] - t[0]
    length = share * span / n_intervals
    for start in rng.uniform(t[0], t[-1] - length, n_intervals):
        hidden |= (t >= start) & (t < start + length)
    return hidden


def simulate_rig_session(
    seed,
    n_cameras=2,
    duration_s=10.0,
    fps=None,
    dt_offset_s=None,
    baseline_m=0.5,
    vicon_rate_hz=300.0,
    pixel_noise_px=0.3,
    marker_noise_m=0.0003,
    hidden_share=0.15,
    board=None,
    max_tilt_rad=0.7,
    focal_px=None,
    image_wh=(640, 480),
):
    """Corner-level synthetic session of N cameras on one rig marker body, with known truth.

    The cameras are fixed to the camera-rig body Cm (``T_Cm_Ci`` each); one board moves by
    hand in front of them (:func:`hand_motion`, in camera 0's frame). Each camera has its own
    intrinsics, frame rate and clock (``t_vicon = t_video_i + dt_offset_s[i]``); the board is
    seen whole, in part (corners outside the image are dropped), or not at all (random
    intervals covering ``hidden_share`` of each camera's take, as a hand or a person would
    hide it), so a frame may be seen by one camera, several, or none.

    Parameters
    ----------
    seed : int
        Seed of every random choice.
    n_cameras : int
        Number of cameras (>= 1).
    duration_s : float
        Video length of each camera, s.
    fps : sequence of float, optional
        Frame rate of each camera, Hz; default 30 for cameras 0 and 1, 25 for the others.
    dt_offset_s : sequence of float, optional
        True offset of each camera's clock; default 2.37 s for camera 0, 1.87 s for camera 1
        (its frames coincide in time with camera 0's: a genlocked pair with its own clock) and
        2.37 + 0.213 i s for the others.
    baseline_m : float
        Spacing of the cameras along camera 0's x axis (0, +b, -b, +2b, ...), m.
    vicon_rate_hz, pixel_noise_px, marker_noise_m, board, max_tilt_rad
        As :func:`simulate_session`.
    hidden_share : float
        Share of each camera's take in which the board is hidden from it.
    focal_px : sequence of float, optional
        Nominal focal length of each camera, px; default 700, 640, 760, ...
    image_wh : (int, int)
        Image width and height of every camera, px.

    Returns
    -------
    session : dict
        ``cameras`` (list, per camera: ``corners`` table, ``camera`` (true K, dist, width,
        height), ``dt_offset_s`` (true)), ``bodies`` (``camera`` is the rig body), ``board``,
        ``truth``: ``T_Bm_B``, ``T_W_Cm`` (the static rig body), ``cameras`` (per camera
        ``K, dist, T_Cm_C, T_C0_C, dt_offset_s, fps, frame, t_s, T_C_B`` (true board pose at
        each frame), ``T_C0_B``, ``hidden``), ``T_C0_B_at`` (callable: camera 0's video time
        -> true T_C0_B).
    """
    if n_cameras < 1:
        raise ValueError(f"simulate_rig_session: n_cameras {n_cameras}; expected >= 1")
    rng = np.random.default_rng(seed)
    if board is None:
        board = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
    fps = list(fps) if fps is not None else [30.0 if i < 2 else 25.0 for i in range(n_cameras)]
    if dt_offset_s is None:
        dt_offset_s = [2.37, 1.87] + [2.37 + 0.213 * i for i in range(2, n_cameras)]
    dt_offset_s = [float(v) for v in dt_offset_s[:n_cameras]]
    if focal_px is None:
        focal_px = [700.0 + 60.0 * ((i + 1) // 2) * (1 if i % 2 else -1) for i in range(n_cameras)]
    W, H = image_wh
    p_B = board_object_points(board)
    T_Cm_C0 = tf.T_from_pose6(
        [0.03, -0.02, 0.05, -np.pi / 2, 0.0, -np.pi / 2] + rng.normal(0, [0.005] * 3 + [0.03] * 3)
    )
    T_Bm_B = tf.T_from_pose6(
        [0.1, 0.07, -0.004, np.pi, 0.0, 0.0] + rng.normal(0, [0.005] * 3 + [0.03] * 3)
    )
    T_W_Cm = tf.T_from_pose6([-1.0, 0.5, 1.2, 0.05, -0.1, 0.3])
    T_C0_B_at = hand_motion(rng, p_B.mean(axis=0), 1.0, max_tilt_rad)  # camera 0's video time
    cams, truths = [], []
    for i in range(n_cameras):
        f = focal_px[i]
        K = K_from_intrinsics(f + rng.normal(0, 5), f + rng.normal(0, 5), W / 2 + rng.normal(0, 5),
                              H / 2 + rng.normal(0, 5))  # fmt: skip
        dist = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02]) * (1 + 0.1 * rng.normal(size=5))
        T_C0_C = _rig_camera_pose(i, baseline_m, rng)
        n_frames = int(round(duration_s * fps[i]))
        t_video = np.arange(n_frames) / fps[i]
        T_C0_B = T_C0_B_at(t_video + (dt_offset_s[i] - dt_offset_s[0]))
        T_C_B = tf.invert_T(T_C0_C) @ T_C0_B
        p_C = np.einsum("fij,pj->fpi", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
        front = p_C[..., 2] > 0.1
        uv = project_points(np.where(front[..., None], p_C, 1.0), K, dist)
        uv = uv + rng.normal(0, pixel_noise_px, uv.shape)
        inside = front & (uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0)
        inside &= uv[..., 1] <= H - 1
        hidden = _hidden_frames(rng, t_video, hidden_share)
        inside[hidden] = False
        found = inside.sum(axis=1) >= 6
        fi, ci = np.nonzero(inside & found[:, None])
        lost = np.flatnonzero(~found)
        corners = pd.DataFrame(
            {
                "frame": np.r_[fi, lost],
                "t_s": t_video[np.r_[fi, lost]],
                "found": np.r_[np.ones(len(fi), bool), np.zeros(len(lost), bool)],
                "corner": np.r_[ci, -np.ones(len(lost), int)],
                "u_px": np.r_[uv[fi, ci, 0], np.full(len(lost), np.nan)],
                "v_px": np.r_[uv[fi, ci, 1], np.full(len(lost), np.nan)],
            }
        ).sort_values(["frame", "corner"], ignore_index=True)
        cams.append({"corners": corners, "camera": {"K": K.tolist(), "dist": dist.tolist(),
                     "width": W, "height": H}, "dt_offset_s": dt_offset_s[i]})  # fmt: skip
        truths.append({"K": K, "dist": dist, "T_Cm_C": T_Cm_C0 @ T_C0_C, "T_C0_C": T_C0_C,
                       "dt_offset_s": dt_offset_s[i], "fps": fps[i], "frame": np.arange(n_frames),
                       "t_s": t_video, "T_C_B": T_C_B, "T_C0_B": T_C0_B, "found": found,
                       "hidden": hidden})  # fmt: skip
    t_vicon = np.arange(0.0, duration_s + max(dt_offset_s) + 1.0, 1.0 / vicon_rate_hz)
    T_W_Cm_all = np.repeat(T_W_Cm[None], len(t_vicon), axis=0)
    T_W_Bm = T_W_Cm @ T_Cm_C0 @ T_C0_B_at(t_vicon - dt_offset_s[0]) @ tf.invert_T(T_Bm_B)
    bodies = mocap_bodies(rng, t_vicon, T_W_Cm_all, T_W_Bm, marker_noise_m)
    return {
        "cameras": cams,
        "bodies": bodies,
        "board": board,
        "truth": {"T_Bm_B": T_Bm_B, "T_W_Cm": T_W_Cm, "cameras": truths, "T_C0_B_at": T_C0_B_at},
    }
