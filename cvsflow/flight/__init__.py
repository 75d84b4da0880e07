"""Flight sessions: a quadcopter's on-board pose error measured against the camera reference.

Frames (in addition to W, C, Cm, B, Bm of docs/methods.md)
----------------------------------------------------------
- ``L``: the on-board estimator's local world frame (PX4: NED; any right-handed frame).
- ``Q``: the quadcopter body frame of the estimate (PX4: FRD).
- ``C``: the camera optical frame, the reference's world; ``B``: the board, fixed on Q by the
  constant mounting ``T_Q_B``.

The reference measures ``T_C_B`` per video frame; its body pose is ``T_C_Q = T_C_B inv(T_Q_B)``.
The log gives ``T_L_Q`` on its own clock. Clock convention (as ``t_vicon_s = t_video_s +
dt_offset_s`` in contracts.md): ``t_ref_s = dt_offset_s + (1 + skew) * t_log_s``.
Frame alignment finds ``T_C_L`` (optionally a similarity with scale ``s``):
``p_C = s R_C_L p_L + t_C_L``.

Errors are on-board minus reference. Per-axis errors are expressed in the axes of L (the
frame a flight engineer reads: north/east/down for PX4) in the reference's metres:
``e_p = R_C_L^T (p_est,C - p_ref,C)``, and attitude errors as wrapped differences of
roll/pitch/yaw of ``R_L_Q`` (R = Rz(yaw) Ry(pitch) Rx(roll)).

Trajectories are DataFrames in the common form of :mod:`cvsflow.io.flightlog` (``t_s, x_m,
y_m, z_m, qx, qy, qz, qw, pos_valid, rot_valid``). No file I/O here.

Reference uncertainty: ``Sigma_ref`` (N, 6, 6) is the covariance of the reference's error
``[dt, dtheta]`` on T_C_B, with ``t_meas = t_true + dt`` (metres, in C) and
``R_meas = Exp(dtheta) R_true`` (radians, left perturbation, in C).

Modules, bottom to top: :mod:`~cvsflow.flight.trajectory` (the common form, the reference from
PnP poses, resampling, association), :mod:`~cvsflow.flight.alignment` (Umeyama, yaw-only,
hand-eye rotations), :mod:`~cvsflow.flight.trajectory_errors` (APE/RPE, per-axis errors, the share the
reference cannot resolve; statistics from :mod:`cvsflow.metrics`),
:mod:`~cvsflow.flight.clock` (:func:`estimate_clock`), :mod:`~cvsflow.flight.reference` (the
reference's covariance) and :mod:`~cvsflow.flight.comparison` (:func:`evaluate_flight`). The
names below are re-exported for existing callers.
"""

from cvsflow.flight.alignment import (
    Alignment,
    align_trajectories,
    align_weighted,
    align_yaw,
    rotation_alignment,
    umeyama_alignment,
)
from cvsflow.flight.clock import Clock, angular_speed, estimate_clock
from cvsflow.flight.comparison import FlightOptions, FlightResult, check_against_truth, evaluate_flight
from cvsflow.flight.reference import (
    corner_noise_per_axis,
    correct_rolling_shutter,
    factor_columns,
    factor_from_columns,
    flip_columns,
    flip_from_columns,
    pnp_flip_term,
    propagate_reference_sigma,
    reference_covariance_from_pnp,
    reference_covariance_model,
    reference_covariance_transfer,
    session_error_model,
    sigma_columns,
    sigma_from_columns,
)
from cvsflow.flight.trajectory import (
    TRAJ_COLS,
    T_from_traj,
    associate,
    check_trajectory,
    interpolate_trajectory,
    reference_from_poses,
    traj_from_T,
    trajectory_frame,
)
from cvsflow.flight.trajectory_errors import (
    ERR_COLS,
    SIG_COLS,
    ape_rotation,
    ape_translation,
    axis_errors,
    axis_stats,
    rpe,
)

__all__ = [
    "align_trajectories", "align_weighted", "align_yaw", "Alignment", "angular_speed",
    "ape_rotation", "ape_translation", "associate", "axis_errors", "axis_stats",
    "check_against_truth", "check_trajectory", "Clock", "corner_noise_per_axis",
    "correct_rolling_shutter", "ERR_COLS", "estimate_clock", "evaluate_flight", "factor_columns",
    "factor_from_columns", "FlightOptions", "FlightResult", "flip_columns", "flip_from_columns",
    "interpolate_trajectory", "pnp_flip_term", "propagate_reference_sigma",
    "reference_covariance_from_pnp", "reference_covariance_model", "reference_covariance_transfer",
    "reference_from_poses", "rotation_alignment", "rpe", "session_error_model", "SIG_COLS",
    "sigma_columns", "sigma_from_columns", "T_from_traj", "TRAJ_COLS", "traj_from_T",
    "trajectory_frame", "umeyama_alignment"
]  # fmt: skip
