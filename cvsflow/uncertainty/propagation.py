"""Covariance of PnP poses and of their errors, propagated to first order.

1. :func:`pnp_covariance`: Cov(rvec, tvec) = sigma_px^2 (J^T J)^-1 with J the Jacobian of
   the corner projections w.r.t. (rvec, tvec) (``cv2.projectPoints``); the first-order
   covariance of a least-squares PnP under iid pixel noise (Hartley & Zisserman 2004,
   sec. 5.2.3).
2. :func:`propagated_pose_covariance` / :func:`pose6_covariance`: the same covariance pushed
   through the linearised map to the composed error [x, y, z, roll, pitch, yaw] in C
   (:func:`cvsflow.metrics.errors.pose_errors`) or to the 6-vector of T_C_B.
3. :func:`parameter_covariance`: the error covariance of each held-out frame that comes from
   the uncertainty of the se3 fit that scored it (intrinsics fx, fy, k1, k2, p1, p2 through
   the PnP pose; the mountings T_Cm_C, T_Bm_B through the Vicon reference), from that fit's
   parameter covariance. Errors of a held-out fold share that fit, so this is what makes
   them large together (a fold whose distortion is extrapolated, a mounting off by a
   fraction of a mrad seen at 3 m).

Covariance blocks travel in feature tables as upper triangles (:func:`cov_columns`,
:func:`cov_from_columns`).
"""

from __future__ import annotations

import cv2
import numpy as np

from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import sample_period
from cvsflow.geometry import transforms as tf
from cvsflow.metrics import ERROR_DIMS, pose_errors


def pnp_covariance(rvec_C_B, tvec_C_B, p_B, K, dist, sigma_px):
    """Covariance of PnP poses propagated from iid corner noise.

    Parameters
    ----------
    rvec_C_B : ndarray, shape (N, 3)
        Rotation vectors of T_C_B, rad.
    tvec_C_B : ndarray, shape (N, 3)
        Translations of T_C_B (board origin in C), m.
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    K : ndarray, shape (3, 3)
        Camera matrix, px.
    dist : ndarray, shape (5,)
        [k1, k2, p1, p2, k3].
    sigma_px : float or ndarray, shape (N,)
        Corner noise per axis, px (e.g. the se3 fit's ``sigma_px``).

    Returns
    -------
    cov_rt : ndarray, shape (N, 6, 6)
        Covariance of [rvec (rad), tvec (m)].

    Notes
    -----
    ``cv2.projectPoints`` returns d(u, v)/d(rvec, tvec, f, c, dist); its first six columns are
    J. Cov = sigma^2 (J^T J)^-1 (Gauss-Newton, first order).
    """
    rvec = np.atleast_2d(np.asarray(rvec_C_B, float))
    tvec = np.atleast_2d(np.asarray(tvec_C_B, float))
    if rvec.shape != tvec.shape or rvec.shape[1] != 3:
        raise OptimiseError(f"pnp_covariance: rvec {rvec.shape}, tvec {tvec.shape}; expected (N, 3)")
    sig = np.broadcast_to(np.asarray(sigma_px, float), (len(rvec),))
    obj = np.asarray(p_B, np.float64).reshape(-1, 1, 3)
    K = np.asarray(K, np.float64)
    dist = np.asarray(dist, np.float64).ravel()
    cov = np.empty((len(rvec), 6, 6))
    for i in range(len(rvec)):
        _, jac = cv2.projectPoints(obj, rvec[i], tvec[i], K, dist)
        J = jac[:, :6]
        cov[i] = sig[i] ** 2 * np.linalg.pinv(np.einsum("mi,mj->ij", J, J, optimize=False))
    return cov


def _numeric_jacobian(func, rvec, tvec, h=1e-6):
    """d func(rvec, tvec) / d [rvec, tvec] by central differences, vectorised over frames."""
    x = np.concatenate([rvec, tvec], axis=1)
    cols = []
    for j in range(6):
        xp, xm = x.copy(), x.copy()
        xp[:, j] += h
        xm[:, j] -= h
        cols.append((func(xp[:, :3], xp[:, 3:]) - func(xm[:, :3], xm[:, 3:])) / (2 * h))
    return np.stack(cols, axis=2)  # (N, d, 6)


def propagated_pose_covariance(rvec_C_B, tvec_C_B, cov_rt, frame="C"):
    """Covariance of the composed error [x, y, z, roll, pitch, yaw] of a PnP pose.

    Parameters
    ----------
    rvec_C_B, tvec_C_B : ndarray, shape (N, 3)
        The PnP pose (rad, m), taken as the linearisation point (error zero).
    cov_rt : ndarray, shape (N, 6, 6)
        Covariance of [rvec, tvec] (:func:`pnp_covariance`).
    frame : {"C", "B"}
        Error frame (:func:`cvsflow.evaluate.heldout.pose_errors`).

    Returns
    -------
    cov_err : ndarray, shape (N, 6, 6)
        Covariance of [err_x_m, err_y_m, err_z_m, err_roll_rad, err_pitch_rad, err_yaw_rad].
    """
    G = composed_error_jacobian(rvec_C_B, tvec_C_B, frame)
    return G @ cov_rt @ np.swapaxes(G, 1, 2)


def composed_error_jacobian(rvec_C_B, tvec_C_B, frame="C"):
    """d[err_x .. err_yaw] / d[rvec, tvec] at each PnP pose, (N, 6, 6).

    What :func:`propagated_pose_covariance` pushes ``cov_rt`` through; a factor ``F`` of it
    (``cov_rt = F F^T``) goes through as ``G F``.

    Parameters
    ----------
    rvec_C_B, tvec_C_B : ndarray, shape (N, 3)
        The PnP pose (rad, m), the linearisation point.
    frame : {"C", "B"}
        Error frame (:func:`cvsflow.evaluate.heldout.pose_errors`).

    Returns
    -------
    ndarray, shape (N, 6, 6)
    """
    rvec = np.atleast_2d(np.asarray(rvec_C_B, float))
    tvec = np.atleast_2d(np.asarray(tvec_C_B, float))
    T0 = tf.T_from_rvec_tvec(rvec, tvec)
    cols = [f"err_{d}" for d in ERROR_DIMS]

    def err(r, t):
        return pose_errors(T0, tf.T_from_rvec_tvec(r, t), frame=frame)[cols].to_numpy()

    return _numeric_jacobian(err, rvec, tvec)


def pose6_covariance(rvec_C_B, tvec_C_B, cov_rt):
    """Covariance of the 6-vector [x, y, z, roll, pitch, yaw] of T_C_B (linearised Euler map).

    Parameters
    ----------
    rvec_C_B, tvec_C_B : ndarray, shape (N, 3)
        The PnP pose (rad, m).
    cov_rt : ndarray, shape (N, 6, 6)
        Covariance of [rvec, tvec].

    Returns
    -------
    cov_pose6 : ndarray, shape (N, 6, 6)
        m^2, m rad, rad^2; R = Rz(yaw) Ry(pitch) Rx(roll). Unreliable near |pitch| = pi/2.
    """
    rvec = np.atleast_2d(np.asarray(rvec_C_B, float))
    tvec = np.atleast_2d(np.asarray(tvec_C_B, float))
    ref = tf.pose6_from_T(tf.T_from_rvec_tvec(rvec, tvec))

    def p6(r, t):
        d = tf.pose6_from_T(tf.T_from_rvec_tvec(r, t)) - ref
        d[:, 3:] = tf.wrap_angle(d[:, 3:])
        return d

    G = _numeric_jacobian(p6, rvec, tvec)
    return G @ cov_rt @ np.swapaxes(G, 1, 2)


#: Columns of :func:`cv2.projectPoints`' Jacobian per intrinsic parameter name.
_INTRINSIC_COLUMN = {"fx": 6, "fy": 7, "cx": 8, "cy": 9, "k1": 10, "k2": 11, "p1": 12, "p2": 13,
                     "k3": 14}
_MOUNT_NAMES = tuple(f"{body}_{s}" for body in ("T_Cm_C", "T_Bm_B")
                     for s in ("rx_rad", "ry_rad", "rz_rad", "x_m", "y_m", "z_m"))
#: The se3 fit's time offset (Vicon clock = video clock + dt), s.
_TIME_OFFSET = "dt_offset_s"
#: Names of the (co)variance blocks :func:`error_features` adds with ``fits``.
PARAM_BLOCKS = ("parcov", "intrcov")


def _fit_parameter_cov(fit, time_offset=False):
    """A se3 fit's parameter uncertainty, free and fixed, for the error propagation.

    Returns
    -------
    names : list of str
        Free intrinsics and mountings (and the time offset ``dt_offset_s`` with
        ``time_offset``), in ``correlation.names`` order.
    cov_data : ndarray, shape (n, n)
        Their data-only covariance (``std_errors_data``, else ``std_errors_cluster``, with
        the data-only ``correlation``).
    fixed : list of str
        The intrinsics held at their calibration values (``fixed_intrinsics.names``; empty
        for a fit without them).
    S : ndarray, shape (n, m)
        Sensitivity of the free estimates to the fixed intrinsics, d x_hat / d theta.
    sd_fixed : ndarray, shape (m,)
        The fixed intrinsics' calibration standard deviations.
    """
    names = list(fit["correlation"]["names"])
    std = fit.get("std_errors_data") or fit.get("std_errors_cluster") or fit["std_errors"]
    sd = np.array([float(std[n]) for n in names])
    cov = np.asarray(fit["correlation"]["matrix"], float) * np.outer(sd, sd)
    keep = [i for i, n in enumerate(names) if n in _INTRINSIC_COLUMN or n in _MOUNT_NAMES
            or (time_offset and n == _TIME_OFFSET)]
    fi = fit.get("fixed_intrinsics") or {}
    fixed = [n for n in fi.get("names", []) if n in _INTRINSIC_COLUMN]
    if fixed and fi.get("sensitivity") is not None:
        cols = [list(fi["names"]).index(n) for n in fixed]
        S = np.asarray(fi["sensitivity"], float)[np.ix_(keep, cols)]
        sd_fixed = np.asarray(fi["std"], float)[cols]
    else:
        fixed, S, sd_fixed = [], np.zeros((len(keep), 0)), np.zeros(0)
    return [names[i] for i in keep], cov[np.ix_(keep, keep)], fixed, S, sd_fixed


def parameter_covariance(frames, p_B, fits, frame="C", h=1e-6, time_offset=False):
    """Error covariance of held-out frames from the uncertainty of the fit that scored them.

    Parameters
    ----------
    frames : DataFrame
        Held-out rows (:func:`cvsflow.evaluate.heldout.cross_validate_se3`): ``fold``, the CVS pose
        ``cvs_rvec_0..2``, ``cvs_x_m..cvs_z_m`` and the reference ``ref_qx..ref_qw``,
        ``ref_x_m..ref_z_m`` (T_C_B).
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    fits : list of dict
        The folds' se3 results (``fold``, ``K``, ``dist``, ``T_Cm_C``, ``T_Bm_B``,
        ``std_errors_cluster`` or ``std_errors``, ``correlation: {names, matrix}``), as in
        heldout/se3_folds.yaml.
    frame : {"C", "B"}
        Error frame.
    h : float
        Step of the central differences (rad, m, px and unitless alike).
    time_offset : bool
        Also propagate the fit's time offset ``dt_offset_s``: the reference is read at
        t + dt, so its error moves each frame's error by the reference's rate of change
        (from the frame's neighbours in the table, same fold, ``t_vicon_s``) times the error
        of dt, correlated with the other parameters through the fit's covariance.

    Returns
    -------
    cov_par : ndarray, shape (N, 6, 6)
        Covariance of [err_x_m .. err_yaw_rad] from all fitted intrinsics and both mountings
        (and the time offset with ``time_offset``)
        (rotations perturbed on the right, R = R0 exp([w]x), translations added, as in
        :mod:`cvsflow.optimise.se3`).
    cov_intr : ndarray, shape (N, 6, 6)
        The part from the intrinsics alone (through the PnP pose).

    Raises
    ------
    OptimiseError
        Missing columns, or a row whose fold has no fit.
    """
    need = ["fold", *[f"cvs_rvec_{j}" for j in range(3)], "cvs_x_m", "cvs_y_m", "cvs_z_m",
            "ref_qx", "ref_qy", "ref_qz", "ref_qw", "ref_x_m", "ref_y_m", "ref_z_m"]
    missing = [c for c in need if c not in frames.columns]
    if missing:
        raise OptimiseError(f"parameter_covariance: frames table lacks columns {missing}")
    by_fold = {int(f["fold"]): f for f in fits}
    fold = frames["fold"].to_numpy().astype(int)
    absent = sorted(set(fold.tolist()) - set(by_fold))
    if absent:
        raise OptimiseError(f"parameter_covariance: no fit for fold(s) {absent}")
    obj = np.asarray(p_B, np.float64).reshape(-1, 1, 3)
    rt_all = frames[need[1:7]].to_numpy(float)
    q_all = frames[need[7:11]].to_numpy(float)
    t_all = frames[need[11:]].to_numpy(float)
    cols = [f"err_{d}" for d in ERROR_DIMS]
    cov_par = np.zeros((len(frames), 6, 6))
    cov_intr = np.zeros((len(frames), 6, 6))
    for k, fit in by_fold.items():
        idx = np.flatnonzero(fold == k)
        if not len(idx):
            continue
        names, Sig, fixed, S, sd_fixed = _fit_parameter_cov(fit, time_offset)
        K = np.asarray(fit["K"], np.float64)
        dist = np.asarray(fit["dist"], np.float64).ravel()
        T_Cm_C = np.asarray(fit["T_Cm_C"], float)
        T_Bm_B = np.asarray(fit["T_Bm_B"], float)
        kn = [n for n in names if n in _INTRINSIC_COLUMN]
        rt = rt_all[idx]
        # d(rvec, tvec)/d(intrinsics) of the PnP pose: -(J^T J)^-1 J^T J_K (implicit function),
        # free intrinsics first, then the fixed ones
        kall = kn + fixed
        A_all = np.zeros((len(idx), 6, len(kall)))
        for i in range(len(idx)):
            _, jac = cv2.projectPoints(obj, rt[i, :3], rt[i, 3:], K, dist)
            Jp = jac[:, :6]
            A_all[i] = -np.linalg.lstsq(
                Jp.T @ Jp, Jp.T @ jac[:, [_INTRINSIC_COLUMN[n] for n in kall]], rcond=None)[0]
        A, A_fix = A_all[:, :, :len(kn)], A_all[:, :, len(kn):]
        T_ref = tf.make_T(tf.R_from_quat(q_all[idx]), t_all[idx])
        T_Cm_Bm = T_Cm_C[None] @ T_ref @ tf.invert_T(T_Bm_B)[None]

        def mount(T0, p, body):
            w = np.array([p.get(f"{body}_r{a}_rad", 0.0) for a in "xyz"])
            dt = np.array([p.get(f"{body}_{a}_m", 0.0) for a in "xyz"])
            return tf.make_T(T0[:3, :3] @ tf.R_from_rvec(w), T0[:3, 3] + dt)

        def err(theta):  # noqa: B023  (called only within this iteration of the loop)
            p = dict(zip(names, theta, strict=True))  # noqa: B023
            rt_i = rt + A @ np.array([p[n] for n in kn])  # noqa: B023
            T_cvs = tf.T_from_rvec_tvec(rt_i[:, :3], rt_i[:, 3:])
            T_r = (tf.invert_T(mount(T_Cm_C, p, "T_Cm_C"))[None] @ T_Cm_Bm  # noqa: B023
                   @ mount(T_Bm_B, p, "T_Bm_B")[None])  # noqa: B023
            return pose_errors(T_r, T_cvs, frame=frame)[cols].to_numpy()

        def err_fixed(dtheta):  # noqa: B023
            rt_i = rt + A_fix @ dtheta  # noqa: B023
            T_cvs = tf.T_from_rvec_tvec(rt_i[:, :3], rt_i[:, 3:])
            return pose_errors(T_ref, T_cvs, frame=frame)[cols].to_numpy()  # noqa: B023

        G = np.zeros((len(idx), 6, len(names)))
        for j in range(len(names)):
            step = np.zeros(len(names))
            step[j] = h
            G[:, :, j] = (err(step) - err(-step)) / (2 * h)
        if _TIME_OFFSET in names:
            G[:, :, names.index(_TIME_OFFSET)] = _reference_rate(
                frames.iloc[idx], T_ref, rt, frame)
        cov_par[idx] = G @ Sig @ np.swapaxes(G, 1, 2)
        ki = [names.index(n) for n in kn]
        Gk = G[:, :, ki]
        cov_intr[idx] = Gk @ Sig[np.ix_(ki, ki)] @ np.swapaxes(Gk, 1, 2)
        if fixed:
            # a fixed intrinsic's error moves the held-out PnP pose directly (A_fix) and the
            # fitted parameters through S; both at once, so they partly cancel (a cx error is
            # to first order a turn of the camera, which the fitted mounting absorbs)
            G_th = np.zeros((len(idx), 6, len(fixed)))
            for j in range(len(fixed)):
                step = np.zeros(len(fixed))
                step[j] = h
                G_th[:, :, j] = (err_fixed(step) - err_fixed(-step)) / (2 * h)
            G_th = G_th + G @ S
            cov_par[idx] += G_th @ (sd_fixed[:, None] ** 2 * np.swapaxes(G_th, 1, 2))
    return cov_par, cov_intr


def _reference_rate(rows, T_ref, rt, frame):
    """d err / d t of the reference (N, 6): central differences over each row's neighbours
    in time (one-sided at a gap or an end; zero without a neighbour within 3.5 periods)."""
    t = rows["t_vicon_s"].to_numpy(float) if "t_vicon_s" in rows else rows["t_s"].to_numpy(float)
    order = np.argsort(t, kind="stable")
    ts = t[order]
    n = len(ts)
    period = sample_period(ts, default=np.inf)
    pos = np.empty(n, int)
    pos[order] = np.arange(n)
    prev = order[np.clip(pos - 1, 0, n - 1)]
    nxt = order[np.clip(pos + 1, 0, n - 1)]
    prev = np.where(t - t[prev] < 3.5 * period, prev, np.arange(n))
    nxt = np.where(t[nxt] - t < 3.5 * period, nxt, np.arange(n))
    span = t[nxt] - t[prev]
    T_cvs = tf.T_from_rvec_tvec(rt[:, :3], rt[:, 3:])
    cols = [f"err_{d}" for d in ERROR_DIMS]
    e_next = pose_errors(T_ref[nxt], T_cvs, frame=frame)[cols].to_numpy()
    e_prev = pose_errors(T_ref[prev], T_cvs, frame=frame)[cols].to_numpy()
    d = e_next - e_prev
    d[:, 3:] = tf.wrap_angle(d[:, 3:])
    return np.where(span[:, None] > 0, d / np.where(span > 0, span, 1.0)[:, None], 0.0)


def cov_columns(block):
    """Column names of a 6x6 covariance block stored as its upper triangle.

    Parameters
    ----------
    block : str
        Block name, e.g. ``"parcov"``, ``"unitcov"``.

    Returns
    -------
    columns : list of str
        ``{block}_{a}{b}`` for 0 <= a <= b < 6 (21 names, row by row).
    """
    return [f"{block}_{a}{b}" for a in range(6) for b in range(a, 6)]


def cov_from_columns(features, block):
    """The (N, 6, 6) symmetric covariance stored as the upper triangle ``{block}_{a}{b}``.

    Parameters
    ----------
    features : DataFrame
        A table with the :func:`cov_columns` of ``block``.
    block : str
        Block name.

    Returns
    -------
    cov : ndarray, shape (N, 6, 6)
        In the units the columns hold (SI for the feature tables of this package).
    """
    vals = features[cov_columns(block)].to_numpy(float)
    iu = np.triu_indices(6)
    C = np.zeros((len(vals), 6, 6))
    C[:, iu[0], iu[1]] = vals
    C[:, iu[1], iu[0]] = vals
    return C
