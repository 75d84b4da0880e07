"""Time offset of the video and Vicon streams (rule ``sync``).

Convention (docs/contracts.md): ``t_vicon_s = t_video_s + dt_offset_s``.

Inputs are ``poses_raw`` (per video frame: ``frame, t_s, valid, rvec_0..2`` = rvec_C_B,
``x_m, y_m, z_m`` = tvec_C_B, Euler of R_C_B) and the native-rate bodies table of
:mod:`cvsflow.mocap.bodies`. The frame association that uses the offset is :mod:`cvsflow.sync.pairs`.

The robust synchronisation compares the board's angular speed seen by both systems. The
camera sees R_C_B; the Vicon gives R_Cm_Bm = R_W_Cm^T R_W_Bm. With R_C_B = R_C_Cm R_Cm_Bm R_Bm_B
and R_C_Cm, R_Bm_B constant, the relative rotation between two instants differs only by a
constant conjugation, so its angle, hence the angular speed, is the same in both streams
whatever the unknown marker offsets are.

The streams are :mod:`cvsflow.sync.streams`, the rotation refinement :mod:`cvsflow.sync.offset_refine`
and the chapter's gesture method :mod:`cvsflow.sync.gesture`; this module cross-correlates the
streams (``sync_angular_speed``) and dispatches on the method (``synchronise``).
"""

from __future__ import annotations

import logging

import numpy as np

from cvsflow.exceptions import OverlapError, SyncError
from cvsflow.geometry import rotation_angle, sample_period
from cvsflow.plausibility import OVERLAP_FLOOR, check_overlap, overlap_share
from cvsflow.sync.gesture import sync_gesture
from cvsflow.sync.offset_refine import refine_offset_rotations
from cvsflow.sync.streams import (
    _cvs_rotations,
    _frame_list,
    _jump_outliers,
    _omega_vicon_between,
    _spans,
    _vicon_relative,
    check_take_covers_video,
)

log = logging.getLogger(__name__)

#: Least quality of a take shorter than the video: on rendered 12 s sessions cut to 20-25 % of
#: the video, the wrong lags that won scored 0.29 and 0.33, the right ones 0.97 and more.
SHORT_TAKE_MIN_QUALITY = 0.5


# --------------------------------------------------------------------------- sync


def masked_ncc(c, mc, v, mv, min_overlap):
    """Pearson correlation of c[j] with v[j + L] over jointly valid samples, for every lag L.

    Parameters
    ----------
    c, v : ndarray, shape (Nc,), (Nv,)
        Two signals on one grid step.
    mc, mv : ndarray of bool
        Their valid samples.
    min_overlap : float
        Fewest jointly valid samples for a lag to count.

    Returns
    -------
    lags : ndarray of int
        Lags L in samples (``scipy.signal.correlation_lags(len(v), len(c))``).
    r : ndarray
        The correlation at each lag; NaN where the overlap is short or a signal constant.
    """
    # scipy.signal loads scipy.stats with it (~0.5 s of CPU per process): imported where it is
    # used, so that jobs which only import this subpackage do not pay for it
    from scipy.signal import correlate, correlation_lags

    a = np.where(mc, c, 0.0)
    b = np.where(mv, v, 0.0)
    fc = mc.astype(float)
    fv = mv.astype(float)

    def xc(x, y):  # sum_j x[j] y[j + L]
        return correlate(y, x, mode="full", method="fft")

    lags = correlation_lags(len(v), len(c))
    N = np.rint(xc(fc, fv))
    Sa = xc(a, fv)
    Sb = xc(fc, b)
    Saa = xc(a * a, fv)
    Sbb = xc(fc, b * b)
    Sab = xc(a, b)
    with np.errstate(invalid="ignore", divide="ignore"):
        cov = Sab - Sa * Sb / N
        var = (Saa - Sa**2 / N) * (Sbb - Sb**2 / N)
        r = cov / np.sqrt(np.clip(var, 0.0, None))
    r[(min_overlap > N) | ~np.isfinite(r)] = np.nan
    return lags, r


def _spans_text(video_span, take_span):
    """Both spans and their lengths, for the messages."""
    (v0, v1), (k0, k1) = video_span, take_span
    return (f"the video spans {v0:.3f}..{v1:.3f} s ({v1 - v0:.3f} s, video clock), the take "
            f"{k0:.3f}..{k1:.3f} s ({k1 - k0:.3f} s, Vicon clock)")


def main_lobe(r, k):
    """Indices [lo, hi] of the lobe around index k where r decreases monotonically away from k.

    Parameters
    ----------
    r : ndarray
        A correlation curve (NaN ends a lobe).
    k : int
        Index of its peak.

    Returns
    -------
    lo, hi : int
        First and last index of the lobe.
    """
    lo = k
    while lo > 0 and np.isfinite(r[lo - 1]) and r[lo - 1] <= r[lo]:
        lo -= 1
    hi = k
    while hi < len(r) - 1 and np.isfinite(r[hi + 1]) and r[hi + 1] <= r[hi]:
        hi += 1
    return lo, hi


def sync_angular_speed(
    poses_raw,
    bodies,
    max_offset_s=30.0,
    min_quality=0.5,
    grid_step_s=None,
    min_overlap_frac=0.5,
    max_baseline=15,
    smooth_s=0.01,
    speed_window_s=0.1,
    camera="camera",
    board="board",
):
    """Time offset by cross-correlating the board's angular speed in both streams.

    Parameters
    ----------
    poses_raw : DataFrame
        ``poses_raw.parquet`` (video clock).
    bodies : DataFrame
        Native-rate bodies table with ``camera`` and ``board`` (Vicon clock).
    max_offset_s : float
        Search range |dt_offset_s| <= max_offset_s, s.
    min_quality : float
        Below this quality (0..1) the offset is refused.
    grid_step_s : float, optional
        Common grid step, s; default a quarter of the video frame interval.
    min_overlap_frac : float
        A lag is considered only where at least this fraction of the valid video samples
        overlap valid Vicon samples.
    max_baseline : int
        Longest frame baseline of the refinement (:func:`refine_offset_rotations`), frames.
    smooth_s : float
        Gaussian smoothing of the Vicon rotations in the refinement, s.
    speed_window_s : float
        Baseline of the correlated angular speeds, s, rounded to whole video frames (at
        least one): the rotation between frames that far apart over their time difference,
        and the Vicon's over the same span. Frame to frame, a PnP rotation noise sigma gives
        a speed noise of sqrt(2) sigma times the frame rate; at 60 fps with the board 2-4 m
        away that left a correlation of 0.64 against a second peak of 0.52 (quality 0.15),
        over 0.1 s it is 0.975 against 0.48 (0.93). Hand motion is slower than 0.1 s.

    Returns
    -------
    sync : dict
        ``dt_offset_s`` (t_vicon_s = t_video_s + dt_offset_s), ``method`` ("angular_speed"),
        ``quality`` in [0, 1], ``details`` (peak correlation, second peak, coarse, parabolic and
        refined offsets, the refinement's jackknife standard error ``dt_sigma_s`` and robust
        residual RMS ``residual_rms_rad``, its settings, sample counts).

    Raises
    ------
    SyncError
        Too few valid samples, quality below ``min_quality``, or the correlation peak at the
        search boundary.
    InputError
        The take is shorter than the video.

    Notes
    -----
    Video frames whose rotation jumps faster than 1.5 times the Vicon's 99.9th percentile
    angular speed plus 0.5 rad/s, in runs of at most 5 frames (PnP flips), are left out
    (``n_jump_frames``). Then three steps: (1) masked normalised cross-correlation (FFT) of both
    angular speeds on a common grid (frames without a board are masked, never interpolated
    over); (2) parabolic interpolation of the peak; (3) refinement within one video frame interval of it by
    :func:`refine_offset_rotations`: the angles of the relative rotations between video frames
    1 to ``max_baseline`` frames apart against the same angles of the (smoothed, SLERPed) Vicon
    rotations at t_video + dt, Huber loss. Step (3) replaces a minimisation of the mismatch of
    frame-to-frame angular speeds, whose sensitivity to dt (angular acceleration times one frame
    interval) drowns in the noise of 30 Hz finite differences: on rendered 20 s sessions it
    moved a parabolic estimate within 1 ms of truth to 3.5 ms off, where step (3) stays within
    1 ms (bench/bench_sync.py).
    Quality = max(r_peak, 0) * (r_peak - r_2) / (1 - r_2), with r_2 the highest correlation
    outside the main lobe: 1 for a perfect, unique peak; 0 when another lag does as well.
    """
    video_span, take_span = _spans(poses_raw, bodies)
    check_take_covers_video(video_span, take_span, min_share=OVERLAP_FLOOR)
    t_frames = np.sort(poses_raw["t_s"].to_numpy(float))
    h = sample_period(t_frames)
    step = h / 4.0 if grid_step_s is None else float(grid_step_s)
    n_win = max(1, int(round(speed_window_s / h)))  # the speeds' baseline, frames
    window = n_win * h
    # Vicon stream on the grid step, over the same baseline
    t_v_all, T_v, valid_v = _vicon_relative(bodies, camera, board)
    g_v = np.arange(t_v_all[0] + window / 2, t_v_all[-1] - window / 2 + 1e-12, step)
    s_v = _omega_vicon_between(t_v_all, T_v, valid_v, g_v - window / 2, g_v + window / 2)
    m_v = np.isfinite(s_v)
    if m_v.sum() < 10:
        raise SyncError("angular-speed sync: fewer than 10 valid Vicon samples of both bodies")
    # video poses that jump faster than the board ever turns in the Vicon (PnP flips) would
    # dominate both the correlation and the refinement: left out
    t_r, R_r, valid_r = _cvs_rotations(poses_raw)
    max_speed = 1.5 * float(np.percentile(s_v[m_v], 99.9)) + 0.5
    flips = _jump_outliers(t_r, R_r, valid_r, max_speed)
    valid_r = valid_r & ~flips
    if flips.any():
        log.warning("sync: %d video frames left out, their rotation jumps faster than %.1f rad/s "
                    "(frames %s)", int(flips.sum()), max_speed, _frame_list(poses_raw, flips))
    t_c = 0.5 * (t_r[:-n_win] + t_r[n_win:])
    w_c = (rotation_angle(np.swapaxes(R_r[:-n_win], 1, 2) @ R_r[n_win:])
           / (t_r[n_win:] - t_r[:-n_win]))  # fmt: skip
    w_c[~(valid_r[:-n_win] & valid_r[n_win:])] = np.nan
    ok_c = np.isfinite(w_c)
    if ok_c.sum() < 10:
        raise SyncError(
            f"angular-speed sync: only {int(ok_c.sum())} video frame pairs {n_win} frame(s) apart "
            "with a board pose (expected at least 10)"
        )
    # video stream on its grid: linear between consecutive valid samples only
    g_c = np.arange(t_c[0], t_c[-1] + 1e-12, step)
    j = np.clip(np.searchsorted(t_c, g_c, side="right") - 1, 0, len(t_c) - 2)
    f = np.clip((g_c - t_c[j]) / (t_c[j + 1] - t_c[j]), 0.0, 1.0)
    s_c = (1 - f) * w_c[j] + f * w_c[j + 1]
    m_c = np.isfinite(s_c)
    # half the shorter stream: a take shorter than the video may lie wholly inside it
    min_overlap = max(OVERLAP_FLOOR * m_c.sum(), min_overlap_frac * min(m_c.sum(), m_v.sum()))
    lags, r = masked_ncc(s_c, m_c, s_v, m_v, min_overlap)
    dt_lag = (g_v[0] - g_c[0]) + lags * step
    allowed = np.abs(dt_lag) <= max_offset_s
    r = np.where(allowed, r, np.nan)
    need = f"{100 * min_overlap / m_c.sum():.0f} % of the video's frames with a board inside the take"
    if not np.isfinite(r).any():
        raise OverlapError(
            f"angular-speed sync: the overlap of the take and the video is too short: no lag "
            f"within +-{max_offset_s} s puts {need} (the least the search accepts); "
            f"{_spans_text(video_span, take_span)}"
        )
    k = int(np.nanargmax(r))
    r_peak = float(r[k])
    if abs(abs(dt_lag[k]) - max_offset_s) < step or k in (0, len(r) - 1):
        raise SyncError(
            f"angular-speed sync: correlation peak (r = {r_peak:.3f}) at the edge of the search "
            f"range, dt = {dt_lag[k]:.3f} s (max_offset_s = {max_offset_s}); no offset can be trusted"
        )
    if not (np.isfinite(r[k - 1]) and np.isfinite(r[k + 1])):
        # the lags beside the peak overlap too little to be scored: the overlap limits the search
        share = overlap_share(t_frames, float(dt_lag[k]), take_span)
        raise OverlapError(
            f"angular-speed sync: the overlap of the take and the video is too short: the best lag "
            f"(dt = {dt_lag[k]:.3f} s, r = {r_peak:.3f}) puts {100 * share:.0f} % of the video "
            f"inside the take, at the limit of the search ({need}), so no peak can be told from "
            f"the edge; {_spans_text(video_span, take_span)}"
        )
    lo, hi = main_lobe(r, k)
    outside = r.copy()
    outside[lo : hi + 1] = np.nan
    r_2 = float(np.nanmax(outside)) if np.isfinite(outside).any() else 0.0
    r_2 = max(r_2, 0.0)
    quality = float(np.clip(max(r_peak, 0.0) * (r_peak - r_2) / max(1.0 - r_2, 1e-12), 0.0, 1.0))
    # parabolic peak interpolation
    y0, y1, y2 = r[k - 1], r[k], r[k + 1]
    denom = y0 - 2 * y1 + y2
    delta = 0.5 * (y0 - y2) / denom if denom < 0 else 0.0
    dt_parab = float(dt_lag[k] + np.clip(delta, -1.0, 1.0) * step)
    # refinement: angles of relative rotations over several baselines (mounting-invariant)
    R_v = np.where(valid_v[:, None, None], T_v[:, :3, :3], np.eye(3))
    ref = refine_offset_rotations(
        t_r, R_r, valid_r, t_v_all, R_v, valid_v, dt_parab, search_s=h,
        max_baseline=max_baseline, smooth_s=smooth_s,
    )
    dt = ref["dt_s"] if ref["dt_s"] is not None else dt_parab
    if ref["dt_s"] is None:
        log.warning("sync: too few frame pairs (%d) for the rotation refinement; parabolic peak kept",
                    ref["n_pairs"])
    details = {
        "r_peak": r_peak,
        "r_second": r_2,
        "dt_coarse_s": float(dt_lag[k]),
        "dt_parabolic_s": dt_parab,
        "dt_refined_s": dt,
        "refinement": "relative_rotation_angles" if ref["dt_s"] is not None else None,
        "dt_sigma_s": ref["sigma_s"],
        "residual_rms_rad": ref["residual_rms_rad"],
        "max_baseline_frames": ref["max_baseline"],
        "vicon_smooth_s": ref["smooth_s"],
        "n_refine_pairs": ref["n_pairs"],
        "n_refine_frames": ref["n_frames"],
        "grid_step_s": step,
        "window_s": window,
        "window_frames": n_win,
        "n_video_pairs": int((valid_r[:-1] & valid_r[1:]).sum()),
        "n_jump_frames": int(flips.sum()),
        "max_speed_rad_s": max_speed,
        "n_grid_video": int(m_c.sum()),
        "n_grid_vicon": int(m_v.sum()),
        "max_offset_s": float(max_offset_s),
        "min_quality": float(min_quality),
    }
    short = (take_span[1] - take_span[0]) < (video_span[1] - video_span[0])
    need = max(min_quality, SHORT_TAKE_MIN_QUALITY) if short else min_quality
    if quality < need:
        raise SyncError(
            f"angular-speed sync: quality {quality:.3f} below min_quality {need:g} "
            f"(peak r = {r_peak:.3f} at dt = {dt:.4f} s, second peak r = {r_2:.3f})"
            + (f"; the take is shorter than the video, so little of the motion is shared (such a "
               f"take needs a quality of {SHORT_TAKE_MIN_QUALITY:g}): "
               f"{_spans_text(video_span, take_span)}" if short else "")
        )
    log.info("sync: dt_offset_s = %.5f s, quality %.3f (r = %.3f)", dt, quality, r_peak)
    return {"dt_offset_s": dt, "method": "angular_speed", "quality": quality, "details": details}


def synchronise(poses_raw, bodies, method="angular_speed", max_offset_s=30.0, min_quality=0.5,
                min_overlap_share=0.8, **kwargs):
    """Time offset between video and Vicon by the configured method (``sync.method``).

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet (video clock, R_C_B).
    bodies : DataFrame
        Native-rate bodies.parquet (Vicon clock, T_W_Cm and T_W_Bm).
    method : {"angular_speed", "gesture"}
        ``sync.method``.
    max_offset_s : float
        Largest |dt_offset_s| searched, s.
    min_quality : float
        Quality (0..1) below which the offset is refused.
    min_overlap_share : float
        Share of video frames inside the take below which a warning is given.
    **kwargs
        Passed to :func:`sync_angular_speed` or :func:`sync_gesture`.

    Returns
    -------
    sync : dict
        For sync.yaml: ``dt_offset_s``, ``method``, ``quality``, ``details``, ``overlap_share``
        (share of video frames whose Vicon time lies inside the take) and ``warnings`` (one
        when the share is below ``min_overlap_share``, ``sync.min_overlap_share``).

    Raises
    ------
    SyncError, InputError
        See :func:`sync_angular_speed` and :func:`sync_gesture`; an unknown method.
    OverlapError
        Under 20 % (or 30 frames) of the video inside the take.
    """
    if method == "angular_speed":
        out = sync_angular_speed(poses_raw, bodies, max_offset_s, min_quality, **kwargs)
    elif method == "gesture":
        out = sync_gesture(poses_raw, bodies, max_offset_s, min_quality, **kwargs)
    else:
        raise SyncError(f"sync method {method!r} unknown (expected 'angular_speed' or 'gesture')")
    # partial overlap: the share of video frames inside the take, a warning under the minimum
    _, take_span = _spans(poses_raw, bodies)
    share, warnings = check_overlap(poses_raw["t_s"].to_numpy(float), out["dt_offset_s"], take_span,
                                    min_share=min_overlap_share, source="sync")
    for w in warnings:
        log.warning(w)
    out["overlap_share"] = share
    out["warnings"] = warnings
    return out


def given_offset(poses_raw, bodies, dt_offset_s, min_overlap_share=0.8, names=None):
    """sync.yaml for a session that states its time offset (``dt_offset_s``): nothing searched.

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet (camera clock).
    bodies : DataFrame
        Native-rate bodies.parquet (mocap clock).
    dt_offset_s : float
        The stated offset, t_mocap = t_camera + dt_offset_s, s.
    min_overlap_share : float
        Share of frames inside the take below which a warning is given.
    names : dict, optional
        What the messages call the streams (:func:`cvsflow.plausibility.check_overlap`'s
        ``names``); default the video's and the Vicon take's.

    Returns
    -------
    sync : dict
        As :func:`synchronise`: ``dt_offset_s``, ``method`` ``given``, ``quality`` None (no
        search), ``details`` (``dt_sigma_s`` 0: held, not estimated), ``overlap_share``,
        ``warnings``.

    Raises
    ------
    OverlapError
        Under 20 % (or 30 frames) of the frames inside the take at that offset.
    """
    _, take_span = _spans(poses_raw, bodies)
    share, warnings = check_overlap(poses_raw["t_s"].to_numpy(float), float(dt_offset_s), take_span,
                                    min_share=min_overlap_share, source="sync", names=names)
    for w in warnings:
        log.warning(w)
    log.info("time offset %.6f s as the session states it (not estimated)", dt_offset_s)
    return {"dt_offset_s": float(dt_offset_s), "method": "given", "quality": None,
            "details": {"dt_sigma_s": 0.0}, "overlap_share": share, "warnings": warnings}
