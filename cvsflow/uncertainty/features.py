"""What is known of a frame when it is measured: the inputs of the transfer model (T).

:func:`measurement_features` gathers, per held-out frame, the pose geometry, the corners it
saw, its image speed and reprojection RMS, the PnP covariance per px^2 of corner noise
(:func:`frame_noise_terms`), the rolling shutter's predicted shear, whether the reference was
gap-filled (:func:`vicon_filled`) and the calibration's propagated covariance; the corner
noise a reprojection RMS implies and its shrinkage toward a pooled value are here too.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pandas as pd

from cvsflow.board import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import sample_period
from cvsflow.geometry import transforms as tf
from cvsflow.metrics import ERROR_DIMS, pose_errors
from cvsflow.optimise import corner_arrays
from cvsflow.uncertainty.ambiguity import pnp_alternatives
from cvsflow.uncertainty.propagation import cov_columns, parameter_covariance, propagated_pose_covariance
from cvsflow.uncertainty.reference_noise import camera_body_error_cov, moving_body_noise
from cvsflow.uncertainty.rolling_shutter import shear_displacement, unsheared_pnp

#: Per-frame quantities known when a frame is measured (:func:`measurement_features`).
#: Image speed (px per frame period) below which a motion-compensated codec codes a board as
#: still: its blocks copied from the last frame with their motion vectors rounded to the
#: codec's precision (half a pixel in MPEG-4 part 2, a quarter in H.264), so the board shows
#: where it was, not where it is, and every corner errs by the same small motion: an error
#: that looks like a pose change (model (T)'s ``s_still``; docs/findings.md 2026-12-05).
STILL_SPEED_PX = 0.5

MEASUREMENT_FEATURES = ("distance_m", "tilt_rad", "radius_norm", "n_corners", "spread_px",
                        "speed_px", "reproj_rms_px")


def seen_corners(corners, frame_ids, n_corners):
    """The corners each of some frames saw, and how fast they moved in the image.

    Parameters
    ----------
    corners : DataFrame
        corners.parquet of the session.
    frame_ids : array_like, shape (N,)
        Frames to return, each with at least one corner.
    n_corners : int
        Corners of the board (P).

    Returns
    -------
    uv_px : ndarray, shape (N, P, 2)
        Observed pixels, NaN where unseen.
    speed_px : ndarray, shape (N,)
        Image speed, px per frame period (the mean travel of its corners between its
        neighbours; next to a gap, to the one neighbour within 3.5 periods; 0 with neither).
    vel_px_s : ndarray, shape (N, P, 2)
        Each seen corner's image velocity, px/s: the central difference between the frame's
        neighbours where both saw it, else the one-sided difference to the one that did; a
        seen corner that neither neighbour saw (a fast swing loses corners in the track)
        takes the affine velocity field of the frame's other corners (the board is flat
        and rigid), or their mean with fewer than 4; NaN where no corner of the frame was
        seen by a neighbour (and not meaningful where the frame did not see the corner).

    Raises
    ------
    OptimiseError
        A frame without corners.
    """
    fr, t, uv = corner_arrays(corners, n_corners, min_corners=1)
    idx = np.searchsorted(fr, frame_ids)
    idx = np.clip(idx, 0, len(fr) - 1)
    if not np.array_equal(fr[idx], np.asarray(frame_ids)):
        missing = sorted(set(np.asarray(frame_ids).tolist()) - set(fr.tolist()))[:5]
        raise OptimiseError(f"measurement_features: frames {missing} have no corners")
    period = sample_period(t, default=1.0)
    n = np.arange(len(fr))
    prev = np.clip(n - 1, 0, None)
    nxt = np.clip(n + 1, None, len(fr) - 1)
    span = np.where(nxt > prev, t[nxt] - t[prev], np.inf)
    travel = _mean_length(uv[nxt] - uv[prev])
    speed = travel / span * period
    near = span < 3.5 * period
    vel = (uv[nxt] - uv[prev]) / np.where(near, span, np.nan)[:, None, None]
    # one-sided differences next to a gap, or for corners one neighbour did not see
    gap_prev = np.where(prev < n, t - t[prev], np.inf)
    gap_next = np.where(nxt > n, t[nxt] - t, np.inf)
    back = (uv - uv[prev]) / np.where(gap_prev < 2.5 * period, gap_prev, np.nan)[:, None, None]
    fwd = (uv[nxt] - uv) / np.where(gap_next < 2.5 * period, gap_next, np.nan)[:, None, None]
    side = np.where(np.isfinite(back), back, fwd)
    vel = np.where(np.isfinite(vel), vel, side)
    side_speed = _mean_length(side) * period
    # a neighbour without shared corners or far away in time (a gap): the one-sided travel,
    # else no estimate, say 0 px
    speed = np.where(np.isfinite(speed) & near, speed,
                     np.where(np.isfinite(side_speed), side_speed, 0.0))  # fmt: skip
    vel = _fill_velocity_field(uv, vel)
    return uv[idx], speed[idx], vel[idx]


def _mean_length(d):
    """Mean length of each frame's corner displacements (N, P, 2), NaN where it has none (a
    frame without corners shared with its neighbour: no warning)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(np.linalg.norm(d, axis=-1), axis=1)


def _fill_velocity_field(uv, vel):
    """Velocities of seen corners without one, from the affine field of the frame's others."""
    seen = np.isfinite(uv).all(axis=-1)
    has = np.isfinite(vel).all(axis=-1) & seen
    out = vel.copy()
    for i in np.flatnonzero((seen & ~has).any(axis=1) & has.any(axis=1)):
        fill = seen[i] & ~has[i]
        src = has[i]
        if src.sum() >= 4:
            A = np.c_[uv[i, src], np.ones(src.sum())]
            coef, *_ = np.linalg.lstsq(A, vel[i, src], rcond=None)
            out[i, fill] = np.c_[uv[i, fill], np.ones(fill.sum())] @ coef
        else:
            out[i, fill] = vel[i, src].mean(axis=0)
    return out


def frame_noise_terms(uv_px, vel_px_s, rvec, tvec, p_B, K, dist, line_delay_s=0.0, frame="C"):
    """Per frame: the PnP error covariance per px^2 of corner noise over the corners it saw,
    and the pose error its rolling shutter's shear predicts.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Observed corners, NaN where unseen.
    vel_px_s : ndarray, shape (N, P, 2)
        Image velocity of each corner, px/s (NaN: taken as 0).
    rvec, tvec : ndarray, shape (N, 3)
        The PnP pose T_C_B (rad, m), the linearisation point.
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    K, dist : ndarray
        Intrinsics of the PnP.
    line_delay_s : float
        Line delay, s per row (0: a global shutter, no shear).
    frame : {"C", "B"}
        Error frame.

    Returns
    -------
    unit : ndarray, shape (N, 6, 6)
        (J^T J)^-1 pushed to the error [x, y, z, roll, pitch, yaw], per px^2.
    shear : ndarray, shape (N, 6)
        The error of PnP on the sheared corners (corner k displaced by its velocity times
        ``line_delay_s`` times its row after the frame's mean row), SI.
    """
    obj = np.asarray(p_B, np.float64)
    seen = np.isfinite(uv_px).all(axis=-1)
    cov_rt = np.empty((len(uv_px), 6, 6))
    d_rt = np.zeros((len(uv_px), 6))
    for i in range(len(uv_px)):
        _, jac = cv2.projectPoints(obj[seen[i]].reshape(-1, 1, 3), rvec[i], tvec[i], K, dist)
        J = jac[:, :6]
        JtJ_inv = np.linalg.pinv(np.einsum("mi,mj->ij", J, J, optimize=False))
        cov_rt[i] = JtJ_inv
        if line_delay_s != 0.0:
            # PnP turns the shear into a pose error
            d_uv = shear_displacement(uv_px[i, seen[i]], vel_px_s[i, seen[i]], line_delay_s)
            d_rt[i] = JtJ_inv @ (J.T @ d_uv.reshape(-1))
    unit = propagated_pose_covariance(rvec, tvec, cov_rt, frame=frame)
    cols = [f"err_{d}" for d in ERROR_DIMS]
    T_at = tf.T_from_rvec_tvec(rvec, tvec)
    shear = pose_errors(tf.T_from_rvec_tvec(rvec - d_rt[:, :3], tvec - d_rt[:, 3:]), T_at,
                        frame=frame)[cols].to_numpy()  # fmt: skip
    return unit, shear


#: Correlation length (px) of the correlated corner noise of model (T): infinite, a shift
#: common to every corner of a frame. On the rendered sessions the detected-minus-true corner
#: errors carry a common shift of 0.15-0.18 times their iid noise (lag-1 autocorrelated
#: 0.2-0.5 from frame to frame: the video codec's inter-frame prediction), which PnP absorbs
#: into the pose. Over the leave-one-session-out it meets 240 of 468 targets against 222
#: without it (a 10 px, macroblock-sized, correlation: 216), but u_far's z band drops out of
#: range (93.3 -> 92.5 % inside 95 %), so it is an option, not the default (issue 15).
CORNER_CORRELATION_PX = np.inf


def correlated_noise_terms(uv_px, rvec, tvec, p_B, K, dist, length_px, frame="C"):
    """Per frame: the PnP error covariance per px^2 of a spatially correlated corner noise.

    The corner errors are a field with unit variance per image axis and correlation
    exp(-d^2 / (2 L^2)) between two corners d px apart (the two axes independent): errors
    shared by nearby corners (a codec's macroblock, a common shift) that PnP cannot tell from
    a pose change, so its reprojection residual does not show them. Through PnP's least
    squares A = (J^T J)^-1 J^T the pose error covariance is A R A^T. L -> 0 gives the iid
    case (:func:`frame_noise_terms`'s ``unit``), L -> inf a common shift of every corner.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Observed corners, NaN where unseen.
    rvec, tvec : ndarray, shape (N, 3)
        The PnP pose T_C_B (rad, m), the linearisation point.
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    K, dist : ndarray
        Intrinsics of the PnP.
    length_px : float
        Correlation length L, px (> 0; ``np.inf``: a common shift of every corner).
    frame : {"C", "B"}
        Error frame.

    Returns
    -------
    corr : ndarray, shape (N, 6, 6)
        A R A^T pushed to the error [x, y, z, roll, pitch, yaw], per px^2.

    Raises
    ------
    OptimiseError
        A correlation length that is not positive.
    """
    if not length_px > 0:
        raise OptimiseError(f"correlated_noise_terms: length_px must be > 0, got {length_px}")
    obj = np.asarray(p_B, np.float64)
    seen = np.isfinite(uv_px).all(axis=-1)
    cov_rt = np.empty((len(uv_px), 6, 6))
    for i in range(len(uv_px)):
        _, jac = cv2.projectPoints(obj[seen[i]].reshape(-1, 1, 3), rvec[i], tvec[i], K, dist)
        J = jac[:, :6]
        A = np.linalg.pinv(J.T @ J) @ J.T
        uv = uv_px[i, seen[i]]
        d2 = np.sum((uv[:, None] - uv[None]) ** 2, axis=-1)
        # residuals are ordered u0, v0, u1, v1, ...: the same field per axis, axes independent
        Rm = np.kron(np.exp(-0.5 * d2 / length_px**2), np.eye(2))
        cov_rt[i] = A @ Rm @ A.T
    return propagated_pose_covariance(rvec, tvec, cov_rt, frame=frame)


def measurement_features(heldout, corners, board, fits=None, frame="C", bodies=None,
                         time_offset=False, corr_length_px=None, inter_coded=False):
    """What is known of each held-out frame when it is measured, and its covariance terms.

    Parameters
    ----------
    heldout : DataFrame
        :func:`cvsflow.evaluate.heldout.cross_validate_se3` rows (``frame``, ``fold``, the CVS pose
        ``cvs_rvec_0..2``, ``cvs_x_m..z_m``, the reference ``ref_*``, ``reproj_rms_px``).
    corners : DataFrame
        corners.parquet of the session (which corners each frame saw, the image speed).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    fits : list of dict
        The folds' se3 results (heldout/se3_folds.yaml): the K, dist of each fold linearise
        its PnP; when they carry their ``correlation`` (a full se3 result), the calibration
        term ``parcov_{a}{b}`` too (:func:`parameter_covariance`, the correlated term common
        to all frames of a fold).
    frame : {"C", "B"}
        Error frame.
    bodies : DataFrame, optional
        bodies.parquet (``t_s``, ``body``, ``n_filled``): adds ``vicon_filled``, 1 where a
        board marker was gap-filled within :data:`FILL_WINDOW_S` of the frame's Vicon time
        (``t_vicon_s``), else 0; with ``fits`` whose camera body moved (``camera_static``
        false), also ``refcov_{a}{b}``, the error covariance the camera body's own pose noise
        puts into the reference (:mod:`cvsflow.uncertainty.reference_noise`).
    time_offset : bool
        Include the fit's time offset in ``parcov`` (:func:`parameter_covariance`).
    corr_length_px : float, optional
        Adds ``corrcov_{a}{b}``, the PnP error covariance per px^2 of a corner noise
        correlated over this many px (:func:`correlated_noise_terms`; e.g.
        :data:`CORNER_CORRELATION_PX`). None: not computed.
    inter_coded : bool
        The video codes frames from other frames (motion compensation: MPEG-4, H.264, HEVC;
        not MJPEG or raw; ``corners_summary.yaml: inter_coded``): adds ``inter_coded`` = 1,
        which lets model (T)'s still-board term act (:func:`cvsflow.uncertainty.transfer.
        fit_transfer_model`). False: 0.

    Returns
    -------
    features : DataFrame
        ``frame``; the :data:`MEASUREMENT_FEATURES` (distance to the board centre m, tilt of
        the board normal from the line of sight rad, radial image position of the board centre
        in normalised units, corners seen, their RMS spread about their centroid px, image
        speed px per frame period (the blur proxy: blur = speed x exposure / period),
        reprojection RMS of the PnP px, of the unsheared corners under a rolling shutter,
        :func:`cvsflow.uncertainty.rolling_shutter.unsheared_pnp`); ``unitcov_{a}{b}``, the
        error covariance of the PnP pose per px^2 of iid corner noise over the corners this
        frame saw ((J^T J)^-1 pushed to [x, y, z, roll, pitch, yaw], m^2 / px^2 .. rad^2 /
        px^2); ``rs_err_{dim}``, the
        CVS pose error that the rolling shutter's shear predicts (the fold's fitted line delay
        times each corner's image velocity and its row after the mean row, through PnP, in
        the error's units; zero for a global shutter); ``flip_{dim}``, the error the
        measured pose has if the planar PnP's other solution is the true pose (zero where
        there is none), and ``flip_dssr_px2``, how much worse that solution fits the corners
        (px^2; inf where there is none: :mod:`cvsflow.uncertainty.ambiguity`);
        ``parcov_{a}{b}`` with ``fits``; ``corrcov_{a}{b}`` with ``corr_length_px``;
        ``inter_coded`` (1 or 0).
    """
    p_B = board_object_points(board)
    need = ["frame", *[f"cvs_rvec_{j}" for j in range(3)], "cvs_x_m", "cvs_y_m", "cvs_z_m",
            "reproj_rms_px"]
    missing = [c for c in need if c not in heldout.columns]
    if missing:
        raise OptimiseError(f"measurement_features: held-out table lacks columns {missing}")
    frames = heldout["frame"].to_numpy()
    uv, speed, vel = seen_corners(corners, frames, len(p_B))
    seen = np.isfinite(uv).all(axis=-1)
    rvec = heldout[need[1:4]].to_numpy(float)
    tvec = heldout[need[4:7]].to_numpy(float)
    if fits:
        K_by_fold = {int(f["fold"]): (np.asarray(f["K"], float), np.asarray(f["dist"], float))
                     for f in fits}  # fmt: skip
        ld_by_fold = {int(f["fold"]): float(f.get("line_delay_s") or 0.0) for f in fits}
        fold = heldout["fold"].to_numpy().astype(int)
    else:
        K_by_fold, fold = None, None
    obj = np.asarray(p_B, np.float64)
    if K_by_fold is None:
        raise OptimiseError("measurement_features: fits are needed (the K of each fold)")
    unit = np.empty((len(frames), 6, 6))
    rs = np.zeros((len(frames), 6))
    for k in np.unique(fold):
        sel = fold == k
        unit[sel], rs[sel] = frame_noise_terms(uv[sel], vel[sel], rvec[sel], tvec[sel], obj,
                                               *K_by_fold[int(k)], ld_by_fold[int(k)], frame)
    # under a rolling shutter the corner noise is read from the unsheared corners, as a
    # flight's reference reads it (cvsflow.flight.reference.correct_rolling_shutter)
    reproj = heldout["reproj_rms_px"].to_numpy(float).copy()
    for k in np.unique(fold):
        sel = (fold == k) & np.isfinite(reproj)
        if ld_by_fold[int(k)] and sel.any():
            reproj[sel] = unsheared_pnp(uv[sel], vel[sel], rvec[sel], tvec[sel], obj,
                                        *K_by_fold[int(k)], ld_by_fold[int(k)])[2]
    R = tf.R_from_rvec(rvec).reshape(-1, 3, 3)
    centre_C = np.einsum("nij,j->ni", R, obj.mean(axis=0)) + tvec
    dist_m = np.linalg.norm(centre_C, axis=1)
    cos_tilt = np.abs(np.einsum("ni,ni->n", R[:, :, 2], centre_C)) / dist_m
    centroid = np.nanmean(uv, axis=1)
    spread = np.sqrt(np.nanmean(np.sum((uv - centroid[:, None]) ** 2, axis=-1), axis=1))
    out = pd.DataFrame({
        "frame": frames,
        "distance_m": dist_m,
        "tilt_rad": np.arccos(np.clip(cos_tilt, -1.0, 1.0)),
        "radius_norm": np.hypot(centre_C[:, 0], centre_C[:, 1]) / centre_C[:, 2],
        "n_corners": seen.sum(axis=1),
        "spread_px": spread,
        "speed_px": speed,
        "reproj_rms_px": reproj,
        "inter_coded": float(bool(inter_coded)),
    })  # fmt: skip
    iu = np.triu_indices(6)
    for c, name in enumerate(cov_columns("unitcov")):
        out[name] = unit[:, iu[0][c], iu[1][c]]
    for j, d in enumerate(ERROR_DIMS):
        out[f"rs_err_{d}"] = rs[:, j]
    if corr_length_px is not None:
        corr = np.empty((len(frames), 6, 6))
        for k in np.unique(fold):
            sel = fold == k
            corr[sel] = correlated_noise_terms(uv[sel], rvec[sel], tvec[sel], obj,
                                               *K_by_fold[int(k)], corr_length_px, frame)
        for c, name in enumerate(cov_columns("corrcov")):
            out[name] = corr[:, iu[0][c], iu[1][c]]
    if bodies is not None and "n_filled" in bodies and "t_vicon_s" in heldout:
        out["vicon_filled"] = vicon_filled(bodies, heldout["t_vicon_s"].to_numpy(float))
    if bodies is not None and fits and all("T_Bm_B" in f for f in fits):
        # the board body's noise over the reference's smoothing scale, and the position noise
        # it gives the board's origin (the lever: T_Bm_B's translation)
        s_rot, s_pos = moving_body_noise(bodies, "board")
        lever = float(np.median([np.linalg.norm(np.asarray(f["T_Bm_B"], float)[:3, 3])
                                 for f in fits]))  # fmt: skip
        out["board_noise_rot_rad"] = s_rot
        out["board_noise_pos_m"] = float(np.hypot(s_pos, s_rot * lever))
    if bodies is not None and fits and any(f.get("camera_static") is False for f in fits):
        # a static camera's mean pose carries no noise worth a term: the demo has none
        ref = camera_body_error_cov(rvec, tvec, *moving_body_noise(bodies), frame=frame)
        for c, name in enumerate(cov_columns("refcov")):
            out[name] = ref[:, iu[0][c], iu[1][c]]
    # The planar PnP's other solution (a far or face-on board): the error the measured pose
    # has if the other one is the truth, in the error's own coordinates, and its cost excess.
    flip = np.zeros((len(frames), 6))
    d_ssr = np.full(len(frames), np.inf)
    for k in np.unique(fold):
        sel = np.flatnonzero(fold == k)
        r_alt, t_alt, d_ssr[sel] = pnp_alternatives(uv[sel], rvec[sel], tvec[sel], obj,
                                                    *K_by_fold[int(k)])
        has = np.isfinite(r_alt).all(axis=1)
        if has.any():
            err = pose_errors(tf.T_from_rvec_tvec(r_alt[has], t_alt[has]),
                              tf.T_from_rvec_tvec(rvec[sel[has]], tvec[sel[has]]), frame=frame)
            flip[sel[has]] = err[[f"err_{d}" for d in ERROR_DIMS]].to_numpy()
    for j, d in enumerate(ERROR_DIMS):
        out[f"flip_{d}"] = flip[:, j]
    out["flip_dssr_px2"] = d_ssr
    if fits and all("correlation" in f for f in fits):
        cov_par, _ = parameter_covariance(heldout, p_B, fits, frame=frame,
                                          time_offset=time_offset)
        for c, name in enumerate(cov_columns("parcov")):
            out[name] = cov_par[:, iu[0][c], iu[1][c]]
    return out


def corner_noise_from_reproj(reproj_rms_px, n_corners):
    """Corner noise per image axis (px) that a PnP reprojection RMS over n corners implies:
    the residual length's RMS over sqrt(2), times sqrt(2n / (2n - 6)) for the 6 pose
    parameters fitted (iid noise: its expectation is the noise).

    Parameters
    ----------
    reproj_rms_px : float or array_like, shape (N,)
        RMS over the corners of the PnP reprojection residual length, px.
    n_corners : int or array_like, shape (N,)
        Corners the PnP used (two residuals each); broadcast against ``reproj_rms_px``. At
        three or fewer corners the correction's denominator is held at 1.

    Returns
    -------
    sigma_px : ndarray, shape (N,) (or () for scalars)
        Standard deviation of the corner noise per image axis, px (NaN where
        ``reproj_rms_px`` is NaN).
    """
    n_res = 2.0 * np.asarray(n_corners, float)
    return np.asarray(reproj_rms_px, float) / np.sqrt(2.0) * np.sqrt(n_res / np.maximum(n_res - 6, 1))


#: Column of a features table with the pooled corner noise (px) its frames' estimates are
#: shrunk toward (model (T) with ``k_shrink``); absent: the median over the rows given.
NOISE_POOL_COLUMN = "noise_pool_px"


def corner_noise_pool(reproj_rms_px, n_corners):
    """The pooled corner noise (px) of a session or flight: the median over its frames of
    :func:`corner_noise_from_reproj` (known at measurement time, from its own corners).

    Parameters
    ----------
    reproj_rms_px : ndarray, shape (N,)
        Each frame's PnP reprojection RMS, px (NaN for frames without a pose).
    n_corners : ndarray, shape (N,)
        Corners each frame's PnP used.

    Returns
    -------
    pool_px : float
        Median corner noise per image axis over the finite frames, px.

    Raises
    ------
    OptimiseError
        No frame with a finite reprojection RMS.
    """
    n = corner_noise_from_reproj(reproj_rms_px, n_corners)
    n = n[np.isfinite(n)]
    if not len(n):
        raise OptimiseError("corner_noise_pool: no frame with a finite reprojection RMS")
    return float(np.median(n))


def shrink_corner_noise(noise_px, n_corners, pool_px, k):
    """Each frame's corner-noise estimate shrunk toward a pooled value.

    n_i'^2 = (dof_i n_i^2 + k n_pool^2) / (dof_i + k), dof_i = 2 n_corners - 6: the posterior
    mean of the noise variance when the frame's residual (dof_i degrees of freedom) is
    combined with a prior of strength k pseudo-degrees of freedom centred on the pool. k = 0
    keeps the frame's own estimate, k -> inf the pool.

    Parameters
    ----------
    noise_px : ndarray, shape (N,)
        :func:`corner_noise_from_reproj` of each frame, px.
    n_corners : ndarray, shape (N,)
        Corners each frame's PnP used.
    pool_px : float or ndarray, shape (N,)
        Pooled noise (:func:`corner_noise_pool`), px.
    k : float
        Prior strength, degrees of freedom (>= 0).

    Returns
    -------
    noise_shrunk_px : ndarray, shape (N,)
    """
    dof = np.maximum(2.0 * np.asarray(n_corners, float) - 6.0, 1.0)
    n2 = np.asarray(noise_px, float) ** 2
    return np.sqrt((dof * n2 + k * np.asarray(pool_px, float) ** 2) / (dof + k))


#: Half-width (s) of the window about a frame's Vicon time whose board samples count for
#: ``vicon_filled`` (the interpolation and the board track's 0.01 s smoothing reach ~1 sample).
FILL_WINDOW_S = 0.01


def vicon_filled(bodies, t_vicon_s, body="board"):
    """1.0 where a marker of ``body`` was gap-filled within FILL_WINDOW_S of each time, else 0.

    Parameters
    ----------
    bodies : DataFrame
        bodies.parquet (long, docs/contracts.md): needs ``body``, ``t_s`` (Vicon clock, s) and
        ``n_filled`` (markers gap-filled in the sample).
    t_vicon_s : array_like, shape (N,)
        Query times on the Vicon clock, s (e.g. the held-out frames' ``t_vicon_s``).
    body : str
        ``"board"`` (T_W_Bm) or ``"camera"`` (T_W_Cm).

    Returns
    -------
    filled : ndarray of float, shape (N,)
        1.0 where at least one sample of ``body`` with ``n_filled > 0`` lies within
        ``FILL_WINDOW_S`` (s) of the time, else 0.0 (also 0.0 for a time with no sample
        nearby or a NaN time).
    """
    b = bodies[bodies["body"] == body].sort_values("t_s")
    t = b["t_s"].to_numpy(float)
    c = np.r_[0, np.cumsum(b["n_filled"].to_numpy(float) > 0)]
    lo = np.searchsorted(t, np.asarray(t_vicon_s) - FILL_WINDOW_S, side="left")
    hi = np.searchsorted(t, np.asarray(t_vicon_s) + FILL_WINDOW_S, side="right")
    return (c[hi] - c[lo] > 0).astype(float)


def still_board_weight(n_corners, speed_px, inter_coded):
    """Weight of U per px^2 of a still board's pose-like codec error, per frame.

    A motion-compensated codec copies a nearly still board's blocks from the last frame, so
    every corner errs by the same small motion; model (T) states it as
    ``s_still^2 sigma_px^2 still_board_weight(...) U``.

    Parameters
    ----------
    n_corners : array_like
        Corners the frame's PnP used.
    speed_px : array_like
        Image speed, px per frame period.
    inter_coded : array_like or bool
        1 (True) where the frame comes from a motion-compensated video, else 0.

    Returns
    -------
    ndarray
        ``inter_coded (n / 3) / (1 + (v / STILL_SPEED_PX)^2)``.
    """

    # a pose-like corner error of s px per coordinate moves the pose as iid noise of
    # s sqrt(n / 3) px on n corners would (its 2n coordinates all in PnP's 6 dimensions)
    n_c = np.asarray(n_corners, float)
    speed = np.asarray(speed_px, float)
    return np.asarray(inter_coded, float) * (n_c / 3.0) / (1.0 + (speed / STILL_SPEED_PX) ** 2)
