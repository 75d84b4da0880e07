"""Simulated camera and motion-capture pose streams with a known time offset and correlated noise.

The true motion is a camera looking at a target from 0.6-1.1 m, its position and roll/tilt
driven by sums of sinusoids with incommensurate periods (so that the angular speed never
repeats and its cross-correlation has one peak). On the true time axis tau:

- camera frames at ``tau_i = t_cam_i`` (the camera's clock is the true one), with jitter and
  detection gaps (runs of missing frames);
- motion-capture samples at ``tau_j``, stamped ``t_mocap_j = tau_j + dt_offset_s``;
- ``T_W_Cm(tau) = T_W_B T_B_C(tau) T_Cm_C^-1``.

The camera's measured ``T_B_C`` is the truth times ``exp(e_rot)`` (right, in C) with ``e_trans``
added in C, both AR(1) in time with correlation time ``tau_corr_s`` (a detector's error persists
while the view changes slowly); the motion capture's is white.
"""

from __future__ import annotations

import numpy as np

from cvsflow.geometry import R_from_rvec, invert_T, make_T

#: Epoch of the simulated clocks (a Unix time in ns, 19 digits as real streams have).
T0_NS = 1_491_754_390_000_000_000


def _look_at(p_B_C, target_B, up_B=np.array([0.0, 1.0, 0.0])):
    """R_B_C of cameras at p_B_C (N, 3) looking at target_B (z forward, y down in the image)."""
    z = target_B - p_B_C
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    x = np.cross(-up_B, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=2)


def true_T_B_C(tau_s, phases) -> np.ndarray:
    """The true camera pose in the target frame at times ``tau_s``.

    Parameters
    ----------
    tau_s : ndarray, shape (N,)
        True times, s.
    phases : ndarray, shape (11,)
        Phases of the motion's sinusoids, rad.

    Returns
    -------
    T_B_C : ndarray, shape (N, 4, 4)
        Camera in the target frame, m.
    """
    t = np.asarray(tau_s, float)[:, None]
    amp = np.array([0.25, 0.20, 0.15])
    periods = np.array([[7.3, 3.1], [5.9, 2.3], [9.7, 4.1]])
    waves = np.sin(2 * np.pi * t[:, :, None] / periods[None] + phases[:6].reshape(1, 3, 2))
    p = np.array([0.3, 0.3, 0.8]) + np.sum(amp[None, :, None] * 0.5 * waves, axis=2)
    R = _look_at(p, np.array([0.3, 0.3, 0.0]))
    t = t[:, 0]
    roll = 0.5 * np.sin(2 * np.pi * t / 6.1 + phases[6]) + 0.25 * np.sin(2 * np.pi * t / 1.7 + phases[7])
    tilt = 0.25 * np.sin(2 * np.pi * t / 4.3 + phases[8]) + 0.12 * np.sin(2 * np.pi * t / 1.3 + phases[9])
    pan = 0.2 * np.sin(2 * np.pi * t / 3.7 + phases[10])
    return make_T(R @ R_from_rvec(np.stack([tilt, pan, roll], axis=1)).reshape(-1, 3, 3), p)


def ar1_noise(rng, t_s, tau_s, sigma) -> np.ndarray:
    """AR(1) noise at irregular times: correlation ``exp(-|dt| / tau_s)``, std ``sigma``.

    Parameters
    ----------
    rng : numpy.random.Generator
    t_s : ndarray, shape (N,)
        Times, increasing, s.
    tau_s : float
        Correlation time, s (0: white).
    sigma : sequence of 3 float
        Standard deviation per component.

    Returns
    -------
    ndarray, shape (N, 3)
    """
    n = len(t_s)
    e = np.empty((n, 3))
    e[0] = rng.normal(0.0, 1.0, 3)
    for i in range(1, n):
        rho = np.exp(-(t_s[i] - t_s[i - 1]) / tau_s) if tau_s > 0 else 0.0
        e[i] = rho * e[i - 1] + np.sqrt(1 - rho**2) * rng.normal(0.0, 1.0, 3)
    return e * np.asarray(sigma, float)


def simulate_streams(seed=0, *, duration_s=40.0, cam_rate_hz=30.0, mocap_rate_hz=100.0,
                     dt_offset_s=0.03, cam_rot_sigma_deg=(0.3, 0.3, 0.1),
                     cam_trans_sigma_mm=(1.5, 1.5, 4.0), tau_corr_s=0.3,
                     mocap_rot_sigma_deg=0.05, mocap_trans_sigma_mm=0.3, n_gaps=5,
                     gap_len_s=(0.2, 0.7), still=False) -> dict:  # fmt: skip
    """A simulated pair of pose streams with known truth.

    Parameters
    ----------
    seed : int
        Seed of ``numpy.random.default_rng``.
    duration_s : float
        Length of the camera stream, s.
    cam_rate_hz, mocap_rate_hz : float
        Frame and sample rates, Hz.
    dt_offset_s : float
        True offset, ``t_mocap = t_camera + dt_offset_s``, s.
    cam_rot_sigma_deg : sequence of 3 float
        Camera rotation noise std about C's x, y, z, deg.
    cam_trans_sigma_mm : sequence of 3 float
        Camera translation noise std along C's x, y, z (depth), mm.
    tau_corr_s : float
        AR(1) correlation time of the camera noise, s.
    mocap_rot_sigma_deg, mocap_trans_sigma_mm : float
        White motion-capture noise std per axis, deg and mm.
    n_gaps : int
        Detection gaps in the camera stream, lengths uniform in ``gap_len_s``.
    gap_len_s : tuple of float
        Shortest and longest gap, s.
    still : bool
        The camera holds still at 30 views and jumps between them (dt unobservable).

    Returns
    -------
    dict
        ``t_cam_ns`` (N,) int64 and ``T_B_C`` (N, 4, 4) measured; ``t_mocap_ns`` (M,) int64 and
        ``T_W_Cm`` (M, 4, 4) measured; the truth ``dt_offset_s``, ``T_Cm_C``, ``T_W_B``.
    """
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0, 2 * np.pi, 11)
    T_Cm_C = make_T(R_from_rvec(rng.normal(0, 0.6, 3)), rng.normal(0, 0.05, 3))
    yaw = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
    T_W_B = make_T(R_from_rvec(yaw + rng.normal(0, 0.1, 3)),
                   np.array([1.0, -0.5, 0.8]) + rng.normal(0, 0.2, 3))  # fmt: skip
    n = int(duration_s * cam_rate_hz)
    tau_c = np.arange(n) / cam_rate_hz + rng.normal(0, 0.001, n)
    keep = np.ones(n, bool)
    for _ in range(n_gaps):
        s = rng.uniform(0, duration_s)
        keep &= ~((tau_c >= s) & (tau_c < s + rng.uniform(*gap_len_s)))
    tau_c = np.sort(tau_c[keep])
    tau_m = np.arange(-2.0 + rng.uniform(0, 1 / mocap_rate_hz), duration_s + 2.0, 1 / mocap_rate_hz)

    def motion(tau):
        if not still:
            return true_T_B_C(tau, phases)
        views = true_T_B_C(np.linspace(0, duration_s * 3, 30), phases)
        return views[np.clip((np.asarray(tau) / duration_s * 30).astype(int), 0, 29)]

    T_true = motion(tau_c)
    e_r = np.radians(ar1_noise(rng, tau_c, tau_corr_s, cam_rot_sigma_deg))
    e_t = 1e-3 * ar1_noise(rng, tau_c, tau_corr_s, cam_trans_sigma_mm)
    R_meas = T_true[:, :3, :3] @ R_from_rvec(e_r).reshape(-1, 3, 3)
    p_meas = T_true[:, :3, 3] + np.einsum("nij,nj->ni", T_true[:, :3, :3], e_t)
    T_W_Cm = T_W_B @ motion(tau_m) @ invert_T(T_Cm_C)
    e_m = rng.normal(0, np.radians(mocap_rot_sigma_deg), (len(tau_m), 3))
    R_m = T_W_Cm[:, :3, :3] @ R_from_rvec(e_m).reshape(-1, 3, 3)
    p_m = T_W_Cm[:, :3, 3] + rng.normal(0, 1e-3 * mocap_trans_sigma_mm, (len(tau_m), 3))
    return {"t_cam_ns": T0_NS + np.round(tau_c * 1e9).astype(np.int64), "T_B_C": make_T(R_meas, p_meas),
            "t_mocap_ns": T0_NS + np.round((tau_m + dt_offset_s) * 1e9).astype(np.int64),
            "T_W_Cm": make_T(R_m, p_m), "dt_offset_s": dt_offset_s, "T_Cm_C": T_Cm_C,
            "T_W_B": T_W_B}  # fmt: skip
