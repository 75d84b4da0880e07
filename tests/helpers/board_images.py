"""Rendered chessboard images for the tests: a board seen by a distortion-free camera.

Shared by test_pose, the test_corners* files and test_calibration (not a test module itself).
"""

from __future__ import annotations

import cv2
import numpy as np

from cvsflow.board.model import board_object_points
from cvsflow.geometry import transforms as tf

BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}  # the demo board, 5x4 inner corners
W, H = 640, 480


def board_centre_pose(rpy, centre_C, board=BOARD):
    """T_C_B such that the board centre lands at ``centre_C`` (m, camera frame)."""
    nx, ny = board["squares_x"] - 1, board["squares_y"] - 1
    c_B = np.array([(nx - 1) * board["square_m"] / 2, (ny - 1) * board["square_m"] / 2, 0.0])
    R = tf.R_from_euler(rpy)
    return tf.make_T(R, np.asarray(centre_C) - R @ c_B)


def render_board(T_C_B, K, board=BOARD, pps=24, margin=1, noise_sigma=2.0, seed=0):
    """Grey image of the chessboard seen by a distortion-free camera, and the true corners.

    Square (i, j) is black when i + j is even (square (0, 0) diagonally outside corner 0);
    a white margin of ``margin`` squares surrounds the squares, the background is mid grey.
    """
    sx, sy, s = board["squares_x"], board["squares_y"], board["square_m"]
    tex_w, tex_h = (sx + 2 * margin) * pps, (sy + 2 * margin) * pps
    cols, rows = np.arange(tex_w) // pps - margin, np.arange(tex_h) // pps - margin
    ii, jj = np.meshgrid(cols, rows)
    inside = (ii >= 0) & (ii < sx) & (jj >= 0) & (jj < sy)
    texture = np.where(inside & ((ii + jj) % 2 == 0), 20, 235).astype(np.uint8)
    # Texture pixel centre (c, r) -> board point X = ((c + 0.5) / pps - 1 - margin) * s.
    A_B_tex = np.array(
        [
            [s / pps, 0.0, (0.5 / pps - 1 - margin) * s],
            [0.0, s / pps, (0.5 / pps - 1 - margin) * s],
            [0.0, 0.0, 1.0],
        ]
    )
    H_img_B = K @ np.column_stack([T_C_B[:3, 0], T_C_B[:3, 1], T_C_B[:3, 3]])
    H_img_tex = H_img_B @ A_B_tex
    img = cv2.warpPerspective(
        texture, H_img_tex, (W, H), flags=cv2.INTER_AREA, borderValue=128
    ).astype(np.float64)
    img = cv2.GaussianBlur(img, (0, 0), 0.7)
    img += np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    gray = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    p_B = board_object_points(board)
    uv, _ = cv2.projectPoints(p_B, tf.rvec_from_R(T_C_B[:3, :3]), T_C_B[:3, 3], K, None)
    return gray, uv.reshape(-1, 2)


def render_board_distorted(T_C_B, K, dist, size, board=BOARD, pps=32, blur_sigma=0.7,
                           noise_sigma=2.0, occluder=None, seed=0):
    """As ``render_board`` at any ``size`` (w, h), through a lens with distortion ``dist``.

    The distortion-free image is rendered first, then resampled at each distorted pixel's
    undistorted position (``cv2.undistortPoints``); ``occluder`` (polygon, (M, 2) px) is filled
    mid-dark grey after distortion (a hand). Returns the image and the true distorted corners.
    """
    w, h = size
    sx, sy, s = board["squares_x"], board["squares_y"], board["square_m"]
    margin = 1
    tex_w, tex_h = (sx + 2 * margin) * pps, (sy + 2 * margin) * pps
    cols, rows = np.arange(tex_w) // pps - margin, np.arange(tex_h) // pps - margin
    ii, jj = np.meshgrid(cols, rows)
    inside = (ii >= 0) & (ii < sx) & (jj >= 0) & (jj < sy)
    texture = np.where(inside & ((ii + jj) % 2 == 0), 20, 235).astype(np.uint8)
    A_B_tex = np.array([[s / pps, 0.0, (0.5 / pps - 1 - margin) * s],
                        [0.0, s / pps, (0.5 / pps - 1 - margin) * s], [0.0, 0.0, 1.0]])
    H_img_tex = K @ np.column_stack([T_C_B[:3, 0], T_C_B[:3, 1], T_C_B[:3, 3]]) @ A_B_tex
    flat = cv2.warpPerspective(texture, H_img_tex, (w, h), flags=cv2.INTER_AREA,
                               borderValue=128)
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    und = cv2.undistortPoints(np.stack([uu.ravel(), vv.ravel()], 1).reshape(-1, 1, 2), K,
                              np.asarray(dist, float), P=K).reshape(h, w, 2).astype(np.float32)
    img = cv2.remap(flat, und[..., 0], und[..., 1], cv2.INTER_LINEAR,
                    borderValue=128).astype(np.float64)
    if occluder is not None:
        cv2.fillPoly(img, [np.round(np.asarray(occluder)).astype(np.int32)], 90.0)
    img = cv2.GaussianBlur(img, (0, 0), blur_sigma)
    img += np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    gray = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    p_B = board_object_points(board)
    uv, _ = cv2.projectPoints(p_B, tf.rvec_from_R(T_C_B[:3, :3]), T_C_B[:3, 3], K,
                              np.asarray(dist, float))
    return gray, uv.reshape(-1, 2)


K_DRIFT = np.array([[700.0, 0.0, 319.5], [0.0, 700.0, 239.5], [0.0, 0.0, 1.0]])


def drifting_board_frame(i: int) -> np.ndarray:
    """Frame i of a board drifting right (grey, 640x480)."""
    T = board_centre_pose([0.1, 0.05, 0.0], [-0.2 + 0.004 * i, 0.0, 1.3])
    return render_board(T, K_DRIFT, seed=i)[0]


def write_h264(path, n_frames, fmt=None, gop=None, b_frames=True):
    """H.264 of ``drifting_board_frame`` 0..n-1 at 30 fps (``fmt="h264"``: a bare Annex B
    stream, as a Raspberry Pi camera writes; ``b_frames=False`` as its encoder does)."""
    import av

    container = av.open(str(path), "w", format=fmt)
    stream = container.add_stream("libx264", rate=30)
    stream.width, stream.height, stream.pix_fmt = W, H, "yuv420p"
    if gop is not None:
        stream.codec_context.gop_size = gop
    if not b_frames:
        stream.codec_context.max_b_frames = 0
    for i in range(n_frames):
        frame = av.VideoFrame.from_ndarray(cv2.cvtColor(drifting_board_frame(i), cv2.COLOR_GRAY2BGR),
                                           format="bgr24").reformat(format="yuv420p")
        for packet in stream.encode(frame):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()


def random_board_poses(n, seed):
    """Board poses spread over the view: 0.8 to 2.5 m away, tilted up to 40 degrees."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        z = rng.uniform(0.8, 2.5)
        centre = np.array([rng.uniform(-0.25, 0.25) * z, rng.uniform(-0.18, 0.18) * z, z])
        rpy = np.radians([rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(-180, 180)])
        out.append(board_centre_pose(rpy, centre))
    return out
