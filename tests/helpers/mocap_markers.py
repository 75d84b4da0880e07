"""Synthetic marker tables of the camera and board bodies at 300 Hz with their true poses.

Shared by test_mocap_layout.py, test_mocap_repair.py and test_mocap.py.
"""

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.geometry.transforms import make_T, transform_points

RATE_HZ = 300.0
BOARD_LAYOUT_M = np.array([[0.0, 0.0, 0.0], [0.76, 0.0, 0.0], [0.0, 0.52, 0.0], [0.58, 0.5, 0.0]])
CAMERA_LAYOUT_M = np.array([[0.0, 0.0, 0.0], [0.0, 0.16, 0.0], [0.0, 0.0, 0.12], [0.0, 0.11, 0.17]])
BOARD_NAMES = ["board:B1", "board:B2", "board:B3", "board:B4"]
CAMERA_NAMES = ["camera:C1", "camera:C2", "camera:C3", "camera:C4"]


def body_specs(learn=False):
    """Body specs of both bodies: the true layouts, or None to have them learned."""
    return {
        "camera": {"names": CAMERA_NAMES, "layout_m": None if learn else CAMERA_LAYOUT_M},
        "board": {"names": BOARD_NAMES, "layout_m": None if learn else BOARD_LAYOUT_M},
    }


def board_motion(t_s, still_s=0.0):
    """True T_W_Bm (N, 4, 4): smooth hand-like motion, still for the first still_s seconds."""
    tau = np.clip(t_s - still_s, 0.0, None)
    rotvec = np.stack(
        [0.5 * np.sin(1.3 * tau), 0.35 * np.sin(0.9 * tau + 0.4), 0.3 * np.sin(0.7 * tau + 1.0)],
        axis=1,
    )
    pos = np.stack(
        [1.0 + 0.3 * np.sin(0.8 * tau), 0.2 * np.sin(1.1 * tau), 1.2 + 0.15 * np.sin(0.6 * tau)],
        axis=1,
    )
    return make_T(Rotation.from_rotvec(rotvec).as_matrix(), pos)


def camera_pose():
    """True T_W_Cm (4, 4), fixed."""
    return make_T(Rotation.from_rotvec([0.05, -0.1, 0.2]).as_matrix(), [-0.5, 0.1, 1.0])


def synthetic_markers(duration_s=4.0, noise_m=0.0, seed=0, still_s=0.0):
    """Marker table of both bodies at 300 Hz with their true poses."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * RATE_HZ))
    frame = np.arange(n)
    t_s = frame / RATE_HZ
    T_W_Bm = board_motion(t_s, still_s)
    T_W_Cm = np.broadcast_to(camera_pose(), (n, 4, 4))
    data = {"frame": frame, "t_s": t_s}
    for names, layout, T in ((CAMERA_NAMES, CAMERA_LAYOUT_M, T_W_Cm), (BOARD_NAMES, BOARD_LAYOUT_M, T_W_Bm)):
        for name, p in zip(names, layout, strict=True):
            xyz = transform_points(T, p) + rng.normal(0.0, noise_m, (n, 3))
            for a, axis in enumerate("xyz"):
                data[f"{name}_{axis}_m"] = xyz[:, a]
    df = pd.DataFrame(data)
    df.attrs["rate_hz"] = RATE_HZ
    df.attrs["markers"] = CAMERA_NAMES + BOARD_NAMES
    return df, T_W_Cm, T_W_Bm
