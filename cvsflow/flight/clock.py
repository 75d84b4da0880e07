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


def angular_speed(t_s, R, baseline_s=None) -> tuple[np.ndarray, np.ndarray]:
    """Angular speed between orientations, rad/s, at the interval midpoints.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Times, increasing, seconds.
    R : ndarray, shape (N, 3, 3)
        Orientations in any fixed world; the speed does not depend on it or on the body frame.
    baseline_s : float, optional
        None: between consecutive samples. Else from each sample to the first one at least
        ``baseline_s`` later: the mean speed over ~``baseline_s``, whose noise from the
        orientations' own errors is ``baseline_s`` / (sample interval) times smaller.

    Returns
    -------
    t_mid_s, omega : ndarray, shape (K,)
        Midpoint times (s) and speeds (rad/s); K = N-1 for consecutive samples.
    span_s : ndarray, shape (K,)
        Time between the two samples of each speed, s (only with ``baseline_s``).
    """
    t_s = np.asarray(t_s, float)
    if baseline_s is None:
        dt = np.diff(t_s)
        ang = rotation_angle(np.swapaxes(R[:-1], -1, -2) @ R[1:])
        return 0.5 * (t_s[1:] + t_s[:-1]), ang / dt
    j = np.searchsorted(t_s, t_s + (baseline_s - 1e-9), side="left")  # 1 ns: rounding of t
    i = np.flatnonzero(j < len(t_s))
    j = j[i]
    ang = rotation_angle(np.swapaxes(R[i], -1, -2) @ R[j])
    span = t_s[j] - t_s[i]
    return 0.5 * (t_s[i] + t_s[j]), ang / span, span


def _xcorr_offset(t_r, R_r, t_e, R_e, rate_hz, max_offset_s, baseline_s):
    """Offset of the log's angular speed against the reference's and the correlation peak.

    Returns ``(dt0_s, quality)``; raises SyncError when no lag has enough overlap.
    """
    if baseline_s is None:
        tm_r, w_r = angular_speed(t_r, R_r)
        tm_e, w_e = angular_speed(t_e, R_e)
        gap_r = np.diff(t_r) < 2.5 * np.median(np.diff(t_r))  # missed frames give no speed
    else:
        tm_r, w_r, span_r = angular_speed(t_r, R_r, baseline_s)
        tm_e, w_e, _ = angular_speed(t_e, R_e, baseline_s)
        gap_r = span_r < baseline_s + 2.5 * np.median(np.diff(t_r))
    tm_r, w_r = tm_r[gap_r], w_r[gap_r]
    if len(tm_r) < 10 or len(tm_e) < 10:
        raise SyncError(
            f"time alignment: {len(tm_r)} reference and {len(tm_e)} log angular speeds over "
            f"{baseline_s} s; at least 10 each needed"
        )
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
    return g_r[0] - g_e[0] + (lags[k] + frac) / rate_hz, quality


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
    speed_baselines_s=(None, 0.2, 0.4, 0.8),
    block_s: float = 2.0,
) -> Clock:
    """Time offset (and skew) of the log against the camera stream.

    1. Coarse: angular speed of both streams (independent of every frame choice), resampled at
       ``rate_hz``; normalised cross-correlation over all lags, peak refined by a parabola.
       Frame-to-frame speeds first; when their peak is below ``min_quality`` (a PnP reference
       of a far board: tilt noise and planar flips), speeds over the longer
       ``speed_baselines_s`` in turn, the first clear peak taken.
    2. Fine (below one video frame): least squares over (offset, skew) of the orientation
       residuals ``log(R_C_B^T R_C_L R_L_Q(tau) R_Q_B)``, with the log SLERPed at the mapped
       times ``tau`` and the constant rotations R_C_L (and R_Q_B when not given) re-solved in
       closed form (:func:`rotation_alignment`) at every trial. Orientation only: position
       drift, scale and invalid positions do not enter.
    3. Uncertainty of the fine step's (offset, skew): a sandwich (H^-1 M H^-1, H = J^T J of the
       weighted residuals) whose middle M sums the residuals' score J_i^T r_i over time blocks
       of ``block_s``: it holds when the stated sigma is off by a factor, and when the
       residuals are correlated in time (the on-board error drifts) over less than a block.

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
    speed_baselines_s : sequence of (float or None)
        Baselines of the coarse step's angular speed, tried in order (None: consecutive
        frames), seconds.
    block_s : float
        Time block of the uncertainty's sandwich, seconds (longer than the on-board error's
        correlation time).

    Returns
    -------
    Clock
        ``details``: ``xcorr_offset_s``, ``xcorr_baseline_s`` (None: frame to frame),
        ``refine_rms`` (weighted residual RMS), ``R_Q_B``; ``t_centre_s`` (reference clock,
        the middle of the reference) and ``dt_centre_std_s``: the standard deviation of the
        log time mapped to ``t_centre_s`` (where the offset correlates least with the skew);
        ``dt_offset_std_s``, ``skew_std`` and ``offset_skew_corr``.

    Raises
    ------
    SyncError
        Too few valid orientations or a correlation peak below ``min_quality`` at every
        baseline.
    """
    m_r = reference["rot_valid"].to_numpy(bool)
    t_r, R_r = _valid_rot(reference)
    t_e, R_e = _valid_rot(onboard)
    if len(t_r) < 10 or len(t_e) < 10:
        raise SyncError(
            f"time alignment: {len(t_r)} reference and {len(t_e)} log orientations; "
            "at least 10 each needed"
        )
    # the shortest baseline whose peak is clear: frame-to-frame speeds are sharpest, but a
    # far, small board's PnP tilt noise (and its planar flips, single-frame 10-40 deg jumps)
    # swamps them; over a longer baseline the orientation noise shrinks with the span
    tried = []
    for baseline_s in speed_baselines_s:
        dt0, quality = _xcorr_offset(t_r, R_r, t_e, R_e, rate_hz, max_offset_s, baseline_s)
        tried.append((baseline_s, quality, dt0))
        if quality >= min_quality:
            break
    else:
        raise SyncError(
            "time alignment: angular-speed correlation peak below min_quality "
            f"{min_quality} at every baseline: "
            + ", ".join(f"{q:.2f} at offset {d:.3f} s over {b or 'one frame'} s"
                        for b, q, d in tried)
        )  # fmt: skip

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
    R_QB_fit = np.asarray(state["R_Q_B"])
    cov_x = _block_sandwich(residual, res.x, t_r, block_s)
    # d dt_offset / d (dt_c, skew * 1e3)
    g = np.array([1 + skew, -(t_c - dt_c) * 1e-3])[: len(res.x)]
    dt_offset_std = float(np.sqrt(g @ cov_x @ g))
    skew_std = float(np.sqrt(cov_x[1, 1]) * 1e-3) if estimate_skew else 0.0
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
            "R_Q_B": R_QB_fit.tolist(),
            "xcorr_baseline_s": baseline_s,
            "t_centre_s": float(t_c),
            "dt_centre_std_s": float(np.sqrt(cov_x[0, 0])),
            "dt_offset_std_s": dt_offset_std,
            "skew_std": skew_std,
            "offset_skew_corr": (
                float(cov_x[0, 1] / np.sqrt(cov_x[0, 0] * cov_x[1, 1])) if estimate_skew else 0.0
            ),
        },
    )
    log.info(
        "time alignment: dt_offset_s %.6f, skew %.3g, correlation %.3f", dt_offset, skew, quality
    )
    return clock


def _block_sandwich(residual, x, t_s, block_s, steps=(1e-4, 1e-2)):
    """Covariance of least-squares parameters from their residuals' scores summed per time block.

    Parameters
    ----------
    residual : callable
        x -> weighted residuals, shape (3 N,), three per row of ``t_s`` (0 where unused).
    x : ndarray, shape (P,)
        The solution.
    t_s : ndarray, shape (N,)
        Time of each row, seconds.
    block_s : float
        Block length, seconds.
    steps : sequence of float
        Central-difference steps of the parameters.

    Returns
    -------
    cov : ndarray, shape (P, P)
        ``H^-1 M H^-1 B / (B - 1)``, H = J^T J, M = sum over the B blocks of s_b s_b^T with
        s_b = sum of J_i^T r_i over the block's rows.
    """
    x = np.asarray(x, float)
    r = residual(x).reshape(len(t_s), 3)
    J = np.empty((len(t_s), 3, len(x)))
    for k in range(len(x)):
        h = np.zeros(len(x))
        h[k] = steps[k]
        J[:, :, k] = (residual(x + h) - residual(x - h)).reshape(len(t_s), 3) / (2 * steps[k])
    score = np.einsum("nip,ni->np", J, r)
    block = np.floor((t_s - t_s[0]) / block_s).astype(int)
    S = np.zeros((block.max() + 1, len(x)))
    np.add.at(S, block, score)
    S = S[np.any(S != 0, axis=1)]
    n_b = len(S)
    H_inv = np.linalg.inv(np.einsum("nip,niq->pq", J, J))
    return H_inv @ (S.T @ S) @ H_inv * n_b / max(n_b - 1, 1)
