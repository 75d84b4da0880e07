"""Per-frame PnP pose covariance and a model that predicts the CVS error spread.

1. :func:`pnp_covariance`: Cov(rvec, tvec) = sigma_px^2 (J^T J)^-1 with J the Jacobian of
   the corner projections w.r.t. (rvec, tvec) (``cv2.projectPoints``); the first-order
   covariance of a least-squares PnP under iid pixel noise (Hartley & Zisserman 2004,
   sec. 5.2.3).
2. :func:`error_covariance` / :func:`pose6_covariance`: the same covariance pushed through
   the linearised map to the composed error [x, y, z, roll, pitch, yaw] in C
   (:func:`cvsflow.evaluate.pose_errors`) or to the 6-vector of T_C_B.
3. An error prediction model (:func:`fit_error_model`): per dimension d,

       sigma_d,i = sqrt(a_d^2 v_d,i + b_d^2) * exp(gamma_d . z_i)                       (M)

   with v_d,i the propagated PnP variance of frame i, b_d a floor (reference noise, what the
   PnP model does not see), and z_i standardised pose features (log distance, tilt, radial
   image position) for what remains; the errors e_d,i ~ N(mu_d, sigma_d,i^2), fitted by
   maximum likelihood. :func:`score_error_model` reports its calibration on held-out data:
   the share of errors inside the predicted 68 % and 95 % bands, and NEES.
4. :func:`parameter_covariance`: the error covariance of each held-out frame that comes from
   the uncertainty of the se3 fit that scored it (intrinsics fx, fy, k1, k2, p1, p2 through
   the PnP pose; the mountings T_Cm_C, T_Bm_B through the Vicon reference), from that fit's
   cluster-robust parameter covariance. Errors of a held-out fold share that fit, so this is
   what makes them large together (a fold whose distortion is extrapolated, a mounting off
   by a fraction of a mrad seen at 3 m). When these columns are present (``error_features``
   with ``fits``), model (P) replaces (M):

       Sigma_i = c^2 P_i + k^2 K_i + diag(b^2)                                          (P)

   with P_i the full propagated parameter covariance, K_i the part of its free intrinsics,
   scales c, k shared by the six dimensions, a floor b_d per dimension, no bias, and errors
   Student-t with nu degrees of freedom and covariance Sigma_i, all fitted by maximum
   likelihood; the bands are the t's quantiles. P_i includes the intrinsics the fit held
   fixed (cx, cy, k3): their calibration error moves the held-out PnP pose and, through the
   fit's sensitivity S, the fitted parameters at once, and the two partly cancel. The PnP
   variance with the pooled sigma_px and the pose features are left out: on the rendered
   sessions they over-fit the training folds (coverage of held-out folds drops).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import minimize
from scipy.special import gammaln
from scipy.stats import chi2
from scipy.stats import t as student_t

from cvsflow import transforms as tf
from cvsflow.calibration import board_object_points
from cvsflow.errors import OptimiseError
from cvsflow.metrics import ERROR_DIMS, pose_errors
from cvsflow.optimise.se3_start import corner_arrays

log = logging.getLogger(__name__)

#: Pose features of the error model (standardised on the training data).
FEATURES = ("log_distance", "tilt_rad", "radius_norm")
#: Two-sided band multipliers of a normal: 68.27 % and 95 % (1.96 sigma).
BANDS = {"68": 1.0, "95": 1.959963984540054}


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


def error_covariance(rvec_C_B, tvec_C_B, cov_rt, frame="C"):
    """Covariance of the composed error [x, y, z, roll, pitch, yaw] of a PnP pose.

    Parameters
    ----------
    rvec_C_B, tvec_C_B : ndarray, shape (N, 3)
        The PnP pose (rad, m), taken as the linearisation point (error zero).
    cov_rt : ndarray, shape (N, 6, 6)
        Covariance of [rvec, tvec] (:func:`pnp_covariance`).
    frame : {"C", "B"}
        Error frame (:func:`cvsflow.evaluate.pose_errors`).

    Returns
    -------
    cov_err : ndarray, shape (N, 6, 6)
        Covariance of [err_x_m, err_y_m, err_z_m, err_roll_rad, err_pitch_rad, err_yaw_rad].
    """
    rvec = np.atleast_2d(np.asarray(rvec_C_B, float))
    tvec = np.atleast_2d(np.asarray(tvec_C_B, float))
    T0 = tf.T_from_rvec_tvec(rvec, tvec)
    cols = [f"err_{d}" for d in ERROR_DIMS]

    def err(r, t):
        return pose_errors(T0, tf.T_from_rvec_tvec(r, t), frame=frame)[cols].to_numpy()

    G = _numeric_jacobian(err, rvec, tvec)
    return G @ cov_rt @ np.swapaxes(G, 1, 2)


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
#: Names of the (co)variance blocks :func:`error_features` adds with ``fits``.
PARAM_BLOCKS = ("parcov", "intrcov")


def _fit_parameter_cov(fit):
    """A se3 fit's parameter uncertainty, free and fixed, for the error propagation.

    Returns
    -------
    names : list of str
        Free intrinsics and mountings (no time offset), in ``correlation.names`` order.
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
    keep = [i for i, n in enumerate(names) if n in _INTRINSIC_COLUMN or n in _MOUNT_NAMES]
    fi = fit.get("fixed_intrinsics") or {}
    fixed = [n for n in fi.get("names", []) if n in _INTRINSIC_COLUMN]
    if fixed and fi.get("sensitivity") is not None:
        cols = [list(fi["names"]).index(n) for n in fixed]
        S = np.asarray(fi["sensitivity"], float)[np.ix_(keep, cols)]
        sd_fixed = np.asarray(fi["std"], float)[cols]
    else:
        fixed, S, sd_fixed = [], np.zeros((len(keep), 0)), np.zeros(0)
    return [names[i] for i in keep], cov[np.ix_(keep, keep)], fixed, S, sd_fixed


def parameter_covariance(frames, p_B, fits, frame="C", h=1e-6):
    """Error covariance of held-out frames from the uncertainty of the fit that scored them.

    Parameters
    ----------
    frames : DataFrame
        Held-out rows (:func:`cvsflow.evaluate.cross_validate_se3`): ``fold``, the CVS pose
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

    Returns
    -------
    cov_par : ndarray, shape (N, 6, 6)
        Covariance of [err_x_m .. err_yaw_rad] from all fitted intrinsics and both mountings
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
        names, Sig, fixed, S, sd_fixed = _fit_parameter_cov(fit)
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


def _cov_columns(block):
    return [f"{block}_{a}{b}" for a in range(6) for b in range(a, 6)]


def _cov_from_columns(features, block):
    """(N, 6, 6) symmetric covariance stored as the upper triangle ``{block}_{a}{b}``."""
    vals = features[_cov_columns(block)].to_numpy(float)
    iu = np.triu_indices(6)
    C = np.zeros((len(vals), 6, 6))
    C[:, iu[0], iu[1]] = vals
    C[:, iu[1], iu[0]] = vals
    return C


def error_features(frames, p_B, K, dist, sigma_px, frame="C", fits=None):
    """Pose features and propagated PnP error covariance of every frame.

    Parameters
    ----------
    frames : DataFrame
        Per-frame table with the CVS pose ``cvs_rvec_0..2`` (rad) and ``cvs_x_m, cvs_y_m,
        cvs_z_m`` (m) of T_C_B (:func:`cvsflow.optimise.se3.apply_se3`).
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    K : ndarray, shape (3, 3)
    dist : ndarray, shape (5,)
    sigma_px : float
        Corner noise, px (the se3 fit's ``sigma_px``).
    frame : {"C", "B"}
        Frame of the errors to be predicted.
    fits : list of dict, optional
        The cross-validation folds' se3 results (heldout/se3_folds.yaml ``folds``); with them
        and ``frames`` a held-out table (``fold``, ``ref_*``), the features also hold the
        parameter covariance of every row (:func:`parameter_covariance`) as upper triangles
        ``parcov_{a}{b}`` and ``intrcov_{a}{b}`` (a <= b over the six error dimensions), and
        the error model is (P).

    Returns
    -------
    features : DataFrame
        ``frame``; ``distance_m`` (camera to board centre), ``log_distance``, ``tilt_rad``
        (angle between the board normal and the line of sight to its centre),
        ``radius_norm`` (distance of the board centre's image from the optical axis, in
        normalised image units); ``pnp_var_{dim}`` (propagated variance of each error
        dimension, m^2 or rad^2).
    cov_err : ndarray, shape (N, 6, 6)
        Full propagated error covariance (:func:`error_covariance`).
    """
    need = [f"cvs_rvec_{j}" for j in range(3)] + ["cvs_x_m", "cvs_y_m", "cvs_z_m"]
    missing = [c for c in need if c not in frames.columns]
    if missing:
        raise OptimiseError(f"error_features: frames table lacks columns {missing}")
    rvec = frames[need[:3]].to_numpy(float)
    tvec = frames[need[3:]].to_numpy(float)
    cov_rt = pnp_covariance(rvec, tvec, p_B, K, dist, sigma_px)
    cov_err = error_covariance(rvec, tvec, cov_rt, frame=frame)
    R = tf.R_from_rvec(rvec).reshape(-1, 3, 3)
    centre_C = np.einsum("nij,j->ni", R, np.asarray(p_B, float).mean(axis=0)) + tvec
    dist_m = np.linalg.norm(centre_C, axis=1)
    normal_C = R[:, :, 2]
    cos_tilt = np.abs(np.einsum("ni,ni->n", normal_C, centre_C)) / dist_m
    out = pd.DataFrame(
        {
            "frame": frames["frame"].to_numpy() if "frame" in frames else np.arange(len(frames)),
            "distance_m": dist_m,
            "log_distance": np.log(dist_m),
            "tilt_rad": np.arccos(np.clip(cos_tilt, -1.0, 1.0)),
            "radius_norm": np.hypot(centre_C[:, 0], centre_C[:, 1]) / centre_C[:, 2],
        }
    )
    for j, d in enumerate(ERROR_DIMS):
        out[f"pnp_var_{d}"] = cov_err[:, j, j]
    if fits is not None:
        iu = np.triu_indices(6)
        covs = parameter_covariance(frames, p_B, fits, frame=frame)
        for block, C in zip(PARAM_BLOCKS, covs, strict=True):
            vals = C[:, iu[0], iu[1]]
            for c, name in enumerate(_cov_columns(block)):
                out[name] = vals[:, c]
    return out, cov_err


def _sigma(params, v, Z):
    """Model (M): sqrt(a^2 v + b^2) exp(gamma . z) for one dimension."""
    log_a, log_b, gamma = params[0], params[1], params[2:]
    return np.sqrt(np.exp(2 * log_a) * v + np.exp(2 * log_b)) * np.exp(Z @ gamma)


def fit_error_model(features, errors, use_features=True):
    """Fit model (M) per error dimension by maximum likelihood.

    Parameters
    ----------
    features : DataFrame
        :func:`error_features` output (training frames).
    errors : DataFrame
        The same frames' ``err_{dim}`` columns (:func:`cvsflow.evaluate.pose_errors`), SI.
    use_features : bool
        Include the pose features z (else sigma = sqrt(a^2 v + b^2) only).

    Returns
    -------
    model : dict
        With the ``parcov``/``intrcov`` columns in ``features``: model (P), ``kind: P``,
        ``nu`` (Student-t degrees of freedom), ``nll``, ``n_train`` and per dimension ``mu``
        (0), ``c``, ``k`` (shared), ``b``. Otherwise
        model (M), ``kind: M``:
        ``dims``; per dimension ``mu`` (bias), ``a`` (scale of the PnP sigma), ``b`` (floor,
        m or rad), ``gamma`` (list, per feature); ``feature_mean``, ``feature_std`` (the
        standardisation), ``features``; ``corr`` (6x6 correlation of the standardised
        training errors); ``n_train``; ``nll`` per dimension.

    Raises
    ------
    OptimiseError
        Missing columns, fewer than 20 frames, or non-finite data.
    """
    cols = [f"err_{d}" for d in ERROR_DIMS]
    if all(c in features.columns for b in PARAM_BLOCKS for c in _cov_columns(b)):
        return _fit_parameter_model(features, errors)
    vcols = [f"pnp_var_{d}" for d in ERROR_DIMS]
    missing = [c for c in cols if c not in errors.columns] + [
        c for c in [*vcols, *FEATURES] if c not in features.columns
    ]
    if missing:
        raise OptimiseError(f"fit_error_model: missing columns {missing}")
    E = errors[cols].to_numpy(float)
    V = features[vcols].to_numpy(float)
    F = features[list(FEATURES)].to_numpy(float)
    if len(E) != len(V) or len(E) < 20:
        raise OptimiseError(
            f"fit_error_model: {len(E)} error rows and {len(V)} feature rows; need equal and >= 20"
        )
    if not (np.isfinite(E).all() and np.isfinite(V).all() and np.isfinite(F).all()):
        raise OptimiseError("fit_error_model: non-finite errors or features")
    f_mean, f_std = F.mean(axis=0), F.std(axis=0)
    f_std = np.where(f_std > 0, f_std, 1.0)
    Z = (F - f_mean) / f_std if use_features else np.zeros((len(F), 0))
    model = {
        "kind": "M",
        "dims": list(ERROR_DIMS),
        "features": list(FEATURES) if use_features else [],
        "feature_mean": f_mean.tolist(),
        "feature_std": f_std.tolist(),
        "n_train": int(len(E)),
    }
    std_resid = np.empty_like(E)
    for j, d in enumerate(ERROR_DIMS):
        e, v = E[:, j], V[:, j]
        mu = float(e.mean())
        r2 = (e - mu) ** 2
        s0 = np.sqrt(np.mean(r2))
        x0 = np.r_[0.0, np.log(0.3 * s0 + 1e-12), np.zeros(Z.shape[1])]

        def nll(p, v=v, r2=r2):
            s = _sigma(p, v, Z)
            return float(np.sum(np.log(s) + 0.5 * r2 / s**2)) / len(r2)

        sol = minimize(nll, x0, method="L-BFGS-B")
        # the bias mu is refitted with weights 1/sigma^2 once (ML for fixed sigma)
        s = _sigma(sol.x, v, Z)
        mu = float(np.sum(e / s**2) / np.sum(1 / s**2))
        r2 = (e - mu) ** 2
        sol = minimize(lambda p, r2=r2, v=v: nll(p, v, r2), sol.x, method="L-BFGS-B")
        s = _sigma(sol.x, v, Z)
        std_resid[:, j] = (e - mu) / s
        model[d] = {
            "mu": mu,
            "a": float(np.exp(sol.x[0])),
            "b": float(np.exp(sol.x[1])),
            "gamma": sol.x[2:].tolist(),
            "nll": float(sol.fun),
        }
    model["corr"] = np.corrcoef(std_resid, rowvar=False).tolist()
    return model


def _fit_parameter_model(features, errors):
    """Model (P) by maximum likelihood, Student-t: var_d = c^2 P_dd + k^2 K_dd + b_d^2.

    One scale c for the parameter covariance and one k for its intrinsics part (shared by the
    six dimensions, so the carried covariance keeps its cross-correlations), a floor b_d per
    dimension, no bias, and a Student-t with nu > 2 degrees of freedom (shared) whose
    covariance is the one above; the six marginal likelihoods are summed.

    Why so few parameters: the errors of a held-out fold share that fold's fit, so training
    on four folds sees about four draws of the parameter error. Per-dimension scales and a
    bias fitted on them describe those four draws, not the next (held-out NEES 10-14 on the
    rendered sessions against 6.5-8.5 with this form), and the frames' errors are heavy
    tailed (nu ~ 3-5 fitted on the rendered demos).
    """
    cols = [f"err_{d}" for d in ERROR_DIMS]
    missing = [c for c in cols if c not in errors.columns]
    if missing:
        raise OptimiseError(f"fit_error_model: missing columns {missing}")
    E = errors[cols].to_numpy(float)
    P = _cov_from_columns(features, "parcov")
    Ki = _cov_from_columns(features, "intrcov")
    if len(E) != len(P) or len(E) < 20:
        raise OptimiseError(
            f"fit_error_model: {len(E)} error rows and {len(P)} feature rows; need equal and >= 20"
        )
    if not (np.isfinite(E).all() and np.isfinite(P).all() and np.isfinite(Ki).all()):
        raise OptimiseError("fit_error_model: non-finite errors or parameter covariances")
    s0 = np.sqrt(np.mean(E**2, axis=0)) + 1e-30  # work in units of each dimension's RMS
    r2 = (E / s0) ** 2
    vp = np.einsum("nii->ni", P) / s0**2
    vk = np.einsum("nii->ni", Ki) / s0**2

    def unpack(q):
        return np.exp(q[0]), np.exp(q[1]), np.exp(q[2:8]), 2.0 + np.exp(q[8])

    def nll(q):
        c, k, b, nu = unpack(q)
        sc2 = (c**2 * vp + k**2 * vk + b**2) * (nu - 2.0) / nu  # t scale^2 from the variance
        return -float(np.mean(gammaln((nu + 1) / 2) - gammaln(nu / 2) - 0.5 * np.log(nu * np.pi * sc2)
                              - (nu + 1) / 2 * np.log1p(r2 / (nu * sc2))))

    x0 = np.r_[0.0, 0.0, np.full(6, np.log(0.3)), np.log(3.0)]
    sol = minimize(nll, x0, method="L-BFGS-B", bounds=[(-20, 20)] * 8 + [(-5, 6)])
    c, k, b, nu = unpack(sol.x)
    b = b * s0
    model = {"kind": "P", "dims": list(ERROR_DIMS), "features": [], "n_train": int(len(E)),
             "nu": float(nu), "nll": float(sol.fun)}
    std_resid = np.empty_like(E)
    for j, d in enumerate(ERROR_DIMS):
        var = c**2 * P[:, j, j] + k**2 * Ki[:, j, j] + b[j] ** 2
        std_resid[:, j] = E[:, j] / np.sqrt(var)
        model[d] = {"mu": 0.0, "c": float(c), "k": float(k), "b": float(b[j])}
    model["corr"] = np.corrcoef(std_resid, rowvar=False).tolist()
    return model


def band_multipliers(model):
    """Half-widths of the 68.27 % and 95 % bands in predicted standard deviations.

    A normal model: 1 and 1.96. A Student-t model (``nu``): its quantiles over its standard
    deviation sqrt(nu / (nu - 2)) (narrower at 68 %, wider in the tails).

    Parameters
    ----------
    model : dict
        An error model (:func:`fit_error_model` or :func:`fit_transfer_model` output, or just
        ``{"nu": nu}``); its ``nu`` key, Student-t degrees of freedom (> 2), picks the
        distribution. Absent, None or non-finite: normal.

    Returns
    -------
    multipliers : dict
        ``{"68": k68, "95": k95}``: half-width of each two-sided band, in units of the
        predicted standard deviation (dimensionless; a band is ``mu +- k * sigma``).
    """
    nu = model.get("nu")
    if nu is None or not np.isfinite(nu):
        return dict(BANDS)
    sd = np.sqrt(nu / (nu - 2.0))
    return {"68": float(student_t.ppf(0.5 + 0.6826894921370859 / 2, nu) / sd),
            "95": float(student_t.ppf(0.975, nu) / sd)}


def predict_error_sigma(model, features):
    """Predicted error standard deviation per frame and dimension (model M).

    Parameters
    ----------
    model : dict
        :func:`fit_error_model` output.
    features : DataFrame
        :func:`error_features` output.

    Returns
    -------
    sigma : ndarray, shape (N, 6)
        m for x, y, z; rad for roll, pitch, yaw.
    mu : ndarray, shape (6,)
        Predicted bias per dimension.
    """
    if model.get("kind") == "P":
        var = np.einsum("nii->ni", _parameter_model_covariance(model, features))
        return np.sqrt(var), np.array([model[d]["mu"] for d in ERROR_DIMS])
    V = features[[f"pnp_var_{d}" for d in ERROR_DIMS]].to_numpy(float)
    if model["features"]:
        F = features[model["features"]].to_numpy(float)
        Z = (F - np.asarray(model["feature_mean"])) / np.asarray(model["feature_std"])
    else:
        Z = np.zeros((len(V), 0))
    sigma = np.empty_like(V)
    mu = np.empty(len(ERROR_DIMS))
    for j, d in enumerate(ERROR_DIMS):
        m = model[d]
        p = np.r_[np.log(m["a"]), np.log(m["b"]), m["gamma"]]
        sigma[:, j] = _sigma(p, V[:, j], Z)
        mu[j] = m["mu"]
    return sigma, mu


def _parameter_model_covariance(model, features):
    """Model (P): D(c) P_i D(c) + D(k) K_i D(k) + diag(b^2), (N, 6, 6)."""
    c = np.array([model[d]["c"] for d in ERROR_DIMS])
    k = np.array([model[d]["k"] for d in ERROR_DIMS])
    b = np.array([model[d]["b"] for d in ERROR_DIMS])
    P = _cov_from_columns(features, "parcov")
    Ki = _cov_from_columns(features, "intrcov")
    return (c[:, None] * P * c[None, :] + k[:, None] * Ki * k[None, :]) + np.diag(b**2)[None]


def predicted_covariance(model, features, cov_err=None):
    """Full 6x6 predicted error covariance per frame: D_i C_i D_i.

    Parameters
    ----------
    model : dict
    features : DataFrame
    cov_err : ndarray, shape (N, 6, 6), optional
        Propagated PnP error covariance; when given its per-frame correlation is C_i, else
        the model's training correlation of standardised errors. Model (P) ignores it: its
        covariance is the scaled parameter covariance plus the diagonal floor.

    Returns
    -------
    cov : ndarray, shape (N, 6, 6)
    """
    if model.get("kind") == "P":
        return _parameter_model_covariance(model, features)
    sigma, _ = predict_error_sigma(model, features)
    if cov_err is None:
        C = np.broadcast_to(np.asarray(model["corr"]), (len(sigma), 6, 6))
    else:
        d = np.sqrt(np.einsum("nii->ni", cov_err))
        C = cov_err / (d[:, :, None] * d[:, None, :])
    return sigma[:, :, None] * C * sigma[:, None, :]


def score_error_model(model, features, errors, cov_err=None):
    """Calibration of the error model on (held-out) frames.

    Parameters
    ----------
    model : dict
        :func:`fit_error_model` output.
    features : DataFrame
        :func:`error_features` of the scored frames.
    errors : DataFrame
        ``err_{dim}`` of the same frames.
    cov_err : ndarray, shape (N, 6, 6), optional
        Propagated PnP error covariance, for the per-frame correlation of the NEES
        (:func:`predicted_covariance`); default the training correlation.

    Returns
    -------
    score : dict
        ``n``; ``inside_68``, ``inside_95``: per dimension (name -> share of |e - mu| inside
        the 68.27 % and 95 % bands, 1 and 1.96 predicted sigma for a normal model,
        :func:`band_multipliers`); ``inside_68_all``, ``inside_95_all`` (pooled);
        ``nees_mean`` (mean of (e - mu)^T Cov^-1 (e - mu); 6 for a consistent model);
        ``nees_inside_95`` (share below the chi-square(6) 95 % quantile);
        ``z_rms`` per dimension (RMS of standardised errors; 1 when calibrated).
    """
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)
    sigma, mu = predict_error_sigma(model, features)
    Zs = (E - mu) / sigma
    out = {"n": int(len(E))}
    for band, k in band_multipliers(model).items():
        inside = np.abs(Zs) <= k
        out[f"inside_{band}"] = {d: float(inside[:, j].mean()) for j, d in enumerate(ERROR_DIMS)}
        out[f"inside_{band}_all"] = float(inside.mean())
    out["z_rms"] = {d: float(np.sqrt(np.mean(Zs[:, j] ** 2))) for j, d in enumerate(ERROR_DIMS)}
    cov = predicted_covariance(model, features, cov_err)
    r = E - mu
    nees = np.einsum("ni,ni->n", r, np.linalg.solve(cov, r[:, :, None])[:, :, 0])
    out["nees_mean"] = float(nees.mean())
    out["nees_inside_95"] = float(np.mean(nees <= chi2.ppf(0.95, 6)))
    return out


# --------------------------------------------------------------------------- model (T): transfer

#: Per-frame quantities known when a frame is measured (:func:`measurement_features`).
MEASUREMENT_FEATURES = ("distance_m", "tilt_rad", "radius_norm", "n_corners", "spread_px",
                        "speed_px", "reproj_rms_px")
#: Parameters of model (T), in the order of its vector (logs of positive scales).
TRANSFER_PARAMS = ("s0_px", "s_speed", "s_reproj", "c_cal", "s_rs", "b_pos_m", "b_rot_rad",
                   "b_fill_pos_m", "b_fill_rot_rad", "nu")
#: Working units of the fit (mm, mrad): keeps the 6x6 covariances well conditioned.
_UNIT = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3])


def _seen_corners(corners, frame_ids, n_corners):
    """Observed pixels (N, P, 2) of the given frames (NaN where unseen), each frame's image
    speed (N,), px per frame period (the mean travel of its corners between its neighbours),
    and each corner's image velocity (N, P, 2), px/s (NaN where not seen in the neighbours)."""
    fr, t, uv = corner_arrays(corners, n_corners, min_corners=1)
    idx = np.searchsorted(fr, frame_ids)
    idx = np.clip(idx, 0, len(fr) - 1)
    if not np.array_equal(fr[idx], np.asarray(frame_ids)):
        missing = sorted(set(np.asarray(frame_ids).tolist()) - set(fr.tolist()))[:5]
        raise OptimiseError(f"measurement_features: frames {missing} have no corners")
    period = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    prev = np.clip(np.arange(len(fr)) - 1, 0, None)
    nxt = np.clip(np.arange(len(fr)) + 1, None, len(fr) - 1)
    span = np.where(nxt > prev, t[nxt] - t[prev], np.inf)
    travel = np.nanmean(np.linalg.norm(uv[nxt] - uv[prev], axis=-1), axis=1)
    speed = travel / span * period
    # a neighbour without shared corners or far away in time (a gap): no estimate, say 0 px
    near = span < 3.5 * period
    speed = np.where(np.isfinite(speed) & near, speed, 0.0)
    vel = (uv[nxt] - uv[prev]) / np.where(near, span, np.nan)[:, None, None]
    return uv[idx], speed[idx], vel[idx]



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
            # corner k is displaced by its image velocity times its row's delay after the mean
            # row (the reference's time); PnP turns the shear into a pose error
            rows = uv_px[i, seen[i], 1]
            d_uv = np.nan_to_num(vel_px_s[i, seen[i]]) * (line_delay_s * (rows - rows.mean()))[:, None]
            d_rt[i] = JtJ_inv @ (J.T @ d_uv.reshape(-1))
    unit = error_covariance(rvec, tvec, cov_rt, frame=frame)
    cols = [f"err_{d}" for d in ERROR_DIMS]
    T_at = tf.T_from_rvec_tvec(rvec, tvec)
    shear = pose_errors(tf.T_from_rvec_tvec(rvec - d_rt[:, :3], tvec - d_rt[:, 3:]), T_at,
                        frame=frame)[cols].to_numpy()  # fmt: skip
    return unit, shear


def measurement_features(heldout, corners, board, fits=None, frame="C", bodies=None):
    """What is known of each held-out frame when it is measured, and its covariance terms.

    Parameters
    ----------
    heldout : DataFrame
        :func:`cvsflow.evaluate.cross_validate_se3` rows (``frame``, ``fold``, the CVS pose
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
        (``t_vicon_s``), else 0.

    Returns
    -------
    features : DataFrame
        ``frame``; the :data:`MEASUREMENT_FEATURES` (distance to the board centre m, tilt of
        the board normal from the line of sight rad, radial image position of the board centre
        in normalised units, corners seen, their RMS spread about their centroid px, image
        speed px per frame period (the blur proxy: blur = speed x exposure / period),
        reprojection RMS of the PnP px); ``unitcov_{a}{b}``, the error covariance of the PnP
        pose per px^2 of iid corner noise over the corners this frame saw ((J^T J)^-1 pushed
        to [x, y, z, roll, pitch, yaw], m^2 / px^2 .. rad^2 / px^2); ``rs_err_{dim}``, the
        CVS pose error that the rolling shutter's shear predicts (the fold's fitted line delay
        times each corner's image velocity and its row after the mean row, through PnP, in
        the error's units; zero for a global shutter); ``parcov_{a}{b}`` with ``fits``.
    """
    p_B = board_object_points(board)
    need = ["frame", *[f"cvs_rvec_{j}" for j in range(3)], "cvs_x_m", "cvs_y_m", "cvs_z_m",
            "reproj_rms_px"]
    missing = [c for c in need if c not in heldout.columns]
    if missing:
        raise OptimiseError(f"measurement_features: held-out table lacks columns {missing}")
    frames = heldout["frame"].to_numpy()
    uv, speed, vel = _seen_corners(corners, frames, len(p_B))
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
        "reproj_rms_px": heldout["reproj_rms_px"].to_numpy(float),
    })  # fmt: skip
    iu = np.triu_indices(6)
    for c, name in enumerate(_cov_columns("unitcov")):
        out[name] = unit[:, iu[0][c], iu[1][c]]
    for j, d in enumerate(ERROR_DIMS):
        out[f"rs_err_{d}"] = rs[:, j]
    if bodies is not None and "n_filled" in bodies and "t_vicon_s" in heldout:
        out["vicon_filled"] = vicon_filled(bodies, heldout["t_vicon_s"].to_numpy(float))
    if fits and all("correlation" in f for f in fits):
        cov_par, _ = parameter_covariance(heldout, p_B, fits, frame=frame)
        for c, name in enumerate(_cov_columns("parcov")):
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


def _transfer_terms(features):
    """(U per px^2, P (N, 6, 6), RS shear error (N, 6), speed (N,), corner noise (N,), Vicon
    gap-filled (N,)), working units."""
    U = _cov_from_columns(features, "unitcov")

    def block(name):
        has = all(c in features.columns for c in _cov_columns(name))
        return _cov_from_columns(features, name) if has else np.zeros_like(U)

    scale = 1.0 / np.outer(_UNIT, _UNIT)
    speed = features["speed_px"].to_numpy(float)
    reproj = corner_noise_from_reproj(features["reproj_rms_px"].to_numpy(float),
                                      features["n_corners"].to_numpy(float))
    rs_cols = [f"rs_err_{d}" for d in ERROR_DIMS]
    RS = (features[rs_cols].to_numpy(float) / _UNIT if all(c in features for c in rs_cols)
          else np.zeros((len(U), 6)))  # fmt: skip
    filled = (features["vicon_filled"].to_numpy(float) if "vicon_filled" in features
              else np.zeros(len(U)))  # fmt: skip
    return U * scale, block("parcov") * scale, RS, speed, reproj, filled


def _unpack_transfer(q):
    return (*np.exp(q[:9]), 2.0 + np.exp(q[9]))


def _shrink_terms(features):
    """(corners per frame (N,), pooled corner noise (N,)) for the shrinkage of model (T)."""
    n_c = features["n_corners"].to_numpy(float)
    if NOISE_POOL_COLUMN in features:
        pool = features[NOISE_POOL_COLUMN].to_numpy(float)
    else:
        pool = np.full(len(n_c), corner_noise_pool(features["reproj_rms_px"].to_numpy(float),
                                                   n_c))  # fmt: skip
    return n_c, pool


def _transfer_cov(q, U, P, RS, speed, reproj, filled, shrink=None):
    """Model (T) mean (N, 6) and covariance (N, 6, 6), working units; ``q`` of 11 entries
    (the last log k) with ``shrink`` = :func:`_shrink_terms` shrinks the corner noise."""
    s0, s_speed, s_reproj, c, s_rs, b_pos, b_rot, f_pos, f_rot, _ = _unpack_transfer(q)
    if len(q) > 10 and shrink is not None:
        reproj = shrink_corner_noise(reproj, shrink[0], shrink[1], np.exp(q[10]))
    var_px = s0**2 + (s_speed * speed) ** 2 + (s_reproj * reproj) ** 2
    floor = np.r_[np.full(3, b_pos), np.full(3, b_rot)] / _UNIT
    fill = np.r_[np.full(3, f_pos), np.full(3, f_rot)] / _UNIT
    S = (var_px[:, None, None] * U + c**2 * P + np.diag(floor**2)[None]
         + filled[:, None, None] * np.diag(fill**2)[None])  # fmt: skip
    return s_rs * RS, S


def fit_transfer_model(features, errors, shrink=None):
    """Fit model (T) by maximum likelihood on frames of one or more sessions.

    Model (T), per frame i (what is known when it is measured):

        sigma_px,i^2 = s0^2 + (s_speed v_i)^2 + (s_reproj n_i)^2
        mu_i = s_rs r_i
        Sigma_i = sigma_px,i^2 U_i + c_cal^2 P_i + diag(b_pos^2 I3, b_rot^2 I3)
                  + f_i diag(b_fill_pos^2 I3, b_fill_rot^2 I3)

    with U_i the PnP error covariance per px^2 of iid corner noise over the corners the frame
    saw (it carries the distance, the view angles, the corner count and their spread), v_i the
    image speed (px per frame period: blur), n_i the corner noise the frame's PnP
    reprojection RMS implies (:func:`corner_noise_from_reproj`; s_reproj = 1 for iid
    noise), P_i the
    calibration's covariance (intrinsics free and fixed, both mountings) propagated through
    PnP and the reference (the term common to every frame the fit scores, hence correlated in
    time), r_i the pose error a rolling shutter's shear predicts (fitted line delay x image
    velocity x row through PnP; 0 for a global shutter: the CVS's PnP ignores the shear, the
    reference is taken at the mean row; a known error, hence a mean, not a variance), and the
    floors b the Vicon reference's own noise, raised by b_fill where a board marker was
    gap-filled about the frame (f_i = 1, ``vicon_filled``: the filled marker's error moves
    the rigid fit). The errors are multivariate
    Student-t with nu > 2 degrees of freedom and covariance Sigma_i. Every scale is in
    physical units shared by all cameras and boards (px, dimensionless, m, rad), so the model
    fitted on some sessions predicts another.

    Parameters
    ----------
    features : DataFrame
        :func:`measurement_features` of the training frames (``unitcov``, optional ``parcov``).
    errors : DataFrame
        The same frames' ``err_{dim}`` (CVS - reference, :func:`cvsflow.evaluate.pose_errors`).
    shrink : None, "fit" or float
        None: n_i as measured. Otherwise n_i is replaced by :func:`shrink_corner_noise`
        toward the pooled noise (column :data:`NOISE_POOL_COLUMN`, else the median over the
        rows) with prior strength k: fitted (``"fit"``) or the given value.

    Returns
    -------
    model : dict
        ``kind: T``, ``dims``, one entry per :data:`TRANSFER_PARAMS` (px, -, -, -, -, m, rad,
        -),
        ``nll`` (mean per frame), ``n_train``; with ``shrink`` also ``k_shrink``.

    Raises
    ------
    OptimiseError
        Missing columns, fewer than 20 frames or non-finite data.
    """
    cols = [f"err_{d}" for d in ERROR_DIMS]
    missing = [c for c in cols if c not in errors.columns]
    missing += [c for c in [*_cov_columns("unitcov"), "speed_px", "reproj_rms_px", "n_corners"]
                if c not in features.columns]  # fmt: skip
    if missing:
        raise OptimiseError(f"fit_transfer_model: missing columns {missing}")
    E = errors[cols].to_numpy(float) / _UNIT
    U, P, RS, speed, reproj, filled = _transfer_terms(features)
    if len(E) != len(U) or len(E) < 20:
        raise OptimiseError(
            f"fit_transfer_model: {len(E)} error rows and {len(U)} feature rows; need equal, >= 20"
        )
    if not (np.isfinite(E).all() and np.isfinite(U).all() and np.isfinite(P).all()):
        raise OptimiseError("fit_transfer_model: non-finite errors or covariances")
    d = 6
    # the shear term is a first-order prediction of the error itself: its scale is 1 in
    # physics (fitted on the rendered rolling-shutter session it comes out at 1.01), and a
    # session without a rolling shutter cannot tell it (fitted line delays of ~1e-7 s would
    # fit it to their noise): held at 1
    fit_rs = False

    fit_k = isinstance(shrink, str)
    if fit_k and shrink != "fit":
        raise OptimiseError(f"fit_transfer_model: shrink={shrink!r}; expected None, 'fit' or k")
    sh = _shrink_terms(features) if shrink is not None else None
    k_fixed = [] if shrink is None or fit_k else [np.log(max(float(shrink), 1e-12))]

    def full(q):
        q = q if fit_rs else np.r_[q[:4], 0.0, q[4:]]
        return np.r_[q, k_fixed]

    def nll(q):
        q = full(q)
        mu, S = _transfer_cov(q, U, P, RS, speed, reproj, filled, sh)
        nu = _unpack_transfer(q)[9]
        try:
            L = np.linalg.cholesky(S * ((nu - 2.0) / nu))
        except np.linalg.LinAlgError:
            return 1e30
        z = np.linalg.solve(L, (E - mu)[:, :, None])[:, :, 0]
        m2 = np.einsum("ni,ni->n", z, z)
        logdet = 2.0 * np.log(np.einsum("nii->ni", L)).sum(axis=1)
        ll = (gammaln((nu + d) / 2) - gammaln(nu / 2) - 0.5 * d * np.log(nu * np.pi)
              - 0.5 * logdet - 0.5 * (nu + d) * np.log1p(m2 / nu))
        return -float(np.mean(ll))

    x0 = np.log([0.2, 0.02, 0.3, 1.0, 1.0, 5e-4, 5e-4, 2e-3, 2e-3, 5.0])
    best = None
    # the likelihood is smooth but can be flat in a term the data do not need (e.g. no
    # parameter covariance, no speed): two starts, keep the better
    keep = np.ones(10, bool)
    keep[4] = fit_rs
    bounds = [(-25, 10)] * (keep.sum() - 1) + [(-4, 6)]
    starts = [x0, x0 + np.r_[0.7, -1.5, -1.5, -0.7, -0.7, 0.7, 0.7, -1.0, -1.0, 0.0]]
    if fit_k:
        # k in pseudo-degrees of freedom: from a tenth of a frame's (~50) to 2e5 (the pool)
        bounds.append((np.log(0.1), np.log(2e5)))
        starts = [np.r_[x[keep], np.log(30.0)] for x in starts]
    else:
        starts = [x[keep] for x in starts]
    for start in starts:
        sol = minimize(nll, start, method="L-BFGS-B", bounds=bounds, options={"maxiter": 500})
        if best is None or sol.fun < best.fun:
            best = sol
    q_best = full(best.x)
    vals = _unpack_transfer(q_best)
    model = {"kind": "T", "dims": list(ERROR_DIMS), "n_train": int(len(E)),
             "nll": float(best.fun), "s_rs_fitted": fit_rs}
    model.update({name: float(v) for name, v in zip(TRANSFER_PARAMS, vals, strict=True)})
    if shrink is not None:
        model["k_shrink"] = float(np.exp(q_best[10]))
    return model


def _q_from_model(model):
    v = [model[n] for n in TRANSFER_PARAMS]
    q = np.r_[np.log(v[:9]), np.log(v[9] - 2.0)]
    k = model.get("k_shrink")
    return q if k is None else np.r_[q, np.log(max(float(k), 1e-12))]


def _model_cov(model, features):
    sh = _shrink_terms(features) if model.get("k_shrink") is not None else None
    return _transfer_cov(_q_from_model(model), *_transfer_terms(features), sh)


def transfer_covariance(model, features):
    """Model (T)'s predicted 6x6 error covariance of each frame, SI (m, rad), (N, 6, 6).

    Parameters
    ----------
    model : dict
        :func:`fit_transfer_model` output (the ``TRANSFER_PARAMS`` and ``nu``; with
        ``k_shrink``, each frame's corner noise is shrunk toward the pooled value).
    features : DataFrame
        :func:`measurement_features` of the frames: ``unitcov_{a}{b}``, ``speed_px``,
        ``reproj_rms_px``, ``n_corners``, and optionally ``parcov_{a}{b}``, ``rs_err_{dim}``,
        ``vicon_filled`` (absent ones count as zero) and ``noise_pool_px`` (default: the
        median corner noise of the rows given).

    Returns
    -------
    cov : ndarray, shape (N, 6, 6)
        Covariance of the pose error ``[x, y, z, roll, pitch, yaw]`` of each frame (the
        ``err_{dim}`` columns, ``dim`` in ``ERROR_DIMS``), m^2, m rad and rad^2. It is
        the Student-t's covariance, not its scale matrix.
    """
    _, S = _model_cov(model, features)
    return S * np.outer(_UNIT, _UNIT)


def transfer_mean(model, features):
    """Model (T)'s predicted error of each frame (the rolling shutter's shear), SI, (N, 6).

    Parameters
    ----------
    model : dict
        :func:`fit_transfer_model` output.
    features : DataFrame
        :func:`measurement_features` of the frames, as for :func:`transfer_covariance`.

    Returns
    -------
    mu : ndarray, shape (N, 6)
        Predicted pose error ``[x, y, z, roll, pitch, yaw]`` of each frame, m and rad: the
        ``rs_err_{dim}`` columns times the model's shear scale, zero without those columns
        (a global shutter).
    """
    mu, _ = _model_cov(model, features)
    return mu * _UNIT


def cramer_rao_sigma(features, sigma_px):
    """Cramer-Rao standard deviation of each frame's pose error from the corner noise alone.

    The PnP pose is the ML estimate under iid Gaussian corner noise of ``sigma_px`` per axis,
    whose covariance is bounded below by sigma_px^2 (J^T J)^-1 (the Fisher information of the
    corners the frame saw), pushed to the error dimensions: the physical floor of a frame.

    Parameters
    ----------
    features : DataFrame
        :func:`measurement_features` of the frames (their ``unitcov_{a}{b}`` columns, the
        error covariance per px^2 of corner noise).
    sigma_px : float or array_like, shape (N,)
        Corner noise per image axis, px: one value for all frames or one per frame.

    Returns
    -------
    crb : ndarray, shape (N, 6)
        m for x, y, z; rad for roll, pitch, yaw.
    """
    U = _cov_from_columns(features, "unitcov")
    sig = np.broadcast_to(np.asarray(sigma_px, float), (len(U),))
    return np.sqrt(np.einsum("nii->ni", U)) * sig[:, None]


def score_covariance(cov, errors, nu=None, mean=None):
    """Calibration of predicted covariances on (held-out) frames.

    Parameters
    ----------
    cov : ndarray, shape (N, 6, 6)
        Predicted error covariance, SI.
    errors : DataFrame
        ``err_{dim}`` of the same frames.
    nu : float, optional
        Student-t degrees of freedom of the prediction (the band quantiles); None: normal.
    mean : ndarray, shape (N, 6), optional
        Predicted error (the bands' centres), SI; default 0.

    Returns
    -------
    score : dict
        ``n``; ``inside_68``, ``inside_95`` per dimension and ``_all``; ``z_rms`` per
        dimension; ``nees_mean``, ``nees_inside_95`` (below the chi-square(6) 95 % quantile).
    """
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)
    if mean is not None:
        E = E - mean
    sigma = np.sqrt(np.einsum("nii->ni", cov))
    Zs = E / sigma
    out = {"n": int(len(E))}
    for band, k in band_multipliers({"nu": nu}).items():
        inside = np.abs(Zs) <= k
        out[f"inside_{band}"] = {d: float(inside[:, j].mean()) for j, d in enumerate(ERROR_DIMS)}
        out[f"inside_{band}_all"] = float(inside.mean())
    out["z_rms"] = {d: float(np.sqrt(np.mean(Zs[:, j] ** 2))) for j, d in enumerate(ERROR_DIMS)}
    S = cov / np.outer(_UNIT, _UNIT)
    r = E / _UNIT
    nees = np.einsum("ni,ni->n", r, np.linalg.solve(S, r[:, :, None])[:, :, 0])
    out["nees_mean"] = float(nees.mean())
    out["nees_inside_95"] = float(np.mean(nees <= chi2.ppf(0.95, 6)))
    return out


def nees_values(cov, errors, mean=None):
    """Per-frame NEES e^T Sigma^-1 e (N,) of errors ``err_{dim}`` (minus ``mean``) under
    covariances (N, 6, 6).

    Parameters
    ----------
    cov : ndarray, shape (N, 6, 6)
        Predicted error covariance of each frame, SI (m^2, m rad, rad^2), e.g.
        :func:`transfer_covariance`.
    errors : DataFrame
        ``err_{dim}`` for ``dim`` in ``ERROR_DIMS`` (``x_m, y_m, z_m`` in m, ``roll_rad,
        pitch_rad, yaw_rad`` in rad) of the same N frames, in the same order.
    mean : ndarray, shape (N, 6), optional
        Predicted error subtracted first (e.g. :func:`transfer_mean`), SI; None: zero.

    Returns
    -------
    nees : ndarray, shape (N,)
        Normalised estimation error squared, dimensionless (chi-square with 6 degrees of
        freedom for a calibrated normal prediction, mean 6). NaN for a frame whose error has
        a NaN.
    """
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)
    E = (E if mean is None else E - mean) / _UNIT
    S = cov / np.outer(_UNIT, _UNIT)
    return np.einsum("ni,ni->n", E, np.linalg.solve(S, E[:, :, None])[:, :, 0])


def _autocorr_lag1(z, fold):
    """Lag-1 autocorrelation of standardised errors z (N, 6) within each fold's runs."""
    same = fold[1:] == fold[:-1]
    a, b = z[:-1][same], z[1:][same]
    return np.sum(a * b, axis=0) / np.sqrt(np.sum(a * a, axis=0) * np.sum(b * b, axis=0))


def score_transfer(model, features, errors, folds=None, sigma_px=None):
    """Model (T) scored on one session: overall and per cross-validation fold.

    Parameters
    ----------
    model : dict
        :func:`fit_transfer_model` output (fitted without this session).
    features, errors : DataFrame
        :func:`measurement_features` and ``err_{dim}`` (and ``t_s``) of its held-out rows.
    folds : ndarray, optional
        The time-block fold of each row (the se3 fit that scored it).
    sigma_px : float or ndarray, optional
        Corner noise for the Cramer-Rao bound (the se3 fits' ``sigma_px``); adds
        ``error_over_crb`` (RMS of error / CRB per axis) and ``crb_median`` per axis.

    Returns
    -------
    score : dict
        :func:`score_covariance` keys, ``lag1_autocorr`` per axis (of the errors standardised
        by their predicted sigma, within folds), ``folds`` (list of per-fold scores with
        ``fold``), and with ``sigma_px`` the CRB keys.
    """
    cov = transfer_covariance(model, features)
    mu = transfer_mean(model, features)
    out = score_covariance(cov, errors, nu=model["nu"], mean=mu)
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)
    z = (E - mu) / np.sqrt(np.einsum("nii->ni", cov))
    fold = np.zeros(len(E), int) if folds is None else np.asarray(folds).astype(int)
    out["lag1_autocorr"] = dict(zip(ERROR_DIMS, map(float, _autocorr_lag1(z, fold)), strict=True))
    if sigma_px is not None:
        crb = cramer_rao_sigma(features, sigma_px)
        out["error_over_crb"] = {d: float(np.sqrt(np.mean((E[:, j] / crb[:, j]) ** 2)))
                                 for j, d in enumerate(ERROR_DIMS)}  # fmt: skip
        out["crb_median"] = {d: float(np.median(crb[:, j])) for j, d in enumerate(ERROR_DIMS)}
    out["folds"] = []
    rho = np.clip(np.mean(list(out["lag1_autocorr"].values())), 0.0, 0.95)
    out.update(_sampling_band(len(E), rho))
    if folds is not None:
        for k in np.unique(fold):
            sel = fold == k
            s = score_covariance(cov[sel], errors[sel].reset_index(drop=True), nu=model["nu"],
                                 mean=mu[sel])
            s["fold"] = int(k)
            s.update(_sampling_band(int(sel.sum()), rho))
            out["folds"].append(s)
    return out


def _sampling_band(n, rho):
    """How far a calibrated model's shares of n frames scatter when the standardised errors
    have lag-1 autocorrelation rho (AR(1)): ``n_effective`` = n (1 - rho) / (1 + rho) and the
    2-sigma binomial half-widths ``inside_95_tolerance``, ``inside_68_tolerance``."""
    n_eff = max(n * (1.0 - rho) / (1.0 + rho), 1.0)
    return {"n_effective": float(n_eff), "lag1_mean": float(rho),
            "inside_95_tolerance": float(2.0 * np.sqrt(0.95 * 0.05 / n_eff)),
            "inside_68_tolerance": float(2.0 * np.sqrt(0.6827 * 0.3173 / n_eff))}


def leave_one_session_out(sessions, shrink=None):
    """Fit model (T) on all sessions but one, score the one left out; every session in turn.

    Parameters
    ----------
    sessions : dict
        Session name -> dict with ``features`` (:func:`measurement_features`), ``errors``
        (the held-out table: ``err_{dim}``, ``fold``) and optional ``sigma_px`` (per row or
        scalar, for the Cramer-Rao bound).
    shrink : None, "fit" or float
        Corner-noise shrinkage of every fit (:func:`fit_transfer_model`).

    Returns
    -------
    result : dict
        ``sessions``: name -> {``model`` (fitted without it), ``score``
        (:func:`score_transfer`)}; ``pooled_model`` (fitted on every session, the one to
        use on new data).

    Raises
    ------
    OptimiseError
        Fewer than two sessions.
    """
    names = list(sessions)
    if len(names) < 2:
        raise OptimiseError(f"leave_one_session_out: {len(names)} session(s); need at least 2")

    def stack(keep):
        f = pd.concat([sessions[n]["features"] for n in keep], ignore_index=True)
        e = pd.concat([sessions[n]["errors"] for n in keep], ignore_index=True)
        return f, e

    out = {"sessions": {}}
    for name in names:
        f, e = stack([n for n in names if n != name])
        model = fit_transfer_model(f, e, shrink)
        s = sessions[name]
        err = s["errors"].reset_index(drop=True)
        folds = err["fold"].to_numpy() if "fold" in err else None
        score = score_transfer(model, s["features"].reset_index(drop=True), err, folds,
                               s.get("sigma_px"))  # fmt: skip
        out["sessions"][name] = {"model": model, "score": score}
        log.info("LOSO %s: NEES %.2f, inside 95 %% %s", name, score["nees_mean"],
                 {d: round(v, 3) for d, v in score["inside_95"].items()})
    out["pooled_model"] = fit_transfer_model(*stack(names), shrink)
    return out


#: Model (T) fitted on the held-out frames of the five rendered sessions of
#: bench/uncertainty_sessions.yaml (1800 frames; five cameras, lenses, boards, distance ranges,
#: one rolling shutter), by ``PYTHONPATH=. .venv/bin/python bench/bench_uncertainty.py``
#: (``pooled_model``). Each of those sessions left out and predicted by the other four: NEES
#: 2.6-7.6, results/bench_uncertainty/loso.yaml and docs/findings.md.
RENDERED_TRANSFER_MODEL = {
    "kind": "T", "dims": list(ERROR_DIMS), "n_train": 1800, "s_rs_fitted": False,
    "s0_px": 0.01084, "s_speed": 4.987e-06, "s_reproj": 1.127, "c_cal": 1.011, "s_rs": 1.0,
    "b_pos_m": 8.242e-05, "b_rot_rad": 0.0001234, "b_fill_pos_m": 0.000779,
    "b_fill_rot_rad": 0.002943, "nu": 13.44,
}  # fmt: skip


def crossfit_transfer(features, errors, sigma_px=None):
    """Model (T) fitted on all time-block folds of a session but one, scored on the last.

    Parameters
    ----------
    features : DataFrame
        :func:`measurement_features` of the session's held-out rows.
    errors : DataFrame
        The held-out rows (``err_{dim}``, ``fold``).
    sigma_px : ndarray, optional
        Per-row corner noise for the Cramer-Rao bound.

    Returns
    -------
    score : dict
        Pooled ``n``, ``inside_68``, ``inside_95`` (per axis and ``_all``), ``nees_mean``,
        ``nees_inside_95``, ``z_rms``, ``model: T``, ``folds`` (per-fold
        :func:`score_covariance` with ``fold`` and the fold's ``params``).
    cov : ndarray, shape (N, 6, 6)
        Each row's covariance from the model that did not see its fold.
    mu : ndarray, shape (N, 6)
        Each row's predicted error (the rolling shutter's shear).
    """
    fold = errors["fold"].to_numpy().astype(int)
    cov = np.full((len(errors), 6, 6), np.nan)
    mu = np.full((len(errors), 6), np.nan)
    folds = []
    for k in np.unique(fold):
        train, test = fold != k, fold == k
        model = fit_transfer_model(features[train].reset_index(drop=True),
                                   errors[train].reset_index(drop=True))  # fmt: skip
        f_test = features[test].reset_index(drop=True)
        cov[test] = transfer_covariance(model, f_test)
        mu[test] = transfer_mean(model, f_test)
        s = score_covariance(cov[test], errors[test].reset_index(drop=True), nu=model["nu"],
                             mean=mu[test])  # fmt: skip
        s["fold"] = int(k)
        s["params"] = {n: model[n] for n in TRANSFER_PARAMS}
        folds.append(s)
    nu = float(np.median([f["params"]["nu"] for f in folds]))
    out = score_covariance(cov, errors, nu=nu, mean=mu)
    out.update(model="T", folds=folds)
    return out, cov, mu
