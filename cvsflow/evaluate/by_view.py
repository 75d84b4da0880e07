"""The held-out error against the board's distance and its tilt (a diagnostic of the report).

A camera's pose error grows with the board's distance (depth error about as distance squared
for a fixed board) and changes with the board's tilt (a board facing the camera has a weakly
determined tilt); the RMS per axis in bins of each says where a session's accuracy comes from.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow.geometry import R_from_quat
from cvsflow.metrics import ERROR_DIMS, error_columns


def view_geometry(frames: pd.DataFrame) -> pd.DataFrame:
    """Distance and tilt of the board per frame, from the reference pose T_C_B.

    Parameters
    ----------
    frames : DataFrame
        ``ref_x_m, ref_y_m, ref_z_m`` (m) and ``ref_qx .. ref_qw`` (scalar last): the reference
        board pose in the camera frame C per frame (``heldout/se3.parquet``).

    Returns
    -------
    DataFrame
        ``distance_m``: the board origin's distance from the camera (m); ``tilt_rad``: the angle
        between the board's normal and the camera's optical axis (rad, 0 when the board faces
        the camera, in [0, pi/2]).
    """
    t = frames[["ref_x_m", "ref_y_m", "ref_z_m"]].to_numpy(float)
    R = R_from_quat(frames[["ref_qx", "ref_qy", "ref_qz", "ref_qw"]].to_numpy(float))
    # the board's z axis in C is R[:, :, 2]; its angle with C's z axis, either side of the board
    cos_tilt = np.clip(np.abs(R[:, 2, 2]), 0.0, 1.0)
    return pd.DataFrame({"distance_m": np.linalg.norm(t, axis=1), "tilt_rad": np.arccos(cos_tilt)},
                        index=frames.index)


def errors_by_view(frames: pd.DataFrame, n_bins: int = 6, min_count: int = 10) -> pd.DataFrame:
    """RMS error per axis in bins of the board's distance and of its tilt.

    Parameters
    ----------
    frames : DataFrame
        The held-out table: ``err_x_m .. err_yaw_rad`` (SI) and the reference pose of
        :func:`view_geometry`.
    n_bins : int
        Bins per quantity, of equal counts (quantiles), so every bin holds about as many frames.
    min_count : int
        Bins with fewer valid frames are left out.

    Returns
    -------
    DataFrame
        One row per (``by``, bin): ``by`` (``distance_m`` or ``tilt_rad``), ``lo``, ``hi``,
        ``centre`` (the bin's median, in the unit of ``by``), ``n``, then the RMS of each error
        dimension under its name in :data:`cvsflow.metrics.ERROR_DIMS` (SI).
    """
    view = view_geometry(frames)
    err = frames[error_columns()].to_numpy(float)
    rows = []
    for by in ("distance_m", "tilt_rad"):
        x = view[by].to_numpy(float)
        ok = np.isfinite(x) & np.isfinite(err).all(axis=1)
        if ok.sum() < min_count:
            continue
        edges = np.unique(np.quantile(x[ok], np.linspace(0.0, 1.0, n_bins + 1)))
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
        for b in range(len(edges) - 1):
            sel = ok & (idx == b)
            if sel.sum() < min_count:
                continue
            row = {"by": by, "lo": edges[b], "hi": edges[b + 1], "centre": float(np.median(x[sel])),
                   "n": int(sel.sum())}
            row.update({d: float(np.sqrt(np.mean(err[sel, k] ** 2))) for k, d in enumerate(ERROR_DIMS)})
            rows.append(row)
    return pd.DataFrame(rows, columns=["by", "lo", "hi", "centre", "n", *ERROR_DIMS])
