"""Pose interpolation in time: linear in position, SLERP in rotation."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import MocapError
from cvsflow.geometry.transforms import make_T


def bracket(t_s, valid, tq_s):
    """The two samples around each query time and the query's fraction between them.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Sample times, increasing, seconds; N >= 2.
    valid : ndarray of bool, shape (N,)
        Samples that may be used.
    tq_s : ndarray, shape (K,)
        Query times, seconds (same clock).

    Returns
    -------
    i0, i1 : ndarray of int, shape (K,)
        Sample before and after each query (i1 = i0 + 1).
    frac : ndarray, shape (K,)
        (tq - t[i0]) / (t[i1] - t[i0]) in [0, 1]; 0 where not ``ok``.
    ok : ndarray of bool, shape (K,)
        The query lies inside [t[0], t[-1]] and both samples are valid.
    """
    n = len(t_s)
    i0 = np.clip(np.searchsorted(t_s, tq_s, side="right") - 1, 0, n - 2)
    i1 = i0 + 1
    frac = (tq_s - t_s[i0]) / (t_s[i1] - t_s[i0])
    ok = (tq_s >= t_s[0]) & (tq_s <= t_s[-1]) & valid[i0] & valid[i1]
    frac = np.clip(np.where(ok, frac, 0.0), 0.0, 1.0)
    return i0, i1, frac, ok


def slerp(R0, R1, frac):
    """Spherical linear interpolation between rotations, R0 exp(frac log(R0^-1 R1)).

    Parameters
    ----------
    R0, R1 : scipy.spatial.transform.Rotation, length K
        Rotations at the start and the end of each interval.
    frac : ndarray, shape (K,)
        Fraction of the way from R0 to R1, in [0, 1].

    Returns
    -------
    R : scipy.spatial.transform.Rotation, length K
        Equals ``scipy.spatial.transform.Slerp`` over the shorter arc.
    """
    return R0 * Rotation.from_rotvec(frac[:, None] * (R0.inv() * R1).as_rotvec())


def interpolate_T(t_s, T, valid, tq_s):
    """Transforms at query times: linear in translation, SLERP in rotation.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Sample times, increasing, seconds.
    T : ndarray, shape (N, 4, 4)
        Transforms T_A_X at the samples, metres (anything where invalid).
    valid : ndarray of bool, shape (N,)
    tq_s : ndarray, shape (K,)
        Query times, seconds.

    Returns
    -------
    T_at : ndarray, shape (K, 4, 4)
        Interpolated T_A_X; NaN outside the samples or next to an invalid sample.
    ok : ndarray of bool, shape (K,)
    near : ndarray of int, shape (K,)
        Index of the nearer of the two samples (for per-sample side information).

    Raises
    ------
    MocapError
        Fewer than two samples.
    """
    n = len(t_s)
    if n < 2:
        raise MocapError(f"interpolation needs at least 2 samples, got {n}")
    i0, i1, frac, ok = bracket(t_s, valid, tq_s)
    R0 = Rotation.from_matrix(np.where(ok[:, None, None], T[i0, :3, :3], np.eye(3)))
    R1 = Rotation.from_matrix(np.where(ok[:, None, None], T[i1, :3, :3], np.eye(3)))
    R = slerp(R0, R1, frac)
    p = (1.0 - frac)[:, None] * T[i0, :3, 3] + frac[:, None] * T[i1, :3, 3]
    out = make_T(R.as_matrix(), p)
    out[~ok] = np.nan
    near = np.where(frac < 0.5, i0, i1)
    return out, ok, near


def interpolate_quats(t_s, q_xyzw, valid, tq_s):
    """SLERP of unit quaternions at query times.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Sample times, increasing, seconds; N >= 2.
    q_xyzw : ndarray, shape (N, 4)
        Scalar-last unit quaternions at the samples.
    valid : ndarray of bool, shape (N,)
    tq_s : ndarray, shape (K,)
        Query times, seconds.

    Returns
    -------
    q_at : ndarray, shape (K, 4)
        Interpolated scalar-last quaternions (the first sample's where not ``ok``).
    ok : ndarray of bool, shape (K,)
        Inside the samples and both neighbours valid.
    """
    i0, i1, f, ok = bracket(t_s, valid, tq_s)
    R0 = Rotation.from_quat(q_xyzw[i0])
    return slerp(R0, Rotation.from_quat(q_xyzw[i1]), f).as_quat(), ok
