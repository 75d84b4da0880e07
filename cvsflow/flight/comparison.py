"""The whole flight comparison (:func:`evaluate_flight`) and its check against a rendered truth.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields, replace

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import InputError, SyncError
from cvsflow.flight.alignment import Alignment, align_trajectories, align_weighted, rotation_alignment
from cvsflow.flight.clock import Clock, estimate_clock
from cvsflow.flight.reference import propagate_reference_sigma
from cvsflow.flight.trajectory import T_from_traj, check_trajectory, interpolate_trajectory, traj_from_T
from cvsflow.flight.trajectory_errors import (
    ERR_COLS,
    SIG_COLS,
    ape_rotation,
    ape_translation,
    axis_errors,
    axis_stats,
    rpe,
)
from cvsflow.geometry import invert_T, make_T, skew, wrap_angle
from cvsflow.metrics import ERROR_DIMS, axis_statistics, error_statistics

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# The whole comparison
# --------------------------------------------------------------------------------------------


@dataclass
class FlightResult:
    """Outcome of :func:`evaluate_flight`.

    Attributes
    ----------
    errors : DataFrame
        Per associated reference frame: ``t_s`` (reference clock), ``t_log_s``, ``err_x_m ..
        err_yaw_rad`` (on-board minus reference, axes of L), ``sigma_x_m .. sigma_yaw_rad`` (reference
        standard deviations), ``ape_m`` (position error norm), ``ape_rot_rad``.
    stats : dict
        ``axes`` (:func:`axis_stats`), ``ape_trans`` / ``ape_rot`` / ``rpe_trans`` /
        ``rpe_rot`` (:func:`cvsflow.metrics.error_statistics`), ``clock``, ``alignment``, ``n_pairs``.
    clock : Clock
    alignment : Alignment
    ref_aligned, est_aligned : DataFrame
        Body trajectories T_C_Q (reference) and s,T_C_L applied to T_L_Q (estimate) at the
        reference times: the files to hand to evo (TUM).
    est_unaligned : DataFrame
        The estimate T_L_Q as logged (frame L, not aligned), interpolated at the reference
        times through the fitted clock: beside ``ref_aligned`` it lets evo's own ``-a`` / ``-s``
        do the alignment.
    Sigma_p_C : ndarray, shape (N_pairs, 3, 3) or None
        Covariance of the reference body positions in C (m^2), what the ``se3w`` alignment was
        weighted by; None for the other alignments.
    """

    errors: pd.DataFrame
    stats: dict
    clock: Clock
    alignment: Alignment
    ref_aligned: pd.DataFrame
    est_aligned: pd.DataFrame
    est_unaligned: pd.DataFrame
    Sigma_p_C: np.ndarray | None = None


@dataclass(frozen=True)
class FlightOptions:
    """How a flight is compared with its reference: the config's ``flight`` options.

    Attributes
    ----------
    alignment : {"se3", "sim3", "yaw"}
        Frame alignment fitted on the associated positions (unused with a given T_C_L).
    z_est_in_ref : (float, float, float)
        ``yaw`` only: the estimate world's z axis in the reference world.
    max_gap_s : float
        Longest log gap bridged when interpolating the log at reference times, seconds.
    sync_rate_hz, max_offset_s, estimate_skew, min_quality
        :func:`~cvsflow.flight.clock.estimate_clock`'s, when the clock is not given.
    rpe_delta : int
        RPE step, in reference frames.
    k_sigma : float
        Threshold of :func:`~cvsflow.flight.trajectory_errors.axis_stats`.
    weighted_alignment : bool
        With ``alignment="se3"`` and a reference covariance: weight the fit by the reference
        body positions' covariance (:func:`~cvsflow.flight.alignment.align_weighted`, method
        ``se3w``): the error the reference's noise puts into the alignment then stays within
        the stated one (docs/findings.md). Off by default: the unweighted fit is evo's
        Umeyama, so evo (``-a``) reproduces the stage's APE from its files.
    """

    alignment: str = "se3"
    z_est_in_ref: tuple = (0.0, 0.0, 1.0)
    max_gap_s: float = 0.1
    sync_rate_hz: float = 100.0
    max_offset_s: float | None = None
    estimate_skew: bool = True
    min_quality: float = 0.3
    rpe_delta: int = 1
    k_sigma: float = 1.0
    weighted_alignment: bool = False


def evaluate_flight(reference: pd.DataFrame, onboard: pd.DataFrame, T_Q_B=None, Sigma_ref=None,
                    options: FlightOptions | None = None, *, clock: Clock | None = None, T_C_L=None,
                    flip_ref=None, cal_factor=None, **overrides) -> FlightResult:
    """On-board pose error of a flight against the camera reference.

    Parameters
    ----------
    reference : DataFrame
        Camera reference T_C_B, common form, reference clock (e.g. from
        :func:`reference_from_poses`).
    onboard : DataFrame
        On-board estimate T_L_Q, common form, log clock (:mod:`cvsflow.io.flightlog`).
    T_Q_B : ndarray, shape (4, 4), optional
        Board mounting on the body. None: its rotation is estimated from the data (hand-eye,
        so a constant attitude error is absorbed) and its lever arm taken as zero.
    Sigma_ref : ndarray, shape (N_ref, 6, 6), optional
        Reference covariance per row of ``reference`` (module docstring); None: no band and
        no unresolved share.
    options : FlightOptions, optional
        How the comparison runs; default its defaults.
    clock : Clock, optional
        Known clock relation; None: :func:`estimate_clock`.
    T_C_L : ndarray, shape (4, 4), optional
        Known (surveyed) alignment; None: fitted.
    flip_ref : ndarray, shape (N_ref, 7), optional
        The planar PnP's flip term in ``Sigma_ref`` per row (``[delta, w]``,
        :func:`reference_covariance_transfer` with ``return_terms``): the stated sigma then
        carries it exactly, not linearised (:func:`propagate_reference_sigma`).
    cal_factor : ndarray, shape (N_ref, 6, k), optional
        The calibration's share of ``Sigma_ref`` as ``G G^T`` per row, one draw for the whole
        flight (:func:`reference_covariance_transfer`, a rig's
        :func:`cvsflow.rig.fusion.rig_calibration_covariance`). A fitted alignment absorbs
        part of such a common error and is moved by the rest, so the stated sigma of the
        recovered error carries it as it comes out of the alignment
        (:func:`_calibration_through_alignment`).
    **overrides
        Fields of :class:`FlightOptions` to change.

    Returns
    -------
    FlightResult

    Raises
    ------
    InputError, SyncError, OptimiseError
        Malformed trajectories or options; no time overlap; too few pairs to align.
    """
    unknown = sorted(set(overrides) - {f.name for f in fields(FlightOptions)})
    if unknown:
        raise InputError(f"flight: unknown options {unknown}")
    opts = replace(options or FlightOptions(), **overrides)
    reference = check_trajectory(reference, "reference")
    onboard = check_trajectory(onboard, "on-board log")
    mounting_given = T_Q_B is not None
    T_Q_B = np.asarray(T_Q_B, float) if mounting_given else None
    Sigma_ref, sigma_rot = _check_reference_terms(reference, Sigma_ref, flip_ref, cal_factor)
    if clock is None:
        clock = estimate_clock(reference, onboard, R_Q_B=T_Q_B[:3, :3] if mounting_given else None,
                               sigma_rot_rad=sigma_rot, rate_hz=opts.sync_rate_hz,
                               max_offset_s=opts.max_offset_s, estimate_skew=opts.estimate_skew,
                               min_quality=opts.min_quality)  # fmt: skip
    t_ref = reference["t_s"].to_numpy(float)
    use, T_C_B, T_L_Q = _associate(reference, onboard, clock, opts.max_gap_s)
    if not mounting_given:
        # rotation of the mounting from the data (hand-eye), no lever arm: a constant attitude
        # error of the estimate is then absorbed and cannot be measured
        w = None if sigma_rot is None else 1.0 / np.maximum(sigma_rot[use], 1e-9) ** 2
        _, R_QB = rotation_alignment(T_C_B[:, :3, :3], T_L_Q[:, :3, :3], None, w)
        T_Q_B = make_T(R_QB, np.zeros(3))
        log.warning("flight: board mounting T_Q_B not given; its rotation was estimated from the "
                    "data (constant attitude errors are absorbed) and its lever arm set to 0")
    T_C_Q = T_C_B @ invert_T(T_Q_B)
    Sigma_p = None
    if opts.weighted_alignment and opts.alignment == "se3" and Sigma_ref is not None and T_C_L is None:
        # p_C_Q = t_C_B + R_C_B t_B_Q: dp = dt - [R_C_B t_B_Q]x dtheta
        J = np.concatenate([np.broadcast_to(np.eye(3), (len(T_C_B), 3, 3)),
                            -skew(T_C_B[:, :3, :3] @ invert_T(T_Q_B)[:3, 3])], axis=2)  # fmt: skip
        Sigma_p = J @ Sigma_ref[use] @ np.swapaxes(J, -1, -2)

    def fit_alignment(p_ref_C, floor_m2=None):
        if T_C_L is not None:
            return Alignment(np.asarray(T_C_L, float), 1.0, "given")
        if Sigma_p is not None:
            return align_weighted(p_ref_C, T_L_Q[:, :3, 3], Sigma_p, floor_m2=floor_m2)
        return align_trajectories(p_ref_C, T_L_Q[:, :3, 3], opts.alignment, opts.z_est_in_ref)

    al = fit_alignment(T_C_Q[:, :3, 3])
    T_est_C = al.apply_T(T_L_Q)
    e = axis_errors(T_C_Q, T_L_Q, al)
    if Sigma_ref is None:
        sigma = np.full_like(e, np.nan)
    else:
        flip = None if flip_ref is None else np.asarray(flip_ref, float)[use]
        G = None if cal_factor is None else np.asarray(cal_factor, float)[use]
        sigma = _recovered_sigma(Sigma_ref[use], flip, G, T_C_B, T_Q_B, T_L_Q, e, al, fit_alignment)
    errors = pd.DataFrame(np.column_stack([e, sigma]), columns=ERR_COLS + SIG_COLS)
    errors.insert(0, "t_log_s", clock.to_log(t_ref[use]))
    errors.insert(0, "t_s", t_ref[use])
    if "frame" in reference:
        errors.insert(0, "frame", reference["frame"].to_numpy()[use])
    errors["ape_m"] = ape_translation(T_C_Q[:, :3, 3], T_est_C[:, :3, 3])
    errors["ape_rot_rad"] = ape_rotation(T_C_Q[:, :3, :3], T_est_C[:, :3, :3])
    stats = _flight_stats(errors, e, sigma if Sigma_ref is not None else None, T_C_Q, T_est_C,
                          len(reference), clock, al, T_Q_B, mounting_given, opts)  # fmt: skip
    t_use = t_ref[use]
    return FlightResult(errors, stats, clock, al,
                        traj_from_T(t_use, T_C_Q, attrs={"frames": "T_C_Q (reference)"}),
                        traj_from_T(t_use, T_est_C, attrs={"frames": "T_C_Q (on-board, aligned)"}),
                        traj_from_T(t_use, T_L_Q, attrs={"frames": "T_L_Q (on-board, unaligned)"}),
                        Sigma_p)  # fmt: skip


def _check_reference_terms(reference, Sigma_ref, flip_ref, cal_factor):
    """Sigma_ref as an array (or None) and its rotation sigma per row (rad); InputError on a shape."""
    n = len(reference)
    sigma_rot = None
    if Sigma_ref is not None:
        Sigma_ref = np.asarray(Sigma_ref, float)
        if Sigma_ref.shape != (n, 6, 6):
            raise InputError(f"Sigma_ref: shape {Sigma_ref.shape}; expected ({n}, 6, 6)")
        sigma_rot = np.sqrt(np.trace(Sigma_ref[:, 3:, 3:], axis1=1, axis2=2) / 3.0)
    if flip_ref is not None and np.shape(flip_ref) != (n, 7):
        raise InputError(f"flip_ref: shape {np.shape(flip_ref)}; expected ({n}, 7)")
    if cal_factor is not None and (np.ndim(cal_factor) != 3 or np.shape(cal_factor)[:2] != (n, 6)):
        raise InputError(f"cal_factor: shape {np.shape(cal_factor)}; expected ({n}, 6, k)")
    return Sigma_ref, sigma_rot


def _associate(reference, onboard, clock, max_gap_s):
    """Reference rows with an on-board pose at their time: the mask (N_ref,), T_C_B and T_L_Q
    (n, 4, 4) of those rows; SyncError with fewer than 3."""
    t_ref = reference["t_s"].to_numpy(float)
    est_i = interpolate_trajectory(onboard, clock.to_log(t_ref), max_gap_s=max_gap_s)
    use = ((reference["pos_valid"] & reference["rot_valid"]).to_numpy()
           & (est_i["pos_valid"] & est_i["rot_valid"]).to_numpy())
    n = int(use.sum())
    if n < 3:
        raise SyncError(
            f"flight: {n} reference frames have a valid on-board pose at the aligned time "
            f"(dt_offset_s {clock.dt_offset_s:.3f}, skew {clock.skew:.3g}); at least 3 needed"
        )
    return use, T_from_traj(reference)[use], T_from_traj(est_i)[use]


def _recovered_sigma(Sigma, flip, G, T_C_B, T_Q_B, T_L_Q, e, al, fit_alignment):
    """The stated sigma (n, 6) of the recovered error in the axes of L: the reference's covariance
    propagated, its calibration share ``G G^T`` (when given) through the refitted alignment."""
    if G is None:
        return propagate_reference_sigma(Sigma, T_C_B, T_Q_B, al.T_ref_est[:3, :3], flip)
    sigma_rest = propagate_reference_sigma(Sigma - G @ np.swapaxes(G, -1, -2), T_C_B, T_Q_B,
                                           al.T_ref_est[:3, :3], flip)  # fmt: skip
    # the weighted fit's floor held: its response to the calibration at these weights
    d = _calibration_through_alignment(G, T_C_B, T_Q_B, T_L_Q, e,
                                       lambda p: fit_alignment(p, getattr(al, "floor_m2", None)))  # fmt: skip
    return np.sqrt(sigma_rest**2 + np.sum(d**2, axis=2))


def _flight_stats(errors, e, sigma, T_C_Q, T_est_C, n_reference, clock, al, T_Q_B, mounting_given, opts):
    """``FlightResult.stats``: per-axis, APE and RPE statistics, the clock and the alignment."""
    stats = {
        "n_pairs": len(e),
        "n_reference": int(n_reference),
        "axes": axis_stats(e, sigma, opts.k_sigma),
        "ape_trans": error_statistics(errors["ape_m"].to_numpy()),
        "ape_rot": error_statistics(errors["ape_rot_rad"].to_numpy()),
        "clock": {"dt_offset_s": clock.dt_offset_s, "skew": clock.skew, "quality": clock.quality},
        "alignment": {"method": al.method, "scale": al.scale, "T_C_L": al.T_ref_est.tolist()}
        | ({"floor_m2": al.floor_m2} if al.method == "se3w" else {}),
        "T_Q_B": T_Q_B.tolist(),
        "mounting_estimated": not mounting_given,
    }
    if len(e) > opts.rpe_delta:
        r = rpe(T_C_Q, T_est_C, opts.rpe_delta)
        stats["rpe_trans"] = error_statistics(r["trans_m"])
        stats["rpe_rot"] = error_statistics(r["rot_rad"])
    for name, st in stats["axes"].items():
        if "unresolved_fraction" in st and st["unresolved_fraction"] > 0.5:
            log.warning("flight: on axis %s the reference cannot resolve %.0f%% of the samples", name,
                        100 * st["unresolved_fraction"])  # fmt: skip
    return stats


def _calibration_through_alignment(G, T_C_B, T_Q_B, T_L_Q, e, fit_alignment):
    """The recovered error's change per standard deviation of each calibration cause (n, 6, k):
    the reference moved by column c of G (``[dt, dtheta]`` in C, rotation on the left), the
    alignment refitted, the axis errors taken again. Linear in G over its 1-sigma range."""
    T_B_Q = invert_T(T_Q_B)
    d = np.empty(G.shape)
    for c in range(G.shape[2]):
        T = T_C_B.copy()
        T[:, :3, 3] += G[:, :3, c]
        T[:, :3, :3] = Rotation.from_rotvec(G[:, 3:, c]).as_matrix() @ T[:, :3, :3]
        T_C_Q_c = T @ T_B_Q
        e_c = axis_errors(T_C_Q_c, T_L_Q, fit_alignment(T_C_Q_c[:, :3, 3]))
        diff = e_c - e
        diff[:, 3:] = wrap_angle(diff[:, 3:])
        d[:, :, c] = diff
    return d


def check_against_truth(result, onboard, truth, T_L_C, clock, max_gap_s=0.05):
    """How well a flight evaluation recovered the injected on-board error (rendered flights).

    The injected error is seen through the evaluation's own fitted alignment (a fitted
    alignment absorbs a constant part of it), then compared with the recovered error in units
    of the reference's stated standard deviation: what is left is the reference's own error
    per frame, which its stated covariance claims to hold.

    Parameters
    ----------
    result : FlightResult
    onboard : DataFrame
        The on-board log (common form, log clock).
    truth : DataFrame
        Common form of the true T_L_Q at the video frames (reference clock), one row per
        frame in order (row k is frame k) or with a ``frame`` column.
    T_L_C : ndarray, shape (4, 4)
        True camera pose in L.
    clock : Clock
        The true log clock.

    Returns
    -------
    dict
        ``z_rms`` per axis (RMS of (recovered - injected) / sigma: 1 when the stated
        uncertainty is right), ``inside_3sigma`` per axis, ``n``; ``z_rms_truth_alignment``:
        the same with the injected error seen through the alignment (same method) fitted to the
        true body poses instead, i.e. against what the evaluation would recover from a perfect
        reference: there the part of the reference's error the alignment absorbs (a
        principal-point error turns C about its origin) cancels, and the error the reference's
        noise puts into the fitted alignment shows.
    """
    fr = result.errors["frame"].to_numpy()
    if "frame" not in truth.columns:
        truth = truth.assign(frame=np.arange(len(truth)))
    truth = truth.set_index("frame").loc[fr].reset_index()
    T_true_C_Q = invert_T(np.asarray(T_L_C, float)) @ T_from_traj(truth)
    est = interpolate_trajectory(onboard, clock.to_log(truth["t_s"].to_numpy(float)), max_gap_s)
    T_est = T_from_traj(est)
    al = result.alignment
    rec = result.errors[ERR_COLS].to_numpy(float)
    sig = result.errors[SIG_COLS].to_numpy(float)
    z = (rec - axis_errors(T_true_C_Q, T_est, al)) / sig
    ok = np.isfinite(z).all(axis=1)
    out = {
        "n": int(ok.sum()),
        "z_rms": _z_rms(z[ok]),
        "inside_3sigma": {a: float(np.mean(np.abs(z[ok, i]) < 3.0)) for i, a in enumerate(ERROR_DIMS)},
    }
    if al.method == "se3w":
        fin = np.isfinite(T_est[:, :3, 3]).all(axis=1)
        al_true = align_weighted(T_true_C_Q[fin, :3, 3], T_est[fin, :3, 3], result.Sigma_p_C[fin],
                                 floor_m2=al.floor_m2)  # fmt: skip
    elif al.method != "given":
        fin = np.isfinite(T_est[:, :3, 3]).all(axis=1)
        al_true = align_trajectories(T_true_C_Q[fin, :3, 3], T_est[fin, :3, 3], al.method,
                                     al.T_ref_est[:3, 2])  # fmt: skip
    if al.method != "given":
        z_t = (rec - axis_errors(T_true_C_Q, T_est, al_true)) / sig
        ok_t = np.isfinite(z_t).all(axis=1)
        out["z_rms_truth_alignment"] = _z_rms(z_t[ok_t])
    return out


def _z_rms(z):
    """RMS of each axis's standardised errors z (N, 6), keyed by ERROR_DIMS: 1 when sigma is right."""
    return {a: s["rmse"] for a, s in axis_statistics(z, names=("rmse",)).items()}
