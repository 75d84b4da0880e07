"""The clock offset between a camera's pose stream and its marker body's, before the joint fit.

1. **Coarse** (:func:`coarse_offset`): the angular-speed magnitudes of both streams over a short
   baseline (independent of the unknown mountings), the camera's linear between its frame pairs
   and masked across detection gaps, the motion capture's on a common grid; the masked
   normalised cross-correlation of :mod:`cvsflow.sync` over every lag, its peak by a parabola,
   and a quality ``max(r1, 0) (r1 - r2) / (1 - r2)`` (r2 the best lag outside the main lobe).
   A peak of speed magnitudes can sit off the true offset (10 ms on ETH's prime_sense_1), so:
2. **Refined** (:func:`refine_offset`): the angles of the relative rotations between frames a
   few frames apart, equal in both streams at the true offset whatever the mountings
   (:func:`cvsflow.sync.refine_offset_rotations`), searched around the coarse offset.
3. Then the joint fit with the mountings (:mod:`cvsflow.handeye.stream_fit`) refines it again.

:func:`frame_motion` says whether the camera moved at its frames at all: a camera held still at
each frame (yac's stills) leaves the offset undetermined whatever the fit reports.
"""

from __future__ import annotations

import numpy as np

from cvsflow.flight import angular_speed
from cvsflow.geometry import PoseCurve, rvec_from_R, sample_period
from cvsflow.sync import main_lobe, masked_ncc, refine_offset_rotations

#: Fewest camera frame pairs one baseline apart for a speed stream.
MIN_CAMERA_SPEEDS = 20


def coarse_offset(t_cam_s, R_B_C, curve: PoseCurve, *, baseline_s=0.1, max_offset_s=2.0,
                  grid_step_s=0.005, min_overlap_frac=0.5) -> dict:  # fmt: skip
    """Offset by masked cross-correlation of the two streams' angular speed magnitudes.

    Parameters
    ----------
    t_cam_s : ndarray, shape (N,)
        Camera frame times, camera clock, s (the curve's epoch).
    R_B_C : ndarray, shape (N, 3, 3)
        Camera rotations in the target frame.
    curve : PoseCurve
        The marker body on the motion-capture clock.
    baseline_s : float
        Speeds from each frame to the first at least this much later (a detector's rotation
        noise over one frame swamps the speed; 0.1 s is three frames at 30 Hz), s.
    max_offset_s : float
        Lags searched, ``|dt| <= max_offset_s``, s.
    grid_step_s : float
        Common grid step, s.
    min_overlap_frac : float
        A lag counts where this share of the camera's valid grid samples overlap the curve's.

    Returns
    -------
    dict
        ``dt_s`` (None without a peak), ``r_peak``, ``r_second``, ``quality`` (0..1),
        ``baseline_s``, ``n_camera_speeds`` (frame pairs one baseline apart without a gap),
        ``reason`` (why ``dt_s`` is None).
    """
    out = {"dt_s": None, "r_peak": None, "r_second": None, "quality": 0.0, "baseline_s": baseline_s,
           "n_camera_speeds": 0, "reason": None}  # fmt: skip
    t = np.asarray(t_cam_s, float)
    if len(t) < 3:
        out["reason"] = f"{len(t)} camera frames"
        return out
    # a pair across a detection gap gives no speed; nor do stills seconds apart
    tol = min(1.5 * sample_period(t), baseline_s)
    tm, w, span = angular_speed(t, R_B_C, baseline_s)
    keep = span <= baseline_s + tol
    tm, w = tm[keep], w[keep]
    out["n_camera_speeds"] = int(len(tm))
    if len(tm) < MIN_CAMERA_SPEEDS:
        out["reason"] = (f"only {len(tm)} camera frame pairs {baseline_s:g} s apart without a gap "
                         f"(need {MIN_CAMERA_SPEEDS}): the camera stream gives no angular speed")  # fmt: skip
        return out
    g_c = np.arange(tm[0], tm[-1], grid_step_s)
    j = np.clip(np.searchsorted(tm, g_c, side="right") - 1, 0, len(tm) - 2)
    f = np.clip((g_c - tm[j]) / (tm[j + 1] - tm[j]), 0.0, 1.0)
    s_c = (1 - f) * w[j] + f * w[j + 1]
    m_c = (tm[j + 1] - tm[j]) <= tol  # never across a gap
    g_v = np.arange(curve.t[0] + baseline_s / 2, curve.t[-1] - baseline_s / 2, grid_step_s)
    R0, _, _, _, s0 = curve.at(g_v - baseline_s / 2)
    R1, _, _, _, s1 = curve.at(g_v + baseline_s / 2)
    s_v = np.linalg.norm(rvec_from_R(np.swapaxes(R0, 1, 2) @ R1).reshape(-1, 3), axis=1) / baseline_s
    lags, r = masked_ncc(s_c, m_c, s_v, (s0 == 0) & (s1 == 0), min_overlap_frac * m_c.sum())
    dt_lag = (g_v[0] - g_c[0]) + lags * grid_step_s
    r = np.where(np.abs(dt_lag) <= max_offset_s, r, np.nan)
    if not np.isfinite(r).any():
        out["reason"] = f"no lag within +-{max_offset_s:g} s overlaps enough motion-capture samples"
        return out
    k = int(np.nanargmax(r))
    if k == 0 or k == len(r) - 1 or not (np.isfinite(r[k - 1]) and np.isfinite(r[k + 1])):
        out.update(r_peak=float(r[k]), reason=f"correlation peak at the edge of the search range "
                                              f"(dt = {dt_lag[k]:.3f} s)")  # fmt: skip
        return out
    lo, hi = main_lobe(r, k)
    rest = r.copy()
    rest[lo : hi + 1] = np.nan
    r2 = max(float(np.nanmax(rest)) if np.isfinite(rest).any() else 0.0, 0.0)
    den = r[k - 1] - 2 * r[k] + r[k + 1]
    delta = float(np.clip(0.5 * (r[k - 1] - r[k + 1]) / den, -1, 1)) if den < 0 else 0.0
    out.update(dt_s=float(dt_lag[k] + delta * grid_step_s), r_peak=float(r[k]), r_second=r2,
               quality=float(np.clip(max(r[k], 0) * (r[k] - r2) / max(1 - r2, 1e-12), 0, 1)))  # fmt: skip
    return out


def best_coarse_offset(t_cam_s, R_B_C, curve, baselines_s=(0.1, 0.2, 0.4), min_quality=0.3,
                       max_offset_s=2.0) -> dict:  # fmt: skip
    """:func:`coarse_offset` over baselines in turn until a peak has ``min_quality``.

    Parameters
    ----------
    t_cam_s, R_B_C, curve
        As :func:`coarse_offset`.
    baselines_s : sequence of float
        Baselines tried, s.
    min_quality : float
        Smallest accepted quality.
    max_offset_s : float
        Lags searched, s.

    Returns
    -------
    dict
        The accepted :func:`coarse_offset`, or the best one with ``dt_s`` None and the reason;
        ``tried``: each baseline's ``dt_s``, ``r_peak``, ``quality``.
    """
    tried = []
    for b in baselines_s:
        c = coarse_offset(t_cam_s, R_B_C, curve, baseline_s=b, max_offset_s=max_offset_s)
        tried.append(c)
        if c["dt_s"] is not None and c["quality"] >= min_quality:
            break
    else:
        c = dict(max(tried, key=lambda x: x["quality"]))
        if c["dt_s"] is None:
            c["reason"] = f"{tried[-1]['reason']} (baselines {list(baselines_s)} s)"
        else:
            c["reason"] = (f"the angular-speed cross-correlation has no clear peak (quality "
                           f"{c['quality']:.2f} < {min_quality} at every baseline {list(baselines_s)} s; "
                           f"best r = {c['r_peak']:.2f} at dt = {c['dt_s']:.3f} s)")  # fmt: skip
            c["dt_s"] = None
    c["tried"] = [{k: x[k] for k in ("baseline_s", "dt_s", "r_peak", "quality")} for x in tried]
    return c


def refine_offset(t_cam_s, R_B_C, curve: PoseCurve, dt0_s, search_s=0.05, max_baseline=15) -> dict:
    """The offset from relative-rotation angles around ``dt0_s`` (mounting invariant).

    Parameters
    ----------
    t_cam_s : ndarray, shape (N,)
        Camera frame times, s.
    R_B_C : ndarray, shape (N, 3, 3)
        Camera rotations in the target frame.
    curve : PoseCurve
        The marker body on the motion-capture clock.
    dt0_s : float
        Start (the coarse offset), s.
    search_s : float
        Searched within ``dt0_s +- search_s``, s.
    max_baseline : int
        Longest frame baseline of the angle pairs.

    Returns
    -------
    dict
        :func:`cvsflow.sync.refine_offset_rotations`' result (``dt_s`` None with fewer than 20
        frame pairs).
    """
    return refine_offset_rotations(t_cam_s, R_B_C, np.ones(len(t_cam_s), bool), curve.t, curve.R,
                                   curve.valid, dt0_s, search_s, max_baseline=max_baseline)  # fmt: skip


def frame_motion(t_cam_s, curve: PoseCurve, dt_s, min_speed_rad_s=0.1, min_speed_m_s=0.05,
                 half_window_s=0.1) -> dict:  # fmt: skip
    """How fast the marker body moved at the camera's frames (speeds over +-``half_window_s``).

    A differentiated motion capture looks like motion over one sample interval (its own noise),
    hence the window.

    Parameters
    ----------
    t_cam_s : ndarray, shape (N,)
        Camera frame times, s.
    curve : PoseCurve
    dt_s : float
        Offset, s.
    min_speed_rad_s, min_speed_m_s : float
        A frame moves when the body turns or travels faster than these.
    half_window_s : float
        Half the speed window, s.

    Returns
    -------
    dict
        ``n_moving``, ``max_speed_deg_s``, ``max_speed_m_s``, ``median_speed_deg_s``,
        ``median_speed_m_s``.
    """
    t = np.asarray(t_cam_s, float) + dt_s
    Ra, pa, _, _, sa = curve.at(t - half_window_s)
    Rb, pb, _, _, sb = curve.at(t + half_window_s)
    both = (sa == 0) & (sb == 0)
    w = np.linalg.norm(rvec_from_R(np.swapaxes(Ra, 1, 2) @ Rb).reshape(-1, 3), axis=1) / (2 * half_window_s)
    w = np.where(both, w, 0.0)
    v = np.where(both, np.linalg.norm(pb - pa, axis=1) / (2 * half_window_s), 0.0)
    moving = (w > min_speed_rad_s) | (v > min_speed_m_s)
    return {"n_moving": int(moving.sum()), "max_speed_deg_s": float(np.degrees(w.max(initial=0.0))),
            "max_speed_m_s": float(v.max(initial=0.0)), "median_speed_deg_s": float(np.degrees(np.median(w))),
            "median_speed_m_s": float(np.median(v))}  # fmt: skip
