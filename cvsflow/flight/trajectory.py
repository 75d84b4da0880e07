"""Flight trajectories: the common form, reading the reference from PnP poses, resampling.

Trajectories are DataFrames in the common form of :mod:`cvsflow.io.flightlog` (``t_s, x_m,
y_m, z_m, qx, qy, qz, qw, pos_valid, rot_valid``); frames and clocks as in
:mod:`cvsflow.flight`. Association of stamps follows evo's ``nearest_time`` rule.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import InputError, SyncError
from cvsflow.geometry import R_from_quat, interpolate_quats, make_T, quat_from_R

TRAJ_COLS = ["t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]


# --------------------------------------------------------------------------------------------
# Trajectory form
# --------------------------------------------------------------------------------------------


def check_trajectory(df: pd.DataFrame, name: str = "trajectory") -> pd.DataFrame:
    """Validate the common trajectory form; add missing validity columns (True where finite).

    Parameters
    ----------
    df : DataFrame
        A trajectory with at least ``TRAJ_COLS`` (``t_s`` s, ``x_m..z_m`` m, ``qx..qw``
        scalar-last).
    name : str, default "trajectory"
        What it is (file, role), for the error messages.

    Returns
    -------
    DataFrame
        A copy (``attrs`` kept) with ``pos_valid`` / ``rot_valid`` added where absent: True
        where the position / quaternion is all finite.

    Raises
    ------
    InputError
        A column is missing or times are not increasing (the message names ``name`` and row).
    """
    missing = [c for c in TRAJ_COLS if c not in df.columns]
    if missing:
        raise InputError(f"{name}: missing column(s) {missing}; expected {TRAJ_COLS}")
    out = df.copy()
    out.attrs = dict(df.attrs)
    if "pos_valid" not in out:
        out["pos_valid"] = np.isfinite(out[["x_m", "y_m", "z_m"]]).all(axis=1)
    if "rot_valid" not in out:
        out["rot_valid"] = np.isfinite(out[["qx", "qy", "qz", "qw"]]).all(axis=1)
    t = out["t_s"].to_numpy(dtype=float)
    bad = np.flatnonzero(~(np.diff(t) > 0))
    if len(bad):
        raise InputError(
            f"{name}: t_s not strictly increasing at row {int(bad[0]) + 1} (0-based): "
            f"{float(t[bad[0] + 1])!r} s after {float(t[bad[0]])!r} s; expected increasing times"
        )
    return out


def T_from_traj(df: pd.DataFrame) -> np.ndarray:
    """Transforms of a trajectory's rows, shape (N, 4, 4); invalid parts stay NaN.

    Parameters
    ----------
    df : DataFrame
        Common trajectory form (e.g. T_L_Q or T_C_B rows), m and scalar-last quaternions.

    Returns
    -------
    T : ndarray, shape (N, 4, 4)
        The row poses, m; the rotation block is NaN where the quaternion is not finite, the
        translation NaN where the position is (validity flags are not applied).
    """
    q = df[["qx", "qy", "qz", "qw"]].to_numpy(dtype=float)
    p = df[["x_m", "y_m", "z_m"]].to_numpy(dtype=float)
    R = np.full((len(df), 3, 3), np.nan)
    ok = np.isfinite(q).all(1)
    if ok.any():
        R[ok] = R_from_quat(q[ok])
    return make_T(R, p)


def trajectory_frame(t_s, p_m, q_xyzw, pos_valid, rot_valid, **extra) -> pd.DataFrame:
    """The common trajectory form from times (N,), positions (N, 3, metres) and scalar-last
    quaternions (N, 4) with their validity flags; ``extra`` columns are appended.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Times, s.
    p_m : array_like, shape (N, 3)
        Positions, m.
    q_xyzw : array_like, shape (N, 4)
        Orientations, scalar-last quaternions.
    pos_valid, rot_valid : bool or array_like of bool, shape (N,)
        Validity flags (a scalar is broadcast).
    **extra
        Further columns, each of length N.

    Returns
    -------
    DataFrame
        ``t_s, x_m, y_m, z_m, qx, qy, qz, qw, pos_valid, rot_valid`` then ``extra``.
    """
    p = np.asarray(p_m, dtype=float)
    q = np.asarray(q_xyzw, dtype=float)
    n = len(p)
    return pd.DataFrame(
        {
            "t_s": np.asarray(t_s, dtype=float),
            "x_m": p[:, 0], "y_m": p[:, 1], "z_m": p[:, 2],
            "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2], "qw": q[:, 3],
            "pos_valid": np.broadcast_to(np.asarray(pos_valid, bool), n).copy(),
            "rot_valid": np.broadcast_to(np.asarray(rot_valid, bool), n).copy(),
            **extra,
        }
    )  # fmt: skip


def traj_from_T(t_s, T, pos_valid=None, rot_valid=None, attrs=None) -> pd.DataFrame:
    """Common trajectory form from times (N,) and transforms (N, 4, 4).

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Times, s.
    T : array_like, shape (N, 4, 4)
        Poses, m; NaN rotation or translation blocks where unknown.
    pos_valid, rot_valid : array_like of bool, shape (N,), optional
        Validity flags; default: the translation / rotation is finite.
    attrs : dict, optional
        Copied into the result's ``attrs``.

    Returns
    -------
    DataFrame
        Common trajectory form; the quaternion NaN where the rotation is not finite.
    """
    T = np.asarray(T, dtype=float)
    R = T[:, :3, :3]
    ok = np.isfinite(R).all((1, 2))
    q = np.full((len(T), 4), np.nan)
    if ok.any():
        q[ok] = quat_from_R(R[ok])
    p = T[:, :3, 3]
    df = trajectory_frame(
        t_s, p, q,
        np.isfinite(p).all(1) if pos_valid is None else pos_valid,
        ok if rot_valid is None else rot_valid,
    )  # fmt: skip
    df.attrs = dict(attrs or {})
    return df


def reference_from_poses(poses_raw: pd.DataFrame, corners: pd.DataFrame | None = None,
                         line_delay_s: float = 0.0) -> pd.DataFrame:
    """Camera reference T_C_B in the common form from poses_raw.parquet (rvec_C_B, tvec_C_B).

    Parameters
    ----------
    poses_raw : DataFrame
        ``frame, t_s, valid, rvec_0..2, x_m, y_m, z_m`` (contracts.md).
    corners : DataFrame, optional
        corners.parquet of the same video; needed with ``line_delay_s``.
    line_delay_s : float
        A rolling shutter's line delay, s per row (the se3 result's ``line_delay_s``). A frame's
        rows are exposed one after another, so its PnP pose is the board's at the time of the
        rows it covers: each frame's time becomes ``t_s + line_delay_s * (mean image row of its
        found corners)``, as se3 times it (``se3_apply``). 0: a global shutter, ``t_s`` as is.

    Returns
    -------
    DataFrame
        Common form plus ``frame``; rows not ``valid`` have ``pos_valid = rot_valid = False``.

    Raises
    ------
    InputError
        A line delay without the corners table.
    """
    rv = poses_raw[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(dtype=float)
    valid = poses_raw["valid"].to_numpy(dtype=bool) & np.isfinite(rv).all(1)
    R = np.full((len(rv), 3, 3), np.nan)
    if valid.any():
        R[valid] = Rotation.from_rotvec(rv[valid]).as_matrix()
    T = make_T(R, poses_raw[["x_m", "y_m", "z_m"]].to_numpy(dtype=float))
    t_s = poses_raw["t_s"].to_numpy(dtype=float)
    if line_delay_s:
        if corners is None:
            raise InputError("reference_from_poses: a line delay needs the corners table "
                             "(the rows each frame's board covers)")
        found = corners[corners["found"]]
        row = found.groupby("frame")["v_px"].mean()
        mean_row = row.reindex(poses_raw["frame"].to_numpy()).to_numpy(dtype=float)
        t_s = t_s + float(line_delay_s) * np.nan_to_num(mean_row, nan=0.0)
    attrs = {"source": "poses_raw"}
    if line_delay_s:
        attrs["line_delay_s"] = float(line_delay_s)
    df = traj_from_T(t_s, T, valid, valid, attrs)
    df.insert(0, "frame", poses_raw["frame"].to_numpy())
    return df


def interpolate_trajectory(df: pd.DataFrame, t_s, max_gap_s: float = 0.1) -> pd.DataFrame:
    """Trajectory at times ``t_s``: positions linearly, orientations by SLERP.

    A sample is valid only between two valid samples at most ``max_gap_s`` apart (or exactly
    on a valid sample); no extrapolation.

    Parameters
    ----------
    df : DataFrame
        Common trajectory form, times increasing.
    t_s : array_like, shape (M,)
        Query times on the same clock, seconds.
    max_gap_s : float
        Longest gap bridged, seconds.

    Returns
    -------
    DataFrame
        Common form at ``t_s`` (M rows).
    """
    t_q = np.asarray(t_s, dtype=float)
    t = df["t_s"].to_numpy(dtype=float)
    out = np.full((len(t_q), 7), np.nan)
    pv = df["pos_valid"].to_numpy(bool)
    rv = df["rot_valid"].to_numpy(bool)
    pos_ok = np.zeros(len(t_q), bool)
    rot_ok = np.zeros(len(t_q), bool)
    for valid, is_pos in ((pv, True), (rv, False)):
        tv = t[valid]
        if len(tv) < 2:
            continue
        i = np.clip(np.searchsorted(tv, t_q, side="right"), 1, len(tv) - 1)
        t0, t1 = tv[i - 1], tv[i]
        ok = (t_q >= tv[0]) & (t_q <= tv[-1]) & ((t1 - t0) <= max_gap_s)
        ok |= np.isin(t_q, tv)
        if not ok.any():
            continue
        if is_pos:
            p = df[["x_m", "y_m", "z_m"]].to_numpy(dtype=float)[valid]
            w = ((t_q - t0) / np.where(t1 > t0, t1 - t0, 1.0))[:, None]
            out[ok, 0:3] = ((1 - w) * p[i - 1] + w * p[i])[ok]
            pos_ok = ok
        else:
            q = df[["qx", "qy", "qz", "qw"]].to_numpy(dtype=float)[valid]
            qq, _ = interpolate_quats(tv, q, np.ones(len(tv), bool), np.clip(t_q[ok], tv[0], tv[-1]))
            out[ok, 3:7] = np.where(qq[:, 3:4] < 0, -qq, qq)
            rot_ok = ok
    res = pd.DataFrame(out, columns=TRAJ_COLS[1:])
    res.insert(0, "t_s", t_q)
    res["pos_valid"] = pos_ok
    res["rot_valid"] = rot_ok
    res.attrs = dict(df.attrs)
    return res


# --------------------------------------------------------------------------------------------
# Association (evo's nearest_time rule)
# --------------------------------------------------------------------------------------------


def associate(t_ref, t_est, max_diff_s: float = 0.01, offset_s: float = 0.0):
    """Match timestamps as evo's ``sync.associate_trajectories`` does.

    Each stamp of the *shorter* series (the estimate's stamps shifted by ``offset_s``) is
    matched to the nearest stamp of the longer one; a match is kept when the gap is at most
    ``max_diff_s``. A stamp of the longer series may be used twice; on a tie the earlier stamp
    wins (``numpy.argmin``).

    Parameters
    ----------
    t_ref, t_est : array_like, shapes (N,), (M,)
        Reference and estimate stamps, seconds; each sorted increasing.
    max_diff_s : float
        Largest accepted time difference, seconds (evo default 0.01).
    offset_s : float
        Added to the estimate's stamps before matching (evo ``--t_offset``).

    Returns
    -------
    i_ref, i_est : ndarray of int, shape (K,)
        Indices of the associated pairs, in the order of the shorter series.

    Raises
    ------
    SyncError
        No pair within ``max_diff_s``.
    """
    t_ref = np.asarray(t_ref, dtype=float)
    t_est = np.asarray(t_est, dtype=float) + offset_s
    est_longer = len(t_est) > len(t_ref)
    short, long_ = (t_ref, t_est) if est_longer else (t_est, t_ref)
    if len(long_) == 0 or len(short) == 0:
        raise SyncError("associate: an empty trajectory")
    order = np.argsort(long_, kind="stable")
    ls = long_[order]
    j = (
        np.clip(np.searchsorted(ls, short, side="left"), 1, len(ls) - 1)
        if len(ls) > 1
        else np.zeros(len(short), int)
    )
    if len(ls) > 1:
        d_lo = np.abs(short - ls[j - 1])
        d_hi = np.abs(short - ls[j])
        pick = np.where(d_lo <= d_hi, j - 1, j)
        # the first of equal stamps, like argmin on the unsorted long series
        pick = np.searchsorted(ls, ls[pick], side="left")
    else:
        pick = j
    diff = np.abs(short - ls[pick])
    keep = diff <= max_diff_s
    i_short = np.flatnonzero(keep)
    i_long = order[pick[keep]]
    if len(i_short) == 0:
        raise SyncError(
            f"associate: no pair of stamps within {max_diff_s} s (offset {offset_s} s); "
            f"reference spans {t_ref.min():.6f}..{t_ref.max():.6f} s, estimate "
            f"{t_est.min():.6f}..{t_est.max():.6f} s"
        )
    return (i_short, i_long) if est_longer else (i_long, i_short)
