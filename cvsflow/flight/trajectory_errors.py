"""Flight error measures: evo's APE/RPE, per-axis errors in the axes of L, the share of them the
reference cannot resolve. Their statistics are :mod:`cvsflow.metrics.statistics`'.
"""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import InputError
from cvsflow.flight.alignment import Alignment
from cvsflow.geometry import euler_from_R, invert_T, rotation_angle, wrap_angle
from cvsflow.metrics import ERROR_DIMS, error_columns, error_statistics

#: Columns of a flight's per-axis errors and of the reference's standard deviations (axes of L).
ERR_COLS = error_columns("err")
SIG_COLS = error_columns("sigma")


# --------------------------------------------------------------------------------------------
# Absolute and relative pose error
# --------------------------------------------------------------------------------------------


def ape_translation(p_ref, p_est_aligned) -> np.ndarray:
    """Absolute position error per pair, metres, shape (N,): |p_ref - p_est| (evo APE, trans).

    Parameters
    ----------
    p_ref : array_like, shape (N, 3)
        Reference positions, m.
    p_est_aligned : array_like, shape (N, 3)
        Estimated positions after alignment into the reference's world, m.

    Returns
    -------
    ndarray, shape (N,)
        Euclidean distance per pair, m (NaN where either is NaN).
    """
    return np.linalg.norm(np.asarray(p_ref, float) - np.asarray(p_est_aligned, float), axis=1)


def ape_rotation(R_ref, R_est_aligned) -> np.ndarray:
    """Absolute rotation error angle per pair, radians, of R_ref^T R_est (N, 3, 3) -> (N,).

    Parameters
    ----------
    R_ref : array_like, shape (N, 3, 3)
        Reference rotations.
    R_est_aligned : array_like, shape (N, 3, 3)
        Estimated rotations after alignment into the reference's world.

    Returns
    -------
    ndarray, shape (N,)
        Angle of ``R_ref^T R_est`` in [0, pi], rad.
    """
    R_ref = np.asarray(R_ref, float)
    return rotation_angle(np.swapaxes(R_ref, -1, -2) @ np.asarray(R_est_aligned, float))


def rpe(T_ref, T_est, delta: int = 1) -> dict:
    """Relative pose error over ``delta`` consecutive pairs (evo RPE, ``--delta`` frames).

    E_i = (T_ref,i^-1 T_ref,i+d)^-1 (T_est,i^-1 T_est,i+d).

    Parameters
    ----------
    T_ref, T_est : ndarray, shape (N, 4, 4)
        Associated poses (the estimate aligned or not: RPE is alignment-free for SE(3)).
    delta : int
        Step in pairs.

    Returns
    -------
    dict
        ``trans_m`` (N-d,) translation norms, metres; ``rot_rad`` (N-d,) angles, radians.
    """
    T_ref = np.asarray(T_ref, float)
    T_est = np.asarray(T_est, float)
    if delta < 1 or len(T_ref) <= delta:
        raise InputError(f"rpe: delta={delta} with {len(T_ref)} pairs; expected 1 <= delta < N")
    d_ref = invert_T(T_ref[:-delta]) @ T_ref[delta:]
    d_est = invert_T(T_est[:-delta]) @ T_est[delta:]
    E = invert_T(d_ref) @ d_est
    return {"trans_m": np.linalg.norm(E[:, :3, 3], axis=1), "rot_rad": rotation_angle(E[:, :3, :3])}


# --------------------------------------------------------------------------------------------
# Per-axis errors, statistics, the share the reference cannot resolve
# --------------------------------------------------------------------------------------------


def axis_errors(T_ref_C_Q, T_est_L_Q, alignment: Alignment) -> np.ndarray:
    """Per-axis on-board error (estimate minus reference) in the axes of L.

    Parameters
    ----------
    T_ref_C_Q : ndarray, shape (N, 4, 4)
        Reference body poses in C.
    T_est_L_Q : ndarray, shape (N, 4, 4)
        On-board body poses in L, at the same instants.
    alignment : Alignment
        T_C_L and scale.

    Returns
    -------
    e : ndarray, shape (N, 6)
        x, y, z (metres, axes of L: R_C_L^T (s R p_est + t - p_ref)); roll, pitch, yaw
        (radians, wrapped difference of the Euler angles of R_L_Q).
    """
    R = alignment.T_ref_est[:3, :3]
    p_est_C = alignment.apply_points(T_est_L_Q[:, :3, 3])
    e_p = (p_est_C - T_ref_C_Q[:, :3, 3]) @ R  # R^T (.)
    rpy_ref = euler_from_R(R.T @ T_ref_C_Q[:, :3, :3])
    rpy_est = euler_from_R(T_est_L_Q[:, :3, :3])
    return np.column_stack([e_p, wrap_angle(rpy_est - rpy_ref)])


def axis_stats(e, sigma=None, k_sigma: float = 1.0) -> dict:
    """The statistics of each axis's error, and the share the reference cannot resolve.

    Parameters
    ----------
    e : ndarray, shape (N, 6)
        Per-axis errors (m, rad); NaN rows ignored.
    sigma : ndarray, shape (N, 6), optional
        Reference standard deviations per axis, same units.
    k_sigma : float
        A sample is *unresolved* on an axis when ``k_sigma * sigma > |e|``: the reference's
        uncertainty is larger than the error it measures.

    Returns
    -------
    dict
        Per axis (:data:`~cvsflow.metrics.errors.ERROR_DIMS`): ``n`` and the statistics of
        :data:`cvsflow.metrics.STATISTICS`; with sigma also ``ref_rms`` (RMS of sigma),
        ``unresolved_fraction`` (share of samples unresolved), ``ref_variance_share`` (mean
        sigma^2 / mean e^2, capped at 1: the share of the measured mean-square error the
        reference's noise accounts for) and ``rmse_corrected`` (sqrt(max(mean e^2 - mean
        sigma^2, 0)), the on-board RMSE with the reference's own noise removed).
    """
    e = np.asarray(e, float)
    out = {}
    for k, name in enumerate(ERROR_DIMS):
        ek = e[:, k]
        m = np.isfinite(ek)
        if sigma is not None:
            m &= np.isfinite(sigma[:, k])
        ek = ek[m]
        st = error_statistics(ek)
        if sigma is not None and st["n"]:
            ms = float(np.mean(ek**2))
            sk = sigma[m, k]
            s2 = float(np.mean(sk**2))
            st |= {
                "ref_rms": float(np.sqrt(s2)),
                "unresolved_fraction": float(np.mean(k_sigma * sk > np.abs(ek))),
                "ref_variance_share": float(min(s2 / ms, 1.0)) if ms > 0 else 1.0,
                "rmse_corrected": float(np.sqrt(max(ms - s2, 0.0))),
            }
        out[name] = st
    return out
