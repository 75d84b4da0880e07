"""The per-frame poses table of a camera whose poses come as a stream (a detector's output).

A session whose camera input is a camera-pose stream (``camera_poses``: the camera's pose in the
target frame per timestamp, as a target detector writes it) has no images: its poses table
(poses_raw.parquet, the columns :func:`cvsflow.calibration.pnp.estimate_poses` writes) is the
stream itself, the board in the camera ``T_C_B = T_B_C^-1`` per row, its times exact.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow.calibration.pnp import POSE_COLUMNS
from cvsflow.exceptions import InputError
from cvsflow.geometry import transforms as tf

log = logging.getLogger(__name__)


def poses_from_stream(t_ns, T_B_C, source: str = "camera pose stream") -> pd.DataFrame:
    """poses_raw.parquet of a camera-pose stream.

    Parameters
    ----------
    t_ns : array_like of int64, shape (N,)
        The poses' times, camera clock, ns, strictly increasing.
    T_B_C : ndarray, shape (N, 4, 4)
        The camera in the target frame B per row, m.
    source : str
        The stream's name, for messages.

    Returns
    -------
    poses : DataFrame
        :data:`cvsflow.calibration.pnp.POSE_COLUMNS` with ``t_ns`` (int64, exact) after
        ``t_s = t_ns / 1e9``: ``frame`` 0..N-1, ``valid`` True where the pose is finite,
        ``rvec_*``, ``x_m..z_m`` and ``roll/pitch/yaw_rad`` of ``T_C_B``; ``reproj_rms_px``
        NaN, ``n_inliers`` and ``n_corners`` 0 (no corners behind a streamed pose).

    Raises
    ------
    InputError
        Shapes that do not match, or times not strictly increasing (the first such row named).
    """
    t_ns = np.asarray(t_ns, np.int64)
    T = np.asarray(T_B_C, float)
    if T.shape != (len(t_ns), 4, 4):
        raise InputError(f"{source}: {len(t_ns)} times and poses of shape {T.shape}; expected (N, 4, 4)")
    back = np.flatnonzero(np.diff(t_ns) <= 0)
    if back.size:
        raise InputError(f"{source}: row {back[0] + 1} at {t_ns[back[0] + 1]} ns does not follow row "
                         f"{back[0]} at {t_ns[back[0]]} ns; expected strictly increasing times")  # fmt: skip
    valid = np.isfinite(T).all(axis=(1, 2))
    T_C_B = tf.invert_T(np.where(valid[:, None, None], T, np.eye(4)))
    rvec = tf.rvec_from_R(T_C_B[:, :3, :3]).reshape(-1, 3)
    rpy = tf.euler_from_R(T_C_B[:, :3, :3]).reshape(-1, 3)
    poses = pd.DataFrame({"frame": np.arange(len(t_ns), dtype=np.int64), "t_s": t_ns / 1e9, "valid": valid})
    for k in range(3):
        poses[f"rvec_{k}"] = rvec[:, k]
    for k, a in enumerate(("x_m", "y_m", "z_m")):
        poses[a] = T_C_B[:, k, 3]
    for k, a in enumerate(("roll_rad", "pitch_rad", "yaw_rad")):
        poses[a] = rpy[:, k]
    poses["reproj_rms_px"] = np.nan
    poses["n_inliers"] = np.int64(0)
    poses["n_corners"] = np.int64(0)
    poses = poses[POSE_COLUMNS]
    poses.loc[~valid, POSE_COLUMNS[3:12]] = np.nan
    poses.insert(2, "t_ns", t_ns)
    log.info("%s: %d poses (%d valid) as the poses table", source, len(poses), int(valid.sum()))
    return poses
