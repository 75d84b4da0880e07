"""Error definitions: the one place that says what a pose error is.

Everything that scores a pose (``analyse``, ``evaluate``, ``uncertainty``, ``flight``, plots) takes
its error dimensions and composed errors from here; their statistics are
:mod:`cvsflow.metrics.statistics`. Bottom level: imports only
:mod:`cvsflow.geometry` and :mod:`cvsflow.exceptions`.

Errors are ``estimate - reference``: the CVS pose (PnP) against the Vicon reference.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow import geometry as geo
from cvsflow.exceptions import OptimiseError

#: The six error dimensions, in the chapter's order [x y z roll pitch yaw] (m, rad).
ERROR_DIMS = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
#: Frames an error can be expressed in (:func:`pose_errors`).
FRAMES = ("C", "B")


#: Each error dimension as figures and report tables show it: label, unit, factor from SI.
REPORT_UNITS = {
    "x_m": ("x", "mm", 1e3), "y_m": ("y", "mm", 1e3), "z_m": ("z", "mm", 1e3),
    "roll_rad": ("roll", "deg", 180.0 / np.pi), "pitch_rad": ("pitch", "deg", 180.0 / np.pi),
    "yaw_rad": ("yaw", "deg", 180.0 / np.pi),
}


def error_columns(prefix="err"):
    """Names of the six per-axis columns of a table, in :data:`ERROR_DIMS` order.

    Parameters
    ----------
    prefix : str
        ``err`` (default: the errors :func:`pose_errors` writes), ``eps`` (an optimiser's
        errors), ``sigma`` (their stated standard deviations), ...

    Returns
    -------
    columns : list of str
        ``{prefix}_x_m .. {prefix}_yaw_rad``.
    """
    return [f"{prefix}_{d}" for d in ERROR_DIMS]


def report_name(dim):
    """An error dimension in report units: ``x_m`` -> ``x_mm``, ``roll_rad`` -> ``roll_deg``.

    Parameters
    ----------
    dim : str
        One of :data:`ERROR_DIMS`.

    Returns
    -------
    str
        The label of :data:`REPORT_UNITS` and its unit.
    """
    label, unit, _ = REPORT_UNITS[dim]
    return f"{label}_{unit}"


def poses_from_table(frames, prefix):
    """Stack of transforms from the pose columns of a table.

    Parameters
    ----------
    frames : DataFrame
        Table with ``{prefix}x_m, {prefix}y_m, {prefix}z_m`` (m) and ``{prefix}qx ..
        {prefix}qw`` (scalar-last quaternion) columns.
    prefix : str
        Column prefix, e.g. ``"cvs_"`` or ``"ref_"``.

    Returns
    -------
    T_C_B : ndarray, shape (F, 4, 4)
        One transform per row (the board in the camera for the ``cvs_``/``ref_`` columns of
        :func:`cvsflow.optimise.se3_apply.apply_se3`), metres.
    """
    q = frames[[f"{prefix}qx", f"{prefix}qy", f"{prefix}qz", f"{prefix}qw"]].to_numpy(float)
    t = frames[[f"{prefix}x_m", f"{prefix}y_m", f"{prefix}z_m"]].to_numpy(float)
    return geo.make_T(geo.R_from_quat(q).reshape(-1, 3, 3), t)


def pose_errors(T_C_B_ref, T_C_B_est, frame="C"):
    """Per-axis errors of estimated board poses from the composed transform.

    Parameters
    ----------
    T_C_B_ref : ndarray, shape (N, 4, 4)
        Reference (true) board pose in the camera, metres.
    T_C_B_est : ndarray, shape (N, 4, 4)
        Estimated board pose in the camera, metres.
    frame : {"C", "B"}
        Frame the error is expressed in. ``"C"`` (default): translation t_est - t_ref in C
        and the rotation error dR = R_est R_ref^T, a rotation about the axes of C.
        ``"B"``: the composed error dT = T_ref^-1 T_est itself, translation
        R_ref^T (t_est - t_ref) and rotation R_ref^T R_est, both in the reference board frame.

    Returns
    -------
    errors : DataFrame
        ``err_x_m, err_y_m, err_z_m`` (m), ``err_roll_rad, err_pitch_rad, err_yaw_rad`` (rad,
        Euler angles of dR, R = Rz(yaw) Ry(pitch) Rx(roll)), ``err_angle_rad`` (rotation
        angle of dR, in [0, pi]) and ``err_dist_m`` (length of the translation error).

    Raises
    ------
    OptimiseError
        Shapes differ or are not (N, 4, 4), or ``frame`` is unknown.

    Notes
    -----
    A pure yaw error of 1 degree about C's z axis gives err_yaw 1 degree and err_angle
    1 degree; a 6-vector difference of Euler angles (the chapter's eq. 1.11) instead mixes
    axes whenever roll or pitch are not small.
    """
    ref = np.asarray(T_C_B_ref, float)
    est = np.asarray(T_C_B_est, float)
    if ref.shape != est.shape or ref.ndim != 3 or ref.shape[1:] != (4, 4):
        raise OptimiseError(
            f"pose_errors: reference {ref.shape} and estimate {est.shape}; expected (N, 4, 4)"
        )
    if frame not in FRAMES:
        raise OptimiseError(f"pose_errors: frame {frame!r}; expected one of {FRAMES}")
    R_ref, R_est = ref[:, :3, :3], est[:, :3, :3]
    dt_C = est[:, :3, 3] - ref[:, :3, 3]
    if frame == "C":
        dt = dt_C
        dR = R_est @ np.swapaxes(R_ref, 1, 2)
    else:
        dT = geo.pose_difference(ref, est)  # T_ref^-1 T_est
        dt, dR = dT[:, :3, 3], dT[:, :3, :3]
    rpy = geo.euler_from_R(dR).reshape(-1, 3)
    return pd.DataFrame(
        {
            "err_x_m": dt[:, 0],
            "err_y_m": dt[:, 1],
            "err_z_m": dt[:, 2],
            "err_roll_rad": rpy[:, 0],
            "err_pitch_rad": rpy[:, 1],
            "err_yaw_rad": rpy[:, 2],
            "err_angle_rad": geo.rotation_angle(dR).reshape(-1),
            "err_dist_m": np.linalg.norm(dt_C, axis=1),
        }
    )


def frame_errors(frames, frame="C"):
    """Composed and chapter-style errors of a per-frame table of CVS and reference poses.

    Parameters
    ----------
    frames : DataFrame
        Output of :func:`cvsflow.optimise.se3_apply.apply_se3`: ``cvs_`` and ``ref_`` pose columns
        (``x_m, y_m, z_m, qx, qy, qz, qw``) of T_C_B, metres.
    frame : {"C", "B"}
        See :func:`pose_errors`.

    Returns
    -------
    errors : DataFrame
        ``frames`` with the :func:`pose_errors` columns and, for comparison, the chapter's
        6-vector differences ``d6_x_m .. d6_yaw_rad`` (pose6(cvs) - pose6(ref), m and rad,
        angles wrapped to (-pi, pi]); column ``error_frame`` names the frame.
    """
    T_ref = poses_from_table(frames, "ref_")
    T_cvs = poses_from_table(frames, "cvs_")
    err = pose_errors(T_ref, T_cvs, frame=frame)
    d6 = geo.pose6_from_T(T_cvs) - geo.pose6_from_T(T_ref)
    d6[:, 3:] = geo.wrap_angle(d6[:, 3:])
    out = pd.concat([frames.reset_index(drop=True), err], axis=1)
    for j, d in enumerate(ERROR_DIMS):
        out[f"d6_{d}"] = d6[:, j]
    out["error_frame"] = frame
    return out
