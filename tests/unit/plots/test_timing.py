"""The scaling figure and exponents of bench/bench_scaling.py (cvsflow.plots.timing)."""

import numpy as np
import pandas as pd
import pytest

from cvsflow.plots.timing import plot_stage_scaling, stage_exponents


def _table():
    """Three stages with known exponents at 640x480, one 720p case that must not enter the fit."""
    rows = []
    for d in (30.0, 90.0, 300.0):
        for stage, b_cpu, b_rss in (("corners", 1.0, 0.0), ("se3", 1.5, 1.0), ("summary", 0.0, 0.0)):
            rows.append({"case": f"{d:g}x480", "duration_s": d, "width_px": 640, "height_px": 480,
                         "stage": stage, "cpu_s": 0.1 * d**b_cpu, "s": 0.3 * d**b_cpu,
                         "max_rss_MB": 50.0 * d**b_rss})
    rows.append({"case": "30x720", "duration_s": 30.0, "width_px": 1280, "height_px": 720,
                 "stage": "corners", "cpu_s": 1e4, "s": 1e4, "max_rss_MB": 1e4})
    return pd.DataFrame(rows)


def test_stage_exponents_recover_the_power_laws():
    fits = stage_exponents(_table()).set_index("stage")
    assert fits.loc["corners", ["b_cpu", "b_wall", "b_rss"]].to_numpy() == pytest.approx([1.0, 1.0, 0.0])
    assert fits.loc["se3", ["b_cpu", "b_rss"]].to_numpy() == pytest.approx([1.5, 1.0])
    assert fits.loc["summary", "b_cpu"] == pytest.approx(0.0, abs=1e-9)
    assert list(fits.index) == ["se3", "corners", "summary"]  # steepest first
    assert (fits["n_lengths"] == 3).all()


def test_stage_exponents_need_two_lengths():
    one = _table()
    one = one[one["duration_s"] == 30.0]
    assert stage_exponents(one).empty


def test_plot_has_a_line_per_stage_and_the_fitted_exponent():
    fig = plot_stage_scaling(_table())
    ax_cpu, ax_wall, ax_rss = fig.axes[:3]
    assert ax_cpu.get_xscale() == "log" and ax_rss.get_yscale() == "log"
    labels = [line.get_label() for line in ax_cpu.get_lines()]
    assert "se3 (b = 1.50)" in labels and "corners (b = 1.00)" in labels
    se3 = next(line for line in ax_cpu.get_lines() if line.get_label().startswith("se3"))
    np.testing.assert_allclose(se3.get_xdata(), [30.0, 90.0, 300.0])
    assert max(ax_cpu.get_lines()[0].get_ydata()) < 1e4  # the 720p row is not drawn


def test_plot_without_cases_at_the_height_says_so():
    with pytest.raises(ValueError, match="1080"):
        plot_stage_scaling(_table(), height_px=1080)


def test_prefer_whole_runs_keeps_one_stage_set_per_stage():
    """A stage measured in whole runs at two lengths and front-only runs at three keeps the
    front-only rows (more lengths); on a tie the whole runs win; a table without ``stages``
    is returned as it is."""
    from cvsflow.plots.timing import prefer_whole_runs

    t = _table().assign(stages="all")
    front = t[t["stage"] == "corners"].assign(stages="front")
    mixed = pd.concat([t[(t["stage"] != "corners") | (t["duration_s"] < 300)], front])
    kept = prefer_whole_runs(mixed)
    assert set(kept.loc[kept["stage"] == "corners", "stages"]) == {"front"}
    assert set(kept.loc[kept["stage"] == "se3", "stages"]) == {"all"}
    tie = prefer_whole_runs(pd.concat([t, front]))
    assert set(tie.loc[tie["stage"] == "corners", "stages"]) == {"all"}
    assert len(tie) == len(t)
    assert prefer_whole_runs(_table()).equals(_table())
