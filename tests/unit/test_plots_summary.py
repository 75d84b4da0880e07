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
