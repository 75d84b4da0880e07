"""Figures across runs: the focal-initialisation sweep and the comparison of sessions.

Both take the summary table of :func:`cvsflow.analyse.summary_row` rows (px, mm, deg).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

STD_COLUMNS = ["std_x_mm", "std_y_mm", "std_z_mm", "std_roll_deg", "std_pitch_deg", "std_yaw_deg"]


def plot_sweep(summary):
    """Final fx, fy and error norm against the initial focal length, per session and method.

    Every start should reach the same answer: flat lines mean the optimiser forgets its start.
    """
    sessions = list(dict.fromkeys(summary["session"]))
    fig = Figure(figsize=(5.0 * len(sessions), 7.0), layout="constrained")
    axes = np.atleast_2d(fig.subplots(2, len(sessions), squeeze=False))
    fig.suptitle("Sweep over the focal-length initialisation")
    for j, session in enumerate(sessions):
        ax_f, ax_n = axes[0, j], axes[1, j]
        for method, runs in summary[summary["session"] == session].groupby("method"):
            runs = runs.sort_values("fx_init_px")
            line = ax_f.plot(runs["fx_init_px"], runs["fx_px"], "o-", label=f"{method} fx")[0]
            ax_f.plot(runs["fy_init_px"], runs["fy_px"], "s--", color=line.get_color(),
                      label=f"{method} fy")
            ax_n.plot(runs["fx_init_px"], runs["norm_final_mm"], "o-", label=method)
        rows = summary[summary["session"] == session]
        if "fx_true_px" in rows and rows["fx_true_px"].notna().any():
            ax_f.axhline(rows["fx_true_px"].iloc[0], color="k", lw=0.8, ls=":", label="true fx")
        ax_f.set(title=session, xlabel="initial focal length (px)", ylabel="final focal length (px)")
        # log scale: the methods' errors differ by orders of magnitude
        ax_n.set(xlabel="initial focal length (px)", ylabel="error norm after (mm, RMS)", yscale="log")
        ax_f.legend(fontsize=8)
        ax_n.legend(fontsize=8)
        for ax in (ax_f, ax_n):
            ax.grid(alpha=0.3)
    return fig


def plot_sessions(summary):
    """Error spread per dimension for each session and method (mm and deg), side by side."""
    table = summary.drop_duplicates(["session", "method"])
    labels = [f"{s}\n{m}" for s, m in zip(table["session"], table["method"], strict=True)]
    fig = Figure(figsize=(max(6.0, 1.6 * len(labels) + 3), 6.5), layout="constrained")
    ax_t, ax_r = fig.subplots(2, 1)
    x = np.arange(len(labels))
    for ax, cols, unit in ((ax_t, STD_COLUMNS[:3], "mm"), (ax_r, STD_COLUMNS[3:], "deg")):
        width = 0.8 / len(cols)
        for k, col in enumerate(cols):
            ax.bar(x + (k - 1) * width, table[col], width, label=col.split("_")[1])
        ax.set_xticks(x, labels)
        ax.set_ylabel(f"error std ({unit})")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle("Error spread per session and method (first focal initialisation)")
    return fig
