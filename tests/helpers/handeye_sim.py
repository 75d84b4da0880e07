"""Simulated hand-eye sessions with known truth, shared by the test_handeye*.py files; a frame
folder with the carrier's pose stream (frames_session, write_stream) for the frames and bag modes."""

from __future__ import annotations

import cv2
import numpy as np

from cvsflow.board.model import board_object_points
from cvsflow.geometry import interpolate_T, invert_T, quat_from_R
from cvsflow.geometry import transforms as tf
from cvsflow.geometry.camera import project_points
from tests.helpers.board_images import board_centre_pose, render_board

BOARD = {"squares_x": 10, "squares_y": 7, "square_m": 0.0236}  # 9x6 inner corners, as ViSP's
K = np.array([[607.59, 0.0, 323.46], [0.0, 607.57, 243.26], [0.0, 0.0, 1.0]])
CAMERA = {"K": K, "dist": np.zeros(5), "width": 640, "height": 480}
T_CM_C_TRUE = tf.make_T(tf.R_from_rvec([0.002, 0.009, 1.58]), [0.0577, -0.0339, -0.0423])
T_W_B_TRUE = tf.make_T(tf.R_from_euler([np.pi, 0.02, 0.4]), [0.52, 0.12, 0.09])
T_W_C_TRUE = tf.make_T(tf.R_from_euler([-2.2, 0.1, 1.4]), [0.9, -0.2, 0.6])
T_BM_B_TRUE = tf.make_T(tf.R_from_rvec([0.3, -0.1, 0.8]), [0.03, 0.05, 0.02])


def board_views(rng, n):
    """n board-in-camera poses, 0.40-0.55 m ahead, tilted up to ~30 deg, all corners in view."""
    out = []
    p_B = board_object_points(BOARD)
    while len(out) < n:
        rpy = [rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-np.pi, np.pi)]
        centre = [rng.uniform(-0.03, 0.03), rng.uniform(-0.02, 0.02), rng.uniform(0.40, 0.55)]
        T = board_centre_pose(rpy, centre, BOARD)
        uv = project_points(tf.transform_points(T, p_B), K, np.zeros(5))
        if uv.min() > 40 and uv[:, 0].max() < 600 and uv[:, 1].max() < 440:
            out.append(T)
    return np.stack(out)


def perturb(T, rng, sigma_pos_m, sigma_rot_rad):
    """Carrier poses with errors: a turn about the carrier origin and a shift in W."""
    n = len(T)
    R = tf.R_from_rvec(rng.normal(0.0, sigma_rot_rad, (n, 3))) @ T[:, :3, :3]
    return tf.make_T(R, T[:, :3, 3] + rng.normal(0.0, sigma_pos_m, (n, 3)))


def simulate(mode, n=10, seed=0, sigma_px=0.3, sigma_pos_m=0.0, sigma_rot_rad=0.0):
    """Carrier poses (noisy), true board poses, noisy corners and the truth of a session."""
    rng = np.random.default_rng(seed)
    T_C_B = board_views(rng, n)
    if mode == "eye_in_hand":
        T_H, T_G = T_CM_C_TRUE, T_W_B_TRUE
        T_W_X = T_W_B_TRUE @ tf.invert_T(T_C_B) @ tf.invert_T(T_CM_C_TRUE)
    else:
        T_H, T_G = T_W_C_TRUE, T_BM_B_TRUE
        T_W_X = T_W_C_TRUE @ T_C_B @ tf.invert_T(T_BM_B_TRUE)
    p_B = board_object_points(BOARD)
    uv = project_points(tf.transform_points(T_C_B[:, None], p_B[None]), K, np.zeros(5))
    uv = uv + rng.normal(0.0, sigma_px, uv.shape)
    return {"T_W_X": perturb(T_W_X, rng, sigma_pos_m, sigma_rot_rad), "T_W_X_true": T_W_X,
            "T_C_B": T_C_B, "uv": uv, "p_B": p_B, "T_H": T_H, "T_G": T_G}  # fmt: skip


def pose_errors(T_true, T_est):
    """[rotation error (rad, about the child axes), translation error (m)] of an estimate."""
    return np.concatenate([tf.rvec_from_R(T_est[:3, :3].T @ T_true[:3, :3]) * -1.0,
                           T_est[:3, 3] - T_true[:3, 3]])  # fmt: skip


#: A Unix time in ns (yac's first frame) the stream sessions start at.
T0 = 1_606_153_907_495_166_540


def write_stream(path, t_ns, T, fmt):
    """A pose stream file: asl (ns, a header) or eth (s, comma separated)."""
    q = quat_from_R(T[:, :3, :3])
    rows = []
    for t, p, qq in zip(t_ns, T[:, :3, 3], q, strict=True):
        stamp = str(int(t)) if fmt == "asl" else f"{int(t) // 10**9}.{int(t) % 10**9:09d}"
        rows.append(",".join([stamp, *(f"{v:.9f}" for v in (*p, *qq))]))
    header = "timestamp [ns],x,y,z,qx,qy,qz,qw\n" if fmt == "asl" else ""
    path.write_text(header + "\n".join(rows) + "\n")
    return path


def frames_session(tmp_path, n=14, extra_after_s=None):
    """Rendered board frames named by ns (0.5 s apart), the carrier's stream at 100 Hz through
    the same views (linear + SLERP between them), ASL; a frame after the stream's end if asked."""
    rng = np.random.default_rng(31)
    T_C_B = board_views(rng, n)
    t_ns = T0 + np.arange(n) * 500_000_000
    T_W_Cm_views = T_W_B_TRUE @ invert_T(T_C_B) @ invert_T(T_CM_C_TRUE)
    tq = np.arange(-1.0, (n - 1) * 0.5 + 1.0, 0.01)
    T_stream, ok, _ = interpolate_T(np.arange(n) * 0.5, T_W_Cm_views, np.ones(n, bool), np.clip(tq, 0, (n - 1) * 0.5))
    assert ok.all()
    frames = tmp_path / "frames"
    frames.mkdir()
    for t, T in zip(t_ns, T_C_B, strict=True):
        cv2.imwrite(str(frames / f"{t}.png"), render_board(T, K, BOARD, pps=40, seed=int(t % 97))[0])
    if extra_after_s is not None:
        t_extra = T0 + int(((n - 1) * 0.5 + extra_after_s) * 1e9)
        cv2.imwrite(str(frames / f"{t_extra}.png"), render_board(T_C_B[0], K, BOARD, pps=40)[0])
    poses = write_stream(tmp_path / "body.csv", T0 + np.round(tq * 1e9).astype(np.int64), T_stream, "asl")
    return frames, poses
