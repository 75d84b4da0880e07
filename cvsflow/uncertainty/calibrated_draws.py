"""How often a calibrated error model meets coverage targets on short, time-correlated samples.

The uncertainty issue's targets are statistics of one held-out session or fold: NEES mean in
[4.5, 7.5], 93-97 % of each axis inside the 95 % band, 64-72 % inside the 68 % band. A fold
holds about 60 frames whose errors are correlated in time, so a model whose every stated
distribution is exactly right still misses some of them: the share inside a 95 % band of 60
independent frames is in [0.93, 0.97] with probability 0.58. :func:`draw_calibrated_errors`
draws errors from a model's own statement (each frame's covariance and predicted error,
Student-t with ``nu``, correlated in time within runs as the real errors are: an AR(1) or
their measured autocorrelation, :func:`autocorrelation`), and :func:`target_pass_rates` scores
many such draws as the real errors are scored. The number of targets a right model meets is
the yardstick for the number met.
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammaln

from cvsflow.exceptions import OptimiseError
from cvsflow.metrics import ERROR_DIMS
from cvsflow.uncertainty.scoring import WORKING_UNITS, band_multipliers

#: The uncertainty issue's targets for a held-out session or fold (closed intervals).
TARGETS = {"nees": (4.5, 7.5), "inside_95": (0.93, 0.97), "inside_68": (0.64, 0.72)}


def autocorrelation(z, runs, max_lag):
    """Autocorrelation per axis of standardised errors at lags 1..max_lag, within runs.

    Parameters
    ----------
    z : ndarray, shape (N, 6)
        Standardised errors (:func:`cvsflow.uncertainty.scoring.standardised_errors`).
    runs : ndarray, shape (N,)
        :func:`cvsflow.uncertainty.scoring.frame_runs` of the rows.
    max_lag : int
        Frames.

    Returns
    -------
    acf : ndarray, shape (max_lag, 6)
        Row k-1: the mean of z_t z_{t+k} over pairs k frames apart in one run, over the mean
        of z^2 (about zero, as ``fit_ar1``); 0 at lags no run is long enough for.
    """
    z = np.asarray(z, float)
    runs = np.asarray(runs)
    power = np.mean(z * z, axis=0)
    acf = np.zeros((int(max_lag), z.shape[1]))
    for k in range(1, int(max_lag) + 1):
        same = runs[k:] == runs[:-k]
        if not same.any():
            break
        acf[k - 1] = np.mean(z[k:][same] * z[:-k][same], axis=0) / power
    return acf


def _acf_of(time_correlation, max_lag):
    """Autocorrelation (max_lag, 6) at lags 1..max_lag: an AR(1) coefficient (scalar or (6,))
    gives rho^k; an array (K, 6) is taken as given (0 beyond K)."""
    tc = np.asarray(time_correlation, float)
    if tc.ndim < 2:
        rho = np.broadcast_to(tc, (6,))
        return rho[None, :] ** np.arange(1, max_lag + 1)[:, None]
    out = np.zeros((max_lag, 6))
    k = min(max_lag, len(tc))
    out[:k] = tc[:k]
    return out


def _whitened_draws(n_draws, runs, acf, rng):
    """Standard normal draws (n_draws, N, 6), stationary within each run with autocorrelation
    ``acf`` (K, 6) at lags 1..K per component (a run starts afresh; a correlation the run's
    length cannot hold positive definite is pulled to the nearest one that can)."""
    runs = np.asarray(runs)
    eps = rng.standard_normal((n_draws, len(runs), 6))
    g = np.empty_like(eps)
    starts = np.flatnonzero(np.r_[True, runs[1:] != runs[:-1]])
    ends = np.r_[starts[1:], len(runs)]
    factors = {}
    for a, b in zip(starts, ends, strict=True):
        m = int(b - a)
        if m not in factors:
            lags = np.abs(np.arange(m)[:, None] - np.arange(m)[None, :])
            L = []
            for j in range(6):
                r = np.r_[1.0, acf[: m - 1, j], np.zeros(max(0, m - 1 - len(acf)))]
                T = r[lags]
                w, V = np.linalg.eigh(T)
                T = (V * np.maximum(w, 1e-9)) @ V.T
                d = np.sqrt(np.diag(T))
                L.append(np.linalg.cholesky(T / np.outer(d, d)))
            factors[m] = L
        for j, L in enumerate(factors[m]):
            g[:, a:b, j] = eps[:, a:b, j] @ L.T
    return g


def draw_calibrated_errors(cov, mean, nu, time_correlation, runs, n_draws, rng):
    """Errors drawn from an error model's own statement.

    Parameters
    ----------
    cov : ndarray, shape (N, 6, 6)
        Each frame's predicted error covariance, SI (m, rad).
    mean : ndarray, shape (N, 6) or None
        Each frame's predicted error (the bands' centres), SI; None: zero.
    nu : float or None
        Student-t degrees of freedom (> 2): each frame's error is its covariance's normal
        draw times sqrt((nu - 2) / chi2(nu)), independent from frame to frame, so ``cov`` is
        its covariance. None or inf: normal.
    time_correlation : float, array_like (6,) or ndarray (K, 6)
        Correlation in time of the whitened error's components within runs, as measured on
        errors (``fit_ar1``, :func:`autocorrelation`): an AR(1) coefficient (scalar or per
        component, in [0, 1), the model's ``ar1_rho``; 0 for independent frames) or the
        autocorrelation at lags 1..K.
    runs : array_like, shape (N,)
        :func:`cvsflow.uncertainty.scoring.frame_runs` of the frames.
    n_draws : int
        Independent draws of the whole sequence.
    rng : numpy.random.Generator

    Returns
    -------
    errors : ndarray, shape (n_draws, N, 6)
        SI, in ``ERROR_DIMS`` order.

    Notes
    -----
    The time correlation acts on the components of ``L^-1 e`` (``cov = L L^T``, Cholesky in
    working units), which equal the per-axis standardised errors for a diagonal covariance
    and mix them otherwise; for the targets' statistics the difference is of second order.
    """
    cov = np.asarray(cov, float)
    runs = np.asarray(runs)
    L = np.linalg.cholesky(cov / np.outer(WORKING_UNITS, WORKING_UNITS))
    longest = int(np.max(np.unique(runs, return_counts=True)[1])) if len(runs) else 1
    acf = _acf_of(time_correlation, max(longest - 1, 1))
    t = nu is not None and np.isfinite(nu)
    if t:
        # The frame's scale s = sqrt((nu - 2) / chi2(nu)), independent in time, lowers the
        # draws' autocorrelation to acf E[s]^2 / E[s^2] (E[s^2] = 1): the normal part gets
        # acf over that, so the draws have the correlation measured on errors.
        mean_s = np.exp(0.5 * np.log((nu - 2.0) / 2.0) + gammaln((nu - 1.0) / 2.0)
                        - gammaln(nu / 2.0))
        acf = np.minimum(acf / mean_s**2, 0.99)
    g = _whitened_draws(int(n_draws), runs, acf, rng)
    if t:
        g = g * np.sqrt((nu - 2.0) / rng.chisquare(nu, size=g.shape[:2]))[..., None]
    e = np.einsum("nij,dnj->dni", L, g) * WORKING_UNITS
    return e if mean is None else e + np.asarray(mean, float)


def _group_scores(E, cov, mean, nu, rows):
    """NEES mean and per-axis shares inside the 68 and 95 % bands of draws E (D, N, 6) on the
    frames ``rows`` (bool, N): arrays (D,), (D, 6), (D, 6)."""
    k = band_multipliers({"nu": nu})
    e = E[:, rows] - (0.0 if mean is None else mean[rows])
    S = cov[rows] / np.outer(WORKING_UNITS, WORKING_UNITS)
    r = e / WORKING_UNITS
    S_inv = np.linalg.inv(S)
    nees = np.einsum("dni,nij,dnj->dn", r, S_inv, r).mean(axis=1)
    z = np.abs(r) / np.sqrt(np.einsum("nii->ni", S))
    return nees, (z <= k["95"]).mean(axis=1), (z <= k["68"]).mean(axis=1)


def _met(nees, in95, in68, targets):
    """Targets met per draw (D,): 1 NEES and 6 axes x 2 bands, as the bench counts them."""
    def inside(v, lim):
        return (v >= lim[0]) & (v <= lim[1])
    return (inside(nees, targets["nees"]).astype(int)
            + inside(in95, targets["inside_95"]).sum(axis=1)
            + inside(in68, targets["inside_68"]).sum(axis=1))


def _scaled(E, mean, k):
    """Draws ``E`` with their spread about the stated ``mean`` (None: zero) times ``k``."""
    return E * k if mean is None else (E - mean) * k + mean


def target_pass_rates(cov, mean, nu, time_correlation, runs, folds=None, n_draws=400, seed=0,
                      targets=None, scale_sd=0.0, fold_scale_sd=0.0):
    """How often a model that is exactly right meets the targets on these frames.

    Parameters
    ----------
    cov, mean, nu, time_correlation, runs
        As :func:`draw_calibrated_errors`: the model's statement for the held-out frames and
        the time correlation of their errors.
    folds : array_like, shape (N,), optional
        The time-block fold of each frame: the targets are counted for the whole set and for
        each fold, as the leave-one-session-out bench counts them. None: the whole set only.
    n_draws : int
        Monte Carlo draws.
    seed : int
        Of the draws' generator.
    targets : dict, optional
        Default :data:`TARGETS`.
    scale_sd : float
        A model right only up to one unknown scale of the whole set: each draw's errors about
        the stated mean are multiplied by ``exp(scale_sd z / 2)``, z standard normal, i.e. the
        variance by a log-normal factor of log-sd ``scale_sd`` (what a model fitted on other
        sessions has, :func:`session_scale_sd`). 0: exactly right.
    fold_scale_sd : float
        The same for each fold on its own, on top (a model right about a session on average
        but not about each stretch of it: a board held still, the farthest views). Needs
        ``folds``.

    Returns
    -------
    rates : dict
        ``n_targets``; ``met_per_draw`` (ndarray (n_draws,): targets met by each draw, for
        summing over sessions); ``nees_per_draw`` (ndarray (n_draws,): the whole set's NEES
        mean in each draw); ``expected_met`` and ``sd_met``; ``groups``: per group
        (``"all"``, then each fold) ``n`` and the probability of meeting each target,
        ``nees`` and ``inside_95`` / ``inside_68`` per axis.
    """
    targets = TARGETS if targets is None else targets
    cov = np.asarray(cov, float)
    mean = None if mean is None else np.asarray(mean, float)
    rng = np.random.default_rng(seed)
    E = draw_calibrated_errors(cov, mean, nu, time_correlation, runs, n_draws, rng)
    if scale_sd:
        E = _scaled(E, mean, np.exp(0.5 * float(scale_sd) * rng.standard_normal(int(n_draws)))[:, None, None])
    groups = [("all", np.ones(len(cov), bool))]
    if folds is not None:
        folds = np.asarray(folds)
        groups += [(int(k), folds == k) for k in np.unique(folds)]
    if fold_scale_sd:
        if folds is None:
            raise OptimiseError("target_pass_rates: fold_scale_sd needs the frames' folds")
        k = np.ones((int(n_draws), len(cov), 1))
        for _, rows in groups[1:]:
            k[:, rows] = np.exp(0.5 * float(fold_scale_sd) * rng.standard_normal(int(n_draws)))[:, None, None]
        E = _scaled(E, mean, k)
    met = np.zeros(int(n_draws), int)
    out_groups, group_nees = [], []
    for name, rows in groups:
        nees, in95, in68 = _group_scores(E, cov, mean, nu, rows)
        group_nees.append(nees)
        met += _met(nees, in95, in68, targets)
        lo, hi = targets["nees"]
        out_groups.append({
            "group": name, "n": int(rows.sum()),
            "nees": float(np.mean((nees >= lo) & (nees <= hi))),
            **{f"inside_{b}": {d: float(np.mean((v[:, j] >= targets[f"inside_{b}"][0])
                                                 & (v[:, j] <= targets[f"inside_{b}"][1])))
                               for j, d in enumerate(ERROR_DIMS)}
               for b, v in (("95", in95), ("68", in68))},
        })
    return {"n_targets": len(groups) * 13, "met_per_draw": met, "nees_per_draw": group_nees[0],
            "group_nees_per_draw": np.array(group_nees),
            "expected_met": float(met.mean()), "sd_met": float(met.std()),
            "groups": out_groups}


def excess_spread(observed, sampled):
    """Spread of some statistic beyond what sampling alone gives it.

    Parameters
    ----------
    observed : array_like, shape (S,)
        The statistic on S units (sessions, folds), e.g. a log NEES ratio.
    sampled : sequence of array_like
        For each unit, the statistic over draws of a model that is right (its sampling
        distribution there).

    Returns
    -------
    tau : float
        sqrt(max(var(observed) - mean of the draws' variances, 0)).

    Raises
    ------
    OptimiseError
        Fewer than two units.
    """
    observed = np.asarray(observed, float)
    if observed.size < 2:
        raise OptimiseError(f"excess_spread: needs two or more units, got {observed.size}")
    sampling = np.mean([np.var(np.asarray(d, float), ddof=1) for d in sampled])
    return float(np.sqrt(max(np.var(observed, ddof=1) - sampling, 0.0)))


def session_scale_sd(nees_mean, nees_draws, dim=6):
    """Spread between sessions of the scale a model misstates them by, net of sampling.

    A model fitted on some sessions and scored on another may be right about each frame's
    covariance only up to a factor common to the session (a camera and codec whose corner
    error has more or less pose-like structure than the training sessions'). The log of
    NEES / dim estimates that factor's log; its spread over sessions is the factor's spread
    plus the sampling spread each session's NEES has under a right model (the draws of
    :func:`target_pass_rates`, ``nees_per_draw``), which is taken off (:func:`excess_spread`).

    Parameters
    ----------
    nees_mean : array_like, shape (S,)
        Each held-out session's NEES mean under the model fitted without it.
    nees_draws : sequence of array_like
        For each session, NEES means of draws from the model's own statement (a right model).
    dim : int
        Error dimensions.

    Returns
    -------
    tau : float
        Log-sd of the session factor on the variance (0 when the sessions scatter no more than
        sampling explains).
    """
    return excess_spread(np.log(np.asarray(nees_mean, float) / dim),
                         [np.log(np.asarray(d, float) / dim) for d in nees_draws])
