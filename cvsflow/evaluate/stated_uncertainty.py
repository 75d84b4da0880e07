"""Whether a stated per-frame uncertainty fits held-out errors that persist in time.

The shares of held-out errors inside the stated 68 % and 95 % bands and their mean NEES scatter
about their right values far more than independent frames would let them when the errors come
in runs (lag-1 autocorrelation 0.1-0.9 on the ETH pose streams): judged against a binomial's
spread, a right statement is called wrong most of the time. :func:`judge_stated_uncertainty`
judges them against the spread they have under the statement itself with the errors' measured
time correlation: errors drawn from each frame's stated distribution, correlated in time as an
AR(1) with the coefficient fitted on the held-out errors
(:func:`cvsflow.uncertainty.fit_ar1`, :func:`cvsflow.uncertainty.draw_calibrated_errors`),
scored as the real ones are (:func:`cvsflow.uncertainty.score_covariance`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow import uncertainty as un
from cvsflow.metrics import ERROR_DIMS

#: Draws of errors from the statement (the sampling intervals' resolution).
N_DRAWS = 400
#: Two-sided level of each statistic's sampling interval. Three statistics: a right statement
#: is called consistent in 95-97 % of simulated recordings with normal errors, about 90 % with
#: Student-t errors of nu 4-8 (the NEES mean's spread is heavy-tailed there).
LEVEL = 0.99
#: The statistics judged (:func:`cvsflow.uncertainty.score_covariance`'s keys).
STATISTICS = ("nees_mean", "inside_68_all", "inside_95_all")
_COLUMNS = [f"err_{d}" for d in ERROR_DIMS]


def _nu_groups(nu, n):
    """(nu or None, rows) per distinct degrees of freedom (a fold's Student-t each)."""
    v = np.full(n, np.inf) if nu is None else np.broadcast_to(np.asarray(nu, float), (n,))
    v = np.where(np.isfinite(v), v, np.inf)
    return [(None if np.isinf(k) else float(k), v == k) for k in np.unique(v)]


def _scores(cov, E, groups):
    """The :data:`STATISTICS` of errors E (N, 6), each group scored with its nu, pooled by frames."""
    out = dict.fromkeys(STATISTICS, 0.0)
    for nu, rows in groups:
        s = un.score_covariance(cov[rows], pd.DataFrame(E[rows], columns=_COLUMNS), nu=nu)
        for k in STATISTICS:
            out[k] += s[k] * rows.sum() / len(E)
    return out


def judge_stated_uncertainty(cov, errors, runs, nu=None, *, time_correlation=True, n_draws=N_DRAWS,
                             level=LEVEL, seed=0) -> dict:  # fmt: skip
    """Coverage and NEES of held-out errors against their sampling spread under the statement.

    Parameters
    ----------
    cov : ndarray, shape (N, 6, 6)
        Each frame's stated error covariance, SI (m, rad).
    errors : DataFrame
        ``err_{dim}`` of the same frames, SI, in time order within each run.
    runs : array_like, shape (N,)
        :func:`cvsflow.uncertainty.frame_runs` of the frames (consecutive frames of one fold).
    nu : float or array_like, shape (N,), optional
        The statement's Student-t degrees of freedom (per frame: each fold's); None or inf:
        normal.
    time_correlation : bool
        Draw the errors correlated in time as an AR(1) fitted on these errors
        (:func:`cvsflow.uncertainty.fit_ar1`); False: independent frames (the binomial's
        spread, for comparison).
    n_draws : int
        Draws of the whole set from the statement.
    level : float
        Two-sided level of each statistic's sampling interval.
    seed : int
        Of the draws.

    Returns
    -------
    dict
        ``verdict``: ``consistent``, ``too narrow`` (the statement understates the errors:
        NEES above, or a share below, its interval), ``too wide`` (overstates them) or ``wrong
        shape`` (both: e.g. too narrow in the tails, too wide in the core); ``reasons`` (the
        statistics outside, in words); ``rho`` per axis (the AR(1) used; 0 without time
        correlation); ``level``, ``n_draws``; per statistic of :data:`STATISTICS` its
        ``observed`` value and the ``low``, ``median``, ``high`` of its draws.
    """
    cov = np.asarray(cov, float)
    runs = np.asarray(runs)
    groups = _nu_groups(nu, len(cov))
    z = un.standardised_errors(cov, errors)
    rho = un.fit_ar1(z, runs) if time_correlation else np.zeros(len(ERROR_DIMS))
    observed = _scores(cov, errors[_COLUMNS].to_numpy(float), groups)
    rng = np.random.default_rng(seed)
    E = np.empty((int(n_draws), len(cov), len(ERROR_DIMS)))
    for g_nu, rows in groups:
        E[:, rows] = un.draw_calibrated_errors(cov[rows], None, g_nu, rho, runs[rows], n_draws, rng)
    sampled = [_scores(cov, E[d], groups) for d in range(int(n_draws))]
    out = {"verdict": "consistent", "reasons": [], "rho": dict(zip(ERROR_DIMS, map(float, rho), strict=True)),
           "level": float(level), "n_draws": int(n_draws)}  # fmt: skip
    narrow = wide = False
    for k in STATISTICS:
        lo, med, hi = np.quantile([s[k] for s in sampled], [(1 - level) / 2, 0.5, (1 + level) / 2])
        v = observed[k]
        out[k] = {"observed": float(v), "low": float(lo), "median": float(med), "high": float(hi)}
        if v < lo or v > hi:
            # a NEES above its interval, or a share below it, is a statement too narrow
            under = (v > hi) if k == "nees_mean" else (v < lo)
            narrow, wide = narrow or under, wide or not under
            out["reasons"].append(f"{k} {v:.3g} {'above' if v > hi else 'below'} {lo:.3g}..{hi:.3g}")
    if narrow or wide:
        out["verdict"] = "wrong shape" if narrow and wide else ("too narrow" if narrow else "too wide")
    return out
