"""Time-correlated scoring of error covariances: AR(1) fit, whitening, block means, LOSO."""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow import uncertainty as un
from cvsflow.metrics.errors import ERROR_DIMS
from tests.helpers.uncertainty_draws import TRUTH_T, draw_transfer

COLS = [f"err_{d}" for d in ERROR_DIMS]


def _ar1(rng, n_runs, run_len, rho, R=None):
    """(n_runs * run_len, 6) unit-variance AR(1) series per run: coefficient rho (per axis),
    innovations with correlation matrix R (identity by default)."""
    rho = np.broadcast_to(np.asarray(rho, float), (6,))
    L = np.linalg.cholesky(np.eye(6) if R is None else R)
    out = np.empty((n_runs, run_len, 6))
    for r in range(n_runs):
        x = L @ rng.normal(size=6)
        for t in range(run_len):
            if t:
                x = rho * x + np.sqrt(1.0 - rho**2) * (L @ rng.normal(size=6))
            out[r, t] = x
    return out.reshape(-1, 6)


def test_frame_runs_break_at_frame_gaps_and_fold_changes():
    frame = np.array([0, 1, 2, 5, 6, 7, 8, 9, 10])
    fold = np.array([0, 0, 0, 0, 0, 1, 1, 1, 2])
    assert un.frame_runs(frame, fold).tolist() == [0, 0, 0, 1, 1, 2, 2, 2, 3]
    assert un.frame_runs(frame).tolist() == [0, 0, 0, 1, 1, 1, 1, 1, 1]


def test_fit_ar1_recovers_rho_and_the_innovations_are_white():
    """On AR(1) series with known coefficients per axis, fit_ar1 recovers them within 0.03;
    the innovations have unit variance and no lag-1 correlation left; pairs across a run
    break are not used (two runs of opposite sign would fake a correlation)."""
    rho = np.array([0.0, 0.3, 0.5, 0.7, 0.8, 0.9])
    rng = np.random.default_rng(1)
    z = _ar1(rng, 40, 250, rho)
    runs = np.repeat(np.arange(40), 250)
    fit = un.fit_ar1(z, runs)
    assert np.all(np.abs(fit - rho) < 0.03), fit
    w = un.ar1_innovations(z, runs, fit)
    assert np.all(np.abs(w.std(axis=0) - 1.0) < 0.04)
    assert np.all(np.abs(un.fit_ar1(w, runs)) < 0.04)
    # single-frame runs: nothing to pair, rho 0 and no whitening
    lone = np.arange(len(z))
    assert np.all(un.fit_ar1(z, lone) == 0.0)
    assert np.array_equal(un.ar1_innovations(z, lone, rho), z)


def test_block_mean_variance_is_the_ar1_sum_and_matches_simulation():
    assert np.isclose(un.block_mean_variance(15, 0.0), 1.0 / 15)
    # n = 2: (2 + 2 rho) / 4
    assert np.isclose(un.block_mean_variance(2, 0.6), (2 + 1.2) / 4)
    rng = np.random.default_rng(2)
    z = _ar1(rng, 2000, 15, 0.7)
    means = z.reshape(2000, 15, 6).mean(axis=1)
    ratio = means.var(axis=0) / un.block_mean_variance(15, 0.7)
    assert np.all(np.abs(ratio - 1.0) < 0.1), ratio


def test_score_time_correlated_is_calibrated_on_ar1_errors_and_flags_an_ignored_correlation():
    """Errors with a known covariance (axis scales and correlations) and an AR(1) in time
    (rho 0.8): whitened by the true rho, NEES ~ 6, the bands hold per axis, block means have
    z RMS ~ 1 and the per-fold shares scatter much less than unwhitened ones. Whitened by
    rho = 0 the scores equal score_covariance's and the block means show the correlation."""
    rng = np.random.default_rng(5)
    A = rng.normal(size=(6, 6))
    C = A @ A.T + 3 * np.eye(6)
    sd = np.sqrt(np.diag(C))
    R = C / np.outer(sd, sd)
    scale = np.r_[1e-3, 1e-3, 3e-3, 2e-3, 2e-3, 1e-3]
    n_runs, run_len = 60, 80
    z = _ar1(rng, n_runs, run_len, 0.8, R)
    cov = np.broadcast_to(np.outer(scale, scale) * R, (len(z), 6, 6)).copy()
    errors = pd.DataFrame(z * scale, columns=COLS)
    runs = np.repeat(np.arange(n_runs), run_len)
    s = un.score_time_correlated(cov, errors, np.full(6, 0.8), runs)
    assert 5.6 < s["nees_mean"] < 6.4
    for d in ERROR_DIMS:
        assert 0.935 < s["inside_95"][d] < 0.965 and 0.655 < s["inside_68"][d] < 0.71, d
        assert 0.85 < s["block_z_rms"][d] < 1.15, d
    assert s["n_blocks"] == n_runs * (run_len // 15)
    # per run (a fold each), the whitened share inside the 68 % band scatters as a binomial
    # of 80 frames would; the unwhitened share scatters more (fewer effective frames)
    plain, white = [], []
    for r in range(n_runs):
        sel = runs == r
        plain.append(list(un.score_covariance(cov[sel], errors[sel])["inside_68"].values()))
        white.append(list(un.score_time_correlated(cov[sel], errors[sel].reset_index(drop=True),
                                                   np.full(6, 0.8), runs[sel])["inside_68"].values()))
    binomial = np.sqrt(0.6827 * 0.3173 / run_len)
    assert np.all(np.abs(np.std(white, axis=0) / binomial - 1.0) < 0.25), np.std(white, axis=0)
    assert np.all(np.std(plain, axis=0) > 1.3 * binomial), np.std(plain, axis=0)
    s0 = un.score_time_correlated(cov, errors, np.zeros(6), runs)
    ref = un.score_covariance(cov, errors)
    assert np.isclose(s0["nees_mean"], ref["nees_mean"])
    assert s0["inside_95"] == ref["inside_95"]
    assert all(v > 2.0 for v in s0["block_z_rms"].values()), s0["block_z_rms"]


def test_leave_one_session_out_scores_with_an_ar1_fitted_on_the_other_sessions():
    """time_correlation=True adds the AR(1) fitted on the training sessions (within runs of
    frames, never across sessions) and the whitened scores per session and fold; the plain
    scores are those of the default call."""
    sessions = {}
    for i in range(3):
        feats, E, _ = draw_transfer(np.random.default_rng(20 + i), 240, TRUTH_T, n_blocks=24)
        E["frame"] = np.arange(len(E))
        E["fold"] = np.arange(len(E)) * 4 // len(E)
        sessions[f"s{i}"] = {"features": feats, "errors": E}
    plain = un.leave_one_session_out(sessions)
    timed = un.leave_one_session_out(sessions, time_correlation=True)
    for name in sessions:
        p, t = plain["sessions"][name], timed["sessions"][name]
        assert p["score"]["nees_mean"] == t["score"]["nees_mean"]
        assert "ar1" not in p["score"]
        rho = np.array(t["model"]["ar1_rho"])
        assert rho.shape == (6,) and np.all((rho >= 0) & (rho <= 0.95))
        # the AR(1) is the one of the other two sessions under the model fitted on them
        others = [n for n in sessions if n != name]
        f = pd.concat([sessions[n]["features"] for n in others], ignore_index=True)
        e = pd.concat([sessions[n]["errors"].assign(session=n) for n in others], ignore_index=True)
        assert np.allclose(rho, un.time_correlation_of(t["model"], f, e))
        assert t["score"]["ar1"]["n"] == 240
        assert [fs["ar1"]["n"] for fs in t["score"]["folds"]] == [60] * 4
    assert len(timed["pooled_model"]["ar1_rho"]) == 6
