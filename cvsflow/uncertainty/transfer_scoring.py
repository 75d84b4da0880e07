"""Model (T) scored on frames it did not see: per session and fold (:func:`score_transfer`,
with the lag-1 autocorrelation and the AR(1)-whitened scores), leave-one-session-out
(:func:`leave_one_session_out`) and within one session across its time-block folds
(:func:`crossfit_transfer`). The model itself is :mod:`cvsflow.uncertainty.transfer`.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow.exceptions import OptimiseError
from cvsflow.metrics import ERROR_DIMS
from cvsflow.uncertainty.crb import cramer_rao_sigma
from cvsflow.uncertainty.scoring import (
    WORKING_UNITS,
    fit_ar1,
    frame_runs,
    score_covariance,
    score_time_correlated,
    standardised_errors,
)
from cvsflow.uncertainty.transfer import (
    TRANSFER_PARAMS,
    _model_terms,
    _transfer_nll,
    fit_transfer_model,
    transfer_covariance,
    transfer_mean,
)

log = logging.getLogger(__name__)


def _autocorr_lag1(z, fold):
    """Lag-1 autocorrelation of standardised errors z (N, 6) within each fold's runs."""
    same = fold[1:] == fold[:-1]
    a, b = z[:-1][same], z[1:][same]
    return np.sum(a * b, axis=0) / np.sqrt(np.sum(a * a, axis=0) * np.sum(b * b, axis=0))


def score_transfer(model, features, errors, folds=None, sigma_px=None, ar1_rho=None):
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
    ar1_rho : array_like, shape (6,), optional
        AR(1) coefficient per axis of the standardised errors, fitted on other frames
        (:func:`time_correlation_of`); adds ``ar1``, the time-correlated scores
        (:func:`cvsflow.uncertainty.scoring.score_time_correlated`, runs of consecutive
        ``frame`` within a fold) of the session, and ``ar1`` in each fold's score.

    Returns
    -------
    score : dict
        :func:`score_covariance` keys, ``lag1_autocorr`` per axis (of the errors standardised
        by their predicted sigma, within folds), ``folds`` (list of per-fold scores with
        ``fold``), with ``sigma_px`` the CRB keys and with ``ar1_rho`` the ``ar1`` scores.
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
    runs = _runs(errors, fold) if ar1_rho is not None else None
    if ar1_rho is not None:
        out["ar1"] = score_time_correlated(cov, errors, ar1_rho, runs, nu=model["nu"], mean=mu)
    if folds is not None:
        for k in np.unique(fold):
            sel = fold == k
            err_k = errors[sel].reset_index(drop=True)
            s = score_covariance(cov[sel], err_k, nu=model["nu"], mean=mu[sel])
            s["fold"] = int(k)
            s.update(_sampling_band(int(sel.sum()), rho))
            if ar1_rho is not None:
                s["ar1"] = score_time_correlated(cov[sel], err_k, ar1_rho, runs[sel],
                                                 nu=model["nu"], mean=mu[sel])  # fmt: skip
            out["folds"].append(s)
    return out


def _runs(errors, fold):
    """Runs of consecutive frames within a fold (rows in order; all one run per fold without
    a ``frame`` column)."""
    frame = errors["frame"].to_numpy() if "frame" in errors else np.arange(len(errors))
    return frame_runs(frame, fold)


def time_correlation_of(model, features, errors):
    """AR(1) coefficient per axis of the errors standardised by model (T), within runs.

    Parameters
    ----------
    model : dict
        :func:`fit_transfer_model` output.
    features, errors : DataFrame
        :func:`measurement_features` and the held-out rows (``err_{dim}``, optional
        ``frame``, ``fold`` and ``session``: a run is consecutive frames of one fold of one
        session) of the frames to fit it on, usually the model's own training frames.

    Returns
    -------
    rho : ndarray, shape (6,)
        :func:`cvsflow.uncertainty.scoring.fit_ar1` of ``ERROR_DIMS``, dimensionless.
    """
    z = standardised_errors(transfer_covariance(model, features), errors,
                            transfer_mean(model, features))  # fmt: skip
    fold = errors["fold"].to_numpy().astype(int) if "fold" in errors else np.zeros(len(z), int)
    if "session" in errors:
        # a session change breaks a run like a fold change does
        fold = fold + 1000 * pd.factorize(errors["session"])[0]
    return fit_ar1(z, _runs(errors, fold))


def _sampling_band(n, rho):
    """How far a calibrated model's shares of n frames scatter when the standardised errors
    have lag-1 autocorrelation rho (AR(1)): ``n_effective`` = n (1 - rho) / (1 + rho) and the
    2-sigma binomial half-widths ``inside_95_tolerance``, ``inside_68_tolerance``."""
    n_eff = max(n * (1.0 - rho) / (1.0 + rho), 1.0)
    return {"n_effective": float(n_eff), "lag1_mean": float(rho),
            "inside_95_tolerance": float(2.0 * np.sqrt(0.95 * 0.05 / n_eff)),
            "inside_68_tolerance": float(2.0 * np.sqrt(0.6827 * 0.3173 / n_eff))}


def leave_one_session_out(sessions, shrink=None, time_correlation=False):
    """Fit model (T) on all sessions but one, score the one left out; every session in turn.

    Parameters
    ----------
    sessions : dict
        Session name -> dict with ``features`` (:func:`measurement_features`), ``errors``
        (the held-out table: ``err_{dim}``, ``fold``) and optional ``sigma_px`` (per row or
        scalar, for the Cramer-Rao bound).
    shrink : None, "fit" or float
        Corner-noise shrinkage of every fit (:func:`fit_transfer_model`).
    time_correlation : bool
        Also fit the AR(1) of the standardised errors on the training sessions
        (:func:`time_correlation_of`, the model's ``ar1_rho``) and score the session left out
        whitened by it (``ar1`` in its score and in each fold's, :func:`score_transfer`).

    Returns
    -------
    result : dict
        ``sessions``: name -> {``model`` (fitted without it), ``score``
        (:func:`score_transfer`)}; ``pooled_model`` (fitted on every session, the one to
        use on new data; with ``time_correlation`` its ``ar1_rho`` too).

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
        e = pd.concat([sessions[n]["errors"].assign(session=n) for n in keep], ignore_index=True)
        return f, e

    def fit(keep):
        f, e = stack(keep)
        model = fit_transfer_model(f, e, shrink)
        if time_correlation:
            model["ar1_rho"] = [float(v) for v in time_correlation_of(model, f, e)]
        return model

    out = {"sessions": {}}
    for name in names:
        model = fit([n for n in names if n != name])
        s = sessions[name]
        err = s["errors"].reset_index(drop=True)
        folds = err["fold"].to_numpy() if "fold" in err else None
        score = score_transfer(model, s["features"].reset_index(drop=True), err, folds,
                               s.get("sigma_px"), model.get("ar1_rho"))  # fmt: skip
        out["sessions"][name] = {"model": model, "score": score}
        log.info("LOSO %s: NEES %.2f, inside 95 %% %s", name, score["nees_mean"],
                 {d: round(v, 3) for d, v in score["inside_95"].items()})
    out["pooled_model"] = fit(names)
    return out


def transfer_nll(model, features, errors):
    """Mean negative log-likelihood per frame of frames' errors under a fitted model (T).

    The proper score of the model on frames it did not see (lower is better), in nats: the
    likelihood :func:`fit_transfer_model` maximises, Student-t with the model's nu.

    Parameters
    ----------
    model : dict
        :func:`fit_transfer_model` output.
    features : DataFrame
        :func:`measurement_features` of the frames, as for :func:`transfer_covariance`.
    errors : DataFrame
        The same frames' ``err_{dim}`` (m, rad).

    Returns
    -------
    float
    """
    q, terms, o = _model_terms(model, features)
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float) / WORKING_UNITS
    return _transfer_nll(q, o["s_corr"], E, terms, o["shrink"], o["r_rs"], o["c_ref"],
                         o["s_still"])[0]


def crossfit_transfer(features, errors, sigma_px=None, start=None):
    """Model (T) fitted on all time-block folds of a session but one, scored on the last.

    Parameters
    ----------
    features : DataFrame
        :func:`measurement_features` of the session's held-out rows.
    errors : DataFrame
        The held-out rows (``err_{dim}``, ``fold``).
    sigma_px : ndarray, optional
        Per-row corner noise for the Cramer-Rao bound.
    start : dict, optional
        The model fitted on all the rows (:func:`fit_transfer_model`): each fold's fit starts
        from it (its ``start``), about a third of the evaluations of two fixed starts.

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
                                   errors[train].reset_index(drop=True), start=start)  # fmt: skip
        f_test = features[test].reset_index(drop=True)
        cov[test] = transfer_covariance(model, f_test)
        mu[test] = transfer_mean(model, f_test)
        s = score_covariance(cov[test], errors[test].reset_index(drop=True), nu=model["nu"],
                             mean=mu[test])  # fmt: skip
        s["fold"] = int(k)
        s["params"] = {n: model[n] for n in TRANSFER_PARAMS}
        # the optional terms the fit had (the demo's global shutter: none)
        s["params"].update({n: model[n] for n in ("k_shrink", "s_corr", "r_rs", "c_ref",
                                                  "s_still") if n in model})
        folds.append(s)
    nu = float(np.median([f["params"]["nu"] for f in folds]))
    out = score_covariance(cov, errors, nu=nu, mean=mu)
    out.update(model="T", folds=folds)
    return out, cov, mu
