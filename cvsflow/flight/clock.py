"""Flight clock: the log's time offset and skew against the camera stream.

Clock convention (as ``t_vicon_s = t_video_s + dt_offset_s`` in contracts.md):
``t_ref_s = dt_offset_s + (1 + skew) * t_log_s``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.optimize import least_squares
from scipy.signal import correlate, correlation_lags
from scipy.spatial.transform import Rotation, Slerp

from cvsflow.errors import SyncError
from cvsflow.flight.alignment import rotation_alignment
from cvsflow.geometry import R_from_quat, rotation_angle

log = logging.getLogger(__name__)


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
