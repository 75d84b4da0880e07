"""Rendered flight demo: trajectories of a quadcopter seen by the ground camera (no images).

The truth is a smooth flight between 3 and 20 m from the camera in the estimator's local
frame L (NED, z down), body Q (FRD), the board B mounted on the back of the body (its face
towards the camera). From it:

- the on-board estimate ``T_L_Q`` with bias, drift (random walk), white noise, sampled on
  its own clock: ``t_ref_s = dt_offset_s + (1 + skew) * t_log_s``;
- the camera reference ``T_C_B`` at the video frames (camera clock = true time). With
  ``reference="pnp"`` it is measured as the CVS measures it: the board's corners projected
  with the camera model, corner noise added, the CVS's PnP (:func:`cvsflow.calibration.pnp.estimate_poses`)
  with a calibration that is off the true lens by a draw of its stated std; its stated
  covariance is model (T)'s (:func:`cvsflow.flight.reference_covariance_transfer`), so the
  truth check tests that model and not the noise it drew. ``reference="model"`` (the
  default, the demo flight's; or a given ``Sigma_ref``) draws the noise from a covariance
  instead (the distance model :func:`cvsflow.flight.reference_covariance_model`, or the given
  array), which the truth check then only echoes;
- the injected error, i.e. what a perfect reference would measure at each video frame.

The measured references (``measure_reference``, ``measure_reference_rig``, ``corner_noise``,
``stereo_rig``, ``calibrate_rig_views``) are in :mod:`cvsflow.synth.flight_reference`. Every
random choice comes from ``numpy.random.default_rng(seed)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import ConfigError
from cvsflow.flight import ERR_COLS, Clock, interpolate_trajectory, reference_covariance_model, traj_from_T
from cvsflow.geometry import R_from_euler, euler_from_R, invert_T, make_T, wrap_angle
from cvsflow.synth.flight_reference import measure_reference, measure_reference_rig, stereo_rig

# Board mounting: board x = body right (y_Q), board y = body down (z_Q), board z (into the
# board) = body forward (x_Q); the board hangs behind the body, its origin at an inner corner.
R_Q_B_DEFAULT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
T_Q_B_DEFAULT = make_T(R_Q_B_DEFAULT, [-0.15, -0.2, -0.15])


MIN_HEIGHT_M = 0.5  # the body never flies lower above the ground (metres)



@dataclass
class FlightDemo:
    """A rendered flight: inputs of :func:`cvsflow.flight.evaluate_flight` and their truth.

    Attributes
    ----------
    reference : DataFrame
        ``frame`` + common form of the measured T_C_B (camera clock, s); missed frames invalid.
    Sigma_ref : ndarray, shape (N_frames, 6, 6)
        Reference covariance per frame ([dt m, dtheta rad] in C).
    onboard : DataFrame
        Common form of the on-board T_L_Q (log clock, s).
    truth : DataFrame
        Common form of the true T_L_Q at the video frames (camera clock).
    injected : DataFrame
        ``frame, t_s, err_x_m .. err_yaw_rad``: the on-board error at the video frames (the log
        interpolated at the true log times of the frames, minus the truth), axes of L.
    T_L_C, T_Q_B : ndarray, shape (4, 4)
        Camera in L; board mounting on the body.
    clock : Clock
        The true log clock.
    flip_ref : ndarray, shape (N_frames, 7) or None
        ``reference="pnp"``: the planar PnP's flip term per frame (``[delta, w]``,
        :func:`cvsflow.flight.reference_covariance_transfer`), else None.
    cal_factor : ndarray, shape (N_frames, 6, k) or None
        ``reference="pnp"`` or ``"stereo"``: the calibration's share of ``Sigma_ref`` as the
        error per standard deviation of each calibration cause, one draw for the flight.
    body_track : callable or None
        The true trajectory, ``f(t_s) -> T_L_Q`` (N, 4, 4) at any true times
        (:func:`true_flight`), for rendering the flight's video.
    """

    reference: pd.DataFrame
    Sigma_ref: np.ndarray
    onboard: pd.DataFrame
    truth: pd.DataFrame
    injected: pd.DataFrame
    T_L_C: np.ndarray
    T_Q_B: np.ndarray
    clock: Clock
    flip_ref: np.ndarray | None = None
    cal_factor: np.ndarray | None = None
    body_track: object = None


def _sines(rng, n_terms, f_lo, f_hi, amp):
    """A random smooth signal: a function of time (s) with standard deviation about ``amp``."""
    f = rng.uniform(f_lo, f_hi, n_terms)
    ph = rng.uniform(0, 2 * np.pi, n_terms)
    a = amp * np.sqrt(2.0 / n_terms) * np.ones(n_terms)
    return lambda t: np.sum(a * np.sin(2 * np.pi * f * np.asarray(t)[:, None] + ph), axis=1)


def camera_pose(height_m: float = 1.0, tilt_up_rad: float = np.deg2rad(8.0)) -> np.ndarray:
    """T_L_C of a camera on a tripod ``height_m`` above the ground, looking north, tilted up.

    Optical axes in NED: z_C north, x_C east, y_C down, then pitched up by ``tilt_up_rad``.

    Parameters
    ----------
    height_m : float, default 1.0
        Height of the optical centre above the ground, m (z = -height_m in NED).
    tilt_up_rad : float, default 8 deg
        Upward tilt of the optical axis, rad.

    Returns
    -------
    T_L_C : ndarray, shape (4, 4)
        Camera pose in the estimator's world frame L (NED), m.
    """
    R_level = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns x_C y_C z_C
    R_tilt = Rotation.from_rotvec([tilt_up_rad, 0.0, 0.0]).as_matrix()  # about x_C: z_C goes up
    return make_T(R_level @ R_tilt, [0.0, 0.0, -height_m])


def true_flight(seed: int, duration_s: float, range_m=(3.0, 20.0), T_L_C=None):
    """The true body trajectory as a function ``f(t_s) -> T_L_Q`` (N, 4, 4) (seeded).

    The body stays in front of the camera: range from the camera between ``range_m``, bearing
    and elevation wobbling a few degrees around its optical axis (and above
    ``MIN_HEIGHT_M``), with sinusoidal roll, pitch and yaw of some degrees.

    Parameters
    ----------
    seed : int
        Seed of the random sinusoid amplitudes, frequencies and phases.
    duration_s : float
        Flight length, s; the range sweeps out and back once over it.
    range_m : (float, float), default (3.0, 20.0)
        Nearest and farthest distance from the camera centre, m.
    T_L_C : ndarray, shape (4, 4), optional
        Camera pose in L; default :func:`camera_pose`.

    Returns
    -------
    callable
        ``f(t_s)``: array of times (N,) in s -> T_L_Q, shape (N, 4, 4), m (L NED, Q FRD).
    """
    rng = np.random.default_rng(seed)
    T_L_C = camera_pose() if T_L_C is None else T_L_C
    r_lo, r_hi = range_m
    bearing = _sines(rng, 4, 0.02, 0.15, np.deg2rad(8.0))
    elev = _sines(rng, 4, 0.02, 0.15, np.deg2rad(4.0))
    r_wobble = _sines(rng, 3, 0.05, 0.3, 0.3)
    roll = _sines(rng, 6, 0.1, 1.5, np.deg2rad(6.0))
    pitch = _sines(rng, 6, 0.1, 1.5, np.deg2rad(6.0))
    yaw = _sines(rng, 5, 0.05, 1.0, np.deg2rad(10.0))
    c = T_L_C[:3, 3]

    def f(t_s):
        t = np.asarray(t_s, float)
        ph = np.clip(t / duration_s, 0.0, 1.0)
        r = r_lo + 0.3 + (r_hi - r_lo - 0.6) * 0.5 * (1 - np.cos(2 * np.pi * ph)) + r_wobble(t)
        r = np.clip(r, r_lo, r_hi)
        a = bearing(t)
        b = np.deg2rad(5.0) + elev(t)  # above the horizon through the lens
        b = np.maximum(
            b, np.arcsin(np.clip((MIN_HEIGHT_M + c[2]) / r, -1.0, 1.0))
        )  # off the ground
        p = c + r[:, None] * np.column_stack(
            [np.cos(b) * np.cos(a), np.cos(b) * np.sin(a), -np.sin(b)]
        )
        rpy = np.column_stack([roll(t), pitch(t), a + yaw(t)])
        return make_T(R_from_euler(rpy), p)

    return f


def render_flight(
    seed: int = 0,
    duration_s: float = 60.0,
    fps: float = 30.0,
    log_rate_hz: float = 100.0,
    range_m=(3.0, 20.0),
    dt_offset_s: float = -17.25,
    skew: float = 2e-4,
    log_margin_s: float = 5.0,
    pos_bias_m=(0.06, -0.04, 0.08),
    pos_rw_m_sqrt_s: float = 0.01,
    pos_noise_m: float = 0.01,
    att_bias_rad=(0.012, -0.009, 0.04),
    att_rw_rad_sqrt_s: float = 0.002,
    att_noise_rad: float = 0.003,
    f_px: float = 700.0,
    board_m: float = 0.5,
    sigma_px: float = 0.3,
    n_corners: int = 20,
    missed_frame_rate: float = 0.02,
    Sigma_ref=None,
    T_Q_B=None,
    reference: str = "model",
    camera=None,
    board=None,
    corner_shared_px: float = 0.0,
    corner_shared_squares: float = 1.0,
    calib_std=None,
    rig=None,
    reference_model=None,
    calibration=None,
) -> FlightDemo:
    """Render a flight: truth, on-board estimate on its own clock, camera reference.

    Parameters
    ----------
    seed : int
        Seed of every random choice.
    duration_s, fps : float
        Video length (s) and frame rate (Hz); video frame k is at t = k / fps (true time).
    log_rate_hz : float
        On-board log rate, Hz (position and attitude logged together).
    range_m : (float, float)
        Closest and farthest distance of the body from the camera, metres.
    dt_offset_s, skew : float
        Log clock: ``t_ref_s = dt_offset_s + (1 + skew) t_log_s``.
    log_margin_s : float
        The log starts this long before the video and ends this long after, seconds.
    pos_bias_m, pos_rw_m_sqrt_s, pos_noise_m : on-board position error: constant bias (m, in
        L), random-walk intensity (m / sqrt(s)), white noise (m), per axis.
    att_bias_rad, att_rw_rad_sqrt_s, att_noise_rad : the same for roll, pitch, yaw (rad).
    f_px, board_m, n_corners : parameters of the distance model (``reference="model"``).
    sigma_px : float
        Corner noise per image axis, px: iid part of the detected corners (``"pnp"``), or of
        the distance model (``"model"``).
    missed_frame_rate : float
        Share of video frames where the board is not found (reference invalid).
    Sigma_ref : ndarray, shape (N_frames, 6, 6), optional
        Reference covariance per frame to draw the reference noise from (overrides
        ``reference``).
    T_Q_B : ndarray, shape (4, 4), optional
        Board mounting; default ``T_Q_B_DEFAULT``.
    reference : {"pnp", "stereo", "model"}
        ``"pnp"``: the reference is measured from noisy corners (:func:`measure_reference`)
        and states model (T)'s covariance; ``"stereo"``: measured by a rig of cameras
        exposed together (:func:`measure_reference_rig`, the board pose fused from every
        camera's corners), stating the fused pose's covariance; ``"model"``: its noise is
        drawn from the distance model, which it states.
    camera, board : dict, optional
        The reference camera (``CAMERA_DEMO``; with ``"stereo"`` every camera's) and the
        board on the body (``BOARD_DEFAULT``), ``"pnp"`` and ``"stereo"`` only.
    corner_shared_px, corner_shared_squares : float
        The part of the corner noise shared by neighbouring corners (:func:`corner_noise`).
    calib_std : dict, optional
        The calibration's 1-sigma (``CALIB_STD_DEFAULT``), ``"pnp"`` and ``"stereo"`` only.
    reference_model : dict, optional
        ``"pnp"`` only: the model (T) the reference states its covariance with (default the
        rendered sessions', :data:`cvsflow.uncertainty.RENDERED_TRANSFER_MODEL`).
    calibration : dict, optional
        ``"pnp"`` only: the calibration the reference uses (a validation session's se3 result)
        instead of the true lens off by a draw of ``calib_std``.
    rig : dict, optional
        ``"stereo"`` only: ``baseline_m`` (default 1.0), ``cross_m`` (10.0) of
        :func:`stereo_rig`; ``n_views`` (20) and ``view_sigma_px`` (0.1) of the rig's
        calibration (:func:`calibrate_rig_views`). Camera 0 is the reference camera
        (``T_L_C``, the reference's frame C).

    Returns
    -------
    FlightDemo

    Raises
    ------
    ConfigError
        Non-positive durations or rates, a range outside (0, inf), skew of 1 % or more, an
        unknown ``reference``.
    """
    if duration_s <= 0 or fps <= 0 or log_rate_hz <= 0:
        raise ConfigError(
            f"flight demo: duration_s={duration_s}, fps={fps}, "
            f"log_rate_hz={log_rate_hz}; all must be > 0"
        )
    if not (0 < range_m[0] < range_m[1]):
        raise ConfigError(f"flight demo: range_m={range_m}; expected 0 < near < far (m)")
    if abs(skew) >= 1e-2:
        raise ConfigError(f"flight demo: skew={skew}; expected |skew| < 0.01")
    if reference not in ("pnp", "stereo", "model"):
        raise ConfigError(f"flight demo: reference={reference!r}; expected 'pnp', 'stereo' or 'model'")
    if rig is not None and reference != "stereo":
        raise ConfigError(f"flight demo: a rig is given with reference={reference!r}; it needs 'stereo'")
    if (reference_model is not None or calibration is not None) and reference != "pnp":
        raise ConfigError(f"flight demo: a reference_model or calibration is given with "
                          f"reference={reference!r}; they need 'pnp'")  # fmt: skip
    rig = {} if rig is None else dict(rig)
    unknown = set(rig) - {"baseline_m", "cross_m", "n_views", "view_sigma_px"}
    if unknown:
        raise ConfigError(f"flight demo: unknown rig keys {sorted(unknown)}; expected baseline_m, "
                          "cross_m, n_views, view_sigma_px")  # fmt: skip
    rng = np.random.default_rng(seed)
    T_L_C = camera_pose()
    T_Q_B = T_Q_B_DEFAULT if T_Q_B is None else np.asarray(T_Q_B, float)
    f = true_flight(int(rng.integers(2**31)), duration_s, range_m, T_L_C)
    clock = Clock(dt_offset_s, skew)

    # camera reference at the video frames (true time)
    n_fr = int(round(duration_s * fps)) + 1
    frame = np.arange(n_fr)
    t_cam = frame / fps
    T_L_Q_cam = f(t_cam)
    T_C_B = invert_T(T_L_C) @ T_L_Q_cam @ T_Q_B
    flip_ref = cal_factor = None
    if Sigma_ref is None and reference == "pnp":
        seen = rng.random(n_fr) >= missed_frame_rate
        T_meas, seen, Sigma_ref, _, _, flip_ref, cal_factor = measure_reference(
            T_C_B, t_cam, seen, rng, camera, board, sigma_px, corner_shared_px,
            corner_shared_squares, calib_std, reference_model, calibration,
            return_terms=True)  # fmt: skip
    elif Sigma_ref is None and reference == "stereo":
        seen = rng.random(n_fr) >= missed_frame_rate
        T_Ci_C0 = stereo_rig(float(rig.get("baseline_m", 1.0)), float(rig.get("cross_m", 10.0)))
        T_meas, seen, Sigma_ref, _, cal_factor = measure_reference_rig(
            T_C_B, seen, rng, T_Ci_C0, None if camera is None else [camera] * len(T_Ci_C0), board,
            sigma_px, corner_shared_px, corner_shared_squares, calib_std, int(rig.get("n_views", 20)),
            float(rig.get("view_sigma_px", 0.1)), return_factor=True)  # fmt: skip
    else:
        if Sigma_ref is None:
            Sigma_ref = reference_covariance_model(T_C_B, f_px, board_m, sigma_px, n_corners)
        Sigma_ref = np.asarray(Sigma_ref, float)
        if Sigma_ref.shape != (n_fr, 6, 6):
            raise ConfigError(
                f"flight demo: Sigma_ref shape {Sigma_ref.shape}; expected ({n_fr}, 6, 6)"
            )
        L = np.linalg.cholesky(Sigma_ref + 1e-30 * np.eye(6))
        d = (L @ rng.standard_normal((n_fr, 6, 1)))[..., 0]
        T_meas = T_C_B.copy()
        T_meas[:, :3, 3] += d[:, :3]
        T_meas[:, :3, :3] = Rotation.from_rotvec(d[:, 3:]).as_matrix() @ T_C_B[:, :3, :3]
        seen = rng.random(n_fr) >= missed_frame_rate  # drawn after the noise (as it was)
        T_meas[~seen] = np.nan
    reference_df = traj_from_T(
        t_cam, T_meas, seen, seen, {"source": "flight_synth", "frames": "T_C_B"}
    )
    reference_df.insert(0, "frame", frame)

    # on-board log on its own clock
    t_log0 = clock.to_log(-log_margin_s)
    t_log1 = clock.to_log(duration_s + log_margin_s)
    t_log = t_log0 + np.arange(int((t_log1 - t_log0) * log_rate_hz) + 1) / log_rate_hz
    T_true_log = f(clock.to_ref(t_log))
    n = len(t_log)
    dt = 1.0 / log_rate_hz

    def process(bias, rw, noise):
        walk = np.cumsum(rng.standard_normal((n, 3)) * rw * np.sqrt(dt), axis=0)
        return np.asarray(bias, float) + walk + rng.standard_normal((n, 3)) * noise

    e_pos = process(pos_bias_m, pos_rw_m_sqrt_s, pos_noise_m)
    e_att = process(att_bias_rad, att_rw_rad_sqrt_s, att_noise_rad)
    rpy_est = euler_from_R(T_true_log[:, :3, :3]) + e_att
    T_est = make_T(R_from_euler(rpy_est), T_true_log[:, :3, 3] + e_pos)
    onboard = traj_from_T(
        t_log, T_est, attrs={"source": "flight_synth", "frames": "T_L_Q, NED/FRD"}
    )

    # injected error at the video frames, as a perfect reference would measure it
    est_cam = interpolate_trajectory(onboard, clock.to_log(t_cam), max_gap_s=2.0 / log_rate_hz)
    R_e = Rotation.from_quat(est_cam[["qx", "qy", "qz", "qw"]].to_numpy()).as_matrix()
    e = np.column_stack(
        [
            est_cam[["x_m", "y_m", "z_m"]].to_numpy() - T_L_Q_cam[:, :3, 3],
            wrap_angle(euler_from_R(R_e) - euler_from_R(T_L_Q_cam[:, :3, :3])),
        ]
    )
    injected = pd.DataFrame(e, columns=ERR_COLS)
    injected.insert(0, "t_s", t_cam)
    injected.insert(0, "frame", frame)
    truth = traj_from_T(t_cam, T_L_Q_cam, attrs={"frames": "T_L_Q (true)"})
    return FlightDemo(reference_df, Sigma_ref, onboard, truth, injected, T_L_C, T_Q_B, clock,
                      flip_ref, cal_factor, f)
