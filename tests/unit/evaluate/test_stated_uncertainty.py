"""cvsflow.evaluate.stated_uncertainty: a stated per-frame covariance judged against the spread its
coverage and NEES have with errors that persist in time (simulated AR(1) errors, known truth)."""

import numpy as np
import pandas as pd

from cvsflow.evaluate.stated_uncertainty import judge_stated_uncertainty
from cvsflow.metrics import ERROR_DIMS
from cvsflow.uncertainty import frame_runs

N = 600
RUNS = frame_runs(np.arange(N))


def _ar1_errors(seed, rho=0.9):
    """Errors whose every frame has its stated (right) covariance, each whitened axis an AR(1)
    with coefficient rho in time: covariances (N, 6, 6) and the errors, SI."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((6, 6))
    units = np.array([1e-3] * 3 + [2e-3] * 3)  # mm and 2 mrad
    S = (A @ A.T + 6.0 * np.eye(6)) * np.outer(units, units)
    cov = S[None] * np.exp(0.6 * np.sin(np.arange(N) / 50.0))[:, None, None]
    g = np.empty((N, 6))
    g[0] = rng.standard_normal(6)
    for t in range(1, N):
        g[t] = rho * g[t - 1] + np.sqrt(1.0 - rho**2) * rng.standard_normal(6)
    e = np.einsum("nij,nj->ni", np.linalg.cholesky(cov), g)
    return cov, pd.DataFrame(e, columns=[f"err_{d}" for d in ERROR_DIMS])


def test_a_right_statement_is_consistent_where_the_iid_judgement_is_not():
    """Right covariances, errors with lag-1 autocorrelation 0.9: judged against the spread under
    the fitted AR(1) the statement is consistent in nearly every recording; judged as if the
    frames were independent it is called wrong in most."""
    verdicts = {"ar1": [], "iid": []}
    for seed in range(10):
        cov, err = _ar1_errors(seed)
        judged = judge_stated_uncertainty(cov, err, RUNS, seed=seed)
        assert all(0.8 < r < 0.95 for r in judged["rho"].values())
        verdicts["ar1"].append(judged["verdict"])
        verdicts["iid"].append(judge_stated_uncertainty(cov, err, RUNS, time_correlation=False, seed=seed)["verdict"])
    assert verdicts["ar1"].count("consistent") >= 8
    assert verdicts["iid"].count("consistent") <= 5


def test_a_statement_two_times_too_small_is_too_narrow_and_too_large_too_wide():
    """The same errors under covariances half the right ones: too narrow (NEES about 12 above
    its interval, the shares below theirs), every time; twice the right ones: too wide."""
    for seed in range(4):
        cov, err = _ar1_errors(100 + seed)
        small = judge_stated_uncertainty(cov / 2.0, err, RUNS, seed=seed)
        assert small["verdict"] == "too narrow" and small["nees_mean"]["observed"] > small["nees_mean"]["high"]
        assert small["inside_95_all"]["observed"] < small["inside_95_all"]["low"]
        assert judge_stated_uncertainty(cov * 2.0, err, RUNS, seed=seed)["verdict"] == "too wide"


def test_each_fold_is_drawn_with_its_own_student_t():
    """Per-frame nu (a fold's each) and runs broken at a fold change: the intervals come from
    each fold's Student-t, and right Student-t errors are judged consistent in most recordings."""
    fold = np.repeat([0, 1], N // 2)
    nu = np.where(fold == 0, 4.0, 8.0)
    verdicts = []
    for seed in range(4):
        cov, err = _ar1_errors(seed, rho=0.5)
        scale = np.sqrt((nu - 2.0) / np.random.default_rng(seed).chisquare(nu))  # Student-t, covariance cov
        judged = judge_stated_uncertainty(cov, err * scale[:, None], frame_runs(np.arange(N), fold), nu, seed=seed)
        assert judged["inside_68_all"]["low"] < 0.6827 < judged["inside_68_all"]["high"]
        verdicts.append(judged["verdict"])
    assert verdicts.count("consistent") >= 3
