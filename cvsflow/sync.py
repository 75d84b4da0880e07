"""Time offset of the video and Vicon streams (rule ``sync``).

Convention (docs/contracts.md): ``t_vicon_s = t_video_s + dt_offset_s``.

Inputs are ``poses_raw`` (per video frame: ``frame, t_s, valid, rvec_0..2`` = rvec_C_B,
``x_m, y_m, z_m`` = tvec_C_B, Euler of R_C_B) and the native-rate bodies table of
:mod:`cvsflow.mocap`. The frame association that uses the offset is :mod:`cvsflow.pairs`.

The robust synchronisation compares the board's angular speed seen by both systems. The
camera sees R_C_B; the Vicon gives R_Cm_Bm = R_W_Cm^T R_W_Bm. With R_C_B = R_C_Cm R_Cm_Bm R_Bm_B
and R_C_Cm, R_Bm_B constant, the relative rotation between two instants differs only by a
constant conjugation, so its angle, hence the angular speed, is the same in both streams
whatever the unknown marker offsets are.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.signal import correlate, correlation_lags
from scipy.spatial.transform import Rotation

from cvsflow.errors import InputError, SyncError
from cvsflow.geometry import (
    R_from_rvec,
    interpolate_quats,
    interpolate_T,
    invert_T,
    mean_rotation,
    rotation_angle,
)
from cvsflow.mocap import body_poses
from cvsflow.plausibility import OVERLAP_FLOOR, check_overlap

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- streams


def _cvs_rotations(poses_raw):
    """Sorted video times (s), R_C_B (N, 3, 3) (identity where invalid) and validity."""
    p = poses_raw.sort_values("frame", kind="stable")
    rvec = p[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
    valid = p["valid"].to_numpy(bool) & np.isfinite(rvec).all(axis=1)
    rvec = np.where(valid[:, None], p[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float), 0.0)
    return p["t_s"].to_numpy(float), R_from_rvec(rvec), valid


def _vicon_relative(bodies, camera="camera", board="board"):
    """Vicon times (s), T_Cm_Bm (N, 4, 4) (NaN where either body is invalid) and validity."""
    t_c, T_W_Cm, v_c = body_poses(bodies, camera)
    t_b, T_W_Bm, v_b = body_poses(bodies, board)
    if len(t_c) != len(t_b) or not np.allclose(t_c, t_b):
        raise InputError("bodies table: camera and board samples are not on the same times")
    valid = v_c & v_b
    T = invert_T(np.where(valid[:, None, None], T_W_Cm, np.eye(4))) @ np.where(
        valid[:, None, None], T_W_Bm, np.eye(4)
    )
    T[~valid] = np.nan
    return t_b, T, valid


def _jump_outliers(t_s, R, valid, max_speed_rad_s, max_frames=5):
    """Frames of short runs set apart by rotation jumps faster than any real motion.

    A pose whose rotation differs from its neighbour's by more than ``max_speed_rad_s`` times
    their time difference is a jump (typically PnP's flip ambiguity of a nearly fronto-parallel
    board). Consecutive valid frames without a jump form runs. First, runs of at most
    ``max_frames`` frames with a jump at both ends are outliers; then, those left out, runs
    of at most ``max_frames`` with a jump at one end (the other end a missing pose or the end
    of the video). A longer run is taken as the truth.

    Returns
    -------
    outlier : ndarray of bool, shape (N,)
    """
    n = len(t_s)
    out = np.zeros(n, dtype=bool)
    if n < 2:
        return out
    for both_ends in (True, False):
        ok = valid & ~out
        pair = ok[:-1] & ok[1:]
        speed = np.zeros(n - 1)
        speed[pair] = rotation_angle(np.swapaxes(R[:-1][pair], 1, 2) @ R[1:][pair]) / np.diff(t_s)[pair]
        jump = pair & (speed > max_speed_rad_s)
        brk = ~pair | jump  # run boundaries between frame k and k + 1
        starts = np.concatenate([[0], np.flatnonzero(brk) + 1])
        ends = np.concatenate([np.flatnonzero(brk), [n - 1]])
        for a, b in zip(starts, ends, strict=True):
            if not ok[a] or b - a + 1 > max_frames:
                continue
            j0, j1 = a > 0 and jump[a - 1], b < n - 1 and jump[b]
            if (j0 and j1) if both_ends else (j0 or j1):
                out[a : b + 1] = True
    return out


def _frame_list(poses_raw, mask, at_most=10):
    """The frame numbers where mask is true (sorted by frame), at most ``at_most`` of them."""
    frames = np.sort(poses_raw["frame"].to_numpy())[mask]
    more = f" and {len(frames) - at_most} more" if len(frames) > at_most else ""
    return ", ".join(str(int(f)) for f in frames[:at_most]) + more


def angular_speed_cvs(poses_raw):
    """Board angular speed seen by the camera, from consecutive video frames.

    Parameters
    ----------
    poses_raw : DataFrame
        ``poses_raw.parquet`` table (``frame, t_s, valid, rvec_0..2``; rvec_C_B).

    Returns
    -------
    t_mid_s : ndarray, shape (N - 1,)
        Mid-times of consecutive frames, video clock, s.
    omega_rad_s : ndarray, shape (N - 1,)
        |omega| = angle(R_C_B(i)^T R_C_B(i+1)) / (t_{i+1} - t_i), rad/s; NaN where either
        frame has no valid pose (masked, not interpolated).
    """
    t, R, valid = _cvs_rotations(poses_raw)
    ang = rotation_angle(np.swapaxes(R[:-1], 1, 2) @ R[1:])
    omega = ang / np.diff(t)
    omega[~(valid[:-1] & valid[1:])] = np.nan
    return 0.5 * (t[:-1] + t[1:]), omega


def _omega_vicon_between(t_v, T_v, valid_v, t0, t1):
    """Angular speed (rad/s) of the Vicon relative rotation between times t0 and t1 (SLERP)."""
    T0, ok0, _ = interpolate_T(t_v, T_v, valid_v, t0)
    T1, ok1, _ = interpolate_T(t_v, T_v, valid_v, t1)
    ok = ok0 & ok1
    R0 = np.where(ok[:, None, None], T0[:, :3, :3], np.eye(3))
    R1 = np.where(ok[:, None, None], T1[:, :3, :3], np.eye(3))
    omega = rotation_angle(np.swapaxes(R0, 1, 2) @ R1) / (t1 - t0)
    omega[~ok] = np.nan
    return omega


def angular_speed_vicon(bodies, window_s, t_grid_s=None, camera="camera", board="board"):
    """Board angular speed relative to the camera body from the Vicon, over a window.

    Parameters
    ----------
    bodies : DataFrame
        Native-rate bodies table.
    window_s : float
        Time between the two rotations compared, s: the video frame interval, so that both
        streams average the true angular speed over the same span.
    t_grid_s : ndarray, optional
        Centre times on the Vicon clock, s; default every native sample.

    Returns
    -------
    t_s : ndarray, shape (K,)
    omega_rad_s : ndarray, shape (K,)
        NaN where the Vicon relative pose is invalid at either end of the window.
    """
    t_v, T_v, valid_v = _vicon_relative(bodies, camera, board)
    t = t_v if t_grid_s is None else np.asarray(t_grid_s, dtype=float)
    return t, _omega_vicon_between(t_v, T_v, valid_v, t - window_s / 2, t + window_s / 2)


def angular_speed_streams(poses_raw, bodies, camera="camera", board="board"):
    """Both angular-speed streams as plotted by :func:`cvsflow.plots.mocap.plot_sync`.

    Parameters
    ----------
    poses_raw : DataFrame
        poses_raw.parquet (``t_s`` video clock, ``valid``, ``rvec_0..2`` of R_C_B).
    bodies : DataFrame
        Native-rate bodies.parquet (T_W_Cm and T_W_Bm).
    camera, board : str
        Body names of the camera-marker and board-marker bodies.

    Returns
    -------
    streams : dict
        ``t_cvs_s``, ``omega_cvs_rad_s`` (video clock) and ``t_vicon_s``,
        ``omega_vicon_rad_s`` (Vicon clock, native samples, same window as the video).
    """
    t_c, w_c = angular_speed_cvs(poses_raw)
    h = float(np.median(np.diff(np.sort(poses_raw["t_s"].to_numpy(float)))))
    t_v, w_v = angular_speed_vicon(bodies, h, camera=camera, board=board)
    return {"t_cvs_s": t_c, "omega_cvs_rad_s": w_c, "t_vicon_s": t_v, "omega_vicon_rad_s": w_v}


# --------------------------------------------------------------------------- checks


def _spans(poses_raw, bodies):
    t_video = poses_raw["t_s"].to_numpy(float)
    t_vicon = bodies["t_s"].to_numpy(float)
    return (float(t_video.min()), float(t_video.max())), (float(t_vicon.min()), float(t_vicon.max()))


def check_take_covers_video(video_span_s, take_span_s, dt_offset_s=None, tol_s=1e-9, min_share=1.0):
    """Raise InputError when the Vicon take is shorter than the video (or misses part of it).

    With ``min_share`` < 1 and no offset, the take need only last ``min_share`` of the video
    (a partial overlap is used for what it covers: :func:`cvsflow.plausibility.check_overlap`).

    Parameters
    ----------
    video_span_s : (float, float)
        First and last video frame times, video clock, s.
    take_span_s : (float, float)
        First and last Vicon sample times, Vicon clock, s.
    dt_offset_s : float, optional
        Known offset; with it, the video span mapped to the Vicon clock must lie in the take.
    tol_s : float
        Slack at each end, s.
    min_share : float
        Share of the video the take must last when no offset is given, in (0, 1].

    Returns
    -------
    None

    Raises
    ------
    InputError
        The take is too short, or the mapped video span falls outside it.
    """
    v0, v1 = video_span_s
    k0, k1 = take_span_s
    if dt_offset_s is None:
        if (k1 - k0) + tol_s < min_share * (v1 - v0):
            raise InputError(
                f"Vicon take is shorter than the video: take spans {k0:.3f}..{k1:.3f} s "
                f"({k1 - k0:.3f} s), video spans {v0:.3f}..{v1:.3f} s ({v1 - v0:.3f} s); "
                f"expected it to last at least {100 * min_share:.0f} % of the video"
            )
        return
    m0, m1 = v0 + dt_offset_s, v1 + dt_offset_s
    if m0 < k0 - tol_s or m1 > k1 + tol_s:
        raise InputError(
            f"Vicon take does not cover the video: video frames span {v0:.3f}..{v1:.3f} s, i.e. "
            f"{m0:.3f}..{m1:.3f} s on the Vicon clock (dt_offset_s = {dt_offset_s:.4f}), but the "
            f"take spans {k0:.3f}..{k1:.3f} s"
        )


# --------------------------------------------------------------------------- rotation refinement


def _quats_continuous(R):
    """Scalar-last unit quaternions of R (N, 3, 3) with consecutive signs made continuous."""
    q = Rotation.from_matrix(R).as_quat()
    flip = np.sum(q[1:] * q[:-1], axis=1) < 0.0
    sign = np.concatenate([[1.0], np.where(np.cumsum(flip) % 2 == 1, -1.0, 1.0)])
    return q * sign[:, None]


def _smooth_rotations(t_s, R, valid, sigma_s):
    """Gaussian-weighted mean of rotations around every sample (zero phase, no time shift).

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Regular sample times, s.
    R : ndarray, shape (N, 3, 3)
        Rotations (anything where invalid).
    valid : ndarray of bool, shape (N,)
    sigma_s : float
        Standard deviation of the Gaussian weight, s; 0 leaves the rotations as they are.

    Returns
    -------
    q : ndarray, shape (N, 4)
        Smoothed unit quaternions (scalar-last; identity where invalid).
    valid : ndarray of bool, shape (N,)
        Valid where every sample within 2.5 sigma is valid: a window with a hole would pull
        the mean towards one side, i.e. shift it in time.

    Notes
    -----
    Over a window of a few tens of milliseconds the rotations differ by a few degrees, where
    the normalised mean of sign-aligned quaternions equals the rotation (chordal) mean to
    far below the noise.
    """
    R = np.where(valid[:, None, None], R, np.eye(3))
    q = _quats_continuous(R)
    if sigma_s <= 0.0 or len(t_s) < 2:
        q[~valid] = [0.0, 0.0, 0.0, 1.0]
        return q, valid.copy()
    step = float(np.median(np.diff(t_s)))
    half = int(np.ceil(2.5 * sigma_s / step))
    if half < 1:
        q[~valid] = [0.0, 0.0, 0.0, 1.0]
        return q, valid.copy()
    kernel = np.exp(-0.5 * (np.arange(-half, half + 1) * step / sigma_s) ** 2)
    w = valid.astype(float)
    num = np.stack([np.convolve(q[:, a] * w, kernel, mode="same") for a in range(4)], axis=1)
    n_bad = np.convolve(1.0 - w, np.ones(2 * half + 1), mode="same")
    inner = np.zeros(len(t_s), dtype=bool)
    inner[half : len(t_s) - half] = True
    ok = valid & (n_bad < 0.5) & inner
    norm = np.linalg.norm(num, axis=1)
    ok &= norm > 0.0
    q = np.where(ok[:, None], num / np.where(norm > 0.0, norm, 1.0)[:, None], [0.0, 0.0, 0.0, 1.0])
    return q, ok


def _relative_angles(q, I, J):
    """Angles (rad) of the relative rotations q_I^-1 q_J (scalar-last unit quaternions)."""
    a, b = q[I], q[J]
    w = np.sum(a * b, axis=1)
    v = a[:, 3:4] * b[:, :3] - b[:, 3:4] * a[:, :3] - np.cross(a[:, :3], b[:, :3])
    return 2.0 * np.arctan2(np.linalg.norm(v, axis=1), np.abs(w))


def _huber(x, c):
    a = np.abs(x)
    return np.where(a <= c, 0.5 * x * x, c * (a - 0.5 * c))


def refine_offset_rotations(
    t_video_s,
    R_C_B,
    valid,
    t_vicon_s,
    R_Cm_Bm,
    valid_vicon,
    dt0_s,
    search_s,
    max_baseline=15,
    smooth_s=0.01,
    scan_step_s=0.001,
    huber_k=1.345,
    n_jackknife=5,
):
    """Time offset from the angles of relative rotations, invariant to the mounting rotations.

    For video frames i, j = i + k (k = 1 .. ``max_baseline``, both with a pose), the angle of
    R_C_B(t_i)^T R_C_B(t_j) equals the angle of R_Cm_Bm(t_i + dt)^T R_Cm_Bm(t_j + dt) at the
    true offset, whatever the constant rotations R_C_Cm and R_Bm_B are: with R_C_B = R_C_Cm
    R_Cm_Bm R_Bm_B the first is the second conjugated by R_Bm_B. The offset minimises the
    Huber loss of the differences of these angles.

    Parameters
    ----------
    t_video_s : ndarray, shape (N,)
        Video frame times (video clock), s, increasing.
    R_C_B : ndarray, shape (N, 3, 3)
        Camera rotations of the board.
    valid : ndarray of bool, shape (N,)
    t_vicon_s : ndarray, shape (M,)
        Vicon sample times (Vicon clock), s, regular.
    R_Cm_Bm : ndarray, shape (M, 3, 3)
        Vicon relative rotations.
    valid_vicon : ndarray of bool, shape (M,)
    dt0_s : float
        Start value, s (t_vicon_s = t_video_s + dt).
    search_s : float
        The offset is searched in dt0_s +- search_s, s.
    max_baseline : int
        Longest baseline, frames (15: 0.5 s at 30 fps). Longer baselines are more sensitive to
        a time shift (the angle changes with the difference of the angular velocities at both
        ends) for the same noise, as long as the rotation stays well below pi.
    smooth_s : float
        The Vicon rotations are first averaged with a Gaussian weight of this standard
        deviation, s (marker noise on a small body tilts it by a tenth of a degree per sample;
        the average is symmetric, so it does not shift the stream in time).
    scan_step_s : float
        Step of the scan of the loss over the search range, s, before the local minimisation.
    huber_k : float
        Huber threshold in robust standard deviations (MAD) of each baseline's differences.
    n_jackknife : int
        Contiguous blocks of frames left out in turn for the jackknife standard error
        (0: none).

    Returns
    -------
    result : dict
        ``dt_s``, ``sigma_s`` (jackknife standard error, s, or None), ``residual_rms_rad``
        (robust RMS of the angle differences at the optimum), ``n_pairs``, ``n_frames``,
        ``max_baseline``, ``smooth_s``. ``dt_s`` is None when fewer than 20 pairs remain.
    """
    q_v, ok_v = _smooth_rotations(t_vicon_s, R_Cm_Bm, valid_vicon, smooth_s)
    grid = dt0_s + np.arange(-search_s, search_s + 0.5 * scan_step_s, scan_step_s)
    # frames whose Vicon rotation exists over the whole search range: a fixed set of pairs,
    # so that the loss does not jump when a pair enters or leaves
    lo_i = np.searchsorted(t_vicon_s, t_video_s + grid[0], side="right") - 1
    hi_i = np.searchsorted(t_vicon_s, t_video_s + grid[-1], side="left")
    inside = (lo_i >= 0) & (hi_i <= len(t_vicon_s) - 1)
    n_bad = np.concatenate([[0], np.cumsum(~ok_v)])
    lo_c, hi_c = np.clip(lo_i, 0, len(t_vicon_s)), np.clip(hi_i + 1, 0, len(t_vicon_s))
    frame_ok = valid & inside & (n_bad[hi_c] - n_bad[lo_c] == 0)
    n = len(t_video_s)
    I, J, K = [], [], []
    for k in range(1, int(max_baseline) + 1):
        i = np.arange(max(n - k, 0))
        m = frame_ok[i] & frame_ok[i + k]
        I.append(i[m])
        J.append(i[m] + k)
        K.append(np.full(int(m.sum()), k))
    I, J, K = np.concatenate(I), np.concatenate(J), np.concatenate(K)
    out = {"dt_s": None, "sigma_s": None, "residual_rms_rad": None, "n_pairs": int(len(I)),
           "n_frames": int(frame_ok.sum()), "max_baseline": int(max_baseline), "smooth_s": float(smooth_s)}
    if len(I) < 20:
        return out
    q_c = _quats_continuous(np.where(valid[:, None, None], R_C_B, np.eye(3)))
    a_c = _relative_angles(q_c, I, J)

    def residuals(dt, sel=slice(None)):
        q, _ = interpolate_quats(t_vicon_s, q_v, ok_v, t_video_s + dt)
        return a_c[sel] - _relative_angles(q, I[sel], J[sel])

    def scales(r):  # robust standard deviation of each baseline's differences
        s = np.empty(int(max_baseline) + 1)
        for k in range(1, int(max_baseline) + 1):
            rk = r[k == K]
            s[k] = 1.4826 * np.median(np.abs(rk - np.median(rk))) if rk.size else 1.0
        return np.maximum(s, 1e-9)

    def minimise(sc, sel=slice(None), lo=None, hi=None, start_grid=True):
        w = 1.0 / sc[K[sel]]

        def loss(dt):
            return float(np.mean(_huber(residuals(dt, sel) * w, huber_k)))

        if start_grid:
            vals = np.array([loss(g) for g in grid])
            k = int(np.argmin(vals))
            lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        res = minimize_scalar(loss, bounds=(lo, hi), method="bounded", options={"xatol": 1e-6})
        return float(res.x)

    sc = scales(residuals(dt0_s))
    dt = minimise(sc)
    sc = scales(residuals(dt))  # scales at the estimate, then once more
    dt = minimise(sc)
    r = residuals(dt)
    out["dt_s"] = dt
    out["residual_rms_rad"] = float(1.4826 * np.median(np.abs(r)))
    if n_jackknife >= 2:
        blocks = np.minimum((I * n_jackknife) // n, n_jackknife - 1)
        est = []
        for b in range(n_jackknife):
            sel = np.flatnonzero(blocks != b)
            est.append(minimise(sc, sel, dt - 4 * scan_step_s, dt + 4 * scan_step_s, start_grid=False))
        est = np.array(est)
        out["sigma_s"] = float(np.sqrt((n_jackknife - 1) / n_jackknife * np.sum((est - est.mean()) ** 2)))
    return out


# --------------------------------------------------------------------------- sync


def _masked_ncc(c, mc, v, mv, min_overlap):
    """Pearson correlation of c[j] with v[j + L] over jointly valid samples, for every lag L."""
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


def _main_lobe(r, k):
    """Indices [lo, hi] of the lobe around index k where r decreases monotonically away from k."""
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
    h = float(np.median(np.diff(t_frames)))
    step = h / 4.0 if grid_step_s is None else float(grid_step_s)
    # Vicon stream on the grid step, window h
    t_v_all, T_v, valid_v = _vicon_relative(bodies, camera, board)
    g_v = np.arange(t_v_all[0] + h / 2, t_v_all[-1] - h / 2 + 1e-12, step)
    s_v = _omega_vicon_between(t_v_all, T_v, valid_v, g_v - h / 2, g_v + h / 2)
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
    t_c = 0.5 * (t_r[:-1] + t_r[1:])
    w_c = rotation_angle(np.swapaxes(R_r[:-1], 1, 2) @ R_r[1:]) / np.diff(t_r)
    w_c[~(valid_r[:-1] & valid_r[1:])] = np.nan
    ok_c = np.isfinite(w_c)
    if ok_c.sum() < 10:
        raise SyncError(
            f"angular-speed sync: only {int(ok_c.sum())} consecutive video frame pairs with a "
            "board pose (expected at least 10)"
        )
    # video stream on its grid: linear between consecutive valid samples only
    g_c = np.arange(t_c[0], t_c[-1] + 1e-12, step)
    j = np.clip(np.searchsorted(t_c, g_c, side="right") - 1, 0, len(t_c) - 2)
    f = np.clip((g_c - t_c[j]) / (t_c[j + 1] - t_c[j]), 0.0, 1.0)
    s_c = (1 - f) * w_c[j] + f * w_c[j + 1]
    m_c = np.isfinite(s_c)
    lags, r = _masked_ncc(s_c, m_c, s_v, m_v, min_overlap_frac * m_c.sum())
    dt_lag = (g_v[0] - g_c[0]) + lags * step
    allowed = np.abs(dt_lag) <= max_offset_s
    r = np.where(allowed, r, np.nan)
    if not np.isfinite(r).any():
        raise SyncError(
            f"angular-speed sync: no lag within +-{max_offset_s} s overlaps enough valid samples "
            f"(video {video_span[0]:.2f}..{video_span[1]:.2f} s, "
            f"take {take_span[0]:.2f}..{take_span[1]:.2f} s)"
        )
    k = int(np.nanargmax(r))
    r_peak = float(r[k])
    at_edge = (
        k == 0
        or k == len(r) - 1
        or not np.isfinite(r[k - 1])
        or not np.isfinite(r[k + 1])
        or abs(abs(dt_lag[k]) - max_offset_s) < step
    )
    if at_edge:
        raise SyncError(
            f"angular-speed sync: correlation peak (r = {r_peak:.3f}) at the edge of the search "
            f"range, dt = {dt_lag[k]:.3f} s (max_offset_s = {max_offset_s}); no offset can be trusted"
        )
    lo, hi = _main_lobe(r, k)
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
        "window_s": h,
        "n_video_pairs": int((valid_r[:-1] & valid_r[1:]).sum()),
        "n_jump_frames": int(flips.sum()),
        "max_speed_rad_s": max_speed,
        "n_grid_video": int(m_c.sum()),
        "n_grid_vicon": int(m_v.sum()),
        "max_offset_s": float(max_offset_s),
        "min_quality": float(min_quality),
    }
    if quality < min_quality:
        raise SyncError(
            f"angular-speed sync: quality {quality:.3f} below min_quality {min_quality} "
            f"(peak r = {r_peak:.3f} at dt = {dt:.4f} s, second peak r = {r_2:.3f})"
        )
    log.info("sync: dt_offset_s = %.5f s, quality %.3f (r = %.3f)", dt, quality, r_peak)
    return {"dt_offset_s": dt, "method": "angular_speed", "quality": quality, "details": details}


def _tilt_onset(t, R, valid, still_s, low_rad, high_rad):
    """Times at which the angle from the still start first crosses low (backtracked) and high."""
    idx = np.flatnonzero(valid)
    if idx.size < 3:
        return None
    t_ok = t[idx]
    start = idx[t_ok <= t_ok[0] + still_s]
    if start.size < 2:
        return None
    R_ref = mean_rotation(R[start])
    ang = np.full(len(t), np.nan)
    ang[idx] = rotation_angle(R_ref.T @ R[idx])
    above = np.flatnonzero(np.nan_to_num(ang, nan=0.0) > high_rad)
    if above.size == 0:
        return None
    k_high = int(above[0])
    below = np.flatnonzero(np.nan_to_num(ang[:k_high], nan=np.inf) < low_rad)
    if below.size == 0:
        return None
    k_low = int(below[-1])

    def crossing(k, level):  # linear crossing between samples k and the next valid one
        nxt = idx[idx > k]
        if nxt.size == 0:
            return t[k]
        k2 = int(nxt[0])
        a0, a1 = ang[k], ang[k2]
        f = 0.0 if a1 == a0 else np.clip((level - a0) / (a1 - a0), 0.0, 1.0)
        return t[k] + f * (t[k2] - t[k])

    prev_high = idx[idx < k_high]
    t_high = crossing(int(prev_high[-1]), high_rad) if prev_high.size else t[k_high]
    return crossing(k_low, low_rad), t_high


def sync_gesture(
    poses_raw,
    bodies,
    max_offset_s=30.0,
    min_quality=0.5,
    still_s=0.5,
    low_rad=np.radians(3.0),
    high_rad=np.radians(10.0),
    camera="camera",
    board="board",
):
    """The chapter's synchronisation: onsets of the forward-tilt gesture in both streams.

    Parameters
    ----------
    poses_raw, bodies : DataFrame
        As :func:`sync_angular_speed`.
    still_s : float
        Length of the still start used as reference attitude in each stream, s.
    low_rad, high_rad : float
        The gesture is the first time the board turns more than ``high_rad`` from its
        reference attitude; its onset is the last crossing of ``low_rad`` before that, rad.

    Returns
    -------
    sync : dict
        As :func:`sync_angular_speed`, ``method`` "gesture". ``dt_offset_s`` is the difference
        of the onsets (Vicon minus video).

    Raises
    ------
    SyncError
        No gesture found in a stream, offset beyond ``max_offset_s``, or quality below
        ``min_quality``.

    Notes
    -----
    Seed section 1.3, "Test Procedure". The angle from the reference attitude is the same in
    both streams (module docstring). Quality = exp(-|d| / h), with d the disagreement between
    the offsets given by the low and the high crossings and h the video frame interval: a
    clean gesture has the same shape in both streams, so both crossings agree.
    """
    video_span, take_span = _spans(poses_raw, bodies)
    check_take_covers_video(video_span, take_span, min_share=OVERLAP_FLOOR)
    t_c, R_c, valid_c = _cvs_rotations(poses_raw)
    t_v, T_v, valid_v = _vicon_relative(bodies, camera, board)
    R_v = np.where(valid_v[:, None, None], T_v[:, :3, :3], np.eye(3))
    on_c = _tilt_onset(t_c, R_c, valid_c, still_s, low_rad, high_rad)
    on_v = _tilt_onset(t_v, R_v, valid_v, still_s, low_rad, high_rad)
    for name, on in (("video", on_c), ("Vicon", on_v)):
        if on is None:
            raise SyncError(
                f"gesture sync: no forward tilt found in the {name} stream (expected a still "
                f"start of {still_s} s, then a rotation above {np.degrees(high_rad):.1f} deg)"
            )
    dt_low = on_v[0] - on_c[0]
    dt_high = on_v[1] - on_c[1]
    h = float(np.median(np.diff(t_c)))
    quality = float(np.exp(-abs(dt_high - dt_low) / h))
    details = {
        "onset_video_s": float(on_c[0]),
        "onset_vicon_s": float(on_v[0]),
        "dt_low_s": float(dt_low),
        "dt_high_s": float(dt_high),
        "low_deg": float(np.degrees(low_rad)),
        "high_deg": float(np.degrees(high_rad)),
        "max_offset_s": float(max_offset_s),
        "min_quality": float(min_quality),
    }
    if abs(dt_low) > max_offset_s:
        raise SyncError(
            f"gesture sync: offset {dt_low:.3f} s beyond max_offset_s {max_offset_s} "
            f"(onsets: video {on_c[0]:.3f} s, Vicon {on_v[0]:.3f} s)"
        )
    if quality < min_quality:
        raise SyncError(
            f"gesture sync: quality {quality:.3f} below min_quality {min_quality} (onset offset "
            f"{dt_low:.4f} s, peak-crossing offset {dt_high:.4f} s disagree)"
        )
    return {"dt_offset_s": float(dt_low), "method": "gesture", "quality": quality, "details": details}


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
