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
``scipy.optimize.least_squares`` (``solver="scipy"``, TRF; the same optimum, docs/findings.md).

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
``std_errors`` are the total.

Fixed intrinsics. The principal point (cx, cy) correlates at ~1.000 with the rotation of the
camera mounting (a shift of the image by d px is, to first order, a turn of the camera by d / f
rad about its y (cx) or x (cy) axis); yet the board's motion-capture pose ties that rotation,
and the video fixes the principal point better than the stills do
(bench/bench_se3_principal_point.py): the workflow frees them (``optimise.se3.free``) and warns
when the stills' value disagrees (:func:`cvsflow.optimise.se3_cov.principal_point_warnings`).
An intrinsic held fixed is not exact: half a pixel of cx turns T_Cm_C by ~0.7 mrad, several
data-only sigma of a 90 s take. The estimate is a function of the fixed values theta;
linearising the M-estimator's normal equations ``J^T psi(r) = 0`` about the solution gives its
sensitivity
``S = d x_hat / d theta = -(J^T W J)^-1 J^T W J_theta`` (``W = diag(psi'(r))``, the sandwich's
curvature weights), and the calibration's errors, independent of the video's, add
``S Sigma_theta S^T``: ``cov_total = cov_data + S Sigma_theta S^T``, ``Sigma_theta`` diagonal
from ``camera["std"]`` (OpenCV's ``stdDeviationsIntrinsics``) or ``DEFAULT_INTRINSIC_STD``
(with a warning). A fit that frees every intrinsic has ``std_errors == std_errors_data``.

Moving camera. Eq. (1) holds at each corner's own time for both bodies: T_W_Cm and T_W_Bm are
interpolated at t_i + dt (+ line_delay_s v_ik), and the derivative w.r.t. dt (and the line
delay) carries the velocity of both. A camera held still (``camera_static_tol``) is replaced
by its mean pose over the take, so its marker noise averages out; a camera found moving is
followed sample by sample through a local quadratic (``camera_moving_smooth_s``): a centred
box long enough to test stillness bends a moving camera's reference (docs/findings.md, the
moving camera). The cost of following the camera: its body's mrad-level orientation noise
enters every frame's reference instead of averaging over the take.

Exposure and rolling shutter. The video time stamp t_i is the mid-exposure time of row 0 (the
renderer's convention); a constant exposure offset of another camera is absorbed by dt. Row v
is exposed ``v * line_delay_s`` later, which a moving board turns into a shear growing with
its speed; the line delay is separable from dt only when the board crosses rows while it moves
(their correlation is reported).

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

from cvsflow.board import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import INTRINSIC_NAMES
from cvsflow.geometry import transforms as tf
from cvsflow.optimise.result import OptimiseResult
from cvsflow.optimise.se3_apply import apply_se3
from cvsflow.optimise.se3_cov import parameter_covariance, principal_point_warnings
from cvsflow.optimise.se3_fit import Se3Options, correlation_warnings, fixed_std, solve, uncertainty_keys
from cvsflow.optimise.se3_lm import (
    loss_weights,
    refuse_implausible_fit,
    robust_cost,
)
from cvsflow.optimise.se3_model import K_from_intrinsics, Se3Model
from cvsflow.optimise.se3_start import corner_arrays, solve_hand_eye, solve_pnp_frames

log = logging.getLogger(__name__)

#: A principal point shifted by d px is, to first order, the camera turned by d / f about its
#: y (cx) or x (cy) axis: fitted together their estimates correlate at ~1.000 by construction,
#: and their standard errors say how well each is fixed (the board's motion-capture pose ties
#: the rotation). Not reported as a warning.
EXPECTED_CORRELATIONS = {("cx", "T_Cm_C_ry_rad"), ("cy", "T_Cm_C_rx_rad")}
#: Fewest frames the solver accepts.
MIN_FRAMES = 10
#: Half-width (s) of the time window around t_i + dt0 that must hold valid Vicon samples.
DT_MARGIN_S = 0.05
def optimise_se3(corners, bodies, camera, board, dt_offset_s, options=None, *, frames=None, init=None,
                 share=None, per_frame=True, **overrides):
    """Joint estimate of intrinsics, T_Cm_C, T_Bm_B and the time offset (method ``se3``).

    Parameters
    ----------
    corners : DataFrame
        corners.parquet: ``frame, t_s`` (video clock, s), ``found, corner, u_px, v_px``.
    bodies : DataFrame
        bodies.parquet (native rate, long): ``t_s`` (mocap clock, s), ``body``
        (``camera``/``board``), ``valid``, ``x_m, y_m, z_m, qx, qy, qz, qw`` (T_W_Cm / T_W_Bm).
    camera : dict
        camera.yaml content: ``K`` (3x3, px) and ``dist`` ([k1, k2, p1, p2, k3]); the start,
        and the values of the intrinsics held fixed; optional ``std`` (name -> 1-sigma, px or
        unitless), the uncertainty of the fixed ones (module docstring).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m).
    dt_offset_s : float
        Starting time offset (sync.yaml), t_vicon_s = t_video_s + dt_offset_s.
    options : Se3Options or dict, optional
        How the fit runs (:class:`~cvsflow.optimise.se3_fit.Se3Options`; a dict: the config's
        ``optimise.se3`` block); default its defaults.
    frames : array_like of int, optional
        Video frames to fit on (e.g. the training blocks); default all usable frames.
    init : dict, optional
        ``T_Cm_C`` and ``T_Bm_B`` (4x4, m) to start from instead of the hand-eye closed form
        (e.g. a board that never turns, or a previous fit).
    share : cvsflow.optimise.se3_share.Se3Share, optional
        Corner arrays, body tracks and PnP poses made once for all fits on these ``corners``,
        ``bodies`` and ``board`` (the held-out folds); the result is the same without it.
    per_frame : bool
        Make the per-frame table ``errors``; False leaves it empty (a held-out fold reads
        only ``result``, and the table's PnP at the fitted camera was a fifth of its time).
    **overrides
        Fields of :class:`~cvsflow.optimise.se3_fit.Se3Options` to change (``loss="huber"``).

    Returns
    -------
    OptimiseResult
        ``iterations``: one row per residual evaluation (``nfev, cost, fx_px, fy_px,
        dt_offset_s, rms_px``); ``errors``: :func:`~cvsflow.optimise.se3_apply.apply_se3`'s
        per-frame table of the fitted frames plus ``rms_px``, ``weight_min``; ``result``: the
        result.yaml mapping (:func:`_result`).

    Raises
    ------
    OptimiseError
        Bad tables, fewer than ``MIN_FRAMES`` usable frames, bad options, a failed hand-eye
        initialisation, or a fit that explains nothing: a focal length not positive, or a
        median corner residual above ``IMPLAUSIBLE_MEDIAN_PX`` (swapped bodies, a wrong clock
        or board; :func:`cvsflow.optimise.se3_lm.refuse_implausible_fit`).
    """
    t0 = time.perf_counter()
    opts = Se3Options.build(options, "se3", **overrides)
    K0, dist0 = camera_start(camera)
    if not np.isfinite(dt_offset_s):
        raise OptimiseError(f"se3: dt_offset_s {dt_offset_s!r}; expected a finite time in s")
    if share is None:
        p_B = board_object_points(board)
        arrays = corner_arrays(corners, len(p_B))
    else:
        share.check(corners, bodies, board)
        p_B, arrays = share.p_B, (share.frame, share.t_video, share.uv)
    cam, brd = opts.tracks(bodies, share)
    log.info("se3: camera body %s", "static (mean pose used)" if cam.static else "moving")
    frame, t_video, uv, n_skip = keep_usable(*arrays, frames, dt_offset_s, cam, brd)
    pnp = None if share is None else (lambda K, dist: share.pnp(share.rows(frame), K, dist))
    T_Cm_C0, T_Bm_B0 = _start_mountings(init, uv, p_B, K0, dist0, t_video + dt_offset_s, cam, brd, pnp)
    intr0 = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], *dist0])
    model = Se3Model(
        intr0, set(opts.free), T_Cm_C0[:3, :3], T_Bm_B0[:3, :3], opts.fit_dt, dt_offset_s,
        t_video, uv, p_B, cam, brd, fit_ld=opts.fit_line_delay, ld0=opts.line_delay_s,
    )  # fmt: skip
    x0 = model.pack(intr0, T_Cm_C0[:3, 3], T_Bm_B0[:3, 3], dt_offset_s, opts.line_delay_s)
    r0 = model.residuals(x0)
    if not np.isfinite(r0).all():
        raise OptimiseError("se3: non-finite residuals at the start (board behind the camera?)")
    log.info("se3: %d frames, %d parameters; start RMS %.3f px", len(frame), model.n_params,
             float(np.sqrt(np.mean(r0**2))))  # fmt: skip

    def row(x, r, nfev):
        intr, _, _, dt = model.unpack(x)
        return {"nfev": nfev, "cost": robust_cost(r, opts.loss, opts.f_scale_px), "fx_px": intr[0],
                "fy_px": intr[1], "dt_offset_s": dt, "rms_px": float(np.sqrt(np.mean(r**2)))}

    sol, history, n_jac, solver_warnings = solve(model, x0, opts, row)
    r = model.residuals(sol.x)
    refuse_implausible_fit(model.unpack(sol.x)[0][:2], r)
    # clusters: contiguous blocks of video time (one frame's residuals share the mocap noise)
    block = np.floor((t_video - t_video[0]) / max(opts.cluster_s, 1e-9)).astype(int)
    warnings = []
    fixed_names = [n for n in INTRINSIC_NAMES if n not in set(opts.free)]
    sd_fixed, defaulted = fixed_std(camera, fixed_names, "se3: camera", warnings)
    J_fixed = model.jacobian_intrinsics(sol.x)[:, ~model.free] if fixed_names else np.zeros((len(r), 0))
    pc = parameter_covariance(model.jacobian(sol.x), r, opts.loss, opts.f_scale_px,
                              block[np.repeat(np.nonzero(model.seen)[0], 2)], J_fixed, sd_fixed)  # fmt: skip
    warnings += correlation_warnings(pc["corr"], model.names, opts.corr_warn, "se3",
                                     EXPECTED_CORRELATIONS)  # fmt: skip
    warnings += principal_point_warnings(camera, model.names, sol.x, pc["se"]) + solver_warnings
    fixed = {"names": fixed_names, "values": [float(intr0[INTRINSIC_NAMES.index(n)]) for n in fixed_names],
             "std": [float(v) for v in sd_fixed], "std_defaulted": list(defaulted),
             "sensitivity": np.asarray(pc["S"], float).tolist()}  # fmt: skip
    start = {"K": K0.tolist(), "dist": dist0.tolist(), "T_Cm_C": T_Cm_C0.tolist(), "T_Bm_B": T_Bm_B0.tolist(),
             "dt_offset_s": float(dt_offset_s), "rms_px": float(np.sqrt(np.mean(r0**2)))}  # fmt: skip
    result = _result(model, sol, r, pc, opts, cam, fixed, start, warnings)
    result.update(n_frames=len(frame), n_frames_skipped=n_skip, n_jacobians=int(n_jac),
                  time_s=float(time.perf_counter() - t0))
    log.info("se3: fx %.2f fy %.2f dt %.4f s, RMS %.3f px, %d evaluations, %.2f s",
             result["K"][0][0], result["K"][1][1], result["dt_offset_s"], result["rms_px"], sol.nfev,
             result["time_s"])  # fmt: skip
    if not per_frame:
        return OptimiseResult(iterations=pd.DataFrame(history), errors=pd.DataFrame(), result=result)
    per_frame = apply_se3({**result, "camera_moving_smooth_s": opts.camera_moving_smooth_s}, corners, bodies,
                          board, frames=frame, share=share)  # fmt: skip
    rms_frame = np.sqrt(np.nanmean(model.per_corner(r**2), axis=1))
    wmin = loss_weights(r, opts.loss, opts.f_scale_px)[0] / np.where(r == 0, 1.0, r)
    wmin = np.nanmin(model.per_corner(np.where(r == 0, 1.0, wmin)), axis=1)
    per_frame = per_frame.merge(pd.DataFrame({"frame": frame, "rms_px": rms_frame, "weight_min": wmin}),
                                on="frame")
    return OptimiseResult(iterations=pd.DataFrame(history), errors=per_frame, result=result)


def keep_usable(frame, t_video, uv, frames, dt_offset_s, cam, brd, label="se3"):
    """The frames a fit can use: those asked for, with mocap poses of both bodies around t + dt.

    Parameters
    ----------
    frame : ndarray of int, shape (F,)
        Video frames with corners (:func:`~cvsflow.optimise.se3_start.corner_arrays`).
    t_video : ndarray, shape (F,)
        Their video times, s.
    uv : ndarray, shape (F, P, 2)
        Their corners, px.
    frames : array_like of int or None
        Frames to fit on (e.g. the training blocks); None: all.
    dt_offset_s : float
        Time offset, s (t_mocap = t_video + dt).
    cam, brd : BodyTrack
        Camera-marker and board-marker tracks (:func:`usable_frames`).
    label : str
        Prefix of the messages (``"se3"``, ``"se3 rig: camera 1"``).

    Returns
    -------
    frame, t_video, uv : ndarray
        The usable rows.
    n_skip : int
        Frames left out for a gap in the mocap poses.

    Raises
    ------
    OptimiseError
        Fewer than ``MIN_FRAMES`` usable frames.
    """
    if frames is not None:
        sel = np.isin(frame, np.asarray(frames))
        frame, t_video, uv = frame[sel], t_video[sel], uv[sel]
    usable = usable_frames(t_video, dt_offset_s, cam, brd)
    n_skip = int((~usable).sum())
    if n_skip:
        log.warning("%s: %d of %d frames skipped (no valid Vicon pose within %.2f s of t + dt)",
                    label, n_skip, len(frame), DT_MARGIN_S)  # fmt: skip
    frame, t_video, uv = frame[usable], t_video[usable], uv[usable]
    if len(frame) < MIN_FRAMES:
        raise OptimiseError(
            f"{label}: {len(frame)} frames with corners and valid Vicon poses at t_video + "
            f"{dt_offset_s:.3f} s; need at least {MIN_FRAMES}"
        )
    return frame, t_video, uv, n_skip


def _start_mountings(init, uv, p_B, K0, dist0, t_vicon, cam, brd, pnp=None):
    """T_Cm_C and T_Bm_B to start from: ``init``'s, else PnP at the calibration (by ``pnp(K,
    dist)`` when given: the poses of the same frames) then AX = ZB."""
    if init is not None:
        try:
            return (np.asarray(init["T_Cm_C"], float).reshape(4, 4),
                    np.asarray(init["T_Bm_B"], float).reshape(4, 4))  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            raise OptimiseError(f"se3: init {init!r}: expected T_Cm_C and T_Bm_B (4x4)") from exc
    T_C_B_pnp, ok = solve_pnp_frames(uv, p_B, K0, dist0) if pnp is None else pnp(K0, dist0)
    T_Cm_Bm = tf.invert_T(cam(t_vicon)) @ brd(t_vicon)
    return solve_hand_eye(T_Cm_Bm[ok], T_C_B_pnp[ok])


def _result(model, sol, r, pc, opts, cam, fixed, start, warnings):
    """The result.yaml mapping of a fit.

    ``method``; ``K`` (3x3), ``dist`` (5); ``T_Cm_C``, ``T_Bm_B`` (4x4) and their ``*_pose6``
    [x, y, z, roll, pitch, yaw] (m, rad); ``dt_offset_s``, ``line_delay_s`` (s per row),
    ``fit_line_delay``, ``free``, ``fit_dt``; :func:`~cvsflow.optimise.se3_fit.uncertainty_keys`
    (rotation parameters are local perturbations about the axes of C and B, so their sigma is
    the rotation uncertainty in rad about those axes; ``std_errors_data`` is the larger of
    ``std_errors_gn`` and ``std_errors_cluster``, ``std_errors^2 = std_errors_data^2 +
    std_errors_fixed^2``); ``fixed_intrinsics`` (``names, values, std, std_defaulted``,
    ``sensitivity`` S, rows in the order of ``correlation.names``); ``init`` (the closed-form
    start); the options (:meth:`~cvsflow.optimise.se3_fit.Se3Options.summary`); ``n_residuals,
    n_clusters, rms_px, sigma_px`` (robust pixel noise, from the M-estimator scale), ``cost,
    n_iterations`` (residual evaluations), ``solver, status, message, warnings``.
    """
    intr, T_Cm_C, T_Bm_B, dt = model.unpack(sol.x)
    K = K_from_intrinsics(*intr[:4])
    result = {
        "method": "se3", "K": K.tolist(), "dist": intr[4:].tolist(), "T_Cm_C": T_Cm_C.tolist(),
        "T_Bm_B": T_Bm_B.tolist(), "T_Cm_C_pose6": tf.pose6_from_T(T_Cm_C).tolist(),
        "T_Bm_B_pose6": tf.pose6_from_T(T_Bm_B).tolist(), "dt_offset_s": dt,
        "line_delay_s": float(model.line_delay(sol.x)), "fit_line_delay": bool(opts.fit_line_delay),
        "free": [n for n in INTRINSIC_NAMES if n in set(opts.free)], "fit_dt": bool(opts.fit_dt),
        **uncertainty_keys(model.names, sol.x, pc), "fixed_intrinsics": fixed, "init": start,
        "n_residuals": int(r.size), "n_clusters": int(pc["n_clusters"]), **opts.summary(cam),
        "rms_px": float(np.sqrt(np.mean(r**2))), "sigma_px": float(np.sqrt(pc["sigma2"])),
        "cost": float(sol.cost), "n_iterations": int(sol.nfev), "solver": opts.solver,
        "status": int(sol.status), "message": str(sol.message), "warnings": warnings,
    }  # fmt: skip
    if opts.camera_static_tol is not None and not cam.static:  # (a static camera's keys unchanged)
        result["camera_moving_smooth_s"] = float(opts.camera_moving_smooth_s)
    return result


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
