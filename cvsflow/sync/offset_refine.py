"""The time offset refined on the relative rotations themselves (rule ``sync``).

``refine_offset_rotations`` starts from the cross-correlation's offset
(:func:`cvsflow.sync.offset.sync_angular_speed`) and minimises a Huber loss of the differences of
relative-rotation angles between video frames, with a jackknife spread.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation

from cvsflow.geometry import interpolate_quats, sample_period

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
    step = sample_period(t_s)
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
