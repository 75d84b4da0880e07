"""A synthetic session with a known video/Vicon offset, shared by test_sync.py and test_pairs.py.

Vicon bodies come from noisy markers through :func:`cvsflow.mocap.bodies.fit_bodies`; ``poses_raw``
from the true T_C_B with rotation and position noise and a share of frames without a board.
"""

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.geometry.transforms import (
    T_from_pose6,
    invert_T,
    make_T,
    pose6_from_T,
    rvec_tvec_from_T,
    transform_points,
)
from cvsflow.mocap.bodies import fit_bodies

RATE_HZ = 300.0
FPS = 30.0
DT_OFFSET_S = 2.3712
BOARD_NAMES = ["board:B1", "board:B2", "board:B3", "board:B4"]
CAMERA_NAMES = ["camera:C1", "camera:C2", "camera:C3", "camera:C4"]
BOARD_LAYOUT_M = np.array([[0.0, 0.0, 0.0], [0.76, 0.0, 0.0], [0.0, 0.52, 0.0], [0.58, 0.5, 0.0]])
CAMERA_LAYOUT_M = np.array([[0.0, 0.0, 0.0], [0.0, 0.16, 0.0], [0.0, 0.0, 0.12], [0.0, 0.11, 0.17]])
SPECS = {
    "camera": {"names": CAMERA_NAMES, "layout_m": CAMERA_LAYOUT_M},
    "board": {"names": BOARD_NAMES, "layout_m": BOARD_LAYOUT_M},
}
T_W_CM = make_T(Rotation.from_rotvec([0.05, -0.1, 1.6]).as_matrix(), [0.2, -1.5, 1.0])
T_CM_C = T_from_pose6([0.03, -0.02, 0.05, -1.5708, 0.0, -1.5708])
T_BM_B = T_from_pose6([0.1, 0.07, -0.004, 3.1416, 0.0, 0.0])


def board_motion(t_s, seed=0, still_s=1.0):
    """True T_W_Bm (N, 4, 4): still, a forward tilt (25 deg, 0.8 s), then hand-like motion."""
    rng = np.random.default_rng(seed)
    tau = t_s - still_s
    tilt = np.where((tau > 0) & (tau < 0.8), np.radians(25.0) * np.sin(np.pi * np.clip(tau, 0, 0.8) / 0.8) ** 2, 0.0)
    free = np.clip(tau - 1.0, 0.0, None)
    ramp = np.clip(free, 0.0, 1.0)
    rotvec = np.zeros((len(t_s), 3))
    pos = np.zeros((len(t_s), 3))
    for a in range(3):
        for _ in range(3):
            f = rng.uniform(0.2, 1.2)
            ph = rng.uniform(0, 2 * np.pi)
            rotvec[:, a] += ramp * 0.15 * (np.sin(2 * np.pi * f * free + ph) - np.sin(ph))
            pos[:, a] += ramp * 0.08 * (np.sin(2 * np.pi * rng.uniform(0.2, 1.0) * free + ph) - np.sin(ph))
    rotvec[:, 0] += tilt
    R_Cm_Bm0 = Rotation.from_euler("xyz", [0.0, 0.0, np.pi]).as_matrix()
    T_Cm_Bm = make_T(R_Cm_Bm0 @ Rotation.from_rotvec(rotvec).as_matrix(), pos + [0.4, 0.3, 1.5])
    return T_W_CM @ T_Cm_Bm


def make_session(duration_video_s=12.0, lead_s=DT_OFFSET_S, tail_s=1.0, noise_m=0.0003,
                 rot_noise_rad=np.radians(0.1), pos_noise_m=0.001, drop_frac=0.05, seed=0,
                 fps=FPS):
    """Synthetic Vicon bodies (via markers and fit_bodies) and poses_raw with known offset."""
    rng = np.random.default_rng(seed)
    n_v = int(round((lead_s + duration_video_s + tail_s) * RATE_HZ))
    t_v = np.arange(n_v) / RATE_HZ
    # the gesture happens in the video at 1 s + tilt: put the still start before the video starts
    T_W_Bm = board_motion(t_v, seed=seed, still_s=lead_s + 1.0)
    data = {"frame": np.arange(n_v), "t_s": t_v}
    for names, layout, T in ((CAMERA_NAMES, CAMERA_LAYOUT_M, np.broadcast_to(T_W_CM, (n_v, 4, 4))),
                             (BOARD_NAMES, BOARD_LAYOUT_M, T_W_Bm)):
        for name, pt in zip(names, layout, strict=True):
            xyz = transform_points(T, pt) + rng.normal(0, noise_m, (n_v, 3))
            for a, ax in enumerate("xyz"):
                data[f"{name}_{ax}_m"] = xyz[:, a]
    markers = pd.DataFrame(data)
    markers.attrs["rate_hz"] = RATE_HZ
    bodies = fit_bodies(markers, SPECS)
    n_f = int(round(duration_video_s * fps))
    t_video = np.arange(n_f) / fps
    T_true = invert_T(T_CM_C) @ invert_T(T_W_CM) @ board_motion(t_video + lead_s, seed=seed, still_s=lead_s + 1.0) @ T_BM_B
    dR = Rotation.from_rotvec(rng.normal(0, rot_noise_rad, (n_f, 3))).as_matrix()
    T_noisy = make_T(T_true[:, :3, :3] @ dR, T_true[:, :3, 3] + rng.normal(0, pos_noise_m, (n_f, 3)))
    rvec, tvec = rvec_tvec_from_T(T_noisy)
    valid = rng.uniform(size=n_f) > drop_frac
    rpy = pose6_from_T(T_noisy)[:, 3:]
    poses = pd.DataFrame({
        "frame": np.arange(n_f), "t_s": t_video, "valid": valid,
        "rvec_0": rvec[:, 0], "rvec_1": rvec[:, 1], "rvec_2": rvec[:, 2],
        "x_m": tvec[:, 0], "y_m": tvec[:, 1], "z_m": tvec[:, 2],
        "roll_rad": rpy[:, 0], "pitch_rad": rpy[:, 1], "yaw_rad": rpy[:, 2],
        "reproj_rms_px": 0.2, "n_inliers": 20,
    })
    poses.loc[~valid, ["rvec_0", "rvec_1", "rvec_2", "x_m", "y_m", "z_m"]] = np.nan
    return poses, bodies, T_true

