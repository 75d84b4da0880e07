"""The cross-run figures draw one column per session and label their units."""

import numpy as np
import pandas as pd

from cvsflow.plots.summary import plot_sessions, plot_sweep


def _summary():
    rng = np.random.default_rng(5)
    rows = []
    for session in ("a", "b"):
        for method in ("seed", "se3"):
            for f0 in (500.0, 700.0, 900.0):
                rows.append({"session": session, "method": method, "fx_init_px": f0, "fy_init_px": f0,
                             "fx_px": 700 + rng.normal(), "fy_px": 699 + rng.normal(),
                             "fx_true_px": 700.0, "norm_final_mm": 5 + rng.random(),
                             **{c: rng.random() for c in ("std_x_mm", "std_y_mm", "std_z_mm",
                                                          "std_roll_deg", "std_pitch_deg",
                                                          "std_yaw_deg")}})
    return pd.DataFrame(rows)


def test_sweep_figure_has_two_rows_per_session_with_units():
    """plot_sweep: 2 x n_sessions axes, px and mm in the labels, one line per method and axis."""
    fig = plot_sweep(_summary())
    axes = fig.get_axes()
    assert len(axes) == 4
    assert "(px)" in axes[0].get_ylabel() and "(mm" in axes[2].get_ylabel()
    assert len(axes[0].get_lines()) == 2 * 2 + 1  # fx and fy per method, and the true fx


def test_sessions_figure_bars_every_session_method():
    """plot_sessions: one bar group per (session, method), translation in mm, rotation in deg."""
    fig = plot_sessions(_summary())
    ax_t, ax_r = fig.get_axes()
    assert len(ax_t.patches) == 4 * 3 and len(ax_r.patches) == 4 * 3
    assert "mm" in ax_t.get_ylabel() and "deg" in ax_r.get_ylabel()


def test_sessions_figure_is_logarithmic_and_hatches_diverged_runs():
    """se3 (mm) beside a diverged seed (m) on a log axis; the diverged run's bars are hatched."""
    summary = _summary()
    summary["diverged"] = summary["method"] == "seed"
    summary.loc[summary["method"] == "seed", "std_x_mm"] = 1200.0
    fig = plot_sessions(summary)
    ax_t, ax_r = fig.get_axes()
    assert ax_t.get_yscale() == "log" and ax_r.get_yscale() == "log"
    hatched = [p for p in ax_t.patches if p.get_hatch()]
    assert len(hatched) == 2 * 3  # two seed runs (sessions a and b), x y z each
    assert "(diverged)" in ax_t.get_xticklabels()[0].get_text()
    assert not any(h.get_hatch() for h in ax_t.get_legend().get_patches())


def test_sweep_with_one_start_is_a_comparison_not_a_line():
    """One f_init per session: methods on a categorical axis, the start and 'no sweep' stated."""
    summary = _summary()
    summary = summary[summary["fx_init_px"] == 700.0].copy()
    summary["fy_init_px"] = 698.0  # a calibrated start: fx and fy differ
    summary["diverged"] = summary["method"] == "seed"
    fig = plot_sweep(summary)
    ax_f, ax_n = fig.get_axes()[0], fig.get_axes()[2]
    assert "one start only" in ax_f.get_title() and "no sweep" in ax_f.get_title()
    assert [t.get_text() for t in ax_f.get_xticklabels()] == ["seed", "se3"]
    # every marker sits at its method's position, none at an initial focal length
    xs = np.concatenate([line.get_xdata() for line in ax_f.get_lines() if len(line.get_xdata()) == 1])
    assert np.all(np.abs(xs) < 1.5)
    assert "diverged" in [t.get_text() for t in ax_f.get_legend().get_texts()]
    assert ax_f.get_yscale() == "log" and ax_n.get_yscale() == "log"


def test_sweep_draws_fy_against_the_same_start_as_fx():
    """A sweep: fx and fy of one run share the x position (the start's fx), a line per method."""
    summary = _summary()
    summary["fy_init_px"] = summary["fx_init_px"] - 3.0
    fig = plot_sweep(summary)
    ax_f = fig.get_axes()[0]
    lines = [line for line in ax_f.get_lines() if len(line.get_xdata()) == 3]
    assert len(lines) == 4
    for line in lines:
        np.testing.assert_allclose(line.get_xdata(), [500.0, 700.0, 900.0])
