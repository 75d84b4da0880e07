"""The ``se3`` method: joint SE(3) calibration by corner reprojection over all frames.

Unknowns (all shared by every frame; there are no per-frame unknowns):

- the intrinsics fx, fy, cx, cy (px) and the distortion terms k1, k2, p1, p2, k3 that the
  caller frees (OpenCV's 5-term model);
- ``T_Cm_C``: the camera optical frame C in the camera-marker body Cm (rotation as a local
  perturbation ``R_Cm_C = R0_Cm_C @ exp([w_C]x)``, w_C in rad about the axes of C; translation
  t_Cm_C in m, in Cm);
- ``T_Bm_B``: the board frame B in the board-marker body Bm (``R_Bm_B = R0_Bm_B @ exp([w_B]x)``,
  w_B in rad about the axes of B; t_Bm_B in m, in Bm);
- ``dt_offset_s``: the time offset, ``t_vicon_s = t_video_s + dt_offset_s`` (docs/contracts.md),
  a refinement of the sync stage's value.

Residuals: for video frame i at time t_i, the board pose predicted by the Vicon,

    T_C_B,i = inv(T_Cm_C) @ inv(T_W_Cm(t_i + dt)) @ T_W_Bm(t_i + dt) @ T_Bm_B      (1)

projects the board's inner corners (corner k at ((k % nx) s, (k // nx) s, 0) in B) through
K and dist (:func:`cvsflow.geometry.camera.project_points`); the residual is observed minus
projected, in px, under a robust loss (soft_l1 or Huber, scale ``f_scale_px``). The Vicon
poses are interpolated at t_i + dt (linear in position, SLERP in rotation) so dt is a
continuous unknown.

Initialisation is closed form: the time offset from sync, the intrinsics from calibration,
and T_Cm_C, T_Bm_B from the robot-world/hand-eye problem A_i X = Z B_i
(:func:`cvsflow.optimise.se3_start.solve_hand_eye`, Shah 2013) with A_i = T_Cm_Bm,i (Vicon),
B_i = T_C_B,i (PnP), X = T_Bm_B, Z = T_Cm_C.

Refinement: the unknowns are only the ~22 shared parameters (the board's pose per frame comes
from the Vicon, not from extra unknowns), so every residual depends on all of them and the
Jacobian is dense but narrow (2 P N x 22): there is no sparsity for ``jac_sparsity`` to
exploit. The analytic Jacobian (checked against finite differences) feeds either our
Levenberg-Marquardt on the 22 x 22 normal equations with the robust loss by iterative
reweighting (default, ``solver="lm"``: one m x n product per iteration) or
``scipy.optimize.least_squares`` (``solver="scipy"``, TRF; the same optimum: on the 90 s demo
both give fx to 1e-7 px in about 1.5 s).

Uncertainty: the Gauss-Newton covariance of an M-estimator (Huber 1981, sec. 7.6)
``sigma_eff^2 (J^T J)^-1`` with ``sigma_eff^2 = m/(m-n) mean(psi^2) / mean(psi')^2`` (equal to
``sum r^2 / (m - n)`` for a quadratic loss), and a cluster-robust sandwich
``H^-1 (sum_c g_c g_c^T) H^-1`` over contiguous time blocks (residuals of one frame share the
Vicon pose noise and are not independent), each block's score corrected for its leverage
(CR2, :mod:`cvsflow.metrics.sandwich`: a 12 s session has only 12 blocks). The data-only standard
errors are the larger of the two per parameter; correlations (identifiability) come from
``(J^T J)^-1``. The intrinsics
held fixed are not exact: their calibration uncertainty (camera.yaml ``std``) is carried into
the free estimates through the sensitivity of the solution to them, and the reported
``std_errors`` are the total (see :func:`optimise_se3`, Notes).

This module is the entry (:func:`optimise_se3`); the pieces live beside it: ``se3_apply``
(per-frame poses of a fit, :func:`~cvsflow.optimise.se3_apply.apply_se3`),
``body_tracks`` (the Vicon tracks and their interpolant), ``se3_start`` (corners as arrays,
PnP per frame, the hand-eye start), ``se3_model`` (parameter vector, residuals, Jacobian),
``se3_lm`` (robust loss and Levenberg-Marquardt), ``se3_cov`` (parameter covariance) and
``se3_sim`` (corner-level synthetic sessions for tests and bench).
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from cvsflow.board import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import INTRINSIC_NAMES
from cvsflow.geometry import transforms as tf
from cvsflow.optimise.body_tracks import CAMERA_MOVING_SMOOTH_S, BodyTrack
from cvsflow.optimise.result import OptimiseResult
from cvsflow.optimise.se3_apply import apply_se3
from cvsflow.optimise.se3_cov import (
    DEFAULT_INTRINSIC_STD,
    fixed_intrinsic_std,
    parameter_covariance,
    principal_point_warnings,
)
from cvsflow.optimise.se3_lm import (
    LOSSES,
    levenberg_marquardt,
    loss_weights,
    refuse_implausible_fit,
    robust_cost,
)
from cvsflow.optimise.se3_model import K_from_intrinsics, Se3Model
from cvsflow.optimise.se3_start import corner_arrays, solve_hand_eye, solve_pnp_frames

log = logging.getLogger(__name__)

#: Intrinsics freed by default.
DEFAULT_FREE = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: A principal point shifted by d px is, to first order, the camera turned by d / f about its
#: y (cx) or x (cy) axis: fitted together their estimates correlate at ~1.000 by construction,
#: and their standard errors say how well each is fixed (the board's motion-capture pose ties
#: the rotation). Not reported as a warning.
EXPECTED_CORRELATIONS = {("cx", "T_Cm_C_ry_rad"), ("cy", "T_Cm_C_rx_rad")}
#: Fewest frames the solver accepts.
MIN_FRAMES = 10
#: Half-width (s) of the time window around t_i + dt0 that must hold valid Vicon samples.
DT_MARGIN_S = 0.05
def optimise_se3(
    corners,
    bodies,
    camera,
    board,
    dt_offset_s,
    *,
    free=DEFAULT_FREE,
    fit_dt=True,
    loss="soft_l1",
    f_scale_px=1.0,
    max_nfev=100,
    corr_warn=0.95,
    cluster_s=1.0,
    camera_smooth_s=1.0,
    board_smooth_s=0.01,
    camera_static_tol=(0.002, 0.002),
    camera_moving_smooth_s=None,
    solver="lm",
    frames=None,
    init=None,
    fit_line_delay=False,
    line_delay_s=0.0,
):
    """Joint estimate of intrinsics, T_Cm_C, T_Bm_B and the time offset (method ``se3``).

    Parameters
    ----------
    corners : DataFrame
        corners.parquet: ``frame, t_s`` (video clock, s), ``found, corner, u_px, v_px``.
    bodies : DataFrame
        bodies.parquet (native rate, long): ``t_s`` (Vicon clock, s), ``body``
        (``camera``/``board``), ``valid``, ``x_m, y_m, z_m, qx, qy, qz, qw`` (T_W_Cm / T_W_Bm).
    camera : dict
        camera.yaml content: ``K`` (3x3, px) and ``dist`` ([k1, k2, p1, p2, k3]); the start,
        and the values of the intrinsics held fixed; optional ``std`` (name -> 1-sigma, px or
        unitless), the uncertainty of the fixed ones (Notes).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m).
    dt_offset_s : float
        Starting time offset (sync.yaml), t_vicon_s = t_video_s + dt_offset_s.
    free : sequence of str
        Intrinsics to estimate, from ``INTRINSIC_NAMES``; the others stay at ``camera``.
    fit_dt : bool
        Refine the time offset (else held at ``dt_offset_s``).
    loss : {"soft_l1", "huber", "linear"}
        Robust loss on the corner residuals.
    f_scale_px : float
        Scale of the robust loss, px (residuals well below it count quadratically).
    max_nfev : int
        Most residual evaluations of the trust-region solver.
    corr_warn : float
        Warn when two estimates correlate beyond this (absolute value).
    cluster_s : float
        Length (s of video time) of the contiguous blocks of frames treated as independent
        clusters in the cluster-robust covariance.
    camera_smooth_s : float
        Window (s) of the centred moving average applied to the camera body track before the
        static test (:func:`~cvsflow.optimise.body_tracks.smooth_track`); the track used when
        ``camera_static_tol`` is None; 0 uses the raw track.
    camera_static_tol : (float, float) or None
        (m, rad): when the smoothed camera track stays this close to its mean over 95 % of the
        take (:func:`~cvsflow.optimise.body_tracks.is_static`), the camera is treated as static
        and its mean pose is used for every frame (its marker noise then averages over the
        take). None: never (the track smoothed by ``camera_smooth_s`` is used as it is).
    camera_moving_smooth_s : float or None
        Window (s) of the local quadratic smoothing
        (:func:`~cvsflow.optimise.body_tracks.smooth_track_local`) of a camera track found
        moving (hand-held, on a robot); None: ``CAMERA_MOVING_SMOOTH_S`` (Notes, Moving
        camera).
    board_smooth_s : float
        Window (s) of the moving average of the board body track (a few Vicon samples: it
        takes the marker noise out of the interpolant's slope, which otherwise puts kinks in
        the cost as a function of dt at every 1/300 s, since 300 Hz is a multiple of 30 fps).
    solver : {"lm", "scipy"}
        ``lm``: Levenberg-Marquardt on the 22 x 22 normal equations with the robust loss by
        iterative reweighting (fast: the work per iteration is one m x n product);
        ``scipy``: ``scipy.optimize.least_squares`` (TRF, exact trust-region solver: an SVD of
        the m x n Jacobian per iteration). Both minimise the same robust cost.
    frames : array_like of int, optional
        Video frames to fit on (e.g. the training blocks); default all usable frames.
    init : dict, optional
        ``T_Cm_C`` and ``T_Bm_B`` (4x4, m) to start from instead of the hand-eye closed form
        (e.g. a board that never turns, or a previous fit).
    fit_line_delay : bool
        Estimate the rolling shutter's line delay (s per image row): corner k of frame i is
        then compared with the Vicon at ``t_i + dt + line_delay_s * v_ik`` (v_ik its observed
        row, px), as Kalibr's rolling-shutter camera model does. False (default): a global
        shutter, every corner at ``t_i + dt`` (unless ``line_delay_s`` is non-zero).
    line_delay_s : float
        The line delay's start (fitted) or its known value (held), s per row; 0 with
        ``fit_line_delay`` False is the global shutter.

    Returns
    -------
    OptimiseResult
        ``iterations``: one row per accepted-or-tried step (``nfev, cost, fx_px, fy_px,
        dt_offset_s``); ``errors``: the per-frame table of
        :func:`~cvsflow.optimise.se3_apply.apply_se3` for the fitted
        frames (plus ``rms_px``, ``weight_min``); ``result``: the result.yaml mapping (see
        Notes).

    Raises
    ------
    OptimiseError
        Bad tables, fewer than ``MIN_FRAMES`` usable frames, bad options, a failed
        hand-eye initialisation, or a fit that explains nothing: a focal length not positive,
        or a median corner residual above ``IMPLAUSIBLE_MEDIAN_PX`` (swapped bodies, a wrong
        clock or board; :func:`cvsflow.optimise.se3_lm.refuse_implausible_fit`).

    Notes
    -----
    ``result`` keys: ``method``; ``K`` (3x3), ``dist`` (5); ``T_Cm_C``, ``T_Bm_B`` (4x4) and their
    ``*_pose6`` [x, y, z, roll, pitch, yaw] (m, rad); ``dt_offset_s``; ``estimates``
    (name -> value) and ``std_errors`` (name -> total 1-sigma) of every free parameter
    (rotation parameters are the local perturbations about the axes of C and B, so their sigma
    is the rotation uncertainty in rad about those axes); ``std_errors_data`` (from the video
    data alone: the larger of ``std_errors_gn`` and ``std_errors_cluster`` per parameter);
    ``std_errors_fixed`` (the part carried in from the fixed intrinsics), with
    ``std_errors^2 = std_errors_data^2 + std_errors_fixed^2``; ``fixed_intrinsics`` (``names``,
    ``values``, ``std`` used, ``std_defaulted``: names whose std came from
    ``DEFAULT_INTRINSIC_STD``, ``sensitivity``: S, rows in the order of ``correlation.names``,
    one column per fixed intrinsic); ``correlation`` (names, matrix: data-only, from
    ``(J^T J)^-1``; the identifiability warnings use it); ``correlation_total`` (of the total
    covariance); ``init`` (the closed-form start); ``n_frames``, ``n_residuals``, ``rms_px``,
    ``sigma_px`` (robust pixel noise, from the M-estimator scale), ``cost``, ``n_iterations``
    (residual evaluations; scipy's TRF takes one per iteration), ``n_jacobians``, ``time_s``,
    ``status``, ``message``, ``warnings`` (list of str); ``line_delay_s`` (s per row) and
    ``fit_line_delay``.

    Moving camera. Eq. (1) holds at each corner's own time for both bodies: T_W_Cm and T_W_Bm
    are interpolated at t_i + dt (+ line_delay_s v_ik) on the same Vicon clock, and the
    derivative w.r.t. dt (and the line delay) carries the velocity of both. A camera held
    still (``camera_static_tol``) is replaced by its mean pose over the take, so its marker
    noise averages out; a camera found moving (hand-held around a fixed board, on a robot) is
    followed sample by sample, smoothed over ``camera_moving_smooth_s`` (by default the
    board's few samples). The 1 s window that tests stillness is never used for a moving
    camera's reference: a centred box keeps sinc(f * 1 s) of a motion of f Hz (64 % at 0.5 Hz),
    which bent the reference by centimetres (a rendered 15 s hand-held session: corner RMS
    10 px, fx 14 px, T_Cm_C 55 mm and dt 50 ms off, held-out errors 104 mm; with the local
    quadratic 0.42 px, 0.2 px, 0.35 mm, 0.13 ms, within 2.4 standard errors, held-out 2.6 mm
    against 1.5 mm for the same video with a fixed camera). The cost of following the
    camera: its body's mrad-level orientation noise (markers 0.17 m apart) enters every
    frame's reference instead of averaging over the take.

    Exposure and rolling shutter. The video time stamp t_i is taken as the mid-exposure time
    of row 0 (the renderer's convention, cvsflow.synth.effects); a constant exposure midpoint
    offset of another camera is the same for every frame, so ``dt_offset_s`` absorbs it. Row
    v is exposed ``v * line_delay_s`` later, which a moving board turns into a shear of the
    image that grows with its speed; the line delay is the slope of that lag in the row and
    is separable from dt only when the board crosses rows while it moves (both are fitted
    from the same motion: their correlation is reported).

    Fixed intrinsics. The principal point (cx, cy) correlates at ~1.000 with the rotation of
    the camera mounting, since a shift of the image by d px is, to first order, a turn of the
    camera by d / f rad about its y (cx) or x (cy) axis; yet the board's motion-capture pose
    ties that rotation, and the video fixes the principal point better than the stills do
    (bench/bench_se3_principal_point.py: 0.14 / 0.11 px on the 20 s demo against the stills'
    0.33 / 0.27 px, 0.23 px on a simulated 90 s session whatever the stills' error); the
    workflow frees them (``optimise.se3.free``) and warns when the stills' value disagrees
    (:func:`cvsflow.optimise.se3_cov.principal_point_warnings`). Holding an intrinsic fixed
    does not make it exact: an error of 0.5 px in cx (about one calibration sigma) turns
    T_Cm_C by 0.7 mrad, several times the data-only standard error of a 90 s take, so
    estimates would sit 6-10 data-only sigma off truth (11.7 px: 1.36 deg). The estimate
    is a function of the fixed values theta; linearising the M-estimator's normal equations
    ``J^T psi(r) = 0`` about the solution gives its sensitivity

        S = d x_hat / d theta = -(J^T W J)^-1 J^T W J_theta,   W = diag(psi'(r)),

    (J_theta the residuals' derivatives w.r.t. the fixed intrinsics, W the robust curvature
    weights, as in the sandwich covariance), and the calibration's errors, independent of the
    video's, add ``S Sigma_theta S^T`` to the covariance: ``cov_total = cov_data + S
    Sigma_theta S^T`` with ``cov_data`` the data-only standard errors and ``(J^T J)^-1``
    correlations, and ``Sigma_theta`` diagonal from ``camera["std"]`` (OpenCV's
    ``stdDeviationsIntrinsics``, :func:`cvsflow.calibration.intrinsics.calibrate_camera`), or
    ``DEFAULT_INTRINSIC_STD`` for a name it lacks (with a warning). A fit that frees every
    intrinsic has ``std_errors == std_errors_data``.
    """
    t0 = time.perf_counter()
    if loss not in LOSSES:
        raise OptimiseError(f"se3: loss {loss!r}; expected one of {LOSSES}")
    if solver not in ("lm", "scipy"):
        raise OptimiseError(f"se3: solver {solver!r}; expected 'lm' or 'scipy'")
    if not f_scale_px > 0:
        raise OptimiseError(f"se3: f_scale_px {f_scale_px!r}; expected > 0 px")
    bad_free = [f for f in free if f not in INTRINSIC_NAMES]
    if bad_free:
        raise OptimiseError(f"se3: free {bad_free} unknown; expected names from {INTRINSIC_NAMES}")
    K0, dist0 = camera_start(camera)
    if not (np.isfinite(line_delay_s) and line_delay_s >= 0.0):
        raise OptimiseError(f"se3: line_delay_s {line_delay_s!r}; expected a finite value >= 0 s")
    if not np.isfinite(dt_offset_s):
        raise OptimiseError(f"se3: dt_offset_s {dt_offset_s!r}; expected a finite time in s")
    p_B = board_object_points(board)
    frame, t_video, uv = corner_arrays(corners, len(p_B))
    if frames is not None:
        sel = np.isin(frame, np.asarray(frames))
        frame, t_video, uv = frame[sel], t_video[sel], uv[sel]
    if camera_moving_smooth_s is None:
        camera_moving_smooth_s = CAMERA_MOVING_SMOOTH_S
    cam = BodyTrack.from_bodies(
        bodies, "camera", smooth_s=camera_smooth_s, static_tol=camera_static_tol,
        moving_smooth_s=camera_moving_smooth_s,
    )
    brd = BodyTrack.from_bodies(bodies, "board", smooth_s=board_smooth_s)
    log.info("se3: camera body %s", "static (mean pose used)" if cam.static else "moving")
    usable = usable_frames(t_video, dt_offset_s, cam, brd)
    n_skip = int((~usable).sum())
    if n_skip:
        log.warning(
            "se3: %d of %d frames skipped (no valid Vicon pose within %.2f s of t + dt)",
            n_skip,
            len(frame),
            DT_MARGIN_S,
        )
    frame, t_video, uv = frame[usable], t_video[usable], uv[usable]
    if len(frame) < MIN_FRAMES:
        raise OptimiseError(
            f"se3: {len(frame)} frames with corners and valid Vicon poses at t_video + "
            f"{dt_offset_s:.3f} s; need at least {MIN_FRAMES}"
        )

    # --- closed-form start: PnP at the calibrated intrinsics, then AX = ZB
    if init is not None:
        try:
            T_Cm_C0 = np.asarray(init["T_Cm_C"], float).reshape(4, 4)
            T_Bm_B0 = np.asarray(init["T_Bm_B"], float).reshape(4, 4)
        except (KeyError, TypeError, ValueError) as exc:
            raise OptimiseError(f"se3: init {init!r}: expected T_Cm_C and T_Bm_B (4x4)") from exc
    else:
        T_C_B_pnp, ok = solve_pnp_frames(uv, p_B, K0, dist0)
        tq = t_video + dt_offset_s
        T_Cm_Bm = tf.invert_T(cam(tq)) @ brd(tq)
        T_Cm_C0, T_Bm_B0 = solve_hand_eye(T_Cm_Bm[ok], T_C_B_pnp[ok])
    intr0 = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], *dist0])
    model = Se3Model(
        intr0, set(free), T_Cm_C0[:3, :3], T_Bm_B0[:3, :3], fit_dt, dt_offset_s,
        t_video, uv, p_B, cam, brd, fit_ld=fit_line_delay, ld0=line_delay_s,
    )  # fmt: skip
    x0 = model.pack(intr0, T_Cm_C0[:3, 3], T_Bm_B0[:3, 3], dt_offset_s, line_delay_s)
    r0 = model.residuals(x0)
    if not np.isfinite(r0).all():
        raise OptimiseError("se3: non-finite residuals at the start (board behind the camera?)")
    log.info(
        "se3: %d frames, %d parameters; start RMS %.3f px",
        len(frame),
        model.n_params,
        float(np.sqrt(np.mean(r0**2))),
    )

    history = []
    n_jac = [0]

    def fun(x):
        r = model.residuals(x)
        intr, _, _, dt = model.unpack(x)
        rho = robust_cost(r, loss, f_scale_px)
        history.append(
            {"nfev": len(history), "cost": rho, "fx_px": intr[0], "fy_px": intr[1],
             "dt_offset_s": dt, "rms_px": float(np.sqrt(np.mean(r**2)))}
        )  # fmt: skip
        return r

    def jac(x):
        n_jac[0] += 1
        return model.jacobian(x)

    if solver == "scipy":
        sol = least_squares(
            fun, x0, jac=jac, method="trf", loss=loss, f_scale=f_scale_px, x_scale="jac",
            max_nfev=max_nfev, xtol=1e-10, ftol=1e-12, gtol=1e-10,
        )  # fmt: skip
    else:
        sol = levenberg_marquardt(fun, jac, x0, loss, f_scale_px, max_nfev)
    if not np.isfinite(sol.x).all():
        raise OptimiseError(f"se3: the solver diverged ({sol.message})")
    x = sol.x
    r = model.residuals(x)
    refuse_implausible_fit(model.unpack(x)[0][:2], r)
    J = model.jacobian(x)
    frame_of_row = np.repeat(np.nonzero(model.seen)[0], 2)
    block = np.floor((t_video - t_video[0]) / max(cluster_s, 1e-9)).astype(int)
    # uncertainty of the intrinsics held fixed, carried into the free estimates (Notes)
    fixed_names = [n for n in INTRINSIC_NAMES if n not in set(free)]
    warnings_out = []
    names = model.names
    if fixed_names:
        sd_fixed, defaulted = fixed_intrinsic_std(camera, fixed_names)
        J_fixed = model.jacobian_intrinsics(x)[:, ~model.free]
        if defaulted:
            msg = (
                f"se3: camera has no std for the fixed {defaulted}; their uncertainty is taken "
                f"as {[DEFAULT_INTRINSIC_STD[n] for n in defaulted]} (DEFAULT_INTRINSIC_STD)"
            )
            warnings_out.append(msg)
            log.warning(msg)
    else:
        sd_fixed, defaulted = np.zeros(0), []
        J_fixed = np.zeros((len(r), 0))
    pc = parameter_covariance(J, r, loss, f_scale_px, block[frame_of_row], J_fixed, sd_fixed)
    se_gn, se_cl, se_data, se_fixed, se = (pc[k] for k in ("se_gn", "se_cl", "se_data",
                                                           "se_fixed", "se"))  # fmt: skip
    corr, corr_total, S = pc["corr"], pc["corr_total"], pc["S"]
    sigma2, n_clusters = pc["sigma2"], pc["n_clusters"]
    warnings_out += correlation_warnings(corr, names, corr_warn, "se3", EXPECTED_CORRELATIONS)
    warnings_out += principal_point_warnings(camera, names, x, se)
    if sol.status <= 0:
        msg = f"se3: solver stopped before converging: {sol.message}"
        warnings_out.append(msg)
        log.warning(msg)
    intr, T_Cm_C, T_Bm_B, dt = model.unpack(x)
    ld = model.line_delay(x)
    K = K_from_intrinsics(*intr[:4])
    dist = intr[4:]

    per_frame = apply_se3(
        {"K": K, "dist": dist, "T_Cm_C": T_Cm_C, "T_Bm_B": T_Bm_B, "dt_offset_s": dt,
         "camera_smooth_s": camera_smooth_s, "board_smooth_s": board_smooth_s,
         "camera_static_tol": camera_static_tol, "camera_moving_smooth_s": camera_moving_smooth_s,
         "line_delay_s": ld},
        corners, bodies, board, frames=frame,
    )  # fmt: skip
    rms_frame = np.sqrt(np.nanmean(model.per_corner(r**2), axis=1))
    wmin = loss_weights(r, loss, f_scale_px)[0] / np.where(r == 0, 1.0, r)
    wmin = np.nanmin(model.per_corner(np.where(r == 0, 1.0, wmin)), axis=1)
    per_frame = per_frame.merge(
        pd.DataFrame({"frame": frame, "rms_px": rms_frame, "weight_min": wmin}), on="frame"
    )
    elapsed = time.perf_counter() - t0
    result = {
        "method": "se3",
        "K": K.tolist(),
        "dist": dist.tolist(),
        "T_Cm_C": T_Cm_C.tolist(),
        "T_Bm_B": T_Bm_B.tolist(),
        "T_Cm_C_pose6": tf.pose6_from_T(T_Cm_C).tolist(),
        "T_Bm_B_pose6": tf.pose6_from_T(T_Bm_B).tolist(),
        "dt_offset_s": dt,
        "line_delay_s": float(ld),
        "fit_line_delay": bool(fit_line_delay),
        "free": [n for n in INTRINSIC_NAMES if n in set(free)],
        "fit_dt": bool(fit_dt),
        "estimates": {n: float(v) for n, v in zip(names, x, strict=True)},
        "std_errors": {n: float(v) for n, v in zip(names, se, strict=True)},
        "std_errors_data": {n: float(v) for n, v in zip(names, se_data, strict=True)},
        "std_errors_fixed": {n: float(v) for n, v in zip(names, se_fixed, strict=True)},
        "fixed_intrinsics": {
            "names": fixed_names,
            "values": [float(intr0[INTRINSIC_NAMES.index(n)]) for n in fixed_names],
            "std": [float(v) for v in sd_fixed],
            "std_defaulted": list(defaulted),
            "sensitivity": np.asarray(S, float).tolist(),
        },
        "std_errors_gn": {n: float(v) for n, v in zip(names, se_gn, strict=True)},
        "std_errors_cluster": {n: float(v) for n, v in zip(names, se_cl, strict=True)},
        "correlation": {"names": list(names), "matrix": np.round(corr, 6).tolist()},
        "correlation_total": {"names": list(names), "matrix": np.round(corr_total, 6).tolist()},
        "init": {
            "K": K0.tolist(),
            "dist": dist0.tolist(),
            "T_Cm_C": T_Cm_C0.tolist(),
            "T_Bm_B": T_Bm_B0.tolist(),
            "dt_offset_s": float(dt_offset_s),
            "rms_px": float(np.sqrt(np.mean(r0**2))),
        },
        "n_frames": len(frame),
        "n_frames_skipped": n_skip,
        "n_residuals": int(r.size),
        "n_clusters": int(n_clusters),
        "cluster_s": float(cluster_s),
        "camera_smooth_s": float(camera_smooth_s),
        "board_smooth_s": float(board_smooth_s),
        "camera_static": bool(cam.static),
        "camera_static_tol": None if camera_static_tol is None else list(camera_static_tol),
        "rms_px": float(np.sqrt(np.mean(r**2))),
        "sigma_px": float(np.sqrt(sigma2)),
        "cost": float(sol.cost),
        "loss": loss,
        "f_scale_px": float(f_scale_px),
        "n_iterations": int(sol.nfev),
        "n_jacobians": int(n_jac[0]),
        "solver": solver,
        "time_s": float(elapsed),
        "status": int(sol.status),
        "message": str(sol.message),
        "warnings": warnings_out,
    }
    if camera_static_tol is not None and not cam.static:  # (a static camera's keys unchanged)
        result["camera_moving_smooth_s"] = float(camera_moving_smooth_s)
    log.info(
        "se3: fx %.2f fy %.2f dt %.4f s, RMS %.3f px, %d evaluations, %.2f s",
        intr[0], intr[1], dt, result["rms_px"], sol.nfev, elapsed,
    )  # fmt: skip
    return OptimiseResult(iterations=pd.DataFrame(history), errors=per_frame, result=result)


def camera_start(camera, label="se3"):
    """Camera matrix and 5-term distortion of a camera.yaml mapping (the se3 start).

    Parameters
    ----------
    camera : dict
        ``K`` (3x3, px) and ``dist`` (up to 5 terms [k1 k2 p1 p2 k3]; missing ones are 0).
    label : str
        Prefix of the error message.

    Returns
    -------
    K : ndarray, shape (3, 3)
    dist : ndarray, shape (5,)

    Raises
    ------
    OptimiseError
        ``K`` or ``dist`` missing or malformed.
    """
    try:
        K0 = np.asarray(camera["K"], float).reshape(3, 3)
        dist0 = np.zeros(5)
        d = np.asarray(camera["dist"], float).ravel()[:5]
        dist0[: d.size] = d
    except (KeyError, TypeError, ValueError) as exc:
        raise OptimiseError(
            f"{label}: camera {camera!r}: expected K (3x3, px) and dist [k1 k2 p1 p2 k3]"
        ) from exc
    return K0, dist0


def usable_frames(t_video, dt_offset_s, cam, brd):
    """Frames with valid Vicon poses of both bodies within ``DT_MARGIN_S`` of t + dt.

    Parameters
    ----------
    t_video : ndarray, shape (F,)
        Video times, s.
    dt_offset_s : float
        Time offset, s (t_vicon = t_video + dt).
    cam, brd : BodyTrack
        Camera-marker and board-marker tracks.

    Returns
    -------
    usable : ndarray of bool, shape (F,)
    """
    usable = np.ones(len(t_video), bool)
    for off in (-DT_MARGIN_S, 0.0, DT_MARGIN_S):
        tq = t_video + dt_offset_s + off
        usable &= cam.ok(tq) & brd.ok(tq)
    return usable


def correlation_warnings(corr, names, corr_warn, label, expected=()):
    """Warnings (logged) for every pair of estimates correlated beyond ``corr_warn``.

    Parameters
    ----------
    corr : ndarray, shape (n, n)
        Correlation of the estimates (data only).
    names : sequence of str
        Parameter names, in the order of ``corr``.
    corr_warn : float
        Absolute correlation above which a pair is reported.
    label : str
        Prefix of the messages (``"se3"``).
    expected : collection of (str, str)
        Pairs whose correlation is known and harmless (``EXPECTED_CORRELATIONS``), not reported.

    Returns
    -------
    warnings : list of str
    """
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if (names[i], names[j]) in expected or (names[j], names[i]) in expected:
                continue
            if abs(corr[i, j]) > corr_warn:
                msg = (
                    f"{label}: {names[i]} and {names[j]} correlate at {corr[i, j]:+.3f} "
                    f"(|corr| > {corr_warn}): the data hardly separate them"
                )
                out.append(msg)
                log.warning(msg)
    return out
