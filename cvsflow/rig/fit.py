"""The ``se3`` method for N cameras on one rig: joint fit from every corner of every camera.

Frames. The cameras are fixed to the one camera-marker body Cm (``body == "camera"`` of
bodies.parquet: docs/contracts.md knows only the ``camera`` and ``board`` bodies, and a rig
tracked as one body is what a multi-camera mount gives), each at its own ``T_Cm_Ci``. The
board is the one of the mono method, ``T_Bm_B``. Each camera has its own clock,
``t_vicon_s = t_video_s,i + dt_offset_s,i``, and frame rate; the cameras need not be
triggered together.

Unknowns: per camera i the free intrinsics, the rotation perturbation and translation of
``T_Cm_Ci`` (as the mono ``T_Cm_C``) and ``dt_offset_s,i`` (and its line delay when fitted);
shared, ``T_Bm_B``. Residuals: eq. (1) of :mod:`cvsflow.optimise.se3` for every corner of
every camera, each camera through its own :class:`~cvsflow.optimise.se3_model.Se3Model`
(:class:`RigModel` maps the rig's parameter vector onto each camera's and stacks residuals
and Jacobians; no residual or derivative is written twice). The parameter order is camera
0's intrinsics and ``T_Cm_C``, camera 1's, ..., then ``T_Bm_B``, then each camera's time
offset (and line delay): with one camera exactly the mono vector, so a one-camera rig is
the mono solve.

Start: PnP and the hand-eye closed form (:func:`~cvsflow.optimise.se3_start.solve_hand_eye`)
on the camera with the most frames, giving ``T_Bm_B`` and its ``T_Cm_C``; every other camera's
``T_Cm_Ci`` from its frames given that ``T_Bm_B``, ``T_Cm_Ci = T_Cm_Bm T_Bm_B inv(T_Ci_B)``
averaged over frames (a camera needs no rotation variety of its own).

Uncertainty: the mono recipe (:func:`~cvsflow.optimise.se3_cov.parameter_covariance`): the
larger of the Gauss-Newton and the cluster-robust standard errors, the clusters time blocks
of the common (Vicon) timeline so that frames of two cameras at one instant, which share the
Vicon pose noise, fall in one cluster; plus each camera's fixed intrinsics carried in through
the sensitivity (their ``std`` from each camera.yaml).

Fused board pose (``se3_rig_poses``, :func:`~cvsflow.rig.poses.fused_rig_poses`):
frames of several cameras at the same Vicon instant (within ``match_tol_s``) form one rig
frame, whose board pose in camera 0's frame is solved from all their corners at once
(:func:`cvsflow.rig.fusion.fused_board_pose`), with its covariance (the corner noise's and the
calibration's); a rig frame seen by one camera is that camera's PnP, mapped to C0.
Held-out scoring (:func:`cross_validate_se3_rig`) uses the time-block folds of
:func:`cvsflow.evaluate.heldout.cross_validate_se3` on the common timeline and scores the fused poses
of the held-out blocks against the Vicon reference.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import pandas as pd

from cvsflow.board import board_object_points
from cvsflow.evaluate import make_time_blocks
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import INTRINSIC_NAMES, project_SO3
from cvsflow.geometry import transforms as tf
from cvsflow.metrics import frame_errors
from cvsflow.optimise import (
    K_from_intrinsics,
    OptimiseResult,
    Se3Model,
    Se3Options,
    camera_start,
    corner_arrays,
    correlation_warnings,
    fixed_std,
    jacobian_fd,
    keep_usable,
    parameter_covariance,
    refuse_implausible_fit,
    robust_cost,
    solve,
    solve_hand_eye,
    solve_pnp_frames,
    uncertainty_keys,
)
from cvsflow.rig.poses import fused_rig_poses

log = logging.getLogger(__name__)

#: Keys of a camera entry of :func:`optimise_se3_rig` besides ``corners``, ``camera`` and
#: ``dt_offset_s``.
CAMERA_OPTIONS = ("free", "frames", "line_delay_s", "fit_line_delay", "T_Cm_C")


class RigModel:
    """N per-camera :class:`Se3Model` sharing T_Bm_B: one parameter vector, stacked residuals.

    Parameters
    ----------
    models : sequence of Se3Model
        One per camera, built with the same ``R0_Bm_B``.

    Attributes
    ----------
    names : list of str
        ``cam{i}_`` + the camera's own parameter names, and the shared ``T_Bm_B_*``.
    index : list of ndarray of int
        For camera i, the positions in the rig vector of its model's parameters.
    rows : list of slice
        Residual rows of each camera.
    """

    def __init__(self, models):
        self.models = list(models)
        pos, names = 0, []
        cam_cols, dt_cols = [], []
        for i, m in enumerate(self.models):
            nf = int(m.free.sum())
            cam_cols.append(np.arange(pos, pos + nf + 6))
            names += [f"cam{i}_{n}" for n in m.names[: nf + 6]]
            pos += nf + 6
        b_cols = np.arange(pos, pos + 6)
        names += [f"T_Bm_B_{n.split('T_Bm_B_')[1]}" for n in self.models[0].names if "T_Bm_B_" in n]
        pos += 6
        for i, m in enumerate(self.models):
            k = int(m.fit_dt) + int(m.fit_ld)
            dt_cols.append(np.arange(pos, pos + k))
            names += [f"cam{i}_{n}" for n in m.names[len(m.names) - k :]]
            pos += k
        self.index = [np.concatenate([c, b_cols, d]) for c, d in zip(cam_cols, dt_cols, strict=True)]
        self.names = names
        self.b_cols = b_cols
        sizes = [2 * int(m.seen.sum()) for m in self.models]
        ends = np.cumsum(sizes)
        self.rows = [slice(int(e - s), int(e)) for s, e in zip(sizes, ends, strict=True)]
        self.n_residuals = int(ends[-1])

    @property
    def n_params(self):
        return len(self.names)

    def pack(self, per_camera, t_Bm_B):
        """Rig vector from per-camera ``(intr, t_Cm_C, dt, ld)`` and the shared t_Bm_B."""
        x = np.zeros(self.n_params)
        for m, idx, (intr, t_Cm_C, dt, ld) in zip(self.models, self.index, per_camera, strict=True):
            x[idx] = m.pack(intr, t_Cm_C, t_Bm_B, dt, ld)
        return x

    def local(self, x, i):
        """Camera i's own parameter vector (its Se3Model's) from the rig vector."""
        return x[self.index[i]]

    def residuals(self, x):
        return np.concatenate([m.residuals(x[idx]) for m, idx in zip(self.models, self.index, strict=True)])

    def jacobian(self, x):
        """d residuals / d x, analytic, shape (m, n): each camera's block in its columns."""
        J = np.zeros((self.n_residuals, self.n_params))
        for m, idx, rows in zip(self.models, self.index, self.rows, strict=True):
            J[rows, idx] = m.jacobian(x[idx])
        return J

    def jacobian_fixed(self, x):
        """d residuals / d (each camera's fixed intrinsics), block diagonal, shape (m, k)."""
        blocks = [
            m.jacobian_intrinsics(x[idx])[:, ~m.free] for m, idx in zip(self.models, self.index, strict=True)
        ]
        J = np.zeros((self.n_residuals, sum(b.shape[1] for b in blocks)))
        col = 0
        for b, rows in zip(blocks, self.rows, strict=True):
            J[rows, col : col + b.shape[1]] = b
            col += b.shape[1]
        return J

    def jacobian_fd(self, x, h=1e-6):
        """Central-difference Jacobian (for tests), shape (m, n)."""
        return jacobian_fd(self.residuals, x, h)


def _camera_frames(i, entry, p_B, cam, brd, frames):
    """Camera i's usable frames: (frame, t_video, uv) and the number skipped for Vicon gaps."""
    corners = entry["corners"]
    if not isinstance(corners, pd.DataFrame) or corners.empty:
        raise OptimiseError(f"se3 rig: camera {i}: corners table is empty (no frame, no corner)")
    try:
        frame, t_video, uv = corner_arrays(corners, len(p_B))
    except OptimiseError as exc:
        raise OptimiseError(f"se3 rig: camera {i}: {exc}") from exc
    c = corners[corners["found"].astype(bool) & corners["frame"].isin(frame)]
    n_times = c.groupby("frame")["t_s"].nunique()
    if (n_times > 1).any():
        f = int(n_times.index[np.argmax(n_times.to_numpy() > 1)])
        raise OptimiseError(f"se3 rig: camera {i}: frame {f} has rows with different t_s")
    if np.any(np.diff(t_video) <= 0):
        k = int(np.argmax(np.diff(t_video) <= 0))
        raise OptimiseError(
            f"se3 rig: camera {i}: t_s does not increase with frame at frame {frame[k + 1]} "
            f"({t_video[k]} s after frame {frame[k]} at {t_video[k + 1]} s)"
        )
    return keep_usable(frame, t_video, uv, frames, float(entry["dt_offset_s"]), cam, brd,
                       f"se3 rig: camera {i}")  # fmt: skip


def _check_cameras(cameras):
    if not isinstance(cameras, (list, tuple)) or not cameras:
        raise OptimiseError("se3 rig: cameras must be a non-empty list of camera entries")
    for i, e in enumerate(cameras):
        if not isinstance(e, dict):
            raise OptimiseError(f"se3 rig: camera {i}: expected a dict, got {type(e).__name__}")
        missing = [k for k in ("corners", "camera", "dt_offset_s") if k not in e]
        if missing:
            raise OptimiseError(f"se3 rig: camera {i}: entry lacks {missing}")
        unknown = sorted(set(e) - {"corners", "camera", "dt_offset_s", *CAMERA_OPTIONS})
        if unknown:
            raise OptimiseError(f"se3 rig: camera {i}: unknown keys {unknown}")
        if not np.isfinite(float(e["dt_offset_s"])):
            raise OptimiseError(
                f"se3 rig: camera {i}: dt_offset_s {e['dt_offset_s']!r}; expected a finite time in s"
            )
        bad = [f for f in e.get("free", ()) if f not in INTRINSIC_NAMES]
        if bad:
            raise OptimiseError(
                f"se3 rig: camera {i}: free {bad} unknown; expected names from {INTRINSIC_NAMES}"
            )
        ld = float(e.get("line_delay_s", 0.0))
        if not (np.isfinite(ld) and ld >= 0.0):
            raise OptimiseError(f"se3 rig: camera {i}: line_delay_s {ld!r}; expected a finite value >= 0 s")


def _mean_pose(T):
    """Chordal mean of rigid transforms (N, 4, 4): projected mean rotation, mean translation."""
    return tf.make_T(project_SO3(T[:, :3, :3].mean(axis=0)), T[:, :3, 3].mean(axis=0))


def common_times(cameras, t_video):
    """Each camera's frame times on camera 0's video clock, through the start offsets.

    ``t_video_i + (dt_i - dt_0)``: the Vicon time less camera 0's offset, so that camera 0's
    times are its own, bit for bit.

    Parameters
    ----------
    cameras : sequence of dict
        Camera entries (``dt_offset_s``).
    t_video : sequence of ndarray
        Each camera's video times, s.

    Returns
    -------
    t_common : list of ndarray
    """
    dt0 = float(cameras[0]["dt_offset_s"])
    return [t + (float(e["dt_offset_s"]) - dt0) if k else t
            for k, (e, t) in enumerate(zip(cameras, t_video, strict=True))]  # fmt: skip


def optimise_se3_rig(cameras, bodies, board, options=None, *, init_T_Bm_B=None, match_tol_s=None,
                     fused_calibration_cov=True, fused_max_residual_px=None, **overrides):
    """Joint se3 estimate for N cameras on one rig body: intrinsics, T_Cm_Ci, dt_i, T_Bm_B.

    Parameters
    ----------
    cameras : list of dict
        One entry per camera: ``corners`` (its corners.parquet, on its own video clock),
        ``camera`` (its camera.yaml: ``K``, ``dist``, optional ``std``), ``dt_offset_s`` (its
        starting offset, t_vicon = t_video + dt); optional ``free`` (its intrinsics to
        estimate; default the rig's ``free``), ``frames`` (its frames to fit on),
        ``line_delay_s`` and ``fit_line_delay`` (default the rig's options), ``T_Cm_C`` (4x4
        start).
    bodies : DataFrame
        bodies.parquet: ``camera`` the rig's marker body (T_W_Cm), ``board`` (T_W_Bm).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    options : Se3Options or dict, optional
        As :func:`cvsflow.optimise.se3.optimise_se3` (``fit_dt`` for every camera).
    init_T_Bm_B : array_like, shape (4, 4), optional
        Start of T_Bm_B; with every camera's ``T_Cm_C`` given, no hand-eye start is solved.
    match_tol_s : float, optional
        Frames of two cameras this close on the Vicon clock are one rig frame in the fused
        poses (:func:`fused_rig_poses`); default a quarter of the shortest frame interval.
    fused_calibration_cov : bool
        The fused poses' covariance includes the calibration's uncertainty
        (:func:`fused_rig_poses` ``calibration_cov``).
    fused_max_residual_px : float, optional
        :func:`fused_rig_poses` ``max_residual_px`` (a view with a corner this far from its
        PnP pose is left out of the fused poses; the fit itself keeps every corner).
    **overrides
        Fields of :class:`cvsflow.optimise.Se3Options` to change.

    Returns
    -------
    OptimiseResult
        ``iterations`` (``nfev, cost, rms_px`` and ``cam{i}_fx_px, cam{i}_fy_px,
        cam{i}_dt_offset_s``); ``errors``: :func:`fused_rig_poses` of the fitted frames;
        ``result``: ``method`` ``se3_rig``, ``cameras`` (:func:`_camera_results`), ``T_Bm_B``,
        ``T_Bm_B_pose6``, the mono fit's uncertainty keys over the rig's parameter names
        (:class:`RigModel`), ``fixed_sensitivity``, ``covariance_total``, the options, and
        ``n_rig_frames``, ``n_rig_frames_by_cameras`` of the fused poses.

    Raises
    ------
    OptimiseError
        Bad options; a camera (named by its index) without corners, with inconsistent times,
        or with fewer than ``MIN_FRAMES`` usable frames; a failed hand-eye start.

    Notes
    -----
    A rig frame seen by one camera enters the fit as any frame of the mono method: the fit
    has no per-frame unknowns, so every corner of every camera counts whether or not another
    camera saw the board at that instant. The time offsets are separable per camera because
    each camera's frames sample the board's motion at their own times. With one camera the
    result equals :func:`~cvsflow.optimise.se3.optimise_se3`'s (same start, same model, same
    solver and covariance; names prefixed ``cam0_``).
    """
    t0 = time.perf_counter()
    opts = Se3Options.build(options, "se3 rig", **overrides)
    _check_cameras(cameras)
    p_B = board_object_points(board)
    cam, brd = opts.tracks(bodies)
    data = [_camera_frames(i, e, p_B, cam, brd, e.get("frames")) for i, e in enumerate(cameras)]
    starts = [camera_start(e["camera"], label=f"se3 rig: camera {i}") for i, e in enumerate(cameras)]
    dts = [float(e["dt_offset_s"]) for e in cameras]
    T_Cm_C0, T_Bm_B0 = _rig_start(cameras, data, starts, dts, p_B, cam, brd, init_T_Bm_B)
    models, per_cam0 = [], []
    for i, e in enumerate(cameras):
        K0, dist0 = starts[i]
        intr0 = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], *dist0])
        ld0 = float(e.get("line_delay_s", opts.line_delay_s))
        models.append(Se3Model(
            intr0, set(e.get("free", opts.free)), T_Cm_C0[i][:3, :3], T_Bm_B0[:3, :3], opts.fit_dt,
            dts[i], data[i][1], data[i][2], p_B, cam, brd,
            fit_ld=bool(e.get("fit_line_delay", opts.fit_line_delay)), ld0=ld0,
        ))  # fmt: skip
        per_cam0.append((intr0, T_Cm_C0[i][:3, 3], dts[i], ld0))
    model = RigModel(models)
    x0 = model.pack(per_cam0, T_Bm_B0[:3, 3])
    r0 = model.residuals(x0)
    if not np.isfinite(r0).all():
        raise OptimiseError("se3 rig: non-finite residuals at the start (board behind a camera?)")
    log.info("se3 rig: %d cameras, %s frames, %d parameters; start RMS %.3f px", len(cameras),
             [len(d[0]) for d in data], model.n_params, float(np.sqrt(np.mean(r0**2))))  # fmt: skip

    def row(x, r, nfev):
        out = {"nfev": nfev, "cost": robust_cost(r, opts.loss, opts.f_scale_px),
               "rms_px": float(np.sqrt(np.mean(r**2)))}  # fmt: skip
        for i, m in enumerate(models):
            intr, _, _, dt = m.unpack(model.local(x, i))
            out.update({f"cam{i}_fx_px": intr[0], f"cam{i}_fy_px": intr[1], f"cam{i}_dt_offset_s": dt})
        return out

    sol, history, n_jac, solver_warnings = solve(model, x0, opts, row, "se3 rig")
    r = model.residuals(sol.x)
    for i, m in enumerate(models):
        refuse_implausible_fit(m.unpack(model.local(sol.x, i))[0][:2], r[model.rows[i]],
                               f"se3 rig: camera {i}")
    warnings, sd_fixed, fixed_out = [], [], []
    for i, (e, m) in enumerate(zip(cameras, models, strict=True)):
        names_i = [n for n, f in zip(INTRINSIC_NAMES, m.free, strict=True) if not f]
        sd, defaulted = fixed_std(e["camera"], names_i, f"se3 rig: camera {i}", warnings)
        sd_fixed.append(sd)
        values = [float(m.intr0[INTRINSIC_NAMES.index(n)]) for n in names_i]
        fixed_out.append({"names": names_i, "values": values, "std": [float(v) for v in sd],
                          "std_defaulted": list(defaulted)})  # fmt: skip
    block = _rig_clusters(cameras, data, models, opts.cluster_s)
    pc = parameter_covariance(model.jacobian(sol.x), r, opts.loss, opts.f_scale_px, block,
                              model.jacobian_fixed(sol.x), np.concatenate(sd_fixed))  # fmt: skip
    warnings += correlation_warnings(pc["corr"], model.names, opts.corr_warn, "se3 rig") + solver_warnings
    cams_out = _camera_results(models, model, sol.x, r, data, fixed_out, T_Cm_C0, dts)
    T_Bm_B = models[0].unpack(model.local(sol.x, 0))[2]
    result = {
        "method": "se3_rig", "cameras": cams_out, "T_Bm_B": T_Bm_B.tolist(),
        "T_Bm_B_pose6": tf.pose6_from_T(T_Bm_B).tolist(), "init_T_Bm_B": T_Bm_B0.tolist(),
        "fit_dt": bool(opts.fit_dt), **uncertainty_keys(model.names, sol.x, pc),
        "fixed_sensitivity": np.asarray(pc["S"], float).tolist(), "n_residuals": int(r.size),
        "n_clusters": int(pc["n_clusters"]), **opts.summary(cam),
        "camera_moving_smooth_s": float(opts.camera_moving_smooth_s),
        "rms_px": float(np.sqrt(np.mean(r**2))), "sigma_px": float(np.sqrt(pc["sigma2"])),
        "cost": float(sol.cost), "n_iterations": int(sol.nfev), "n_jacobians": int(n_jac),
        "solver": opts.solver, "status": int(sol.status), "message": str(sol.message),
        "warnings": warnings, "covariance_total": pc["cov_total"].tolist(),
    }  # fmt: skip
    per_frame = fused_rig_poses(result, [e["corners"] for e in cameras], bodies, board,
                                frames=[d[0] for d in data], match_tol_s=match_tol_s,
                                calibration_cov=fused_calibration_cov,
                                max_residual_px=fused_max_residual_px)  # fmt: skip
    result["n_rig_frames"] = len(per_frame)
    result["n_rig_frames_by_cameras"] = {
        int(k): int(v) for k, v in per_frame["n_cameras"].value_counts().sort_index().items()
    }
    result["time_s"] = float(time.perf_counter() - t0)
    log.info("se3 rig: %d cameras, RMS %.3f px, %d evaluations, %.2f s", len(cameras), result["rms_px"],
             sol.nfev, result["time_s"])  # fmt: skip
    return OptimiseResult(iterations=pd.DataFrame(history), errors=per_frame, result=result)


def _rig_start(cameras, data, starts, dts, p_B, cam, brd, init_T_Bm_B):
    """Start mountings: hand-eye on the camera with most frames, the others' given T_Bm_B.

    Returns ``T_Cm_C0`` (list of (4, 4), one per camera) and ``T_Bm_B0`` (4, 4), metres.
    """
    n_cam = len(cameras)
    T_Cm_C0 = [None if e.get("T_Cm_C") is None else np.asarray(e["T_Cm_C"], float).reshape(4, 4)
               for e in cameras]  # fmt: skip
    T_Bm_B0 = None if init_T_Bm_B is None else np.asarray(init_T_Bm_B, float).reshape(4, 4)
    pnp, A = [None] * n_cam, [None] * n_cam
    for i, ((_, t_video, uv, _), (K0, dist0)) in enumerate(zip(data, starts, strict=True)):
        if T_Cm_C0[i] is None or T_Bm_B0 is None:
            pnp[i] = solve_pnp_frames(uv, p_B, K0, dist0)
            tq = t_video + dts[i]
            A[i] = tf.invert_T(cam(tq)) @ brd(tq)
    if T_Bm_B0 is None:
        ref = int(np.argmax([len(d[0]) for d in data]))
        T_C_B, ok = pnp[ref]
        try:
            Z, T_Bm_B0 = solve_hand_eye(A[ref][ok], T_C_B[ok])
        except OptimiseError as exc:
            raise OptimiseError(f"se3 rig: camera {ref} (the start): {exc}") from exc
        if T_Cm_C0[ref] is None:
            T_Cm_C0[ref] = Z
    for i in range(n_cam):
        if T_Cm_C0[i] is None:
            T_C_B, ok = pnp[i]
            if ok.sum() < 1:
                raise OptimiseError(f"se3 rig: camera {i}: no frame with a PnP pose for the start")
            T_Cm_C0[i] = _mean_pose(A[i][ok] @ T_Bm_B0 @ tf.invert_T(T_C_B[ok]))
    return T_Cm_C0, T_Bm_B0


def _rig_clusters(cameras, data, models, cluster_s):
    """The cluster of every residual: blocks of ``cluster_s`` on the common timeline (frames at
    one instant share the mocap noise), shape (m,)."""
    t_common = common_times(cameras, [d[1] for d in data])
    t_first = min(t[0] for t in t_common)
    return np.concatenate([
        np.repeat(np.floor((t - t_first) / max(cluster_s, 1e-9)).astype(int)[np.nonzero(m.seen)[0]], 2)
        for t, m in zip(t_common, models, strict=True)
    ])  # fmt: skip


def _camera_results(models, model, x, r, data, fixed_out, T_Cm_C0, dts):
    """Per camera: ``K, dist, T_Cm_C, T_Cm_C_pose6, T_C0_C`` (camera i in camera 0, m),
    ``dt_offset_s, line_delay_s, fit_line_delay, free, n_frames, n_frames_skipped, rms_px,
    fixed_intrinsics, init``."""
    cams_out = []
    for i, m in enumerate(models):
        intr, T_Cm_C, _, dt = m.unpack(model.local(x, i))
        ri = r[model.rows[i]]
        cams_out.append({
            "K": K_from_intrinsics(*intr[:4]).tolist(), "dist": intr[4:].tolist(),
            "T_Cm_C": T_Cm_C.tolist(), "T_Cm_C_pose6": tf.pose6_from_T(T_Cm_C).tolist(),
            "dt_offset_s": float(dt), "line_delay_s": float(m.line_delay(model.local(x, i))),
            "fit_line_delay": bool(m.fit_ld),
            "free": [n for n, f in zip(INTRINSIC_NAMES, m.free, strict=True) if f],
            "n_frames": len(data[i][0]), "n_frames_skipped": data[i][3],
            "rms_px": float(np.sqrt(np.mean(ri**2))), "fixed_intrinsics": fixed_out[i],
            "init": {"K": K_from_intrinsics(*m.intr0[:4]).tolist(), "dist": m.intr0[4:].tolist(),
                     "T_Cm_C": T_Cm_C0[i].tolist(), "dt_offset_s": dts[i]},
        })  # fmt: skip
    T_Cm_C_0 = np.asarray(cams_out[0]["T_Cm_C"])
    for c in cams_out:
        c["T_C0_C"] = (tf.invert_T(T_Cm_C_0) @ np.asarray(c["T_Cm_C"])).tolist()
    return cams_out


def cross_validate_se3_rig(cameras, bodies, board, *, n_folds=5, block_s=5.0, seed=0, frame="C",
                           **options):  # fmt: skip
    """Fit the rig on all folds but one, score the held-out fold's fused poses; each fold in turn.

    The folds are contiguous time blocks (:func:`cvsflow.evaluate.heldout.make_time_blocks`) of the
    common timeline (:func:`common_times`), so that frames of two cameras at one instant go to
    the same fold.

    Parameters
    ----------
    cameras, bodies, board
        As :func:`optimise_se3_rig` (a camera's own ``frames`` is replaced by each fold's).
    n_folds : int
        Folds.
    block_s : float
        Block length, s.
    seed : int
        Seed of the block-to-fold assignment.
    frame : {"C", "B"}
        Frame of the errors (:func:`cvsflow.metrics.errors.pose_errors`); ``C`` is camera 0's.
    **options
        Passed to ``optimise_se3_rig``.

    Returns
    -------
    heldout : DataFrame
        One row per held-out rig frame: :func:`fused_rig_poses` and
        :func:`cvsflow.metrics.errors.frame_errors` columns, ``fold`` and ``sigma_px``.
    fits : list of dict
        Each fold's ``result``, with ``fold``.
    """
    p_B = board_object_points(board)
    ids, times = [], []
    for i, e in enumerate(cameras):
        try:
            fr, tv, _ = corner_arrays(e["corners"], len(p_B))
        except OptimiseError as exc:
            raise OptimiseError(f"se3 rig: camera {i}: {exc}") from exc
        ids.append(fr)
        times.append(tv)
    t_common = common_times(cameras, times)
    fold_all = make_time_blocks(np.concatenate(t_common), block_s, n_folds, seed)
    folds = np.split(fold_all, np.cumsum([len(t) for t in t_common])[:-1])
    parts, fits = [], []
    for k in range(n_folds):
        train = [dict(e, frames=fr[f != k]) for e, fr, f in zip(cameras, ids, folds, strict=True)]
        fit = optimise_se3_rig(train, bodies, board, **options)
        res = dict(fit.result)
        res["fold"] = k
        fits.append(res)
        test = [fr[f == k] for fr, f in zip(ids, folds, strict=True)]
        scored = frame_errors(fused_rig_poses(res, [e["corners"] for e in cameras], bodies, board,
                                              frames=test, match_tol_s=options.get("match_tol_s"),
                                              calibration_cov=options.get("fused_calibration_cov", True),
                                              max_residual_px=options.get("fused_max_residual_px")),
                              frame=frame)  # fmt: skip
        scored["fold"] = k
        scored["sigma_px"] = res["sigma_px"]
        parts.append(scored)
        log.info("se3 rig cross-validation fold %d: %s test frames", k, [len(t) for t in test])
    heldout = pd.concat(parts, ignore_index=True).sort_values("t_vicon_s", ignore_index=True)
    return heldout, fits
