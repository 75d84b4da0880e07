"""cvsflow.metrics.statistics: the registry of error statistics, one key set, the block bootstrap."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cvsflow.evaluate import analyse
from cvsflow.evaluate import heldout as evaluate
from cvsflow.metrics import errors
from cvsflow.metrics import statistics as st


def _errors(seed, n=200):
    rng = np.random.default_rng(seed)
    E = rng.normal(0.0, 1.0, (n, 6)) * [1e-3, 2e-3, 4e-3, 1e-3, 2e-3, 5e-4] + [1e-4, 0, 0, 0, 0, 2e-4]
    return pd.DataFrame(E, columns=errors.error_columns("eps"))


def test_each_statistic_has_its_definition():
    """rmse about zero, the sample std (ddof 1), median, min, max, the sum of squares; n the count."""
    x = np.array([1.0, 2.0, 3.0, 6.0])
    s = st.error_statistics(x)
    assert list(s) == ["n", *st.STATISTICS]
    assert s == {"n": 4, "rmse": np.sqrt(50.0 / 4.0), "mean": 3.0, "median": 2.5, "std": np.std(x, ddof=1),
                 "min": 1.0, "max": 6.0, "sse": 50.0}


def test_non_finite_values_are_left_out_and_none_gives_nan():
    """NaN and inf are not errors: they are dropped and not counted; an empty series is all NaN."""
    s = st.error_statistics([1.0, np.nan, 3.0, np.inf])
    assert s["n"] == 2 and s["mean"] == 2.0 and s["max"] == 3.0
    empty = st.error_statistics([np.nan])
    assert empty["n"] == 0 and all(np.isnan(v) for k, v in empty.items() if k != "n")
    assert np.isnan(st.error_statistics([2.0])["std"])


def test_a_new_statistic_is_one_registry_entry(monkeypatch):
    """An entry added to STATISTICS appears in every summary: a run's stats.json (analyse) and
    the held-out comparison (evaluate), under its name, per axis."""
    p95 = st.Statistic("p95_abs", lambda e: float(np.quantile(np.abs(e), 0.95)))
    monkeypatch.setitem(st.STATISTICS, "p95_abs", p95)
    table = _errors(3)
    per_run = analyse.run_statistics(table)["per_dim"]
    compared = evaluate.compare_methods({"se3": table}, block_len=5, n_boot=20)["se3"]["per_dim"]
    for j, d in enumerate(errors.ERROR_DIMS):
        want = np.quantile(np.abs(table.iloc[:, j]), 0.95)
        assert per_run[d]["p95_abs"] == compared[d]["p95_abs"] == pytest.approx(want, rel=1e-12)


def test_axis_statistics_keys_the_axes_by_error_dims():
    """One naming of the axes: x_m .. yaw_rad; a column's NaNs are left out of that column only."""
    E = _errors(4).to_numpy().copy()
    E[0, 2] = np.nan
    s = st.axis_statistics(E)
    assert list(s) == list(errors.ERROR_DIMS)
    assert s["z_m"]["n"] == len(E) - 1 and s["x_m"]["n"] == len(E)
    assert s["y_m"]["rmse"] == pytest.approx(np.sqrt(np.mean(E[:, 1] ** 2)), rel=1e-14)
    with pytest.raises(Exception, match="5 columns for 6 axes"):
        st.axis_statistics(E[:, :5])


def test_analyse_and_evaluate_state_the_same_statistics():
    """The per-run statistics (analyse) and the method comparison (evaluate) use one
    definition: on the same table every statistic is equal, bit for bit."""
    table = _errors(1)
    per_run = analyse.normality_tests(table)
    compared = evaluate.compare_methods({"se3": table}, block_len=5, n_boot=20)["se3"]["per_dim"]
    for d in errors.ERROR_DIMS:
        for k in ("n", *st.STATISTICS):
            assert compared[d][k] == per_run.loc[d, k], (d, k)


def test_bootstrap_ci_coverage_on_iid_normal():
    """On iid N(0.3, 1) data (n=200), the 95 % CIs of the mean and std contain the truth in
    roughly 95 % of 200 seeded repetitions (accepted 88-99 %)."""
    hit_mean = hit_std = 0
    reps = 200
    for rep in range(reps):
        x = np.random.default_rng(rep).normal(0.3, 1.0, 200)
        b = st.bootstrap_error_stats(x, block_len=1, n_boot=300, seed=rep)
        hit_mean += b["mean_lo"][0] <= 0.3 <= b["mean_hi"][0]
        hit_std += b["std_lo"][0] <= 1.0 <= b["std_hi"][0]
    assert 0.88 <= hit_mean / reps <= 0.99
    assert 0.88 <= hit_std / reps <= 0.99


def test_block_bootstrap_widens_for_autocorrelated_errors():
    """For AR(1) errors (phi = 0.9) the block bootstrap CI of the mean is at least twice as
    wide as the iid bootstrap's (the iid one ignores autocorrelation)."""
    rng = np.random.default_rng(7)
    e = np.zeros(2000)
    for i in range(1, len(e)):
        e[i] = 0.9 * e[i - 1] + rng.normal()
    w_iid = np.ptp(np.r_[st.bootstrap_error_stats(e, 1, 400, seed=1)["mean_lo"],
                         st.bootstrap_error_stats(e, 1, 400, seed=1)["mean_hi"]])  # fmt: skip
    b = st.bootstrap_error_stats(e, 60, 400, seed=1)
    assert b["mean_hi"][0] - b["mean_lo"][0] > 2 * w_iid
    assert b["Sigma"].shape == (1, 1)


def test_bootstrap_in_chunks_is_the_bootstrap_at_once(monkeypatch):
    """The resamples taken a few at a time (memory flat in the session's length) give every
    interval bit for bit as all at once: a chunk of one resample, of 7, and all 250."""
    rng = np.random.default_rng(11)
    E = rng.normal(size=(900, 6)) * np.array([1e-3, 2e-3, 5e-3, 1e-3, 1e-3, 4e-4])
    results = []
    for resamples_per_chunk in (1, 7, 250):
        monkeypatch.setattr(st, "BOOTSTRAP_CHUNK_BYTES", 16 * 900 * 6 * resamples_per_chunk)
        results.append(st.bootstrap_error_stats(E, 30, n_boot=250, seed=5))
    for other in results[:2]:
        for name in ("mean_lo", "mean_hi", "std_lo", "std_hi", "Sigma_lo", "Sigma_hi"):
            assert np.array_equal(other[name], results[2][name])
    assert not np.array_equal(results[2]["std_lo"], results[2]["std_hi"])
