"""The yardstick for the uncertainty targets: what an exactly right model scores."""

import numpy as np
import pytest
from scipy import stats

from cvsflow.exceptions import OptimiseError
from cvsflow.uncertainty.calibrated_draws import (
    TARGETS,
    autocorrelation,
    draw_calibrated_errors,
    excess_spread,
    session_scale_sd,
    target_pass_rates,
)
from cvsflow.uncertainty.scoring import frame_runs


def _covariances(n, rng):
    """Frame covariances of a PnP-like error: mm and mrad scales, correlated axes."""
    A = rng.normal(size=(n, 6, 6)) * np.array([1e-3, 1e-3, 4e-3, 2e-3, 2e-3, 5e-4])[:, None]
    return A @ np.swapaxes(A, 1, 2) + np.eye(6) * 1e-9


def test_independent_normal_frames_meet_the_targets_as_the_binomial_says():
    """60 independent normal frames: the chance that the share inside the 95 % band lies in
    [0.93, 0.97] is the binomial's P(56 <= X <= 58), X ~ B(60, 0.95) (0.58), inside the 68 %
    band B(60, 0.6827) in [39, 43], and the NEES mean in [4.5, 7.5] is chi2(360) in [270, 450];
    the Monte Carlo agrees within four of its standard errors."""
    rng = np.random.default_rng(1)
    n, d = 60, 4000
    cov = _covariances(n, rng)
    rates = target_pass_rates(cov, None, None, 0.0, frame_runs(np.arange(n)), n_draws=d, seed=3)
    g = rates["groups"][0]
    p95 = stats.binom.cdf(58, n, 0.95) - stats.binom.cdf(55, n, 0.95)
    p68 = stats.binom.cdf(43, n, 0.6826894921370859) - stats.binom.cdf(38, n, 0.6826894921370859)
    p_nees = stats.chi2.cdf(7.5 * n, 6 * n) - stats.chi2.cdf(4.5 * n, 6 * n)
    for p_mc, p in [(v, p95) for v in g["inside_95"].values()] + \
                   [(v, p68) for v in g["inside_68"].values()] + [(g["nees"], p_nees)]:
        assert abs(p_mc - p) < 4 * np.sqrt(p * (1 - p) / d) + 1e-3
    assert rates["n_targets"] == 13
    assert abs(rates["expected_met"] - (6 * p95 + 6 * p68 + p_nees)) < 0.1


def test_the_draws_are_what_the_model_states():
    """Student-t draws around a predicted mean: their mean and covariance are the stated ones
    (within Monte Carlo error), and their whitened lag-1 autocorrelation is the stated rho
    within each run, none across a run break."""
    rng = np.random.default_rng(2)
    n = 40
    cov = np.repeat(_covariances(1, rng), n, axis=0)
    mean = rng.normal(size=(n, 6)) * 1e-3
    frame = np.r_[np.arange(20), np.arange(100, 120)]
    runs = frame_runs(frame)
    E = draw_calibrated_errors(cov, mean, 8.0, 0.6, runs, 20000, np.random.default_rng(4))
    e = E - mean
    C = np.einsum("dni,dnj->ij", e, e) / (e.shape[0] * e.shape[1])
    sd = np.sqrt(np.diag(cov[0]))
    assert np.allclose(C / np.outer(sd, sd), cov[0] / np.outer(sd, sd), atol=0.03)
    assert np.all(np.abs(e.mean(axis=(0, 1)) / sd) < 0.02)
    g = np.einsum("ij,dnj->dni", np.linalg.inv(np.linalg.cholesky(cov[0])), e)
    lag1 = np.mean(g[:, 1:20] * g[:, :19]) / np.mean(g * g)
    across = np.mean(g[:, 20] * g[:, 19]) / np.mean(g * g)
    assert abs(lag1 - 0.6) < 0.03
    assert abs(across) < 0.03


def test_time_correlation_lowers_the_chance_of_meeting_band_targets():
    """Errors correlated in time scatter a fold's shares more: a right model with rho 0.6
    meets the 95 % band target less often than with independent frames, and the per-fold and
    whole-set targets are all counted."""
    rng = np.random.default_rng(5)
    n = 300
    cov = _covariances(n, rng)
    fold = np.repeat(np.arange(5), 60)
    runs = frame_runs(np.arange(n), fold)
    iid = target_pass_rates(cov, None, 12.0, 0.0, runs, fold, n_draws=1500, seed=6)
    ar = target_pass_rates(cov, None, 12.0, 0.6, runs, fold, n_draws=1500, seed=6)
    assert iid["n_targets"] == ar["n_targets"] == 6 * 13
    assert [g["n"] for g in iid["groups"]] == [300, 60, 60, 60, 60, 60]
    p_iid = np.mean([np.mean(list(g["inside_95"].values())) for g in iid["groups"][1:]])
    p_ar = np.mean([np.mean(list(g["inside_95"].values())) for g in ar["groups"][1:]])
    assert p_ar < p_iid - 0.03
    assert ar["expected_met"] < iid["expected_met"] - 2
    assert iid["met_per_draw"].shape == (1500,)
    assert TARGETS["nees"] == (4.5, 7.5)


def test_draws_with_a_measured_autocorrelation_have_it_and_a_slow_part_costs_targets():
    """Draws with a long-memory autocorrelation (a part common to a whole run, 0.4 of the
    variance, plus an AR(1) of 0.5) measure back as that autocorrelation at lags 1, 5 and
    20; with the same lag-1 correlation an AR(1) meets many more band targets, since the
    slow part moves a fold's shares together."""
    rng = np.random.default_rng(7)
    n = 300
    cov = _covariances(n, rng)
    fold = np.repeat(np.arange(5), 60)
    runs = frame_runs(np.arange(n), fold)
    lags = np.arange(1, 60)
    acf_true = 0.4 + 0.6 * 0.5**lags
    acf = np.repeat(acf_true[:, None], 6, axis=1)
    E = draw_calibrated_errors(cov, None, None, acf, runs, 3000, np.random.default_rng(8))
    L = np.linalg.cholesky(cov)
    g = np.linalg.solve(L[None], E[..., None])[..., 0]
    # the draws one after another, each its own runs: the estimator pooled over them
    measured = autocorrelation(g.reshape(-1, 6), (runs[None] + 100 * np.arange(3000)[:, None]).ravel(),
                               20)
    for k in (1, 5, 20):
        assert np.all(np.abs(measured[k - 1] - acf_true[k - 1]) < 0.04)
    slow = target_pass_rates(cov, None, None, acf, runs, fold, n_draws=1500, seed=9)
    ar1 = target_pass_rates(cov, None, None, acf_true[0], runs, fold, n_draws=1500, seed=9)
    assert slow["expected_met"] < ar1["expected_met"] - 8


def test_a_session_scale_spreads_the_nees_as_stated_and_costs_targets():
    """With scale_sd 0.3 each draw's NEES mean is its right-model value times a log-normal
    factor of log-sd 0.3 (the log NEES spread grows by that variance), the stated mean stays
    the centre, and fewer targets are met; scale_sd 0 reproduces the right model's draws."""
    rng = np.random.default_rng(7)
    n = 120
    cov = _covariances(n, rng)
    mean = rng.normal(size=(n, 6)) * 1e-4
    runs = frame_runs(np.arange(n))
    right = target_pass_rates(cov, mean, None, 0.0, runs, n_draws=3000, seed=8)
    again = target_pass_rates(cov, mean, None, 0.0, runs, n_draws=3000, seed=8, scale_sd=0.0)
    scaled = target_pass_rates(cov, mean, None, 0.0, runs, n_draws=3000, seed=8, scale_sd=0.3)
    assert np.array_equal(right["met_per_draw"], again["met_per_draw"])
    v_right = np.var(np.log(right["nees_per_draw"]))
    v_scaled = np.var(np.log(scaled["nees_per_draw"]))
    assert abs(v_scaled - v_right - 0.09) < 0.012
    assert abs(np.mean(np.log(scaled["nees_per_draw"] / 6))) < 0.02
    assert scaled["expected_met"] < right["expected_met"] - 2


def test_session_scale_sd_recovers_the_spread_net_of_sampling():
    """Sessions whose NEES is a right model's sampling draw times a log-normal factor of log-sd
    tau: the estimate is near tau, and near 0 when tau is 0 (the sampling spread is taken
    off, not mistaken for a scale)."""
    rng = np.random.default_rng(9)
    draws = [6.0 * np.exp(0.06 * rng.standard_normal(400)) for _ in range(200)]
    for tau in (0.0, 0.25):
        nees = [6.0 * np.exp(0.06 * rng.standard_normal() + tau * rng.standard_normal())
                for _ in range(200)]
        assert abs(session_scale_sd(nees, draws) - tau) < 0.05


def test_a_fold_scale_spreads_each_folds_nees_about_its_session():
    """fold_scale_sd 0.4: each fold's log NEES about the whole set's spreads by about that
    variance more than a right model's (the folds' factors are independent), and it needs folds."""
    rng = np.random.default_rng(10)
    n = 300
    cov = _covariances(n, rng)
    fold = np.repeat(np.arange(5), 60)
    runs = frame_runs(np.arange(n), fold)
    right = target_pass_rates(cov, None, None, 0.0, runs, fold, n_draws=2000, seed=11)
    scaled = target_pass_rates(cov, None, None, 0.0, runs, fold, n_draws=2000, seed=11,
                               fold_scale_sd=0.4)
    def spread(r):
        g = r["group_nees_per_draw"]
        return np.var(np.log(g[1:] / g[0]))
    # the whole set's NEES averages the five factors, so a fold's about it spreads by 0.16 * 4/5
    assert abs(spread(scaled) - spread(right) - 0.16 * 0.8) < 0.02
    with pytest.raises(OptimiseError, match="folds"):
        target_pass_rates(cov, None, None, 0.0, runs, None, n_draws=10, fold_scale_sd=0.4)
    with pytest.raises(OptimiseError, match="two or more"):
        excess_spread([0.1], [[0.0, 1.0]])
