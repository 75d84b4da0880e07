"""Poses in time: the sample period of a stream, interpolation (linear in position, SLERP in rotation).

The one SLERP of the package is :func:`slerp` (scipy's quaternion product): :class:`PoseInterpolant`
(poses and their rates, the se3 solver's tracks), :func:`interpolate_T` and :func:`interpolate_quats`
use it, and so do the flight's trajectories and clock.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import MocapError
from cvsflow.geometry.transforms import make_T


def sample_period(t_s, default=float("nan")):
    """The sample period of a time series: the median spacing of its sample times.

    The frame period of a video, the sample period of a motion-capture stream: the median
    stays the nominal period when frames are dropped or a timestamp jitters.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Sample times, seconds (sorted here; a sorted series gives the same bits).
    default : float
        Returned when there are fewer than two samples.

    Returns
    -------
    float
        Median of the sorted times' differences, seconds.
    """
    t = np.asarray(t_s, dtype=float)
    if t.size < 2:
        return float(default)
    return float(np.median(np.diff(np.sort(t))))


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


def slerp(R0, R1, frac, rotvec_01=None):
    """Spherical linear interpolation between rotations, R0 exp(frac log(R0^-1 R1)): the one SLERP.

    Parameters
    ----------
    R0, R1 : scipy.spatial.transform.Rotation, length K
        Rotations at the start and the end of each interval (``R1`` unused with ``rotvec_01``).
    frac : ndarray, shape (K,)
        Fraction of the way from R0 to R1, in [0, 1] (beyond it: extrapolation on the same arc).
    rotvec_01 : ndarray, shape (K, 3), optional
        log(R0^-1 R1) when the caller has it already (rad, in R0's frame).

    Returns
    -------
    R : scipy.spatial.transform.Rotation, length K
        Equals ``scipy.spatial.transform.Slerp`` over the shorter arc.
    """
    w = (R0.inv() * R1).as_rotvec() if rotvec_01 is None else rotvec_01
    return R0 * Rotation.from_rotvec(frac[:, None] * w)


class PoseInterpolant:
    """Poses between samples: linear in position, SLERP in rotation; with the rates.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Sample times, increasing, seconds; N >= 2.
    T : ndarray, shape (N, 4, 4)
        Transforms T_A_X at the samples, metres (anything where invalid; NaN is taken as
        the identity).
    valid : ndarray of bool, shape (N,), optional
        Samples :meth:`ok` may use; default all.

    Raises
    ------
    MocapError
        Fewer than two samples.
    """

    def __init__(self, t_s, T, valid=None):
        self.t = np.asarray(t_s, dtype=float)
        if len(self.t) < 2:
            raise MocapError(f"interpolation needs at least 2 samples, got {len(self.t)}")
        T = np.asarray(T, dtype=float)
        self.valid = np.ones(len(self.t), bool) if valid is None else np.asarray(valid, bool)
        # an invalid sample keeps its value (a smoothed track's estimate there) unless not finite
        T = np.where(np.isfinite(T).all(axis=(1, 2))[:, None, None], T, np.eye(4))
        self.rot = Rotation.from_matrix(T[:, :3, :3])
        self.p = T[:, :3, 3]
        # each interval's rotation, log(R_i^-1 R_i+1), in the earlier sample's frame (rad)
        self.w = (self.rot[:-1].inv() * self.rot[1:]).as_rotvec()

    def locate(self, tq_s):
        """Interval index i0 (K,) and fraction (tq - t[i0]) / (t[i0 + 1] - t[i0]) (K,), not clipped."""
        tq = np.asarray(tq_s, dtype=float)
        i0 = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self.t) - 2)
        return i0, (tq - self.t[i0]) / (self.t[i0 + 1] - self.t[i0])

    def ok(self, tq_s):
        """True where a query lies inside the samples between two valid ones, shape (K,)."""
        tq = np.asarray(tq_s, dtype=float)
        i0, _ = self.locate(tq)
        inside = (tq >= self.t[0]) & (tq <= self.t[-1])
        return inside & self.valid[i0] & self.valid[i0 + 1]

    def __call__(self, tq_s, rates=False):
        """T_A_X at query times (K,), shape (K, 4, 4); outside the samples the end intervals go on.

        With ``rates``, also the velocity v_A (K, 3), m/s, and the angular velocity omega_X
        (K, 3), rad/s, in the interpolated frame (dR/dt = R [omega_X]x): constant over an
        interval.
        """
        i0, frac = self.locate(tq_s)
        R = slerp(self.rot[i0], None, frac, self.w[i0]).as_matrix()
        p0, p1 = self.p[i0], self.p[i0 + 1]
        T = make_T(R, (1.0 - frac)[:, None] * p0 + frac[:, None] * p1)
        if not rates:
            return T
        h = (self.t[i0 + 1] - self.t[i0])[:, None]
        return T, (p1 - p0) / h, self.w[i0] / h


def interpolate_T(t_s, T, valid, tq_s):
    """Transforms at query times: linear in translation, SLERP in rotation (:class:`PoseInterpolant`).

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
    track = PoseInterpolant(t_s, T, valid)
    i0, i1, frac, ok = bracket(track.t, track.valid, np.asarray(tq_s, dtype=float))
    out = track(tq_s)
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


class PoseCurve:
    """A pose stream as a curve in time: linear position, SLERP rotation, and their rates.

    Between samples k and k+1 the rotation is ``R_k exp(f w_k)`` with ``w_k = log(R_k^T
    R_k+1)`` and ``f = (t - t_k) / (t_k+1 - t_k)``, the position ``p_k + f (p_k+1 - p_k)``: the
    curve of :func:`interpolate_T` (SLERP on the shorter arc, so a quaternion sign flip
    between rows does no harm). Its body angular rate ``w_k / (t_k+1 - t_k)`` and velocity
    ``(p_k+1 - p_k) / (t_k+1 - t_k)`` are the time derivatives a time offset's Jacobian needs.

    Parameters
    ----------
    t_s : ndarray, shape (M,)
        Sample times, strictly increasing, s (any epoch).
    T : ndarray, shape (M, 4, 4)
        Poses ``T_A_X`` at the samples, m.
    valid : ndarray of bool, shape (M,), optional
        Usable samples (default: the finite ones).
    max_gap_s : float, optional
        Longest interval interpolated over; a longer one is a gap. Default 3 times the median
        sample interval.

    Raises
    ------
    MocapError
        Fewer than two samples, poses of another shape, or times not strictly increasing.
    """

    def __init__(self, t_s, T, valid=None, max_gap_s=None):
        self.t = np.asarray(t_s, float)
        T = np.asarray(T, float)
        if len(self.t) < 2 or T.shape != (len(self.t), 4, 4):
            raise MocapError(f"pose curve: {len(self.t)} samples and poses of shape {T.shape}; expected "
                             "at least 2 samples and (M, 4, 4) poses")  # fmt: skip
        if np.any(np.diff(self.t) <= 0):
            raise MocapError("pose curve: sample times not strictly increasing")
        finite = np.isfinite(T).all(axis=(1, 2))
        self.valid = finite if valid is None else (np.asarray(valid, bool) & finite)
        T = np.where(self.valid[:, None, None], T, np.eye(4))
        # the curve itself is PoseInterpolant's; this class adds the gaps and the status
        self.track = PoseInterpolant(self.t, T, self.valid)
        self.R = T[:, :3, :3]
        self.p = T[:, :3, 3]
        self.h = np.diff(self.t)
        self.max_gap_s = 3.0 * sample_period(self.t) if max_gap_s is None else float(max_gap_s)
        self.interval_ok = self.valid[:-1] & self.valid[1:] & (self.h <= self.max_gap_s)

    def at(self, tq_s):
        """The pose and its rates at query times.

        Parameters
        ----------
        tq_s : ndarray, shape (K,)
            Query times, s (the samples' clock).

        Returns
        -------
        R : ndarray, shape (K, 3, 3)
            R_A_X (identity where not ok).
        p : ndarray, shape (K, 3)
            p_A_X, m (0 where not ok).
        omega : ndarray, shape (K, 3)
            Body angular velocity (in X), rad/s.
        v : ndarray, shape (K, 3)
            Velocity in A, m/s.
        status : ndarray of int, shape (K,)
            0 ok; 1 outside the samples' span; 2 in a gap (an interval longer than
            ``max_gap_s`` or next to an invalid sample).
        """
        tq = np.atleast_1d(np.asarray(tq_s, float))
        i0, _ = self.track.locate(tq)
        inside = (tq >= self.t[0]) & (tq <= self.t[-1])
        ok = inside & self.interval_ok[i0]
        status = np.where(ok, 0, np.where(inside, 2, 1))
        T, v, omega = self.track(np.where(ok, tq, self.t[i0]), rates=True)
        R, p = T[:, :3, :3], T[:, :3, 3]
        R[~ok] = np.eye(3)
        p[~ok], omega[~ok], v[~ok] = 0.0, 0.0, 0.0
        return R, p, omega, v, status
