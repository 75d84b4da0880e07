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
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import SyncError
from cvsflow.flight.alignment import rotation_alignment
from cvsflow.geometry import PoseInterpolant, R_from_quat, make_T, rotation_angle, sample_period
from cvsflow.metrics import leverage_corrected_scores

log = logging.getLogger(__name__)

#: Scale of the fine step's soft_l1 loss, in units of the stated sigma: Huber's 1.345, at which
#: the loss keeps 95 % of least squares' efficiency on Gaussian residuals (soft_l1: 95.4 %)
#: and a PnP reference's planar flips (single frames 10-40 deg off) lose most of their weight.
SOFT_L1_SCALE = 1.345
CHI2_1_MEDIAN = 0.454936  # median of chi-square with one degree of freedom


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
    # scipy.signal loads scipy.stats with it (~0.5 s of CPU per process): imported where it is
    # used, so that jobs which only import this subpackage do not pay for it
    from scipy.signal import correlate, correlation_lags

    if baseline_s is None:
        tm_r, w_r = angular_speed(t_r, R_r)
        tm_e, w_e = angular_speed(t_e, R_e)
        gap_r = np.diff(t_r) < 2.5 * sample_period(t_r)  # missed frames give no speed
    else:
        tm_r, w_r, span_r = angular_speed(t_r, R_r, baseline_s)
        tm_e, w_e, _ = angular_speed(t_e, R_e, baseline_s)
        gap_r = span_r < baseline_s + 2.5 * sample_period(t_r)
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
    max_floor_deg: float = 8.0,
) -> Clock:
    """Time offset (and skew) of the log against the camera stream.

    1. Coarse: angular speed of both streams (independent of every frame choice), resampled at
       ``rate_hz``; normalised cross-correlation over all lags, peak refined by a parabola.
       Frame-to-frame speeds first; when their peak is below ``min_quality`` (a PnP reference
       of a far board: tilt noise and planar flips), speeds over the longer
       ``speed_baselines_s`` in turn, the first clear peak taken.
    2. Fine (below one video frame): a robust fit over (offset, skew) of the orientation
       residuals ``log(R_C_B^T R_C_L R_L_Q(tau) R_Q_B)`` in units of the stated sigma, with
       the log SLERPed at the mapped times ``tau`` and the constant rotations R_C_L (and R_Q_B
       when not given) re-solved in closed form (:func:`rotation_alignment`) at every trial.
       The loss is soft_l1 with scale :data:`SOFT_L1_SCALE` sigma: a PnP reference's planar
       flips (single frames 10-40 deg off, which its stated sigma does not cover) lose most
       of their weight. Orientation only: position drift, scale and invalid positions do not
       enter.
    3. Uncertainty of the fine step's (offset, skew): the M-estimator's sandwich
       (:func:`_block_sandwich`) whose middle sums the residuals' scores over time blocks of
       ``block_s``: it holds when the stated sigma is off by a factor, and when the
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
        Reference orientation standard deviation per row (weights 1/sigma); None: one sigma
        for all rows, the residuals' robust scale (1.4826 MAD) at the coarse offset.
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
    max_floor_deg : float
        Largest orientation error of the log beyond the reference's stated sigma (the fine
        step's floor, ``details["sigma_floor_rad"]``) at which the streams count as aligned;
        above it the next baseline's peak is tried. Only with ``sigma_rot_rad``.

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
        Too few valid orientations, a correlation peak below ``min_quality`` at every
        baseline, or every clear peak leaving the orientations more than ``max_floor_deg``
        apart beyond the stated sigma.
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
    # fine: orientation residuals; parameters (offset at the reference's centre, skew * 1e3)
    sigma = (
        None if sigma_rot_rad is None
        else np.maximum(np.asarray(sigma_rot_rad, float)[m_r], 1e-9)
    )  # fmt: skip
    w = np.ones(len(t_r))  # the residuals' weights, set by fine() below
    log_track = PoseInterpolant(t_e, make_T(R_e, np.zeros((len(R_e), 3))))
    t_c = 0.5 * (t_r[0] + t_r[-1])
    state = {"R_Q_B": R_Q_B}

    def residual(x):
        dt_c, skew = x[0], (x[1] * 1e-3 if len(x) > 1 else 0.0)
        tau = (t_r - t_c) / (1 + skew) + (t_c - dt_c)  # log time of each reference row
        inside = (tau >= t_e[0]) & (tau <= t_e[-1])
        if inside.sum() < 10:
            return np.full(3 * len(t_r), 1e3)
        Re = log_track(np.clip(tau, t_e[0], t_e[-1]))[:, :3, :3]
        R_CL, R_QB = rotation_alignment(R_r[inside], Re[inside], R_Q_B, w[inside] ** 2, n_iter=3)
        state["R_Q_B"] = R_QB
        r = Rotation.from_matrix(np.swapaxes(R_r, -1, -2) @ R_CL @ Re @ R_QB).as_rotvec()
        r = np.where(inside[:, None], r * w[:, None], 0.0)
        # in units of sigma while every row overlaps the log; rows that fall out of it scale
        # the rest up, so that losing rows does not lower the cost
        return r.ravel() * np.sqrt(len(t_r) / inside.sum())

    def fit(x_start):
        return least_squares(
            residual,
            x_start,
            x_scale=[0.01, 0.1][: len(x_start)],
            diff_step=[1e-5, 1e-3][: len(x_start)],
            loss="soft_l1",
            f_scale=SOFT_L1_SCALE,
        )

    def fine(dt0):
        x0 = np.array([dt0, 0.0]) if estimate_skew else np.array([dt0])  # dt_c = dt0, skew 0
        w[:] = 1.0 if sigma is None else 1.0 / sigma
        if sigma is None:
            # no stated sigma: the residuals' own robust scale at the coarse offset (1.4826
            # MAD, the Gaussian sigma), so that the robust loss engages in the same units
            r0 = np.abs(residual(x0))
            w[:] /= 1.4826 * max(float(np.median(r0[r0 > 0])), 1e-12)
            return fit(x0), 0.0
        # the residual is the reference's error plus the log's own, which no sigma states: fit
        # once, take the floor the stated sigma leaves unexplained, refit with both
        res = fit(x0)
        r_rad = res.fun.reshape(-1, 3) / w[:, None]
        used = np.any(r_rad != 0, axis=1)
        floor = _error_floor(r_rad[used], sigma[used])
        w[:] = 1.0 / np.hypot(sigma, floor)
        return fit(res.x), floor

    # the shortest baseline whose peak is clear: frame-to-frame speeds are sharpest, but a
    # far, small board's PnP tilt noise (and its planar flips, single-frame 10-40 deg jumps)
    # swamps them; over a longer baseline the orientation noise shrinks with the span. A clear
    # peak at the wrong lag leaves the orientations tens of degrees apart beyond their stated
    # sigma (14-22 deg on rendered flights, against 0.4-1 deg aligned): the next baseline's
    # peak is tried then
    tried, misaligned = [], []
    for baseline_s in speed_baselines_s:
        dt0, quality = _xcorr_offset(t_r, R_r, t_e, R_e, rate_hz, max_offset_s, baseline_s)
        tried.append((baseline_s, quality, dt0))
        if quality < min_quality:
            continue
        res, sigma_floor = fine(dt0)
        if sigma_floor <= np.radians(max_floor_deg):
            break
        misaligned.append((baseline_s, dt0, sigma_floor))
    else:
        if misaligned:
            raise SyncError(
                "time alignment: at every clear correlation peak the log's orientation stays "
                f"more than {max_floor_deg:g} deg from the reference's beyond its stated sigma ("
                + ", ".join(f"{np.degrees(f):.1f} deg at offset {d:.3f} s over {b or 'one frame'} s"
                            for b, d, f in misaligned)
                + "): the clocks are not aligned; narrow max_offset_s around the true offset"
            )  # fmt: skip
        raise SyncError(
            "time alignment: angular-speed correlation peak below min_quality "
            f"{min_quality} at every baseline: "
            + ", ".join(f"{q:.2f} at offset {d:.3f} s over {b or 'one frame'} s"
                        for b, q, d in tried)
        )  # fmt: skip
    dt_c = float(res.x[0])
    skew = float(res.x[1] * 1e-3) if estimate_skew else 0.0
    # tau = (t_r - t_c)/(1+skew) + t_c - dt_c  =>  t_r = (1+skew)(tau - t_c + dt_c) + t_c
    dt_offset = t_c - (1 + skew) * (t_c - dt_c)
    R_QB_fit = np.asarray(state["R_Q_B"])
    cov_x = _block_sandwich(residual, res.x, t_r, block_s, SOFT_L1_SCALE)
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
            "refine_rms": float(np.sqrt(np.mean(res.fun**2))),
            "sigma_floor_rad": float(sigma_floor),
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


def _error_floor(r_rad, sigma_rad, tol_rad=1e-6):
    """The error each residual has beyond its stated sigma: a robust variance component.

    Parameters
    ----------
    r_rad : ndarray, shape (N, 3)
        Residuals, rad.
    sigma_rad : ndarray, shape (N,)
        Their stated standard deviation per component, rad.
    tol_rad : float
        Bisection tolerance, rad.

    Returns
    -------
    float
        ``s0`` >= 0 such that ``r^2 / (sigma^2 + s0^2)`` has its median, weighted by
        ``1 / (sigma^2 + s0^2)``, at the median of chi-square(1), 0.455: the robust form of
        the variance component's likelihood equation, whose weights let the precise rows,
        where the floor shows, decide. 0 when the stated sigma already covers the residuals.
    """
    r2 = np.asarray(r_rad, float) ** 2
    v_stated = np.asarray(sigma_rad, float) ** 2

    def excess(s0):
        v = np.repeat(v_stated + s0**2, 3)
        q = r2.ravel() / v
        order = np.argsort(q)
        cw = np.cumsum(1.0 / v[order])
        return q[order][np.searchsorted(cw, 0.5 * cw[-1])] - CHI2_1_MEDIAN

    if excess(0.0) <= 0:
        return 0.0
    lo, hi = 0.0, float(np.sqrt(r2.max()))
    while hi - lo > tol_rad:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) > 0 else (lo, mid)
    return 0.5 * (lo + hi)


def _block_sandwich(residual, x, t_s, block_s, f_scale, steps=(1e-4, 1e-2)):
    """Covariance of soft_l1 M-estimated parameters from their scores summed per time block.

    Parameters
    ----------
    residual : callable
        x -> residuals in units of their sigma, shape (3 N,), three per row of ``t_s`` (0
        where unused).
    x : ndarray, shape (P,)
        The solution.
    t_s : ndarray, shape (N,)
        Time of each row, seconds.
    block_s : float
        Block length, seconds.
    f_scale : float
        The soft_l1 loss's scale, units of the residuals.
    steps : sequence of float
        Central-difference steps of the parameters.

    Returns
    -------
    cov : ndarray, shape (P, P)
        ``H^-1 M H^-1 B / (B - 1)`` (the M-estimator's sandwich, Huber 1967): with
        ``z = (r / f_scale)^2``, H = sum of psi'(r_i) J_i^T J_i, psi'(r) = (1 + z)^-3/2 the
        derivative of the loss's influence function ``psi(r) = r (1 + z)^-1/2``; M = sum over
        the B blocks of s_b s_b^T with s_b = (I - H_b H^-1)^-1 sum of J_i^T psi(r_i) over
        the block's rows, H_b the block's part of H (CR3 small-sample correction: H^-1 s_b
        is the one-step change of the solution when the block is left out).
    """
    x = np.asarray(x, float)
    r = residual(x).reshape(len(t_s), 3)
    J = np.empty((len(t_s), 3, len(x)))
    for k in range(len(x)):
        h = np.zeros(len(x))
        h[k] = steps[k]
        J[:, :, k] = (residual(x + h) - residual(x - h)).reshape(len(t_s), 3) / (2 * steps[k])
    z = (r / f_scale) ** 2
    score = np.einsum("nip,ni->np", J, r / np.sqrt(1 + z))
    H_row = np.einsum("ni,nip,niq->npq", (1 + z) ** -1.5, J, J)
    block = np.floor((t_s - t_s[0]) / block_s).astype(int)
    S = np.zeros((block.max() + 1, len(x)))
    H_b = np.zeros((block.max() + 1, len(x), len(x)))
    np.add.at(S, block, score)
    np.add.at(H_b, block, H_row)
    used = np.any(S != 0, axis=1)
    S, H_b = S[used], H_b[used]
    n_b = len(S)
    # a block that carries much of H pulls the fit to its own residuals, which then understate
    # its error: its leverage undone (CR3, cvsflow.metrics.sandwich)
    S, lam, V = leverage_corrected_scores(S, H_b)
    H_inv = (V / lam) @ V.T
    return H_inv @ (S.T @ S) @ H_inv * n_b / max(n_b - 1, 1)
