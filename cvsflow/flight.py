"""Flight sessions: a quadcopter's on-board pose error measured against the camera reference.

Frames (in addition to design.md's W, C, Cm, B, Bm)
---------------------------------------------------
- ``L``: the on-board estimator's local world frame (PX4: NED; any right-handed frame).
- ``Q``: the quadcopter body frame of the estimate (PX4: FRD).
- ``C``: the camera optical frame, the reference's world; ``B``: the board, fixed on Q by the
  constant mounting ``T_Q_B``.

The reference measures ``T_C_B`` per video frame; its body pose is ``T_C_Q = T_C_B inv(T_Q_B)``.
The log gives ``T_L_Q`` on its own clock. Clock convention (as ``t_vicon_s = t_video_s +
dt_offset_s`` in contracts.md): ``t_ref_s = dt_offset_s + (1 + skew) * t_log_s``.
Frame alignment finds ``T_C_L`` (optionally a similarity with scale ``s``):
``p_C = s R_C_L p_L + t_C_L``.

Errors are on-board minus reference. Per-axis errors are expressed in the axes of L (the
frame a flight engineer reads: north/east/down for PX4) in the reference's metres:
``e_p = R_C_L^T (p_est,C - p_ref,C)``, and attitude errors as wrapped differences of
roll/pitch/yaw of ``R_L_Q`` (R = Rz(yaw) Ry(pitch) Rx(roll)).

Trajectories are DataFrames in the common form of :mod:`cvsflow.io.flightlog` (``t_s, x_m,
y_m, z_m, qx, qy, qz, qw, pos_valid, rot_valid``). No file I/O here.

Reference uncertainty: ``Sigma_ref`` (N, 6, 6) is the covariance of the reference's error
``[dt, dtheta]`` on T_C_B, with ``t_meas = t_true + dt`` (metres, in C) and
``R_meas = Exp(dtheta) R_true`` (radians, left perturbation, in C).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import least_squares
from scipy.signal import correlate, correlation_lags
from scipy.spatial.transform import Rotation, Slerp

from cvsflow import uncertainty as un
from cvsflow.errors import InputError, OptimiseError, SyncError
from cvsflow.geometry.camera import INTRINSIC_NAMES
from cvsflow.optimise.se3_cov import DEFAULT_INTRINSIC_STD
from cvsflow.transforms import (
    R_from_quat,
    euler_from_R,
    invert_T,
    make_T,
    mean_rotation,
    quat_from_R,
    rotation_angle,
    wrap_angle,
)
from cvsflow.transforms import (
    skew as skew_matrix,
)
from cvsflow.uncertainty import error_covariance, pnp_covariance

log = logging.getLogger(__name__)

TRAJ_COLS = ["t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]
AXES = ["x", "y", "z", "roll", "pitch", "yaw"]
ERR_COLS = ["ex_m", "ey_m", "ez_m", "eroll_rad", "epitch_rad", "eyaw_rad"]
SIG_COLS = ["sx_m", "sy_m", "sz_m", "sroll_rad", "spitch_rad", "syaw_rad"]


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


def reference_from_poses(poses_raw: pd.DataFrame) -> pd.DataFrame:
    """Camera reference T_C_B in the common form from poses_raw.parquet (rvec_C_B, tvec_C_B).

    Parameters
    ----------
    poses_raw : DataFrame
        ``frame, t_s, valid, rvec_0..2, x_m, y_m, z_m`` (contracts.md).

    Returns
    -------
    DataFrame
        Common form plus ``frame``; rows not ``valid`` have ``pos_valid = rot_valid = False``.
    """
    rv = poses_raw[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(dtype=float)
    valid = poses_raw["valid"].to_numpy(dtype=bool) & np.isfinite(rv).all(1)
    R = np.full((len(rv), 3, 3), np.nan)
    if valid.any():
        R[valid] = Rotation.from_rotvec(rv[valid]).as_matrix()
    T = make_T(R, poses_raw[["x_m", "y_m", "z_m"]].to_numpy(dtype=float))
    df = traj_from_T(poses_raw["t_s"], T, valid, valid, {"source": "poses_raw"})
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
            slerp = Slerp(tv, Rotation.from_quat(q))
            qq = slerp(np.clip(t_q[ok], tv[0], tv[-1])).as_quat()
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


# --------------------------------------------------------------------------------------------
# Frame alignment
# --------------------------------------------------------------------------------------------


@dataclass
class Alignment:
    """A similarity ``p_ref = s R p_est + t`` mapping the estimate's world into the reference's.

    Attributes
    ----------
    T_ref_est : ndarray, shape (4, 4)
        Rigid part (R, t); for flights this is T_C_L.
    scale : float
        s (1 for SE(3) and yaw-only).
    method : str
        ``se3``, ``sim3``, ``yaw`` or ``given``.
    """

    T_ref_est: np.ndarray
    scale: float = 1.0
    method: str = "se3"

    def apply_points(self, p_est):
        """Map points (N, 3) from the estimate's world into the reference's."""
        R, t = self.T_ref_est[:3, :3], self.T_ref_est[:3, 3]
        return self.scale * (np.asarray(p_est, float) @ R.T) + t

    def apply_T(self, T_est):
        """Map poses (N, 4, 4) of the estimate into the reference world (positions scaled)."""
        T = np.array(T_est, dtype=float)
        T[:, :3, 3] = self.apply_points(T[:, :3, 3])
        T[:, :3, :3] = self.T_ref_est[:3, :3] @ T[:, :3, :3]
        return T


def _check_points(p_ref, p_est, n_min):
    """Shapes and finiteness of two point sets, n_min points at least."""
    p_ref = np.asarray(p_ref, dtype=float)
    p_est = np.asarray(p_est, dtype=float)
    if p_ref.shape != p_est.shape or p_ref.ndim != 2 or p_ref.shape[1] != 3:
        raise OptimiseError(
            f"alignment: point sets of shapes {p_ref.shape} and {p_est.shape}; "
            "expected two (N, 3) arrays"
        )
    if not (np.isfinite(p_ref).all() and np.isfinite(p_est).all()):
        raise OptimiseError("alignment: non-finite points; pass valid pairs only")
    if len(p_ref) < n_min:
        raise OptimiseError(f"alignment: {len(p_ref)} point pairs; at least {n_min} needed")
    return p_ref, p_est


def umeyama(p_ref, p_est, with_scale: bool = False) -> Alignment:
    """Least-squares similarity (or rigid) transform from estimate to reference points.

    Parameters
    ----------
    p_ref, p_est : ndarray, shape (N, 3)
        Associated positions, reference world and estimate world, metres.
    with_scale : bool
        Sim(3) when True, SE(3) otherwise.

    Returns
    -------
    Alignment
        ``p_ref ≈ s R p_est + t``.

    Raises
    ------
    OptimiseError
        Fewer than 3 pairs, non-finite values, or points all on one spot.

    Notes
    -----
    Umeyama, "Least-squares estimation of transformation parameters between two point
    patterns", IEEE TPAMI 13(4), 1991, eqs. 38-42; the same formulae as evo's
    ``core.geometry.umeyama_alignment``.
    """
    y, x = _check_points(p_ref, p_est, 3)
    n = len(x)
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    sigma_x = np.sum(xc**2) / n  # eq. 36
    if sigma_x <= 0:
        raise OptimiseError("alignment: all estimate points coincide; nothing to align")
    cov = yc.T @ xc / n  # eq. 38
    U, d, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:  # eq. 39
        S[2, 2] = -1
    R = U @ S @ Vt  # eq. 40
    s = float(np.trace(np.diag(d) @ S) / sigma_x) if with_scale else 1.0  # eq. 42
    t = my - s * R @ mx  # eq. 41
    return Alignment(make_T(R, t), s, "sim3" if with_scale else "se3")


def _R_between(a, b):
    """Smallest rotation taking unit vector a onto unit vector b, shape (3, 3)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        if c > 0:
            return np.eye(3)
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return Rotation.from_rotvec(np.pi * axis / np.linalg.norm(axis)).as_matrix()
    return Rotation.from_rotvec(
        v / np.linalg.norm(v) * np.arctan2(np.linalg.norm(v), c)
    ).as_matrix()


def align_yaw(p_ref, p_est, z_est_in_ref=(0.0, 0.0, 1.0)) -> Alignment:
    """Four-DoF alignment: a rotation about the vertical only, plus a translation.

    For estimators whose roll and pitch are observable (gravity), only the heading and the
    origin of their world are arbitrary.

    Parameters
    ----------
    p_ref, p_est : ndarray, shape (N, 3)
        Associated positions, metres.
    z_est_in_ref : array_like, shape (3,)
        Direction of the estimate world's z axis expressed in the reference world (known
        from levelling; default: the two z axes coincide).

    Returns
    -------
    Alignment
        ``R = Rot(z_est_in_ref, psi) R0`` with R0 the smallest rotation taking e_z onto
        ``z_est_in_ref``; psi and t in closed form (least squares).

    Raises
    ------
    OptimiseError
        Fewer than 2 pairs or non-finite values.
    """
    y, x = _check_points(p_ref, p_est, 2)
    R0 = _R_between(np.array([0.0, 0.0, 1.0]), np.asarray(z_est_in_ref, dtype=float))
    yl = y @ R0  # reference points in a frame whose z is the estimate's z: R0^T y
    xc, yc = x - x.mean(0), yl - yl.mean(0)
    # minimise sum |yc - Rz(psi) xc|^2 -> psi = atan2(sum(x*y' - y*x'), sum(x*x' + y*y'))
    psi = np.arctan2(
        np.sum(xc[:, 0] * yc[:, 1] - xc[:, 1] * yc[:, 0]),
        np.sum(xc[:, 0] * yc[:, 0] + xc[:, 1] * yc[:, 1]),
    )
    Rz = Rotation.from_euler("z", psi).as_matrix()
    R = R0 @ Rz
    t = y.mean(0) - R @ x.mean(0)
    return Alignment(make_T(R, t), 1.0, "yaw")


def align_trajectories(p_ref, p_est, method: str = "se3", z_est_in_ref=(0.0, 0.0, 1.0)):
    """Dispatch to :func:`umeyama` (``se3``, ``sim3``) or :func:`align_yaw` (``yaw``).

    Parameters
    ----------
    p_ref, p_est : ndarray, shape (N, 3)
        Associated positions of the reference and the estimate, each in its own world, m.
    method : {"se3", "sim3", "yaw"}, default "se3"
        Rigid, rigid plus scale, or rotation about the vertical plus translation.
    z_est_in_ref : array_like, shape (3,), default (0, 0, 1)
        ``yaw`` only: the estimate world's z axis in the reference world.

    Returns
    -------
    Alignment
        ``p_ref ≈ s R p_est + t`` (s = 1 unless ``sim3``).

    Raises
    ------
    InputError
        An unknown ``method``.
    OptimiseError
        Too few pairs or degenerate points (from the solvers).
    """
    if method == "se3":
        return umeyama(p_ref, p_est, False)
    if method == "sim3":
        return umeyama(p_ref, p_est, True)
    if method == "yaw":
        return align_yaw(p_ref, p_est, z_est_in_ref)
    raise InputError(f"alignment method {method!r}; expected 'se3', 'sim3' or 'yaw'")


# --------------------------------------------------------------------------------------------
# Absolute and relative pose error
# --------------------------------------------------------------------------------------------


def error_stats(e) -> dict:
    """evo's statistics of an error series: rmse, mean, median, std, min, max, sse (and n).

    Parameters
    ----------
    e : array_like
        Errors (any unit); non-finite values are left out.

    Returns
    -------
    dict
        ``rmse, mean, median, std`` (population, ddof 0), ``min, max, sse`` as floats in the
        unit of ``e``, and ``n`` the finite count; all NaN with ``n`` 0 when none is finite.
    """
    e = np.asarray(e, dtype=float)
    e = e[np.isfinite(e)]
    if len(e) == 0:
        return {k: float("nan") for k in ("rmse", "mean", "median", "std", "min", "max", "sse")} | {
            "n": 0
        }
    return {
        "rmse": float(np.sqrt(np.mean(e**2))),
        "mean": float(np.mean(e)),
        "median": float(np.median(e)),
        "std": float(np.std(e)),
        "min": float(np.min(e)),
        "max": float(np.max(e)),
        "sse": float(np.sum(e**2)),
        "n": int(len(e)),
    }


def ape_translation(p_ref, p_est_aligned) -> np.ndarray:
    """Absolute position error per pair, metres, shape (N,): |p_ref - p_est| (evo APE, trans).

    Parameters
    ----------
    p_ref : array_like, shape (N, 3)
        Reference positions, m.
    p_est_aligned : array_like, shape (N, 3)
        Estimated positions after alignment into the reference's world, m.

    Returns
    -------
    ndarray, shape (N,)
        Euclidean distance per pair, m (NaN where either is NaN).
    """
    return np.linalg.norm(np.asarray(p_ref, float) - np.asarray(p_est_aligned, float), axis=1)


def ape_rotation(R_ref, R_est_aligned) -> np.ndarray:
    """Absolute rotation error angle per pair, radians, of R_ref^T R_est (N, 3, 3) -> (N,).

    Parameters
    ----------
    R_ref : array_like, shape (N, 3, 3)
        Reference rotations.
    R_est_aligned : array_like, shape (N, 3, 3)
        Estimated rotations after alignment into the reference's world.

    Returns
    -------
    ndarray, shape (N,)
        Angle of ``R_ref^T R_est`` in [0, pi], rad.
    """
    R_ref = np.asarray(R_ref, float)
    return rotation_angle(np.swapaxes(R_ref, -1, -2) @ np.asarray(R_est_aligned, float))


def rpe(T_ref, T_est, delta: int = 1) -> dict:
    """Relative pose error over ``delta`` consecutive pairs (evo RPE, ``--delta`` frames).

    E_i = (T_ref,i^-1 T_ref,i+d)^-1 (T_est,i^-1 T_est,i+d).

    Parameters
    ----------
    T_ref, T_est : ndarray, shape (N, 4, 4)
        Associated poses (the estimate aligned or not: RPE is alignment-free for SE(3)).
    delta : int
        Step in pairs.

    Returns
    -------
    dict
        ``trans_m`` (N-d,) translation norms, metres; ``rot_rad`` (N-d,) angles, radians.
    """
    T_ref = np.asarray(T_ref, float)
    T_est = np.asarray(T_est, float)
    if delta < 1 or len(T_ref) <= delta:
        raise InputError(f"rpe: delta={delta} with {len(T_ref)} pairs; expected 1 <= delta < N")
    d_ref = invert_T(T_ref[:-delta]) @ T_ref[delta:]
    d_est = invert_T(T_est[:-delta]) @ T_est[delta:]
    E = invert_T(d_ref) @ d_est
    return {"trans_m": np.linalg.norm(E[:, :3, 3], axis=1), "rot_rad": rotation_angle(E[:, :3, :3])}


# --------------------------------------------------------------------------------------------
# Time alignment
# --------------------------------------------------------------------------------------------


def angular_speed(t_s, R) -> tuple[np.ndarray, np.ndarray]:
    """Angular speed between consecutive orientations, rad/s, at the interval midpoints.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
    R : ndarray, shape (N, 3, 3)
        Orientations in any fixed world; the speed does not depend on it or on the body frame.

    Returns
    -------
    t_mid_s, omega : ndarray, shape (N-1,)
    """
    t_s = np.asarray(t_s, float)
    dt = np.diff(t_s)
    ang = rotation_angle(np.swapaxes(R[:-1], -1, -2) @ R[1:])
    return 0.5 * (t_s[1:] + t_s[:-1]), ang / dt


@dataclass
class Clock:
    """Log clock to reference clock: ``t_ref_s = dt_offset_s + (1 + skew) * t_log_s``."""

    dt_offset_s: float
    skew: float = 0.0
    quality: float = float("nan")
    details: dict = field(default_factory=dict)

    def to_ref(self, t_log_s):
        """Map log times to the reference clock."""
        return self.dt_offset_s + (1.0 + self.skew) * np.asarray(t_log_s, float)

    def to_log(self, t_ref_s):
        """Map reference times to the log clock."""
        return (np.asarray(t_ref_s, float) - self.dt_offset_s) / (1.0 + self.skew)


def _valid_rot(df):
    """Times and rotation matrices of the valid orientations of a trajectory."""
    m = df["rot_valid"].to_numpy(bool)
    return df["t_s"].to_numpy(float)[m], R_from_quat(
        df.loc[m, ["qx", "qy", "qz", "qw"]].to_numpy(float)
    )


def _hand_eye_rotation(R_ref_C_B, R_est_L_Q, lags=(3, 10, 30)):
    """R_Q_B from relative rotations: their axes satisfy v_Q = R_Q_B v_B (Park and Martin 1994)."""
    vB, vQ = [], []
    for h in lags:
        if len(R_ref_C_B) <= h:
            continue
        vB.append(
            Rotation.from_matrix(np.swapaxes(R_ref_C_B[:-h], -1, -2) @ R_ref_C_B[h:]).as_rotvec()
        )
        vQ.append(
            Rotation.from_matrix(np.swapaxes(R_est_L_Q[:-h], -1, -2) @ R_est_L_Q[h:]).as_rotvec()
        )
    if not vB:
        return np.eye(3)
    vB, vQ = np.concatenate(vB), np.concatenate(vQ)
    U, _, Vt = np.linalg.svd(vQ.T @ vB)  # Kabsch: min sum |vQ - X vB|^2
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_alignment(R_ref_C_B, R_est_L_Q, R_Q_B=None, weights=None, n_iter: int = 10):
    """Constant rotations linking two orientation streams: R_C_B ≈ R_C_L R_L_Q R_Q_B.

    Closed-form chordal means; when ``R_Q_B`` is not given it is estimated too: started from
    the axes of relative rotations (Park and Martin, IEEE TRA 10(5), 1994), then alternated
    with R_C_L (the rotation part of a hand-eye calibration; needs rotation about two axes).

    Parameters
    ----------
    R_ref_C_B : ndarray, shape (N, 3, 3)
        Reference orientations of the board in C.
    R_est_L_Q : ndarray, shape (N, 3, 3)
        On-board orientations of the body in L, at the same instants.
    R_Q_B : ndarray, shape (3, 3), optional
        Known board mounting; None: estimated.
    weights : ndarray, shape (N,), optional
        Non-negative weights.

    Returns
    -------
    R_C_L, R_Q_B : ndarray, shape (3, 3)
    """
    fixed = R_Q_B is not None
    R_QB = _hand_eye_rotation(R_ref_C_B, R_est_L_Q) if R_Q_B is None else np.asarray(R_Q_B, float)
    R_CL = mean_rotation(R_ref_C_B @ R_QB.T @ np.swapaxes(R_est_L_Q, -1, -2), weights)
    if fixed:
        return R_CL, R_QB
    for _ in range(n_iter):
        R_QB = mean_rotation(np.swapaxes(R_est_L_Q, -1, -2) @ R_CL.T @ R_ref_C_B, weights)
        R_CL_new = mean_rotation(R_ref_C_B @ R_QB.T @ np.swapaxes(R_est_L_Q, -1, -2), weights)
        done = rotation_angle(R_CL_new.T @ R_CL) < 1e-10
        R_CL = R_CL_new
        if done:
            break
    return R_CL, R_QB


def estimate_clock(
    reference: pd.DataFrame,
    onboard: pd.DataFrame,
    *,
    R_Q_B=None,
    sigma_rot_rad=None,
    rate_hz: float = 100.0,
    max_offset_s: float | None = None,
    estimate_skew: bool = True,
    min_quality: float = 0.3,
) -> Clock:
    """Time offset (and skew) of the log against the camera stream.

    1. Coarse: angular speed of both streams (independent of every frame choice), resampled at
       ``rate_hz``; normalised cross-correlation over all lags, peak refined by a parabola.
    2. Fine (below one video frame): least squares over (offset, skew) of the orientation
       residuals ``log(R_C_B^T R_C_L R_L_Q(tau) R_Q_B)``, with the log SLERPed at the mapped
       times ``tau`` and the constant rotations R_C_L (and R_Q_B when not given) re-solved in
       closed form (:func:`rotation_alignment`) at every trial. Orientation only: position
       drift, scale and invalid positions do not enter.

    Parameters
    ----------
    reference : DataFrame
        Camera reference (common form, T_C_B), reference clock.
    onboard : DataFrame
        On-board log (common form, T_L_Q), log clock.
    R_Q_B : ndarray, shape (3, 3), optional
        Board mounting rotation; None: estimated with the clock.
    sigma_rot_rad : ndarray, shape (N_ref,), optional
        Reference orientation standard deviation per row (weights 1/sigma).
    rate_hz : float
        Resampling rate of the cross-correlation, Hz.
    max_offset_s : float or None
        Largest lag searched, seconds, from the offset that lines up the two streams' starts.
    estimate_skew : bool
        Fit the skew too (else 0).
    min_quality : float
        Smallest accepted normalised correlation peak (0..1).

    Returns
    -------
    Clock
        ``details``: ``xcorr_offset_s``, ``refine_rms`` (weighted residual RMS), ``R_Q_B``.

    Raises
    ------
    SyncError
        Too few valid orientations or a correlation peak below ``min_quality``.
    """
    m_r = reference["rot_valid"].to_numpy(bool)
    t_r, R_r = _valid_rot(reference)
    t_e, R_e = _valid_rot(onboard)
    if len(t_r) < 10 or len(t_e) < 10:
        raise SyncError(
            f"time alignment: {len(t_r)} reference and {len(t_e)} log orientations; "
            "at least 10 each needed"
        )
    tm_r, w_r = angular_speed(t_r, R_r)
    tm_e, w_e = angular_speed(t_e, R_e)
    gap_r = np.diff(t_r) < 2.5 * np.median(np.diff(t_r))  # missed frames give no speed
    tm_r, w_r = tm_r[gap_r], w_r[gap_r]
    g_r = np.arange(tm_r[0], tm_r[-1], 1.0 / rate_hz)
    g_e = np.arange(tm_e[0], tm_e[-1], 1.0 / rate_hz)
    a_r = np.interp(g_r, tm_r, w_r)
    a_e = np.interp(g_e, tm_e, w_e)
    a_r = (a_r - a_r.mean()) / (a_r.std() + 1e-12)
    a_e = (a_e - a_e.mean()) / (a_e.std() + 1e-12)
    c = correlate(a_r, a_e, mode="full", method="fft")
    lags = correlation_lags(len(a_r), len(a_e), mode="full")
    # a_r[n + k] ~ a_e[n]  <=>  dt_offset = g_r[0] - g_e[0] + k / rate
    overlap = np.minimum(
        np.minimum(len(a_e) + lags, len(a_r) - lags), min(len(a_r), len(a_e))
    ).astype(float)
    ok = overlap >= max(10, min(len(a_r), len(a_e)) / 3)
    if max_offset_s is not None:
        ok &= np.abs(lags / rate_hz) <= max_offset_s
    if not ok.any():
        raise SyncError("time alignment: no lag with enough overlap between log and reference")
    cn = np.where(ok, c / np.maximum(overlap, 1), -np.inf)
    k = int(np.argmax(cn))
    quality = float(cn[k])
    frac = 0.0
    if 0 < k < len(cn) - 1 and np.isfinite(cn[k - 1]) and np.isfinite(cn[k + 1]):
        den = cn[k - 1] - 2 * cn[k] + cn[k + 1]
        frac = float(0.5 * (cn[k - 1] - cn[k + 1]) / den) if den < 0 else 0.0
    dt0 = g_r[0] - g_e[0] + (lags[k] + frac) / rate_hz
    if quality < min_quality:
        raise SyncError(
            f"time alignment: angular-speed correlation peak {quality:.2f} at offset "
            f"{dt0:.3f} s is below min_quality {min_quality}"
        )

    # fine: orientation residuals; parameters (offset at the reference's centre, skew * 1e3)
    w = (
        np.ones(len(t_r))
        if sigma_rot_rad is None
        else 1.0 / np.maximum(np.asarray(sigma_rot_rad, float)[m_r], 1e-9)
    )
    slerp = Slerp(t_e, Rotation.from_matrix(R_e))
    t_c = 0.5 * (t_r[0] + t_r[-1])
    state = {"R_Q_B": R_Q_B}

    def residual(x):
        dt_c, skew = x[0], (x[1] * 1e-3 if len(x) > 1 else 0.0)
        tau = (t_r - t_c) / (1 + skew) + (t_c - dt_c)  # log time of each reference row
        inside = (tau >= t_e[0]) & (tau <= t_e[-1])
        if inside.sum() < 10:
            return np.full(3 * len(t_r), 1e3)
        Re = slerp(np.clip(tau, t_e[0], t_e[-1])).as_matrix()
        R_CL, R_QB = rotation_alignment(R_r[inside], Re[inside], R_Q_B, w[inside] ** 2, n_iter=3)
        state["R_Q_B"] = R_QB
        r = Rotation.from_matrix(np.swapaxes(R_r, -1, -2) @ R_CL @ Re @ R_QB).as_rotvec()
        r = np.where(inside[:, None], r * w[:, None], 0.0)
        return r.ravel() / np.sqrt(inside.sum())

    x0 = np.array([dt0, 0.0]) if estimate_skew else np.array([dt0])  # dt_c = dt0 when skew = 0
    res = least_squares(
        residual,
        x0,
        x_scale=[0.01, 0.1][: len(x0)],
        diff_step=[1e-5, 1e-3][: len(x0)],
        loss="soft_l1",
        f_scale=3.0,
    )
    dt_c = float(res.x[0])
    skew = float(res.x[1] * 1e-3) if estimate_skew else 0.0
    # tau = (t_r - t_c)/(1+skew) + t_c - dt_c  =>  t_r = (1+skew)(tau - t_c + dt_c) + t_c
    dt_offset = t_c - (1 + skew) * (t_c - dt_c)
    if abs(dt_c - dt0) > 0.5:
        log.warning(
            "time alignment: refinement moved the offset by %.3f s from the cross-correlation peak",
            dt_c - dt0,
        )
    clock = Clock(
        dt_offset,
        skew,
        quality,
        {
            "xcorr_offset_s": float(dt0),
            "rate_hz": rate_hz,
            "refine_rms": float(np.sqrt(2 * res.cost / 3)),
            "refine_status": int(res.status),
            "R_Q_B": np.asarray(state["R_Q_B"]).tolist(),
        },
    )
    log.info(
        "time alignment: dt_offset_s %.6f, skew %.3g, correlation %.3f", dt_offset, skew, quality
    )
    return clock


# --------------------------------------------------------------------------------------------
# Reference uncertainty
# --------------------------------------------------------------------------------------------


def reference_covariance_model(
    T_C_B, f_px: float = 700.0, board_m: float = 0.5, sigma_px: float = 0.3, n_corners: int = 20
) -> np.ndarray:
    """A simple distance-dependent covariance of a PnP board pose (stand-in for se3's model).

    Lateral position error ~ d sigma_px / (f sqrt(n)); depth error ~ d^2 sigma_px /
    (f L sqrt(n)); tilt (about the camera's x, y) ~ d sigma_px / (f L) and in-plane rotation
    (about z) ~ d sigma_px / (f L sqrt(n)), with d the board distance and L its size.

    Parameters
    ----------
    T_C_B : ndarray, shape (N, 4, 4)
        Board poses in the camera frame, metres.
    f_px, board_m, sigma_px, n_corners : float
        Focal length (px), board size (m), corner noise (px), number of corners.

    Returns
    -------
    Sigma : ndarray, shape (N, 6, 6)
        Diagonal covariance of ``[dt (m, in C), dtheta (rad, in C)]`` (module docstring).
    """
    d = np.linalg.norm(np.asarray(T_C_B, float)[:, :3, 3], axis=1)
    rn = np.sqrt(n_corners)
    s_lat = d * sigma_px / (f_px * rn)
    s_depth = d**2 * sigma_px / (f_px * board_m * rn)
    s_tilt = d * sigma_px / (f_px * board_m)
    s_roll = s_tilt / rn
    sig = np.column_stack([s_lat, s_lat, s_depth, s_tilt, s_tilt, s_roll])
    Sigma = np.zeros((len(d), 6, 6))
    idx = np.arange(6)
    Sigma[:, idx, idx] = sig**2
    return Sigma


def _euler_rate_inverse(rpy):
    """E^-1 with E mapping roll/pitch/yaw increments to a world-frame rotation vector."""
    p, y = rpy[:, 1], rpy[:, 2]  # E does not depend on roll
    cy, sy, cp, sp = np.cos(y), np.sin(y), np.cos(p), np.sin(p)
    E = np.zeros((len(rpy), 3, 3))
    E[:, :, 0] = np.column_stack([cy * cp, sy * cp, -sp])  # Rz Ry e_x
    E[:, :, 1] = np.column_stack([-sy, cy, np.zeros_like(y)])  # Rz e_y
    E[:, 2, 2] = 1.0  # e_z
    return np.linalg.inv(E)


def propagate_reference_sigma(Sigma_C_B, T_C_B, T_Q_B, R_C_L) -> np.ndarray:
    """Per-axis standard deviations of the reference body pose in the error axes of L.

    Parameters
    ----------
    Sigma_C_B : ndarray, shape (N, 6, 6)
        Covariance of the board pose error [dt, dtheta] in C (module docstring).
    T_C_B : ndarray, shape (N, 4, 4)
        Measured board poses.
    T_Q_B : ndarray, shape (4, 4)
        Board mounting on the body.
    R_C_L : ndarray, shape (3, 3)
        Rotation of the alignment.

    Returns
    -------
    sigma : ndarray, shape (N, 6)
        Standard deviations of x, y, z (m, axes of L) and roll, pitch, yaw (rad of R_L_Q).
    """
    T_B_Q = invert_T(T_Q_B)
    T_C_Q = T_C_B @ T_B_Q
    lever = T_C_B[:, :3, :3] @ T_B_Q[:3, 3]  # R_C_B t_B_Q
    J = np.zeros((len(T_C_B), 6, 6))
    R_L_C = R_C_L.T
    J[:, :3, :3] = R_L_C
    J[:, :3, 3:] = -R_L_C @ skew_matrix(lever)  # dp = dt - [lever]x dtheta
    rpy = euler_from_R(R_L_C @ T_C_Q[:, :3, :3])
    J[:, 3:, 3:] = _euler_rate_inverse(rpy) @ R_L_C
    S = J @ np.asarray(Sigma_C_B, float) @ np.swapaxes(J, -1, -2)
    return np.sqrt(np.clip(np.diagonal(S, axis1=1, axis2=2), 0, None))


# --------------------------------------------------------------------------------------------
# Per-axis errors, statistics, the share the reference cannot resolve
# --------------------------------------------------------------------------------------------


def axis_errors(T_ref_C_Q, T_est_L_Q, alignment: Alignment) -> np.ndarray:
    """Per-axis on-board error (estimate minus reference) in the axes of L.

    Parameters
    ----------
    T_ref_C_Q : ndarray, shape (N, 4, 4)
        Reference body poses in C.
    T_est_L_Q : ndarray, shape (N, 4, 4)
        On-board body poses in L, at the same instants.
    alignment : Alignment
        T_C_L and scale.

    Returns
    -------
    e : ndarray, shape (N, 6)
        x, y, z (metres, axes of L: R_C_L^T (s R p_est + t - p_ref)); roll, pitch, yaw
        (radians, wrapped difference of the Euler angles of R_L_Q).
    """
    R = alignment.T_ref_est[:3, :3]
    p_est_C = alignment.apply_points(T_est_L_Q[:, :3, 3])
    e_p = (p_est_C - T_ref_C_Q[:, :3, 3]) @ R  # R^T (.)
    rpy_ref = euler_from_R(R.T @ T_ref_C_Q[:, :3, :3])
    rpy_est = euler_from_R(T_est_L_Q[:, :3, :3])
    return np.column_stack([e_p, wrap_angle(rpy_est - rpy_ref)])


def axis_stats(e, sigma=None, k_sigma: float = 1.0) -> dict:
    """RMSE, mean, std and max |e| per axis, and the share the reference cannot resolve.

    Parameters
    ----------
    e : ndarray, shape (N, 6)
        Per-axis errors (m, rad); NaN rows ignored.
    sigma : ndarray, shape (N, 6), optional
        Reference standard deviations per axis, same units.
    k_sigma : float
        A sample is *unresolved* on an axis when ``k_sigma * sigma > |e|``: the reference's
        uncertainty is larger than the error it measures.

    Returns
    -------
    dict
        Per axis name (x..yaw): ``rmse, mean, std, max_abs, n``; with sigma also
        ``ref_rms`` (RMS of sigma), ``unresolved_fraction`` (share of samples unresolved),
        ``ref_variance_share`` (mean sigma^2 / mean e^2, capped at 1: the share of the
        measured mean-square error the reference's noise accounts for) and
        ``rmse_corrected`` (sqrt(max(mean e^2 - mean sigma^2, 0)), the on-board RMSE with the
        reference's own noise removed).
    """
    e = np.asarray(e, float)
    out = {}
    for k, name in enumerate(AXES):
        ek = e[:, k]
        m = np.isfinite(ek)
        if sigma is not None:
            m &= np.isfinite(sigma[:, k])
        ek = ek[m]
        st = {"n": int(m.sum())}
        if st["n"] == 0:
            out[name] = st | {
                "rmse": float("nan"),
                "mean": float("nan"),
                "std": float("nan"),
                "max_abs": float("nan"),
            }
            continue
        ms = float(np.mean(ek**2))
        st |= {
            "rmse": float(np.sqrt(ms)),
            "mean": float(ek.mean()),
            "std": float(ek.std()),
            "max_abs": float(np.abs(ek).max()),
        }
        if sigma is not None:
            sk = sigma[m, k]
            s2 = float(np.mean(sk**2))
            st |= {
                "ref_rms": float(np.sqrt(s2)),
                "unresolved_fraction": float(np.mean(k_sigma * sk > np.abs(ek))),
                "ref_variance_share": float(min(s2 / ms, 1.0)) if ms > 0 else 1.0,
                "rmse_corrected": float(np.sqrt(max(ms - s2, 0.0))),
            }
        out[name] = st
    return out


# --------------------------------------------------------------------------------------------
# The whole comparison
# --------------------------------------------------------------------------------------------


@dataclass
class FlightResult:
    """Outcome of :func:`evaluate_flight`.

    Attributes
    ----------
    errors : DataFrame
        Per associated reference frame: ``t_s`` (reference clock), ``t_log_s``, ``ex_m ..
        eyaw_rad`` (on-board minus reference, axes of L), ``sx_m .. syaw_rad`` (reference
        standard deviations), ``ape_m`` (position error norm), ``ape_rot_rad``.
    stats : dict
        ``axes`` (:func:`axis_stats`), ``ape_trans`` / ``ape_rot`` / ``rpe_trans`` /
        ``rpe_rot`` (:func:`error_stats`), ``clock``, ``alignment``, ``n_pairs``.
    clock : Clock
    alignment : Alignment
    ref_aligned, est_aligned : DataFrame
        Body trajectories T_C_Q (reference) and s,T_C_L applied to T_L_Q (estimate) at the
        reference times: the files to hand to evo (TUM).
    est_unaligned : DataFrame
        The estimate T_L_Q as logged (frame L, not aligned), interpolated at the reference
        times through the fitted clock: beside ``ref_aligned`` it lets evo's own ``-a`` / ``-s``
        do the alignment.
    """

    errors: pd.DataFrame
    stats: dict
    clock: Clock
    alignment: Alignment
    ref_aligned: pd.DataFrame
    est_aligned: pd.DataFrame
    est_unaligned: pd.DataFrame


def evaluate_flight(
    reference: pd.DataFrame,
    onboard: pd.DataFrame,
    T_Q_B=None,
    Sigma_ref=None,
    *,
    alignment: str = "se3",
    clock: Clock | None = None,
    T_C_L=None,
    z_est_in_ref=(0.0, 0.0, 1.0),
    max_gap_s: float = 0.1,
    sync_rate_hz: float = 100.0,
    max_offset_s: float | None = None,
    estimate_skew: bool = True,
    min_quality: float = 0.3,
    rpe_delta: int = 1,
    k_sigma: float = 1.0,
) -> FlightResult:
    """On-board pose error of a flight against the camera reference.

    Parameters
    ----------
    reference : DataFrame
        Camera reference T_C_B, common form, reference clock (e.g. from
        :func:`reference_from_poses`).
    onboard : DataFrame
        On-board estimate T_L_Q, common form, log clock (:mod:`cvsflow.io.flightlog`).
    T_Q_B : ndarray, shape (4, 4), optional
        Board mounting on the body. None: its rotation is estimated from the data (hand-eye,
        so a constant attitude error is absorbed) and its lever arm taken as zero.
    Sigma_ref : ndarray, shape (N_ref, 6, 6), optional
        Reference covariance per row of ``reference`` (module docstring); None: no band and
        no unresolved share.
    alignment : {"se3", "sim3", "yaw"}
        Frame alignment fitted on the associated positions (ignored when T_C_L is given).
    clock : Clock, optional
        Known clock relation; None: :func:`estimate_clock`.
    T_C_L : ndarray, shape (4, 4), optional
        Known (surveyed) alignment; None: fitted.
    max_gap_s : float
        Longest log gap bridged when interpolating the log at reference times, seconds.
    rpe_delta : int
        RPE step, in reference frames.
    k_sigma : float
        Threshold of :func:`axis_stats`.

    Returns
    -------
    FlightResult

    Raises
    ------
    InputError, SyncError, OptimiseError
        Malformed trajectories; no time overlap; too few pairs to align.
    """
    reference = check_trajectory(reference, "reference")
    onboard = check_trajectory(onboard, "on-board log")
    mounting_given = T_Q_B is not None
    T_Q_B = np.asarray(T_Q_B, float) if mounting_given else None
    sigma_rot = None
    if Sigma_ref is not None:
        Sigma_ref = np.asarray(Sigma_ref, float)
        if Sigma_ref.shape != (len(reference), 6, 6):
            raise InputError(
                f"Sigma_ref: shape {Sigma_ref.shape}; expected ({len(reference)}, 6, 6)"
            )
        sigma_rot = np.sqrt(np.trace(Sigma_ref[:, 3:, 3:], axis1=1, axis2=2) / 3.0)
    if clock is None:
        clock = estimate_clock(
            reference,
            onboard,
            R_Q_B=T_Q_B[:3, :3] if mounting_given else None,
            sigma_rot_rad=sigma_rot,
            rate_hz=sync_rate_hz,
            max_offset_s=max_offset_s,
            estimate_skew=estimate_skew,
            min_quality=min_quality,
        )
    ref_ok = (reference["pos_valid"] & reference["rot_valid"]).to_numpy()
    t_ref = reference["t_s"].to_numpy(float)
    est_i = interpolate_trajectory(onboard, clock.to_log(t_ref), max_gap_s=max_gap_s)
    est_ok = (est_i["pos_valid"] & est_i["rot_valid"]).to_numpy()
    use = ref_ok & est_ok
    n = int(use.sum())
    if n < 3:
        raise SyncError(
            f"flight: {n} reference frames have a valid on-board pose at the aligned time "
            f"(dt_offset_s {clock.dt_offset_s:.3f}, skew {clock.skew:.3g}); at least 3 needed"
        )
    T_C_B = T_from_traj(reference)[use]
    T_L_Q = T_from_traj(est_i)[use]
    if not mounting_given:
        # rotation of the mounting from the data (hand-eye), no lever arm: a constant attitude
        # error of the estimate is then absorbed and cannot be measured
        w = None if sigma_rot is None else 1.0 / np.maximum(sigma_rot[use], 1e-9) ** 2
        _, R_QB = rotation_alignment(T_C_B[:, :3, :3], T_L_Q[:, :3, :3], None, w)
        T_Q_B = make_T(R_QB, np.zeros(3))
        log.warning(
            "flight: board mounting T_Q_B not given; its rotation was estimated from the "
            "data (constant attitude errors are absorbed) and its lever arm set to 0"
        )
    T_C_Q = T_C_B @ invert_T(T_Q_B)
    if T_C_L is not None:
        al = Alignment(np.asarray(T_C_L, float), 1.0, "given")
    else:
        al = align_trajectories(T_C_Q[:, :3, 3], T_L_Q[:, :3, 3], alignment, z_est_in_ref)
    T_est_C = al.apply_T(T_L_Q)
    e = axis_errors(T_C_Q, T_L_Q, al)
    sigma = (
        propagate_reference_sigma(Sigma_ref[use], T_C_B, T_Q_B, al.T_ref_est[:3, :3])
        if Sigma_ref is not None
        else np.full_like(e, np.nan)
    )
    ape_t = ape_translation(T_C_Q[:, :3, 3], T_est_C[:, :3, 3])
    ape_r = ape_rotation(T_C_Q[:, :3, :3], T_est_C[:, :3, :3])
    errors = pd.DataFrame(np.column_stack([e, sigma]), columns=ERR_COLS + SIG_COLS)
    errors.insert(0, "t_log_s", clock.to_log(t_ref[use]))
    errors.insert(0, "t_s", t_ref[use])
    if "frame" in reference:
        errors.insert(0, "frame", reference["frame"].to_numpy()[use])
    errors["ape_m"] = ape_t
    errors["ape_rot_rad"] = ape_r
    stats = {
        "n_pairs": n,
        "n_reference": int(len(reference)),
        "axes": axis_stats(e, sigma if Sigma_ref is not None else None, k_sigma),
        "ape_trans": error_stats(ape_t),
        "ape_rot": error_stats(ape_r),
        "clock": {"dt_offset_s": clock.dt_offset_s, "skew": clock.skew, "quality": clock.quality},
        "alignment": {"method": al.method, "scale": al.scale, "T_C_L": al.T_ref_est.tolist()},
        "T_Q_B": T_Q_B.tolist(),
        "mounting_estimated": not mounting_given,
    }
    if n > rpe_delta:
        r = rpe(T_C_Q, T_est_C, rpe_delta)
        stats["rpe_trans"] = error_stats(r["trans_m"])
        stats["rpe_rot"] = error_stats(r["rot_rad"])
    ref_aligned = traj_from_T(t_ref[use], T_C_Q, attrs={"frames": "T_C_Q (reference)"})
    est_aligned = traj_from_T(t_ref[use], T_est_C, attrs={"frames": "T_C_Q (on-board, aligned)"})
    est_unaligned = traj_from_T(t_ref[use], T_L_Q, attrs={"frames": "T_L_Q (on-board, unaligned)"})
    for name, st in stats["axes"].items():
        if "unresolved_fraction" in st and st["unresolved_fraction"] > 0.5:
            log.warning(
                "flight: on axis %s the reference cannot resolve %.0f%% of the samples",
                name,
                100 * st["unresolved_fraction"],
            )
    return FlightResult(errors, stats, clock, al, ref_aligned, est_aligned, est_unaligned)


def sigma_columns(Sigma):
    """Flatten (N, 6, 6) covariances into a DataFrame of columns ``S00 .. S55`` (SI).

    Parameters
    ----------
    Sigma : array_like, shape (N, 6, 6)
        Covariances of ``[dt (m), dtheta (rad)]`` in C (module docstring).

    Returns
    -------
    DataFrame
        N rows, 36 columns ``S{i}{j}`` (row-major), in m^2, m rad and rad^2.
    """
    Sigma = np.asarray(Sigma, float)
    columns = [f"S{i}{j}" for i in range(6) for j in range(6)]
    return pd.DataFrame(Sigma.reshape(len(Sigma), 36), columns=columns)


def sigma_from_columns(df):
    """Inverse of :func:`sigma_columns`: (N, 6, 6) from columns ``S00 .. S55``.

    Parameters
    ----------
    df : DataFrame
        A table with the 36 columns ``S00 .. S55`` (e.g. ``reference.parquet``).

    Returns
    -------
    Sigma : ndarray, shape (N, 6, 6)
        Covariances of ``[dt (m), dtheta (rad)]`` in C.

    Raises
    ------
    InputError
        A column is missing.
    """
    cols = [f"S{i}{j}" for i in range(6) for j in range(6)]
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise InputError(f"reference covariance table lacks columns {missing[:3]}...")
    return df[cols].to_numpy(float).reshape(len(df), 6, 6)


def check_against_truth(result, onboard, truth, T_L_C, clock, max_gap_s=0.05):
    """How well a flight evaluation recovered the injected on-board error (rendered flights).

    The injected error is seen through the evaluation's own fitted alignment (a fitted
    alignment absorbs a constant part of it), then compared with the recovered error in units
    of the reference's stated standard deviation: what is left is the reference's own error
    per frame, which its stated covariance claims to hold.

    Parameters
    ----------
    result : FlightResult
    onboard : DataFrame
        The on-board log (common form, log clock).
    truth : DataFrame
        Common form of the true T_L_Q at the video frames (reference clock), one row per
        frame in order (row k is frame k) or with a ``frame`` column.
    T_L_C : ndarray, shape (4, 4)
        True camera pose in L.
    clock : Clock
        The true log clock.

    Returns
    -------
    dict
        ``z_rms`` per axis (RMS of (recovered - injected) / sigma: 1 when the stated
        uncertainty is right), ``inside_3sigma`` per axis, ``n``; ``z_rms_truth_alignment``:
        the same with the injected error seen through the alignment (same method) fitted to the
        true body poses instead, i.e. against what the evaluation would recover from a perfect
        reference: there the part of the reference's error the alignment absorbs (a
        principal-point error turns C about its origin) cancels, and the error the reference's
        noise puts into the fitted alignment shows.
    """
    fr = result.errors["frame"].to_numpy()
    if "frame" not in truth.columns:
        truth = truth.assign(frame=np.arange(len(truth)))
    truth = truth.set_index("frame").loc[fr].reset_index()
    T_true_C_Q = invert_T(np.asarray(T_L_C, float)) @ T_from_traj(truth)
    est = interpolate_trajectory(onboard, clock.to_log(truth["t_s"].to_numpy(float)), max_gap_s)
    T_est = T_from_traj(est)
    al = result.alignment
    rec = result.errors[ERR_COLS].to_numpy(float)
    sig = result.errors[SIG_COLS].to_numpy(float)
    z = (rec - axis_errors(T_true_C_Q, T_est, al)) / sig
    ok = np.isfinite(z).all(axis=1)
    out = {
        "n": int(ok.sum()),
        "z_rms": {a: float(np.sqrt(np.mean(z[ok, i] ** 2))) for i, a in enumerate(AXES)},
        "inside_3sigma": {a: float(np.mean(np.abs(z[ok, i]) < 3.0)) for i, a in enumerate(AXES)},
    }
    if al.method != "given":
        fin = np.isfinite(T_est[:, :3, 3]).all(axis=1)
        al_true = align_trajectories(T_true_C_Q[fin, :3, 3], T_est[fin, :3, 3], al.method,
                                     al.T_ref_est[:3, 2])  # fmt: skip
        z_t = (rec - axis_errors(T_true_C_Q, T_est, al_true)) / sig
        ok_t = np.isfinite(z_t).all(axis=1)
        out["z_rms_truth_alignment"] = {a: float(np.sqrt(np.mean(z_t[ok_t, i] ** 2)))
                                        for i, a in enumerate(AXES)}  # fmt: skip
    return out


def corner_noise_per_axis(reproj_rms_px, n_corners):
    """Corner noise per image axis (px) from PnP's 2-D reprojection RMS over ``n_corners``:
    the RMS of the residual length over sqrt(2), corrected for the 6 pose parameters fitted.

    Parameters
    ----------
    reproj_rms_px : float
        RMS over the corners of the reprojection residual length, px.
    n_corners : int
        Corners in the PnP fit.

    Returns
    -------
    float
        ``reproj_rms_px / sqrt(2) * sqrt(2n / (2n - 6))``, px per axis.
    """
    n_res = 2 * int(n_corners)
    return float(reproj_rms_px) / np.sqrt(2.0) * np.sqrt(n_res / max(n_res - 6, 1))


def reference_covariance_from_pnp(poses_raw, p_B, K, dist, sigma_px):
    """Reference covariance per frame of a real flight, propagated from the corner noise.

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet of the flight's video (``valid``, ``rvec_0..2``, ``x_m..z_m``).
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    K, dist : array_like
        Intrinsics (the se3 calibration's where available), px.
    sigma_px : float
        Corner noise per axis, px (the se3 fit's ``sigma_px``).

    Returns
    -------
    Sigma_ref : ndarray, shape (N, 6, 6)
        ``[dt, dtheta]`` in C (module docstring) per row of ``poses_raw``; NaN where not valid.
    """

    valid = poses_raw["valid"].to_numpy(bool)
    Sigma = np.full((len(poses_raw), 6, 6), np.nan)
    if valid.any():
        rv = poses_raw.loc[valid, ["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
        tv = poses_raw.loc[valid, ["x_m", "y_m", "z_m"]].to_numpy(float)
        cov_rt = pnp_covariance(rv, tv, p_B, np.asarray(K, float), np.asarray(dist, float), sigma_px)
        Sigma[valid] = error_covariance(rv, tv, cov_rt, frame="C")
    return Sigma


def _intrinsics_std(calib):
    """1-sigma of [fx, fy, cx, cy, k1, k2, p1, p2, k3] from an se3 result or a camera.yaml."""

    sd = dict(DEFAULT_INTRINSIC_STD)
    std = calib.get("std") if isinstance(calib.get("std"), dict) else {}
    sd.update({k: float(v) for k, v in std.items() if k in sd and v is not None})
    fixed = calib.get("fixed_intrinsics") or {}
    sd.update(dict(zip(fixed.get("names", []), map(float, fixed.get("std", [])), strict=False)))
    se = calib.get("std_errors") or {}
    sd.update({k: float(v) for k, v in se.items() if k in sd})
    return np.array([sd[n] for n in INTRINSIC_NAMES])


def pnp_flip_term(uv_px, rvec, tvec, p_B, K, dist):
    """The other solution of each frame's planar PnP and how much worse it fits its corners.

    A planar board seen small or nearly face-on has two poses that fit its corners almost
    equally (IPPE's two solutions: the board tilted one way or mirrored about the line of
    sight); noise can make the PnP pick the wrong one, an error of up to twice the tilt that
    no first-order covariance holds. Each IPPE solution is refined (LM); the alternative is the
    one farther in rotation from the measured pose.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Observed corners, NaN where unseen.
    rvec, tvec : ndarray, shape (N, 3)
        The measured poses T_C_B.
    p_B : ndarray, shape (P, 3)
    K, dist : ndarray
        The intrinsics of the PnP.

    Returns
    -------
    delta : ndarray, shape (N, 6)
        Measured minus alternative, ``[dt m, dtheta rad]`` in C (module docstring); 0 where
        the two solutions coincide.
    d_ssr : ndarray, shape (N,)
        Sum of squared reprojection residuals of the alternative minus the measured pose's,
        px^2 (inf where there is no distinct alternative).
    """
    obj = np.asarray(p_B, np.float64)
    K = np.asarray(K, np.float64)
    dist = np.asarray(dist, np.float64).ravel()
    rvec, tvec = np.array(rvec, np.float64), np.array(tvec, np.float64)  # writable copies
    delta = np.zeros((len(uv_px), 6))
    d_ssr = np.full(len(uv_px), np.inf)

    def ssr(o, img, r, t):
        proj, _ = cv2.projectPoints(o, r, t, K, dist)
        return float(np.sum((proj.reshape(-1, 2) - img.reshape(-1, 2)) ** 2))

    for i in range(len(uv_px)):
        seen = np.isfinite(uv_px[i]).all(axis=1)
        if seen.sum() < 4:
            continue
        o = np.ascontiguousarray(obj[seen]).reshape(-1, 1, 3)
        img = np.ascontiguousarray(uv_px[i, seen], np.float64).reshape(-1, 1, 2)
        n, rvs, tvs, _ = cv2.solvePnPGeneric(o, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
        R_m = Rotation.from_rotvec(rvec[i])
        best = None
        for r0, t0 in zip(rvs[:n], tvs[:n], strict=True):
            r1, t1 = cv2.solvePnPRefineLM(o, img, K, dist, r0.copy(), t0.copy())
            ang = (Rotation.from_rotvec(r1.ravel()) * R_m.inv()).magnitude()
            if best is None or ang > best[0]:
                best = (ang, r1.ravel(), t1.ravel())
        if best is None or best[0] < 1e-6:
            continue
        _, r_alt, t_alt = best
        d_ssr[i] = ssr(o, img, r_alt, t_alt) - ssr(o, img, rvec[i], tvec[i])
        delta[i, :3] = tvec[i] - t_alt
        delta[i, 3:] = (R_m * Rotation.from_rotvec(r_alt).inv()).as_rotvec()
    return delta, d_ssr


def reference_covariance_transfer(poses_raw, corners, p_B, calib, model=None, flips=True):
    """Reference covariance per frame of a flight from the error model (T) of the se3 stage.

    The camera reference of a flight is the PnP pose of the board: its error is what model (T)
    (:func:`cvsflow.uncertainty.fit_transfer_model`) predicts for the CVS side, without the
    Vicon's floor and mountings (a flight has no Vicon): the corner noise from each frame's
    image speed and reprojection RMS through the PnP of the corners it saw, the calibration's
    intrinsics uncertainty through PnP (one draw for the whole flight: correlated; the principal
    point's is left out, the alignment absorbs it), and, with a
    rolling shutter (``calib["line_delay_s"]``), the outer product of the pose error its shear
    predicts (the reference does not correct it), and (``flips``) the planar PnP's two-fold
    ambiguity: ``w delta delta^T`` with ``delta`` the measured pose minus the other IPPE
    solution (:func:`pnp_flip_term`) and ``w = 1 / (1 + exp(d_ssr / (2 sigma_px^2)))`` the
    chance that the other one is the true pose given how much worse it fits the corners (the
    covariance of the two-solution mixture about the measured pose).

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet of the flight's video (``frame``, ``valid``, ``rvec_0..2``,
        ``x_m..z_m``, ``reproj_rms_px``).
    corners : DataFrame
        corners.parquet of the flight's video.
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    calib : dict
        The se3 result (``K``, ``dist``, ``std_errors``, ``fixed_intrinsics``,
        ``line_delay_s``) or a camera.yaml (``K``, ``dist``, ``std``); intrinsics without a
        standard deviation take ``DEFAULT_INTRINSIC_STD``; their correlations are left out.
    model : dict, optional
        Model (T); default :data:`cvsflow.uncertainty.RENDERED_TRANSFER_MODEL`.
    flips : bool
        Add the PnP ambiguity term.

    Returns
    -------
    Sigma_ref : ndarray, shape (N, 6, 6)
        ``[dt, dtheta]`` in C per row of ``poses_raw``; NaN where not valid.
    """

    model = un.RENDERED_TRANSFER_MODEL if model is None else model
    valid = poses_raw["valid"].to_numpy(bool)
    Sigma = np.full((len(poses_raw), 6, 6), np.nan)
    if not valid.any():
        return Sigma
    rows = poses_raw[valid]
    rv = rows[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
    tv = rows[["x_m", "y_m", "z_m"]].to_numpy(float)
    K = np.asarray(calib["K"], float)
    dist = np.asarray(calib["dist"], float).ravel()
    uv, speed, vel = un._seen_corners(corners, rows["frame"].to_numpy(), len(p_B))
    ld = float(calib.get("line_delay_s") or 0.0)
    unit, shear = un.frame_noise_terms(uv, vel, rv, tv, p_B, K, dist, ld, frame="C")
    n_seen = np.isfinite(uv).all(axis=-1).sum(axis=1)
    reproj = un.corner_noise_from_reproj(rows["reproj_rms_px"].to_numpy(float), n_seen)
    if model.get("k_shrink") is not None:
        # the model's shrinkage option: toward the flight's own pooled corner noise
        pool = un.corner_noise_pool(rows["reproj_rms_px"].to_numpy(float), n_seen)
        reproj = un.shrink_corner_noise(reproj, n_seen, pool, model["k_shrink"])
    var_px = (model["s0_px"] ** 2 + (model["s_speed"] * speed) ** 2
              + (model["s_reproj"] * reproj) ** 2)  # fmt: skip
    # intrinsics through PnP: d(rvec, tvec)/d(intrinsics) = -(J^T J)^-1 J^T J_K
    sd = _intrinsics_std(calib)
    # a principal-point error is to first order a turn of C about its origin, which the
    # flight's alignment (R_C_L) absorbs: only focal lengths and distortion stay
    sd[2:4] = 0.0
    seen = np.isfinite(uv).all(axis=-1)
    cov_rt = np.empty((len(rows), 6, 6))
    obj = np.asarray(p_B, np.float64)
    for i in range(len(rows)):
        _, jac = cv2.projectPoints(obj[seen[i]].reshape(-1, 1, 3), rv[i], tv[i], K, dist)
        Jp, JK = jac[:, :6], jac[:, 6:15]
        A = -np.linalg.lstsq(Jp.T @ Jp, Jp.T @ JK, rcond=None)[0]
        cov_rt[i] = (A * sd**2) @ A.T

    cal = error_covariance(rv, tv, cov_rt, frame="C")
    S = (var_px[:, None, None] * unit + model["c_cal"] ** 2 * cal
         + shear[:, :, None] * shear[:, None, :])  # fmt: skip
    if flips:
        delta, d_ssr = pnp_flip_term(uv, rv, tv, p_B, K, dist)
        w = 1.0 / (1.0 + np.exp(np.clip(d_ssr / (2.0 * var_px), -50.0, 50.0)))
        S = S + w[:, None, None] * delta[:, :, None] * delta[:, None, :]
    Sigma[valid] = S
    return Sigma
