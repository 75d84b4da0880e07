"""Tests of cvsflow.evaluate.analyse (statistics by hand) and cvsflow.plots.results (figure structure)."""

import json

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from cvsflow.evaluate import analyse
from cvsflow.exceptions import InputError
from cvsflow.metrics import ERROR_DIMS

DIMS = ERROR_DIMS


def _errors(n=500, seed=0):
    """Errors table: correlated normal eps (known covariance), poses, Vicon, orig/improved CVS."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(6, 6)) * np.array([0.01, 0.01, 0.03, 0.01, 0.01, 0.02])
    eps = rng.normal(size=(n, 6)) @ A.T
    eps_orig = eps * 1.5 + 0.002
    pose = np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.4, 0.4, n),
                            rng.uniform(1.0, 4.0, n), rng.uniform(-0.5, 0.5, (n, 3))])
    df = pd.DataFrame({"frame": np.arange(n), "t_s": np.arange(n) / 30.0})
    P_bar = np.array([0.05, -0.02, 0.1, 0.01, 0.0, 3.1])
    for i, d in enumerate(DIMS):
        df[f"cvs_{d}"] = pose[:, i]
        df[f"vic_{d}"] = pose[:, i] - P_bar[i] - eps[:, i]
        df[f"cvs_orig_{d}"] = pose[:, i] + eps_orig[:, i] - eps[:, i]
        df[f"eps_{d}"] = eps[:, i]
        df[f"eps_orig_{d}"] = eps_orig[:, i]
    return df, eps, P_bar


def _iterations(k=5):
    """A small iterations table with every column the analysis reads."""
    rows = []
    for j in range(k + 1):
        row = {"iteration": j, "fx_px": 660.0 + j, "fy_px": 730.0 - j, "objective": 1.0 / (j + 1),
               "norm_normalised": 0.05 / (j + 1)}
        for d in DIMS:
            for s in ("mean", "std", "rmse"):
                row[f"eps_{s}_{d}"] = 0.01 / (j + 1)
            row[f"P_bar_{d}"] = 0.0
        rows.append(row)
    return pd.DataFrame(rows)


def test_normality_table_matches_numpy_and_scipy():
    """Moments equal numpy's; test statistics equal scipy.stats.normaltest / anderson."""
    df, eps, _ = _errors()
    t = analyse.normality_tests(df)
    for i, d in enumerate(DIMS):
        x = eps[:, i]
        assert t.loc[d, "mean"] == pytest.approx(x.mean(), abs=1e-15)
        assert t.loc[d, "std"] == pytest.approx(x.std(ddof=1), rel=1e-12)
        assert t.loc[d, "rmse"] == pytest.approx(np.sqrt(np.mean(x**2)), rel=1e-12)
        assert t.loc[d, "min"] == x.min() and t.loc[d, "max"] == x.max()
        assert t.loc[d, "dagostino_p"] == pytest.approx(stats.normaltest(x).pvalue, rel=1e-12)
        assert t.loc[d, "anderson_stat"] == pytest.approx(stats.anderson(x, dist="norm", method="interpolate").statistic, rel=1e-12)
    # normal data of n=500: no dimension is rejected at the 0.1 % level
    assert (t["dagostino_p"] > 1e-3).all()


def test_normality_rejects_uniform_errors():
    """Uniform errors (n = 2000) are rejected by both tests at 5 %."""
    df, _, _ = _errors(2000, seed=1)
    df["eps_x_m"] = np.random.default_rng(2).uniform(-0.01, 0.01, 2000)
    t = analyse.normality_tests(df)
    assert t.loc["x_m", "dagostino_p"] < 0.05
    assert t.loc["x_m", "anderson_p"] < 0.05
    assert not t.loc["x_m", "normal_at_5pct"]


def test_covariance_and_correlation_by_hand():
    """Sigma equals numpy's ddof=1 covariance (eq. 1.14); corr equals np.corrcoef."""
    df, eps, _ = _errors()
    Sigma, corr = analyse.sample_error_covariance(df)
    c = eps - eps.mean(axis=0)
    np.testing.assert_allclose(Sigma, c.T @ c / (len(eps) - 1), rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(corr, np.corrcoef(eps, rowvar=False), atol=1e-12)


def test_binned_error_map_by_hand():
    """Each cell's mean equals the mean of the samples falling in it; sparse cells are NaN."""
    df, eps, _ = _errors(800, seed=3)
    m = analyse.binned_error_map(df, "x_m", "z_m", "y_m", bins=4, min_count=1)
    a, b = df["cvs_x_m"].to_numpy(), df["cvs_z_m"].to_numpy()
    ia = np.clip(np.searchsorted(m["edges_a"], a, side="right") - 1, 0, 3)
    ib = np.clip(np.searchsorted(m["edges_b"], b, side="right") - 1, 0, 3)
    for i in range(4):
        for j in range(4):
            sel = (ia == i) & (ib == j)
            assert m["count"][i, j] == sel.sum()
            if sel.any():
                assert m["mean"][i, j] == pytest.approx(eps[sel, 1].mean(), rel=1e-10)
    sparse = analyse.binned_error_map(df, "x_m", "z_m", "y_m", bins=40, min_count=5)
    assert np.all(np.isnan(sparse["mean"][sparse["count"] < 5]))
    with pytest.raises(InputError, match="dimension"):
        analyse.binned_error_map(df, "x", "z_m", "y_m")


def test_vicon_vs_cvs_differences_are_eps():
    """improved - vicon equals eps and original - vicon equals eps_orig (angles wrapped)."""
    df, eps, P_bar = _errors()
    P_bar0 = P_bar + 0.01
    tr = analyse.mocap_vs_cvs(df, {"P_bar": P_bar.tolist(), "P_bar_init": P_bar0.tolist()})
    for i, d in enumerate(DIMS):
        diff = tr[f"improved_{d}"] - tr[f"vicon_{d}"]
        diff0 = tr[f"original_{d}"] - tr[f"vicon_{d}"]
        if i >= 3:
            diff, diff0 = np.angle(np.exp(1j * diff)), np.angle(np.exp(1j * diff0))
        # vic = cvs - P_bar - eps and cvs_orig = cvs + eps_orig - eps, so with P_bar_init
        # shifted the original track minus Vicon is eps_orig - (P_bar_init - P_bar)
        np.testing.assert_allclose(diff, eps[:, i], atol=1e-12)
        np.testing.assert_allclose(diff0, df[f"eps_orig_{d}"] - 0.01, atol=1e-12)


def test_statistics_dict_is_json_ready():
    """run_statistics dumps to JSON and its numbers equal numpy's on the same table."""
    df, eps, _ = _errors()
    s = analyse.run_statistics(df)
    back = json.loads(json.dumps(s))
    assert back["n"] == len(eps)
    assert back["per_dim"]["z_m"]["std"] == pytest.approx(eps[:, 2].std(ddof=1), rel=1e-12)
    np.testing.assert_allclose(back["Sigma"], np.cov(eps, rowvar=False), rtol=1e-10)


def test_optimum_summary_and_convergence():
    """optimum_summary copies f, P_bar and the norm ratio; convergence keeps every row."""
    res = {"fx_px": 628.0, "fy_px": 535.0, "P_bar": [0.2, 0.04, 0.37, 3.2, -0.05, -3.1],
           "f_init_px": [700.0, 700.0], "norm_normalised_init_m": 1.15,
           "norm_normalised_final_m": 0.81}
    s = analyse.optimum_summary(res)
    assert s["norm_ratio"] == pytest.approx(0.81 / 1.15)
    assert s["fx_px"] == 628.0 and len(s["P_bar"]) == 6
    with pytest.raises(InputError, match="fy_px"):
        analyse.optimum_summary({"fx_px": 1.0})
    # se3 has no 6-vector offset: P_bar is optional and then NaN
    no_offset = {k: v for k, v in res.items() if k != "P_bar"}
    assert np.isnan(analyse.optimum_summary(no_offset)["P_bar"]).all()
    conv = analyse.convergence(_iterations(5))
    assert len(conv) == 6 and "eps_rmse_yaw_rad" in conv


def test_too_few_rows_and_missing_columns_raise():
    """An errors table with < 3 rows or without eps columns is an InputError naming it."""
    df, _, _ = _errors()
    with pytest.raises(InputError, match="at least 3"):
        analyse.normality_tests(df.iloc[:2])
    with pytest.raises(InputError, match="eps_roll_rad"):
        analyse.sample_error_covariance(df.drop(columns="eps_roll_rad"))


# ------------------------------------------------------------------ figures (structure only)


def _labelled(ax):
    """True when both axis labels carry a unit in brackets."""
    return "[" in ax.get_xlabel() and "[" in ax.get_ylabel()


def test_plot_functions_return_labelled_figures():
    """Every plot returns a Figure with the expected axes, each labelled with units."""
    from matplotlib.figure import Figure

    from cvsflow.plots import results as pr

    df, _, P_bar = _errors(300)
    figs = {
        "conv": (pr.plot_convergence(analyse.convergence(_iterations())), 8),
        "hist": (pr.plot_error_histograms(df, analyse.normality_tests(df)), 6),
        "qq": (pr.plot_qq(analyse.qq_data(df)), 6),
    }
    for name, (fig, n_axes) in figs.items():
        assert isinstance(fig, Figure), name
        assert len(fig.axes) == n_axes, name
        assert all(_labelled(ax) for ax in fig.axes), name
    Sigma, corr = analyse.sample_error_covariance(df)
    fig = pr.plot_covariance(Sigma, corr)
    assert len(fig.axes) == 3  # table, heat map, colour bar
    assert fig.axes[1].get_xticklabels()[0].get_text() == "x [mm]"  # units on the ticks
    assert fig.axes[1].get_yticklabels()[5].get_text() == "yaw ψ [deg]"


def test_error_maps_one_row_and_one_colour_scale_per_error_dimension():
    """18 maps in 6 rows (error dims) x 3 columns (pose pairs); a row shares one colour scale."""
    from cvsflow.plots import results as pr

    df, _, _ = _errors(300)
    fig = pr.plot_error_maps(analyse.error_maps(df, bins=6))
    maps = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(maps) == 18 and len(bars) == 6
    assert all(_labelled(ax) for ax in maps)
    assert "mm" in maps[0].get_xlabel() and "deg" in maps[-1].get_xlabel()
    assert "in x [mm]" in bars[0].get_ylabel() and "yaw" in bars[-1].get_ylabel()
    for row in range(6):
        limits = {tuple(np.round(c.get_clim(), 12)) for ax in maps[3 * row: 3 * row + 3]
                  for c in ax.collections}
        assert len(limits) == 1  # one colour scale per row
        lo, hi = limits.pop()
        assert lo == -hi and hi > 0


def test_vicon_vs_cvs_errors_in_mm_and_lines_broken_at_gaps():
    """Track and error rows per dimension; the error panel is eps in mm; a gap breaks the lines."""
    from cvsflow.plots import results as pr

    df, eps, P_bar = _errors(300)
    df = df.drop(index=range(100, 130)).reset_index(drop=True)  # 1 s without frames
    eps = np.delete(eps, range(100, 130), axis=0)
    fig = pr.plot_vicon_vs_cvs(analyse.mocap_vs_cvs(df, {"P_bar": P_bar}), diverged_reason="fy at 5000 px")
    assert len(fig.axes) == 12
    assert "DIVERGED: fy at 5000 px" in fig.get_suptitle()
    ax_x, ax_ex = fig.axes[0], fig.axes[3]
    assert ax_ex.get_ylabel() == "CVS - Vicon, x [mm]"
    improved_err = ax_ex.get_lines()[2].get_ydata()  # zero line, original, improved
    finite = np.isfinite(improved_err)
    assert (~finite).sum() == 1  # one NaN: the one gap
    np.testing.assert_allclose(improved_err[finite], 1e3 * eps[:, 0], atol=1e-9)
    t = ax_x.get_lines()[0].get_xdata()
    k = np.flatnonzero(np.isnan(t))[0]
    assert t[k - 1] == pytest.approx(99 / 30) and t[k + 1] == pytest.approx(130 / 30)
    assert fig.axes[-1].get_xlabel() == "time [s]"
    assert "deg" in fig.axes[-1].get_ylabel()


def test_break_gaps_leaves_a_regular_series_alone():
    from cvsflow.plots.results import break_gaps

    t = np.arange(10) / 30.0
    tt, y = break_gaps(t, np.ones(10))
    np.testing.assert_array_equal(tt, t)
    tt, y = break_gaps(np.r_[t, 1.0], np.ones(11))
    assert np.isnan(tt[10]) and np.isnan(y[10]) and tt.size == 12


def test_covariance_display_units():
    """Sigma is shown in mm and deg: x-x scaled by 1e6, x-roll by 1e3 * 180 / pi."""
    from cvsflow.plots.results import _to_display

    S = np.ones((6, 6))
    D = _to_display(S)
    assert D[0, 0] == pytest.approx(1e6)
    assert D[0, 3] == pytest.approx(1e3 * 180 / np.pi)
    assert D[5, 5] == pytest.approx((180 / np.pi) ** 2)


def test_convergence_states_the_grid_bounds_and_divergence():
    from cvsflow.plots import results as pr

    fig = pr.plot_convergence(analyse.convergence(_iterations()), (100.0, 5000.0),
                              diverged_reason="fy = 4985.8 px within a grid step of the bound")
    assert fig.get_suptitle().splitlines()[1].startswith("DIVERGED: fy = 4985.8 px")
    assert fig.axes[6].get_title() == "focal lengths (grid bounds 100 to 5000 px)"
    assert "DIVERGED" not in pr.plot_convergence(analyse.convergence(_iterations())).get_suptitle()


def test_mark_diverged_appends_the_reason_in_red_and_leaves_converged_runs_alone():
    from cvsflow.plots import results as pr

    df, _, _ = _errors(100)
    fig = pr.mark_diverged(pr.plot_qq(analyse.qq_data(df)), "fy = 4985.8 px at the bound")
    title = fig.get_suptitle()
    assert title.startswith("Normal Q-Q plots") and title.endswith("DIVERGED: fy = 4985.8 px at the bound")
    assert fig._suptitle.get_color() == "tab:red"
    Sigma, corr = analyse.sample_error_covariance(df)
    assert pr.mark_diverged(pr.plot_covariance(Sigma, corr), "x").get_suptitle() == "DIVERGED: x"
    assert pr.mark_diverged(pr.plot_qq(analyse.qq_data(df)), None).get_suptitle() == "Normal Q-Q plots of the errors"
