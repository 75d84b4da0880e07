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
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import minimize
from scipy.stats import chi2

from cvsflow import transforms as tf
from cvsflow.errors import OptimiseError
from cvsflow.evaluate import ERROR_DIMS, pose_errors

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


def error_features(frames, p_B, K, dist, sigma_px, frame="C"):
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


def predicted_covariance(model, features, cov_err=None):
    """Full 6x6 predicted error covariance per frame: D_i C_i D_i.

    Parameters
    ----------
    model : dict
    features : DataFrame
    cov_err : ndarray, shape (N, 6, 6), optional
        Propagated PnP error covariance; when given its per-frame correlation is C_i, else
        the model's training correlation of standardised errors.

    Returns
    -------
    cov : ndarray, shape (N, 6, 6)
    """
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
        1 and 1.96 predicted sigma); ``inside_68_all``, ``inside_95_all`` (pooled);
        ``nees_mean`` (mean of (e - mu)^T Cov^-1 (e - mu); 6 for a consistent model);
        ``nees_inside_95`` (share below the chi-square(6) 95 % quantile);
        ``z_rms`` per dimension (RMS of standardised errors; 1 when calibrated).
    """
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)
    sigma, mu = predict_error_sigma(model, features)
    Zs = (E - mu) / sigma
    out = {"n": int(len(E))}
    for band, k in BANDS.items():
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
