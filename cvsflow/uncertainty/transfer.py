"""Model (T): an error covariance from what is known when a frame is measured.

Fitted by maximum likelihood on the held-out frames of one or more sessions
(:func:`fit_transfer_model`), it predicts another session or a flight
(:func:`transfer_covariance`, :func:`transfer_mean`);
:mod:`cvsflow.uncertainty.transfer_scoring` scores it on frames it did not see. The inputs
are :func:`cvsflow.uncertainty.features.measurement_features`.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.optimize import minimize
from scipy.special import digamma, gammaln

from cvsflow.exceptions import OptimiseError
from cvsflow.metrics import ERROR_DIMS
from cvsflow.uncertainty.ambiguity import flip_weight
from cvsflow.uncertainty.features import (
    NOISE_POOL_COLUMN,
    corner_noise_from_reproj,
    corner_noise_pool,
    shrink_corner_noise,
    still_board_weight,
)
from cvsflow.uncertainty.propagation import cov_columns, cov_from_columns
from cvsflow.uncertainty.scoring import WORKING_UNITS

log = logging.getLogger(__name__)

#: Parameters of model (T), in the order of its vector (logs of positive scales).
TRANSFER_PARAMS = ("s0_px", "s_speed", "s_reproj", "c_cal", "s_rs", "b_pos_m", "b_rot_rad",
                   "b_fill_pos_m", "b_fill_rot_rad", "nu")


def _transfer_terms(features):
    """(U per px^2, P (N, 6, 6), RS shear error (N, 6), speed (N,), corner noise (N,), Vicon
    gap-filled (N,), C per px^2, the moving camera body's reference noise R (N, 6, 6), the
    planar PnP's flip (error if the other solution is true (N, 6), its cost excess px^2
    (N,)), the weight of U per px^2 of a still board's pose-like codec error (N,)), working
    units."""
    U = cov_from_columns(features, "unitcov")

    def block(name):
        has = all(c in features.columns for c in cov_columns(name))
        return cov_from_columns(features, name) if has else np.zeros_like(U)

    scale = 1.0 / np.outer(WORKING_UNITS, WORKING_UNITS)
    speed = features["speed_px"].to_numpy(float)
    reproj = corner_noise_from_reproj(features["reproj_rms_px"].to_numpy(float),
                                      features["n_corners"].to_numpy(float))
    rs_cols = [f"rs_err_{d}" for d in ERROR_DIMS]
    RS = (features[rs_cols].to_numpy(float) / WORKING_UNITS if all(c in features for c in rs_cols)
          else np.zeros((len(U), 6)))  # fmt: skip
    filled = (features["vicon_filled"].to_numpy(float) if "vicon_filled" in features
              else np.zeros(len(U)))  # fmt: skip
    flip_cols = [f"flip_{d}" for d in ERROR_DIMS]
    if all(c in features for c in flip_cols) and "flip_dssr_px2" in features:
        flip = features[flip_cols].to_numpy(float) / WORKING_UNITS
        d_ssr = features["flip_dssr_px2"].to_numpy(float)
    else:
        flip, d_ssr = np.zeros((len(U), 6)), np.full(len(U), np.inf)
    inter = (features["inter_coded"].to_numpy(float) if "inter_coded" in features
             else np.zeros(len(U)))  # fmt: skip
    still = still_board_weight(features["n_corners"].to_numpy(float), speed, inter)
    return (U * scale, block("parcov") * scale, RS, speed, reproj, filled,
            block("corrcov") * scale, block("refcov") * scale, (flip, d_ssr), still)


def _has_corr(features):
    return all(c in features.columns for c in cov_columns("corrcov"))


def _has_ref(features):
    return all(c in features.columns for c in cov_columns("refcov"))


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


def _transfer_cov(q, U, P, RS, speed, reproj, filled, C=None, R=None, flip=None, still=None,
                  shrink=None, s_corr=0.0, r_rs=0.0, c_ref=0.0, s_still=0.0):
    """Model (T) mean (N, 6) and covariance (N, 6, 6), working units; ``q`` of 11 entries
    (the last log k) with ``shrink`` = :func:`_shrink_terms` shrinks the corner noise;
    ``s_corr`` is the correlated share of the corner noise (its variance s_corr^2 sigma_px^2
    through ``C``, per px^2); ``r_rs`` the relative error of the shear's prediction (variance
    r_rs^2 mu mu^T); ``c_ref`` the scale of the moving camera body's reference noise ``R``;
    ``flip`` = (delta (N, 6), d_ssr (N,)) adds the planar PnP's two-solution mixture,
    ``w delta delta^T`` with ``w`` :func:`cvsflow.uncertainty.ambiguity.flip_weight` of the
    frame's corner variance (physics: no parameter of its own); ``s_still`` the pose-like
    error of a board the codec codes as still, as a share of the frame's corner noise
    sigma_px, through ``still`` (N,) (:func:`_transfer_terms`) times U."""
    s0, s_speed, s_reproj, c, s_rs, b_pos, b_rot, f_pos, f_rot, _ = _unpack_transfer(q)
    if len(q) > 10 and shrink is not None:
        reproj = shrink_corner_noise(reproj, shrink[0], shrink[1], np.exp(q[10]))
    var_px = s0**2 + (s_speed * speed) ** 2 + (s_reproj * reproj) ** 2
    floor = np.r_[np.full(3, b_pos), np.full(3, b_rot)] / WORKING_UNITS
    fill = np.r_[np.full(3, f_pos), np.full(3, f_rot)] / WORKING_UNITS
    S = (var_px[:, None, None] * U + c**2 * P + np.diag(floor**2)[None]
         + filled[:, None, None] * np.diag(fill**2)[None])  # fmt: skip
    if s_corr and C is not None:
        S = S + (s_corr**2 * var_px)[:, None, None] * C
    mu = s_rs * RS
    if r_rs:
        S = S + r_rs**2 * mu[:, :, None] * mu[:, None, :]
    if c_ref and R is not None:
        S = S + c_ref**2 * R
    if s_still and still is not None:
        S = S + (s_still**2 * still * var_px)[:, None, None] * U
    if flip is not None and np.isfinite(flip[1]).any():
        w = flip_weight(flip[1], var_px)
        S = S + w[:, None, None] * flip[0][:, :, None] * flip[0][:, None, :]
    return mu, S


def _transfer_nll(q, s_corr, E, terms, shrink=None, r_rs=0.0, c_ref=0.0, s_still=0.0):
    """Mean negative log-likelihood of model (T) and its analytic gradient.

    The frames' errors ``E`` (N, 6, working units) are multivariate Student-t with nu degrees
    of freedom and covariance S_i (:func:`_transfer_cov`), i.e. scale matrix S_i (nu-2)/nu:

        ll_i = lnG((nu+d)/2) - lnG(nu/2) - d/2 ln(pi (nu-2)) - 1/2 ln|S_i|
               - (nu+d)/2 ln(1 + m_i / (nu-2)),   m_i = r_i^T S_i^-1 r_i,  r_i = E_i - mu_i.

    With w_i = S_i^-1 r_i, d ll_i / d S_i = G_i = -S_i^-1 / 2 + (nu+d) w_i w_i^T / (2 (nu-2+m_i)),
    so a parameter moving S_i by dS_i moves ll_i by tr(G_i dS_i); every scale enters S_i as
    its square (d/d ln s of s^2 X is 2 s^2 X).

    Parameters
    ----------
    q : ndarray, shape (10,) or (11,)
        Logs of :data:`TRANSFER_PARAMS` (the last one log(nu - 2)), and log k of the shrinkage
        when ``shrink`` is given.
    s_corr : float
        Correlated share of the corner noise (0: no ``C`` term).
    E : ndarray, shape (N, 6)
    terms : tuple
        :func:`_transfer_terms` of the frames (the flip term last, or None).
    shrink : tuple, optional
        :func:`_shrink_terms` of the frames.
    r_rs : float
        Relative error of the shear's prediction (0: no such term).
    c_ref : float
        Scale of the moving camera body's reference noise (0: no such term).
    s_still : float
        A still board's pose-like codec error over the frame's corner noise (0: no such term).

    Returns
    -------
    nll : float
        -mean(ll_i); 1e30 where a covariance is not positive definite.
    grad_q : ndarray, shape of ``q``
        d nll / d q (zero where the covariance failed).
    grad_log_s_corr : float
        d nll / d ln s_corr.
    grad_log_r_rs : float
        d nll / d ln r_rs.
    grad_log_c_ref : float
        d nll / d ln c_ref.
    grad_log_s_still : float
        d nll / d ln s_still.
    """
    U, P, RS, speed, reproj, filled, C, R, flip, still = terms
    d = E.shape[1]
    s0, s_speed, s_reproj, c, s_rs, b_pos, b_rot, f_pos, f_rot, nu = _unpack_transfer(q)
    mu, S = _transfer_cov(q, U, P, RS, speed, reproj, filled, C, R, flip, still, shrink, s_corr,
                          r_rs, c_ref, s_still)
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return 1e30, np.zeros(len(q)), 0.0, 0.0, 0.0, 0.0
    L_inv = np.linalg.inv(L)
    S_inv = np.matmul(np.swapaxes(L_inv, 1, 2), L_inv)
    r = E - mu
    w = np.einsum("nij,nj->ni", S_inv, r)
    m = np.einsum("ni,ni->n", r, w)
    logdet = 2.0 * np.log(np.einsum("nii->ni", L)).sum(axis=1)
    ll = (gammaln((nu + d) / 2) - gammaln(nu / 2) - 0.5 * d * np.log(np.pi * (nu - 2.0))
          - 0.5 * logdet - 0.5 * (nu + d) * np.log1p(m / (nu - 2.0)))
    beta = (nu + d) / (nu - 2.0 + m)
    G = -0.5 * S_inv + (0.5 * beta)[:, None, None] * w[:, :, None] * w[:, None, :]
    tr_U = np.einsum("nij,nij->n", G, U)
    tr_P = np.einsum("nij,nij->n", G, P)
    use_corr = bool(s_corr) and C is not None
    tr_C = np.einsum("nij,nij->n", G, C) if use_corr else np.zeros(len(E))
    G_diag = np.einsum("nii->ni", G)
    n_px = reproj
    if len(q) > 10 and shrink is not None:
        n_px = shrink_corner_noise(reproj, shrink[0], shrink[1], np.exp(q[10]))
    var_px = s0**2 + (s_speed * speed) ** 2 + (s_reproj * n_px) ** 2
    use_still = bool(s_still) and still is not None
    still_gain = s_still**2 * still if use_still else 0.0
    tr_var = tr_U * (1.0 + still_gain) + s_corr**2 * tr_C  # d ll / d var_px
    if flip is not None and np.isfinite(flip[1]).any():
        # the flip weight w = 1 / (1 + exp(d_ssr / (2 var))) moves with the corner variance:
        # dw / dvar = w (1 - w) d_ssr / (2 var^2)
        w_flip = flip_weight(flip[1], var_px)
        dssr = np.where(np.isfinite(flip[1]), flip[1], 0.0)
        tr_flip = np.einsum("ni,nij,nj->n", flip[0], G, flip[0])
        tr_var = tr_var + tr_flip * w_flip * (1.0 - w_flip) * dssr / (2.0 * var_px**2)
    g = np.zeros(len(q))  # d mean(ll) / d q
    g[0] = np.mean(tr_var * 2.0 * s0**2)
    g[1] = np.mean(tr_var * 2.0 * (s_speed * speed) ** 2)
    g[2] = np.mean(tr_var * 2.0 * (s_reproj * n_px) ** 2)
    g[3] = np.mean(tr_P * 2.0 * c**2)
    # d ll / d ln r_rs per frame: S holds r_rs^2 mu mu^T, so tr(G 2 r_rs^2 mu mu^T)
    tr_rs = 2.0 * r_rs**2 * np.einsum("ni,nij,nj->n", mu, G, mu) if r_rs else np.zeros(len(E))
    # d ll / d ln s_rs: mu = s_rs RS moves the mean and, as s_rs^2, the shear's variance
    g[4] = np.mean(beta * np.einsum("ni,ni->n", w, mu) + tr_rs)
    inv_wu2 = 1.0 / WORKING_UNITS**2
    g_floor = 2.0 * np.mean(G_diag, axis=0) * inv_wu2
    g_fill = 2.0 * np.mean(filled[:, None] * G_diag, axis=0) * inv_wu2
    g[5], g[6] = b_pos**2 * g_floor[:3].sum(), b_rot**2 * g_floor[3:].sum()
    g[7], g[8] = f_pos**2 * g_fill[:3].sum(), f_rot**2 * g_fill[3:].sum()
    dll_dnu = (0.5 * digamma((nu + d) / 2) - 0.5 * digamma(nu / 2) - 0.5 * d / (nu - 2.0)
               - 0.5 * np.log1p(m / (nu - 2.0)) + 0.5 * (nu + d) * m / ((nu - 2.0) * (nu - 2.0 + m)))
    g[9] = (nu - 2.0) * np.mean(dll_dnu)
    if len(q) > 10 and shrink is not None:
        k = np.exp(q[10])
        dof = np.maximum(2.0 * shrink[0] - 6.0, 1.0)
        dn2_dlogk = k * dof * (shrink[1] ** 2 - reproj**2) / (dof + k) ** 2
        g[10] = np.mean(tr_var * s_reproj**2 * dn2_dlogk)
    g_corr = np.mean(tr_C * 2.0 * s_corr**2 * var_px) if use_corr else 0.0
    g_ref = np.mean(2.0 * c_ref**2 * np.einsum("nij,nij->n", G, R)) if c_ref and R is not None else 0.0
    g_still = np.mean(tr_U * 2.0 * still_gain * var_px) if use_still else 0.0
    return (-float(np.mean(ll)), -g, -float(g_corr), -float(np.mean(tr_rs)), -float(g_ref),
            -float(g_still))


def fit_transfer_model(features, errors, shrink=None, still=True, start=None):
    """Fit model (T) by maximum likelihood on frames of one or more sessions.

    Model (T), per frame i (what is known when it is measured):

        sigma_px,i^2 = s0^2 + (s_speed v_i)^2 + (s_reproj n_i)^2
        mu_i = s_rs r_i
        Sigma_i = sigma_px,i^2 U_i + c_cal^2 P_i + diag(b_pos^2 I3, b_rot^2 I3)
                  + f_i diag(b_fill_pos^2 I3, b_fill_rot^2 I3) [+ s_corr^2 sigma_px,i^2 C_i]
                  [+ r_rs^2 mu_i mu_i^T] [+ c_ref^2 R_i]
                  [+ s_still^2 sigma_px,i^2 (n_i / 3) / (1 + (v_i / v_still)^2) U_i]

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
    the rigid fit). When the features carry ``corrcov`` (:func:`measurement_features` with
    ``corr_length_px``), C_i is the PnP error covariance per px^2 of a corner noise correlated
    between corners (a video codec's shared error: one PnP absorbs into the pose, so n_i
    does not show it), whose standard deviation is the share s_corr of the frame's corner
    noise sigma_px,i (on the rendered sessions' true corner errors the common shift is
    0.15-0.18 of the iid noise), fitted too; else the term is absent. When some frame has a
    shear (a fitted line delay), r_rs is the relative error of its prediction: the line
    delay's error and the corner velocities' (finite differences of the track) scale the
    whole shear, so the term is rank one along mu_i (on the three rolling-shutter renders of
    config/realistic.yaml the held-out error left after mu_i was 0.07-0.18 of |mu_i| and the
    z-scores of the frames with the largest shear 1.1-1.7); bounded by 1. When the features
    carry ``refcov`` (a moving camera body, :mod:`cvsflow.uncertainty.reference_noise`), R_i
    is the reference noise that body's own pose noise puts into the error (its rotation noise
    times the board's distance) and c_ref its scale (1 in physics; fitted, bounded by 3).
    When some frame is ``inter_coded`` (a motion-compensated video), s_still is the pose-like
    error of a board the codec codes as still (v_i well under v_still =
    :data:`cvsflow.uncertainty.features.STILL_SPEED_PX`: its blocks copied from the last
    frame, so every corner errs by
    the same small motion, which PnP takes for a pose change and n_i does not show), as a
    share of sigma_px,i: a pose-like error of s px moves the pose as iid noise of
    s sqrt(n_i / 3) px does (on the rendered sessions' MPEG-4 video a still board's
    PnP-absorbed corner error is 0.16-0.36 of the total against 0.07-0.15 for iid noise, a
    moving one's as iid; bounded by 3).
    The errors are multivariate Student-t with nu > 2 degrees of freedom and covariance
    Sigma_i. Every scale is in
    physical units shared by all cameras and boards (px, dimensionless, m, rad), so the model
    fitted on some sessions predicts another. L-BFGS-B maximises the likelihood from two
    starts with its analytic gradient (:func:`_transfer_nll`), to ftol 1e-12 and gtol 1e-9.

    Parameters
    ----------
    features : DataFrame
        :func:`measurement_features` of the training frames (``unitcov``, optional ``parcov``).
    errors : DataFrame
        The same frames' ``err_{dim}`` (CVS - reference, :func:`cvsflow.evaluate.heldout.pose_errors`).
    shrink : None, "fit" or float
        None: n_i as measured. Otherwise n_i is replaced by :func:`shrink_corner_noise`
        toward the pooled noise (column :data:`NOISE_POOL_COLUMN`, else the median over the
        rows) with prior strength k: fitted (``"fit"``) or the given value.
    still : bool
        Fit the still-board codec term s_still where some frame is ``inter_coded``.
    start : dict, optional
        A model fitted on frames including these (a session's, for its folds): one start
        from it instead of two fixed ones; a fold's optimum lies near it.

    Returns
    -------
    model : dict
        ``kind: T``, ``dims``, one entry per :data:`TRANSFER_PARAMS` (px, -, -, -, -, m, rad,
        -),
        ``nll`` (mean per frame), ``n_train``; with ``shrink`` also ``k_shrink``; with
        ``corrcov`` features also ``s_corr`` (-); with a shear in some frame also ``r_rs``
        (-); with ``refcov`` features also ``c_ref`` (-); with inter-coded frames (and
        ``still``) also ``s_still`` (-); with the
        :data:`BOARD_NOISE_COLUMNS` also ``board_noise`` (their medians: the scale of the
        floors, :func:`_floors_for`).

    Raises
    ------
    OptimiseError
        Missing columns, fewer than 20 frames or non-finite data.
    """
    cols = [f"err_{d}" for d in ERROR_DIMS]
    missing = [c for c in cols if c not in errors.columns]
    missing += [c for c in [*cov_columns("unitcov"), "speed_px", "reproj_rms_px", "n_corners"]
                if c not in features.columns]  # fmt: skip
    if missing:
        raise OptimiseError(f"fit_transfer_model: missing columns {missing}")
    E = errors[cols].to_numpy(float) / WORKING_UNITS
    U, P, RS, speed, reproj, filled, C, R, flip, still_w = _transfer_terms(features)
    # a still board's codec term where some frame is inter-coded
    fit_still = bool(still) and bool(np.any(still_w > 0))
    fit_corr = _has_corr(features)
    fit_rrs = bool(np.any(RS != 0.0))
    fit_ref = _has_ref(features)
    if len(E) != len(U) or len(E) < 20:
        raise OptimiseError(
            f"fit_transfer_model: {len(E)} error rows and {len(U)} feature rows; need equal, >= 20"
        )
    if not (np.isfinite(E).all() and np.isfinite(U).all() and np.isfinite(P).all()):
        raise OptimiseError("fit_transfer_model: non-finite errors or covariances")
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

    # log s_corr, log r_rs, log c_ref, log s_still after the model's entries, those fitted
    n_extra = int(fit_corr) + int(fit_rrs) + int(fit_ref) + int(fit_still)

    def full(q):
        q = q[:len(q) - n_extra]
        q = q if fit_rs else np.r_[q[:4], 0.0, q[4:]]
        return np.r_[q, k_fixed]

    def extras(x):
        tail = list(np.exp(x[len(x) - n_extra:]))
        s_corr = float(tail.pop(0)) if fit_corr else 0.0
        r_rs = float(tail.pop(0)) if fit_rrs else 0.0
        c_ref = float(tail.pop(0)) if fit_ref else 0.0
        s_still = float(tail.pop(0)) if fit_still else 0.0
        return s_corr, r_rs, c_ref, s_still

    terms = (U, P, RS, speed, reproj, filled, C, R, flip, still_w)
    # which entries of the full vector (10 or 11) the optimiser moves, in its order
    free = [i for i in range(10) if fit_rs or i != 4] + ([10] if fit_k else [])

    def nll(x):
        s_corr, r_rs, c_ref, s_still = extras(x)
        f, g_q, g_corr, g_rrs, g_ref, g_still = _transfer_nll(full(x), s_corr, E, terms, sh, r_rs,
                                                              c_ref, s_still)
        g = g_q[free]
        g = np.r_[g, g_corr] if fit_corr else g
        g = np.r_[g, g_rrs] if fit_rrs else g
        g = np.r_[g, g_ref] if fit_ref else g
        return f, (np.r_[g, g_still] if fit_still else g)

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
    if fit_corr:
        bounds.append((-25, 5))
        starts = [np.r_[x, np.log(0.15)] for x in starts]
    if fit_rrs:
        bounds.append((-25, 0))
        starts = [np.r_[x, np.log(0.1)] for x in starts]
    if fit_ref:
        bounds.append((-25, np.log(3.0)))
        starts = [np.r_[x, 0.0] for x in starts]
    if fit_still:
        bounds.append((-25, np.log(3.0)))
        starts = [np.r_[x, np.log(0.3)] for x in starts]
    if start is not None:
        starts = [_x_from_model(start, starts[0], keep, fit_k,
                                [("s_corr", fit_corr), ("r_rs", fit_rrs), ("c_ref", fit_ref),
                                 ("s_still", fit_still)], bounds)]
    for x_start in starts:
        sol = minimize(nll, x_start, jac=True, method="L-BFGS-B", bounds=bounds,
                       options={"maxiter": 500, "ftol": 1e-12, "gtol": 1e-9})
        if best is None or sol.fun < best.fun:
            best = sol
    q_best = full(best.x)
    vals = _unpack_transfer(q_best)
    model = {"kind": "T", "dims": list(ERROR_DIMS), "n_train": int(len(E)),
             "nll": float(best.fun), "s_rs_fitted": fit_rs}
    model.update({name: float(v) for name, v in zip(TRANSFER_PARAMS, vals, strict=True)})
    if shrink is not None:
        model["k_shrink"] = float(np.exp(q_best[10]))
    s_corr, r_rs, c_ref, s_still = extras(best.x)
    if fit_still:
        model["s_still"] = s_still
    if fit_corr:
        model["s_corr"] = s_corr
    if fit_rrs:
        model["r_rs"] = r_rs
    if fit_ref:
        model["c_ref"] = c_ref
    noise = board_noise_of(features)
    if noise is not None:
        model["board_noise"] = noise
    return model


def _x_from_model(model, x_default, keep, fit_k, extras, bounds):
    """:func:`fit_transfer_model`'s optimiser vector at a fitted ``model`` (its free entries,
    log k, the optional terms fitted; ``x_default`` where the model lacks one), in ``bounds``."""
    x = list(_q_from_model({**model, "k_shrink": None})[keep])
    for name, fitted in [("k_shrink", fit_k), *extras]:
        if fitted:
            x.append(np.log(model[name]) if model.get(name) else x_default[len(x)])
    lo, hi = np.array(bounds, float).T
    return np.clip(np.asarray(x, float), lo, hi)


def _q_from_model(model):
    v = [model[n] for n in TRANSFER_PARAMS]
    q = np.r_[np.log(v[:9]), np.log(v[9] - 2.0)]
    k = model.get("k_shrink")
    return q if k is None else np.r_[q, np.log(max(float(k), 1e-12))]


#: Per-session columns of :func:`measurement_features` (with ``bodies``): the board body's
#: own pose noise, rotation (rad) and the position noise it and the lever to the board's
#: origin give (m), over the reference's smoothing.
BOARD_NOISE_COLUMNS = ("board_noise_rot_rad", "board_noise_pos_m")
_FLOORS = {"board_noise_pos_m": ("b_pos_m", "b_fill_pos_m"),
           "board_noise_rot_rad": ("b_rot_rad", "b_fill_rot_rad")}


def board_noise_of(features):
    """The board body's noise of a set of frames.

    Parameters
    ----------
    features : DataFrame
        :func:`measurement_features` rows (with ``bodies``: the :data:`BOARD_NOISE_COLUMNS`).

    Returns
    -------
    dict or None
        Each of :data:`BOARD_NOISE_COLUMNS` to its median over the rows; None without them.
    """
    if not all(c in features.columns for c in BOARD_NOISE_COLUMNS):
        return None
    return {c: float(np.median(features[c].to_numpy(float))) for c in BOARD_NOISE_COLUMNS}


def _floors_for(model, features):
    """The model with its reference floors scaled to the scored frames' board noise.

    The floors b_pos, b_rot (and the gap-filled ones) are the Vicon board body's own noise:
    fitted on sessions of one mocap they are that mocap's. A model that records the board
    noise of its training frames (``board_noise``) scales them by the scored frames' over
    it: 0.3 mm markers gave 0.086 mm / 0.135 mrad and floors of 0.082 mm / 0.123 mrad; 1 mm
    markers 0.27 mm / 0.43 mrad and within-session floors of 0.19-0.22 mm / 0.38-0.43 mrad.
    Frames of the training session itself get the floors unchanged (the ratio is exactly 1).
    """
    ref, now = model.get("board_noise"), board_noise_of(features)
    if not ref or now is None:
        return model
    out = dict(model)
    for col, names in _FLOORS.items():
        ratio = now[col] / ref[col]
        for n in names:
            out[n] = model[n] * ratio
    return out


def _model_terms(model, features):
    """(q, terms, options) of a fitted model on the given frames: what :func:`_transfer_cov`
    and :func:`_transfer_nll` take, the floors scaled to the frames' board noise."""
    model = _floors_for(model, features)
    s_corr = float(model.get("s_corr") or 0.0)
    if s_corr and not _has_corr(features):
        raise OptimiseError("model (T) has s_corr but the features lack corrcov columns "
                            "(measurement_features(corr_length_px=...))")
    options = {
        "shrink": _shrink_terms(features) if model.get("k_shrink") is not None else None,
        "s_corr": s_corr,
        "r_rs": float(model.get("r_rs") or 0.0),
        # a model fitted without a moving camera scores one with the physical scale, 1
        "c_ref": float(model.get("c_ref", 1.0)) if _has_ref(features) else 0.0,
        "s_still": float(model.get("s_still") or 0.0),
    }
    return _q_from_model(model), _transfer_terms(features), options


def _model_cov(model, features):
    q, terms, options = _model_terms(model, features)
    return _transfer_cov(q, *terms, **options)


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
    return S * np.outer(WORKING_UNITS, WORKING_UNITS)


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
    return mu * WORKING_UNITS


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
    # the board body's noise of those sessions (medians of measurement_features' columns;
    # added after the fit, which had no such columns): the scale of the floors
    "board_noise": {"board_noise_rot_rad": 1.3362e-04, "board_noise_pos_m": 8.548e-05},
}  # fmt: skip
