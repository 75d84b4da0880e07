"""The pose-level fit of a camera-pose-stream session, and its held-out time blocks.

A session whose camera input is a detector's camera-pose stream (``camera_poses``) has no
corners: the poses stage's table comes from the stream itself, and the fit is the stream fit of
:func:`cvsflow.handeye.estimate_streams` (time offset, ``T_Cm_C`` and the target's pose as one
robust fit with block-sandwich standard errors) instead of se3.

- :func:`stream_inputs`: the fit's two streams from the session's tables: the detector's
  ``T_B_C`` per frame (poses_raw.parquet) and the camera body in the board body,
  ``T_Bm_Cm = T_W_Bm^-1 T_W_Cm`` (bodies.parquet). Without a board body the board body is the
  mocap world itself (``T_W_Bm = I``), so the fitted ``T_Bm_B`` is the target in the world.
- :func:`cross_validate_streams`: fit on all folds of contiguous time blocks
  (:func:`cvsflow.evaluate.heldout.make_time_blocks`, as the video sessions' held-out
  evaluation) but one; predict each held-out frame's camera pose through the motion-capture
  chain, ``T_B_C = T_Bm_B^-1 T_Bm_Cm(t + dt) T_Cm_C``, and score the detector's pose against it
  (``err_*`` of :func:`cvsflow.metrics.pose_errors`: estimate - reference, in C or B).
- The stated per-frame uncertainty of a held-out error (:func:`heldout_covariance`): the
  covariance of a Student-t fitted to the fold fit's residuals on its own frames
  (:func:`residual_model`: a frame's detector and motion-capture error together, heavier-tailed
  than a Gaussian) mapped into the error's coordinates, plus the fold fit's parameter
  covariance propagated through the chain; scored by
  :func:`cvsflow.uncertainty.score_covariance` with that Student-t's bands (shares inside the
  68 % and 95 % bands per axis, NEES), pooled over the folds.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pandas as pd

from cvsflow import geometry as geo
from cvsflow import uncertainty as un
from cvsflow.evaluate.heldout import compare_methods, make_time_blocks
from cvsflow.evaluate.stated_uncertainty import judge_stated_uncertainty
from cvsflow.exceptions import OptimiseError
from cvsflow.handeye import (
    StreamProblem,
    StreamsOptions,
    StreamsResult,
    estimate_streams,
    inflate,
    split_half_check,
    split_half_inflation,
    stream_offset,
    streams_record,
)
from cvsflow.metrics import ERROR_DIMS, pose_errors
from cvsflow.plausibility import camera_pose_names
from cvsflow.sync import given_offset

log = logging.getLogger(__name__)

#: Finite-difference step of the propagation, in the parameters' units (rad, m, s).
FD_STEP = 1e-6


def _table_T(table: pd.DataFrame, rvec: bool) -> np.ndarray:
    """(N, 4, 4) from a poses table's rvec_0..2 or a bodies table's quaternion, and x_m y_m z_m."""
    if rvec:
        R = geo.R_from_rvec(table[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)).reshape(-1, 3, 3)
    else:
        R = geo.R_from_quat(table[["qx", "qy", "qz", "qw"]].to_numpy(float)).reshape(-1, 3, 3)
    return geo.make_T(R, table[["x_m", "y_m", "z_m"]].to_numpy(float))


def _t_ns(table: pd.DataFrame) -> np.ndarray:
    """A table's exact ``t_ns``, or its ``t_s`` rounded to ns."""
    if "t_ns" in table:
        return table["t_ns"].to_numpy(np.int64)
    return np.round(table["t_s"].to_numpy(float) * 1e9).astype(np.int64)


def stream_inputs(poses: pd.DataFrame, bodies: pd.DataFrame):
    """The stream fit's inputs from a session's poses and bodies tables.

    Parameters
    ----------
    poses : DataFrame
        poses_raw.parquet (``frame, t_s, [t_ns], valid, rvec_0..2, x_m, y_m, z_m``: T_C_B).
    bodies : DataFrame
        bodies.parquet at its native rate (``frame, t_s, [t_ns], body, valid``, position and
        quaternion of T_W_Cm and T_W_Bm).

    Returns
    -------
    frame : ndarray of int64, shape (N,)
        The poses table's frame of each valid pose.
    t_cam_ns : ndarray of int64, shape (N,)
        Their times, camera clock, ns.
    T_B_C : ndarray, shape (N, 4, 4)
        The camera in the target frame, m.
    t_mocap_ns : ndarray of int64, shape (M,)
        The bodies' sample times, mocap clock, ns.
    T_Bm_Cm : ndarray, shape (M, 4, 4)
        The camera body in the board body, m; NaN where either body is invalid.

    Raises
    ------
    OptimiseError
        A body missing from the bodies table.
    """
    ok = poses["valid"].to_numpy(bool)
    p = poses[ok].sort_values("t_s")
    T_B_C = geo.invert_T(_table_T(p, rvec=True))
    parts = {}
    for body in ("camera", "board"):
        b = bodies[bodies["body"] == body].sort_values("frame")
        if b.empty:
            raise OptimiseError(f"bodies table: no {body!r} body; expected the camera and board bodies")
        parts[body] = b.set_index("frame")
    cam = parts["camera"]
    brd = parts["board"].reindex(cam.index)
    T_W_Cm, T_W_Bm = _table_T(cam, rvec=False), _table_T(brd, rvec=False)
    valid = cam["valid"].to_numpy(bool) & brd["valid"].fillna(False).to_numpy(bool)
    T_Bm_Cm = geo.invert_T(np.where(valid[:, None, None], T_W_Bm, np.eye(4))) @ T_W_Cm
    T_Bm_Cm[~valid] = np.nan
    return p["frame"].to_numpy(np.int64), _t_ns(p), T_B_C, _t_ns(cam.reset_index()), T_Bm_Cm


def stream_sync(poses: pd.DataFrame, bodies: pd.DataFrame, min_overlap_share: float = 0.8,
                stream: str = "camera-pose stream") -> dict:
    """sync.yaml of a camera-pose session: the stream fit's own offset search.

    The angular-speed cross-correlation of the camera stream and the camera body (its coarse
    offset) refined from relative rotations (:func:`cvsflow.handeye.stream_offset`): the
    offset ``cvsflow handeye --camera-poses`` starts its joint fit from, so that the session's
    fit is that command's. A recording whose offset the search cannot find keeps 0 (one clock)
    with the reason in ``warnings``; the fit then says whether the hand-eye holds without it.

    Parameters
    ----------
    poses, bodies : DataFrame
        poses_raw.parquet (the stream's) and bodies.parquet.
    min_overlap_share : float
        Share of the camera's poses inside the motion capture below which a warning is given.
    stream : str
        The camera-pose stream file as the session names it: what the messages and
        ``camera_poses`` name (never "video").

    Returns
    -------
    dict
        As :func:`cvsflow.sync.synchronise`: ``dt_offset_s`` (``t_mocap = t_camera +
        dt_offset_s``), ``method`` (``pose_streams``, or ``none`` when no offset was found),
        ``quality`` (the cross-correlation's), ``details`` (``coarse``, ``refined``,
        ``dt_sigma_s`` the refinement's own, ``min_quality`` the least accepted, ``reason``),
        ``overlap_share``, ``warnings``, ``camera_poses`` (``stream``).

    Raises
    ------
    OverlapError
        Under 20 % (or 30) of the camera's poses inside the motion capture at that offset, the
        stream and both spans named.
    """
    _, *streams = stream_inputs(poses, bodies)
    off = stream_offset(*streams)
    dt = 0.0 if off["dt_s"] is None else off["dt_s"]
    out = given_offset(poses, bodies, dt, min_overlap_share, names=camera_pose_names(stream))
    coarse, refined = off.get("coarse") or {}, off.get("refined") or {}
    if off["dt_s"] is None:
        out["warnings"].append(f"no time offset found ({off['reason']}); 0 kept (one clock)")
        log.warning("sync: %s", out["warnings"][-1])
    out.update(method="pose_streams" if off["dt_s"] is not None else "none", quality=coarse.get("quality"),
               details={"coarse": off.get("coarse"), "refined": off.get("refined"),
                        "dt_sigma_s": refined.get("sigma_s"), "min_quality": StreamsOptions().min_quality,
                        "reason": off["reason"]}, camera_poses=str(stream))  # fmt: skip
    return out


def fit_pose_streams(t_cam_ns, T_B_C, t_mocap_ns, T_Bm_Cm, dt_offset_s=None, dt_start_s=None, offset=None,
                     split_half=True):  # fmt: skip
    """The session's pose-level fit: :func:`cvsflow.handeye.estimate_streams` as ``cvsflow handeye
    --camera-poses`` runs it, with its split-half check and the widening it may call for.

    Parameters
    ----------
    t_cam_ns, T_B_C, t_mocap_ns, T_Bm_Cm
        :func:`stream_inputs`' output.
    dt_offset_s : float, optional
        A stated offset (``t_mocap = t_camera + dt_offset_s``, s): held, not estimated.
    dt_start_s : float, optional
        Where the offset's fit starts (:func:`stream_sync`'s): no search of its own.
    offset : dict, optional
        The search that gave ``dt_start_s`` (``coarse``, ``refined``): the result's ``offset``.
    split_half : bool
        Fit the recording's halves alone (each searching its own offset start, as handeye does)
        and widen the stated errors by the Birge ratio when they disagree beyond them
        (:func:`cvsflow.handeye.split_half_inflation`).

    Returns
    -------
    res : StreamsResult
        The fit, its errors widened where the split-half check calls for it.
    split : dict or None
        :func:`cvsflow.handeye.split_half_check`'s result (None when not run).
    """
    held = StreamsOptions(estimate_dt=dt_offset_s is None, dt_init_s=dt_offset_s)
    options = held if dt_offset_s is not None or dt_start_s is None else StreamsOptions(dt_init_s=dt_start_s)
    streams = (t_cam_ns, T_B_C, t_mocap_ns, T_Bm_Cm)
    res = estimate_streams(*streams, options)
    if offset is not None:
        res = replace(res, offset={"coarse": offset.get("coarse"), "refined": offset.get("refined")})
    split = None
    if split_half and res.T_Cm_C is not None:
        split = split_half_check(*streams, held)
        factor = split_half_inflation(split)
        if factor > 1.0:
            log.warning("split-half check: the recording's halves disagree beyond their stated errors "
                        "(mean z^2 %.2f > %.2f): the standard errors are widened by %.2f",
                        split["mean_z2"], split["mean_z2_limit"], factor)  # fmt: skip
            res = inflate(res, factor)
    return res, split


def fold_options(offset: dict, dt_used_s: float, dt_offset_s=None) -> StreamsOptions:
    """Options of the held-out folds' fits: the full fit's, started at its offset start.

    Parameters
    ----------
    offset : dict
        The full fit's ``offset`` (``coarse`` and ``refined``, each None or with ``dt_s``).
    dt_used_s : float
        The offset the full fit used, s: held by the folds when the search found none.
    dt_offset_s : float, optional
        A stated offset, s: held by the folds.

    Returns
    -------
    StreamsOptions
        ``dt_init_s`` the cross-correlation's offset, refined (what the full fit started from,
        so no fold searches again; no held-out frame's estimate leaks in), dt estimated; or
        dt held at the stated offset or at ``dt_used_s``.
    """
    if dt_offset_s is not None:
        return StreamsOptions(estimate_dt=False, dt_init_s=float(dt_offset_s))
    found = [offset.get(k) or {} for k in ("refined", "coarse")]
    start = next((f["dt_s"] for f in found if f.get("dt_s") is not None), None)
    if start is None:
        return StreamsOptions(estimate_dt=False, dt_init_s=float(dt_used_s))
    return StreamsOptions(estimate_dt=True, dt_init_s=float(start))


def pose_fit_record(res: StreamsResult, split: dict | None, board_body: bool) -> dict:
    """The pose-level fit as pose_fit/result.yaml holds it: handeye.yaml's record, the target
    named in its marker body.

    Parameters
    ----------
    res : StreamsResult
    split : dict or None
        :func:`cvsflow.handeye.split_half_check`'s result.
    board_body : bool
        Whether the session has a board body (else the board body is the mocap world).

    Returns
    -------
    dict
        :func:`cvsflow.handeye.streams_record` with ``T_W_B`` named ``T_Bm_B`` (in ``std``,
        ``std_gauss_newton``, ``std_sandwich`` too), ``frames`` saying what Bm is, and
        ``board_body``.
    """
    rec = streams_record(res, split)
    rec["T_Bm_B"] = rec.pop("T_W_B")
    for key in ("std", "std_gauss_newton", "std_sandwich"):
        rec[key]["T_Bm_B"] = rec[key].pop("T_W_B")
    rec["dof"] = {k.replace("T_W_B", "T_Bm_B"): v for k, v in rec["dof"].items()}
    where = ("the board marker body Bm" if board_body else
             "the motion-capture world (no board body: Bm is W, the target static in it)")
    rec["frames"] = (f"T_Cm_C: camera optical frame C in its marker body Cm; T_Bm_B: the target B in "
                     f"{where}; t_mocap = t_camera + dt_offset_s")  # fmt: skip
    rec["board_body"] = bool(board_body)
    return rec


def _predict(x, prob, curve, t_s):
    """Predicted T_C_B (N, 4, 4) of frames at camera times t_s at parameter vector x, and the
    curve status per frame."""
    dt, R_X, p_X, R_Y, p_Y, _, _ = prob.unpack(x)
    R_A, p_A, _, _, status = curve.at(t_s + dt)
    T_B_C = geo.invert_T(geo.make_T(R_Y, p_Y)) @ geo.make_T(R_A, p_A) @ geo.make_T(R_X, p_X)
    return geo.invert_T(T_B_C), status


def _err(T_ref, T_est, frame):
    """(N, 6) errors in ERROR_DIMS order (estimate - reference)."""
    e = pose_errors(T_ref, T_est, frame=frame)
    return e[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)


def _problem(res: StreamsResult, t_s, T_B_C_meas, curve) -> StreamProblem:
    """The stream model of frames at camera times t_s, linearised at a fit's estimate."""
    fit_dt = res.param_names[0] == "dt_offset_s"
    return StreamProblem(t_s, T_B_C_meas[:, :3, :3], T_B_C_meas[:, :3, 3], curve, res.estimate["T_Cm_C"],
                         res.estimate["T_W_B"], res.dt_used_s, fit_dt=fit_dt)  # fmt: skip


def residual_model(res: StreamsResult, t_s, T_B_C, curve):
    """The per-frame noise of a fit's own frames: a multivariate Student-t of their residuals.

    A detector's pose errors have heavier tails than a Gaussian (a few views in which the
    target's corners are poorly placed): the fit's robust scatter describes the Gaussian core
    only. The residuals of the frames the fit used, in C (rad, m), give the covariance and the
    degrees of freedom of a Student-t by maximum likelihood
    (:func:`cvsflow.uncertainty.fit_multivariate_t`).

    Parameters
    ----------
    res : StreamsResult
        The fit.
    t_s : ndarray, shape (N,)
        Its frames' camera times, s since ``res.t_ref_ns``.
    T_B_C : ndarray, shape (N, 4, 4)
        Their detector poses.
    curve : PoseCurve
        ``T_Bm_Cm`` on the mocap clock.

    Returns
    -------
    cov : ndarray, shape (6, 6)
        Covariance of a frame's residual (rad, m; C), the Student-t's.
    nu : float
        Its degrees of freedom.
    """
    r, status = _problem(res, t_s, T_B_C, curve).raw(np.zeros(12 + (res.param_names[0] == "dt_offset_s")))
    return un.fit_multivariate_t(r[status == 0])


def heldout_covariance(res: StreamsResult, t_s, T_B_C_meas, curve, frame="C", meas_cov=None):
    """Held-out frames' errors against the mocap chain and their stated covariance.

    Parameters
    ----------
    res : StreamsResult
        A fit that did not see these frames (``T_Cm_C`` not None, ``scatter`` set).
    t_s : ndarray, shape (N,)
        The frames' camera times, s since ``res.t_ref_ns``.
    T_B_C_meas : ndarray, shape (N, 4, 4)
        The detector's camera poses, m.
    curve : PoseCurve
        The camera body in the board body, ``T_Bm_Cm``, on the mocap clock (s since
        ``res.t_ref_ns``).
    frame : {"C", "B"}
        Frame of the errors (:func:`cvsflow.metrics.pose_errors`).
    meas_cov : ndarray, shape (6, 6), optional
        Covariance of a frame's residual in C (:func:`residual_model`); default the fit's
        robust scatter.

    Returns
    -------
    T_C_B_ref : ndarray, shape (N, 4, 4)
        The board in the camera predicted through the chain (the reference).
    err : DataFrame
        :func:`cvsflow.metrics.pose_errors` of the detector's pose against it.
    cov : ndarray, shape (N, 6, 6)
        Stated covariance of each frame's error (SI, ``ERROR_DIMS`` order): the residual
        covariance as a right perturbation of the detector's pose in C, ``G S G^T``, plus the
        fit's parameter covariance through the chain, ``H C H^T`` (both by central
        differences of :data:`FD_STEP`).
    status : ndarray of int, shape (N,)
        The curve's status per frame (0 inside the motion capture; 1 outside, 2 in a gap: their
        rows are NaN).
    """
    prob = _problem(res, t_s, T_B_C_meas, curve)
    P = prob.n_params
    T_ref, status = _predict(np.zeros(P), prob, curve, t_s)
    T_est = geo.invert_T(T_B_C_meas)
    ok = status == 0
    T_ref[~ok] = np.eye(4)
    H = np.zeros((len(t_s), 6, P))
    for k in range(P):
        step = np.zeros(P)
        step[k] = FD_STEP
        up, _ = _predict(step, prob, curve, t_s)
        dn, _ = _predict(-step, prob, curve, t_s)
        up[~ok], dn[~ok] = np.eye(4), np.eye(4)
        H[:, :, k] = (_err(up, T_est, frame) - _err(dn, T_est, frame)) / (2 * FD_STEP)
    G = np.zeros((len(t_s), 6, 6))
    R_M, p_M = T_B_C_meas[:, :3, :3], T_B_C_meas[:, :3, 3]
    for k in range(6):
        d = np.zeros(6)
        d[k] = FD_STEP
        moved = []
        for sgn in (1.0, -1.0):
            dr, dp = sgn * d[:3], sgn * d[3:]
            M = geo.make_T(R_M @ geo.R_from_rvec(dr), p_M + R_M @ dp)
            moved.append(_err(T_ref, geo.invert_T(M), frame))
        G[:, :, k] = (moved[0] - moved[1]) / (2 * FD_STEP)
    S = res.scatter if meas_cov is None else meas_cov
    cov = G @ S @ np.swapaxes(G, 1, 2) + H @ res.cov @ np.swapaxes(H, 1, 2)
    err = pose_errors(T_ref, T_est, frame=frame)
    err[~ok] = np.nan
    T_ref[~ok] = np.nan
    cov[~ok] = np.nan
    return T_ref, err, cov, status


def _pose_columns(T, prefix):
    """``{prefix}x_m .. {prefix}qw`` columns of (N, 4, 4) transforms."""
    q = geo.quat_from_R(np.where(np.isfinite(T[:, :3, :3]), T[:, :3, :3], np.eye(3))).reshape(-1, 4)
    q[~np.isfinite(T).all(axis=(1, 2))] = np.nan
    cols = {f"{prefix}{a}": T[:, k, 3] for k, a in enumerate(("x_m", "y_m", "z_m"))}
    cols.update({f"{prefix}{a}": q[:, k] for k, a in enumerate(("qx", "qy", "qz", "qw"))})
    return cols


def cross_validate_streams(frame_ids, t_cam_ns, T_B_C, t_mocap_ns, T_Bm_Cm,
                           options: StreamsOptions | None = None, *, n_folds=5, block_s=2.0, seed=0,
                           frame="C", progress=None):  # fmt: skip
    """Fit the stream model on all time-block folds but one, score the held-out fold; each in turn.

    Parameters
    ----------
    frame_ids : ndarray of int, shape (N,)
        Frame number of each camera pose (poses_raw.parquet's ``frame``).
    t_cam_ns, T_B_C, t_mocap_ns, T_Bm_Cm
        As :func:`cvsflow.handeye.estimate_streams` (:func:`stream_inputs`' output).
    options : StreamsOptions, optional
        Of every fold's fit (a start ``dt_init_s`` saves each fold the offset search).
    n_folds, block_s, seed
        Folds of contiguous time blocks (:func:`cvsflow.evaluate.heldout.make_time_blocks`):
        count, block length (s), shuffle seed.
    frame : {"C", "B"}
        Frame of the errors.
    progress : callable, optional
        ``progress(k)`` after each fold, k folds done.

    Returns
    -------
    heldout : DataFrame
        One row per camera pose scored by the fit that did not see it: ``frame, t_s, t_ns,
        fold``, the :func:`cvsflow.metrics.pose_errors` columns, ``sigma_{dim}`` (stated
        standard deviation), ``nees``, ``nu`` (the stated Student-t's degrees of freedom), the
        ``cvs_`` (detector) and ``ref_`` (mocap chain)
        poses of T_C_B, ``error_frame``; frames whose time falls outside the motion capture or
        in a gap are left out.
    fits : list of dict
        Per fold: ``fold``, ``n_train``, ``n_test``, ``n_scored``, ``dt_offset_s`` (used),
        ``dt_estimated``, ``nu``, ``T_Cm_C``, ``T_Bm_B`` (4x4 lists), ``std`` (per parameter, SI).
    score : dict
        :func:`cvsflow.uncertainty.score_covariance` per fold (its Student-t's bands) pooled
        over the scored frames (``inside_68``, ``inside_95`` per axis and ``_all``, ``z_rms``,
        ``nees_mean``, ``nees_inside_95``, ``nu`` min and max), ``lag1_autocorr`` per axis,
        ``n_effective``, ``inside_68_tolerance``, ``inside_95_tolerance`` (how far a right
        statement's shares scatter with errors that persist in time), ``judgement`` (the
        shares and NEES against their spread under the statement with the errors' AR(1) in
        time: :func:`cvsflow.evaluate.stated_uncertainty.judge_stated_uncertainty`, its
        ``verdict`` consistent / too narrow / too wide) and ``folds`` (each fold's).

    Raises
    ------
    OptimiseError
        Fewer blocks than folds, a fold whose fit cannot determine the hand-eye, or fewer than
        3 scored frames.
    """
    opts = options or StreamsOptions()
    t_cam_ns, t_mocap_ns = np.asarray(t_cam_ns, np.int64), np.asarray(t_mocap_ns, np.int64)
    t_ref = int(t_cam_ns[0])
    t_s = (t_cam_ns - t_ref) / 1e9
    fold = make_time_blocks(t_s, block_s, n_folds, seed)
    curve = geo.PoseCurve((t_mocap_ns - t_ref) / 1e9, T_Bm_Cm, max_gap_s=opts.max_gap_s)
    parts, fits, covs, fold_scores = [], [], [], []
    for k in range(n_folds):
        train, test = fold != k, fold == k
        res = estimate_streams(t_cam_ns[train], T_B_C[train], t_mocap_ns, T_Bm_Cm, opts, t_ref_ns=t_ref)
        if res.T_Cm_C is None:
            raise OptimiseError(f"held-out fold {k}: the fit on the other folds cannot determine the "
                                f"hand-eye ({res.observability['hand_eye']['reason']})")  # fmt: skip
        meas_cov, nu = residual_model(res, t_s[train], T_B_C[train], curve)
        T_ref, err, cov, status = heldout_covariance(res, t_s[test], T_B_C[test], curve, frame, meas_cov)
        rows = pd.DataFrame({"frame": frame_ids[test], "t_s": t_cam_ns[test] / 1e9, "t_ns": t_cam_ns[test],
                             "fold": k})  # fmt: skip
        rows = pd.concat([rows, err, pd.DataFrame(_pose_columns(geo.invert_T(T_B_C[test]), "cvs_")),
                          pd.DataFrame(_pose_columns(T_ref, "ref_"))], axis=1)  # fmt: skip
        ok = status == 0
        rows, cov = rows[ok].reset_index(drop=True), cov[ok]
        for j, d in enumerate(ERROR_DIMS):
            rows[f"sigma_{d}"] = np.sqrt(cov[:, j, j])
        rows["nees"] = un.nees_values(cov, rows)
        parts.append(rows)
        covs.append(cov)
        rows["nu"] = nu
        s = un.score_covariance(cov, rows, nu=nu) if len(rows) else {"n": 0}
        s.update(fold=k, nu=nu)
        fold_scores.append(s)
        fits.append({"fold": k, "n_train": int(train.sum()), "n_test": int(test.sum()),
                     "n_scored": int(ok.sum()), "dt_offset_s": float(res.dt_used_s),
                     "dt_estimated": res.dt_offset_s is not None, "nu": nu, "T_Cm_C": res.T_Cm_C.tolist(),
                     "T_Bm_B": res.T_W_B.tolist(), "std": dict(res.std)})  # fmt: skip
        log.info("held-out fold %d: %d train, %d test frames (%d inside the motion capture)", k,
                 int(train.sum()), int(test.sum()), int(ok.sum()))  # fmt: skip
        if progress:
            progress(k + 1)
    heldout = pd.concat(parts, ignore_index=True)
    if len(heldout) < 3:
        raise OptimiseError(f"held-out evaluation: {len(heldout)} frames scored; expected at least 3")
    order = np.argsort(heldout["t_ns"].to_numpy(), kind="stable")
    cov = np.concatenate(covs)[order]
    heldout = heldout.iloc[order].reset_index(drop=True)
    heldout["error_frame"] = frame
    score = _pooled(fold_scores)
    score.update(_time_correlation(cov, heldout))
    runs = un.frame_runs(heldout["frame"].to_numpy(), heldout["fold"].to_numpy())
    score["judgement"] = judge_stated_uncertainty(cov, heldout, runs, heldout["nu"].to_numpy(), seed=seed)
    score["folds"] = fold_scores
    return heldout, fits, score


def _time_correlation(cov, heldout) -> dict:
    """How the held-out errors persist from pose to pose, and what that does to the shares' spread.

    The per-frame statement says nothing of it; the lag-1 autocorrelation of the standardised
    errors within runs of consecutive poses of one fold (:func:`cvsflow.uncertainty.fit_ar1`)
    gives the effective number of independent poses, ``n (1 - rho) / (1 + rho)``, and the
    2-sigma binomial half-widths of the 68 % and 95 % shares a right statement scatters by.
    """
    z = un.standardised_errors(cov, heldout)
    rho = un.fit_ar1(z, un.frame_runs(heldout["frame"].to_numpy(), heldout["fold"].to_numpy()))
    r = float(np.clip(np.mean(rho), 0.0, 0.95))
    n_eff = max(len(z) * (1.0 - r) / (1.0 + r), 1.0)
    return {"lag1_autocorr": dict(zip(ERROR_DIMS, map(float, rho), strict=True)), "n_effective": float(n_eff),
            "inside_68_tolerance": float(2.0 * np.sqrt(0.6827 * 0.3173 / n_eff)),
            "inside_95_tolerance": float(2.0 * np.sqrt(0.95 * 0.05 / n_eff))}  # fmt: skip


def _pooled(folds: list) -> dict:
    """Per-fold scores (each with its own nu's bands) pooled, weighted by their frames."""
    folds = [f for f in folds if f["n"]]
    n = np.array([f["n"] for f in folds], float)
    w = n / n.sum()

    def pool(get, rms=False):
        v = sum(wi * (get(f) ** 2 if rms else get(f)) for wi, f in zip(w, folds, strict=True))
        return float(np.sqrt(v) if rms else v)

    out = {"n": int(n.sum())}
    for band in ("68", "95"):
        out[f"inside_{band}"] = {d: pool(lambda f, b=band, d=d: f[f"inside_{b}"][d]) for d in ERROR_DIMS}
        out[f"inside_{band}_all"] = pool(lambda f, b=band: f[f"inside_{b}_all"])
    out["z_rms"] = {d: pool(lambda f, d=d: f["z_rms"][d], rms=True) for d in ERROR_DIMS}
    out["nees_mean"] = pool(lambda f: f["nees_mean"])
    out["nees_inside_95"] = pool(lambda f: f["nees_inside_95"])
    out["nu"] = {"min": float(min(f["nu"] for f in folds)), "max": float(max(f["nu"] for f in folds))}
    return out


def heldout_summary(heldout: pd.DataFrame, fits: list, score: dict, *, boot_block_s=2.0, n_boot=1000,
                    seed=0) -> dict:  # fmt: skip
    """The held-out evaluation as heldout/pose_fit.yaml holds it.

    Parameters
    ----------
    heldout, fits, score
        :func:`cross_validate_streams`' output.
    boot_block_s, n_boot, seed
        Moving-block bootstrap of the error statistics (:func:`cvsflow.evaluate.heldout.compare_methods`).

    Returns
    -------
    dict
        ``method`` (``pose_fit``), ``n``, ``error_frame``, ``per_dim`` (statistics per axis
        with bootstrap intervals, SI), ``error_model`` (``score``: the stated per-frame
        uncertainty's coverage and NEES), ``uncertainty`` (how the per-frame covariance is
        made), ``folds`` (``fits``).
    """
    table = heldout.copy()
    for d in ERROR_DIMS:
        table[f"eps_{d}"] = table[f"err_{d}"]
    fps = 1.0 / geo.sample_period(table["t_s"].to_numpy(float))
    stats = compare_methods({"pose_fit": table}, block_len=max(1, int(round(boot_block_s * fps))),
                            n_boot=n_boot, seed=seed)["pose_fit"]  # fmt: skip
    return {"method": "pose_fit", "n": stats["n"], "error_frame": str(heldout["error_frame"].iloc[0]),
            "per_dim": stats["per_dim"], "error_model": score,
            "uncertainty": "per frame: the covariance of a multivariate Student-t fitted (maximum "
                           "likelihood) to the fold fit's residuals on its own frames (detector and "
                           "motion-capture error of one frame, a right perturbation of the detector's "
                           "pose in C) plus the fold fit's stated parameter covariance, both carried to "
                           "the error's axes; bands from the Student-t's quantiles (folds[].nu), NEES "
                           "under the full 6 x 6 covariance",
            "folds": fits}  # fmt: skip
