"""Figures across runs: the focal-initialisation sweep and the comparison of sessions.

Both take the summary table of :func:`cvsflow.evaluate.summary.summary_row` rows (px, mm, deg).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch

STD_COLUMNS = ["std_x_mm", "std_y_mm", "std_z_mm", "std_roll_deg", "std_pitch_deg", "std_yaw_deg"]


def _diverged(rows):
    return rows["diverged"].astype(bool).to_numpy() if "diverged" in rows else np.zeros(len(rows), bool)


def plot_sweep(summary):
    """Final fx, fy and error norm against the initial focal length, per session and method.

    Every start should reach the same answer: flat lines mean the optimiser forgets its start.
    Both fx and fy are drawn against the run's initial fx (a calibrated start has fx != fy).
    A session with a single start value has no sweep to draw: its column shows the final
    focal lengths per method beside the start and the truth, and says that one start was run.
    Diverged runs (the seed method's own check) are marked with a red cross.

    Parameters
    ----------
    summary : DataFrame
        One row per (session, method, start): ``session``, ``method``, ``fx_init_px``,
        ``fx_px``, ``fy_px`` (px), ``norm_final_mm`` (mm, RMS), optionally ``fx_true_px``
        (px; NaN or absent: no truth line) and ``diverged`` (bool; absent: none diverged).

    Returns
    -------
    Figure
        2 x n_sessions axes: focal lengths (px, log when a run diverged), error norm (mm, log).
    """
    sessions = list(dict.fromkeys(summary["session"]))
    fig = Figure(figsize=(5.0 * len(sessions), 7.0), layout="constrained")
    axes = np.atleast_2d(fig.subplots(2, len(sessions), squeeze=False))
    fig.suptitle("Sweep over the focal-length initialisation (config optimise.f_init)")
    for j, session in enumerate(sessions):
        ax_f, ax_n = axes[0, j], axes[1, j]
        rows = summary[summary["session"] == session]
        starts = rows["fx_init_px"].round(6).nunique()
        methods = list(dict.fromkeys(rows["method"]))
        for k, method in enumerate(methods):
            runs = rows[rows["method"] == method].sort_values("fx_init_px")
            bad = _diverged(runs)
            if starts > 1:
                x = runs["fx_init_px"].to_numpy(float)
                line = ax_f.plot(x, runs["fx_px"], "o-", label=f"{method} fx")[0]
                ax_f.plot(x, runs["fy_px"], "s--", color=line.get_color(), label=f"{method} fy")
                ax_n.plot(x, runs["norm_final_mm"], "o-", color=line.get_color(), label=method)
            else:  # one start: the methods side by side at categorical positions
                x = np.full(len(runs), float(k))
                color = f"C{k}"
                ax_f.plot(x - 0.08, runs["fx_px"], "o", color=color, label=f"{method} fx")
                ax_f.plot(x + 0.08, runs["fy_px"], "s", color=color, label=f"{method} fy")
                ax_f.plot(x, runs["fx_init_px"], "_", color="0.4", ms=18,
                          label="start fx" if k == 0 else None)
                ax_n.bar(x, runs["norm_final_mm"], 0.5, color=color, label=method)
            if bad.any():
                for col in ("fx_px", "fy_px"):
                    ax_f.plot(x[bad], runs[col].to_numpy(float)[bad], "x", color="tab:red", ms=12,
                              mew=2, label="diverged" if col == "fx_px" and k == 0 else None)
                ax_n.plot(x[bad], runs["norm_final_mm"].to_numpy(float)[bad], "x",
                          color="tab:red", ms=12, mew=2)
        if "fx_true_px" in rows and rows["fx_true_px"].notna().any():
            ax_f.axhline(rows["fx_true_px"].iloc[0], color="k", lw=0.8, ls=":", label="true fx")
        if _diverged(rows).any():  # the diverged focal lengths are orders of magnitude away
            ax_f.set_yscale("log")
        if starts > 1:
            ax_f.set(title=session, xlabel="initial focal length fx (px)",
                     ylabel="final focal length (px)")
            ax_n.set(xlabel="initial focal length fx (px)")
        else:
            f0 = rows["fx_init_px"].iloc[0]
            ax_f.set(title=f"{session}: one start only (fx {f0:.1f} px), no sweep",
                     ylabel="final focal length (px)")
            for ax in (ax_f, ax_n):
                ax.set_xticks(range(len(methods)), methods)
                ax.set_xlim(-0.6, len(methods) - 0.4)
                ax.set_xlabel("method")
        # log scale: the methods' errors differ by orders of magnitude
        ax_n.set(ylabel="error norm after (mm, RMS)", yscale="log")
        ax_f.legend(fontsize=8)
        ax_n.legend(fontsize=8)
        for ax in (ax_f, ax_n):
            ax.grid(alpha=0.3, which="both")
    return fig


def plot_sessions(summary):
    """Error spread per dimension for each session and method (mm and deg), side by side.

    The axes are logarithmic: se3 errors are millimetres, a diverged seed run's are metres.
    Bars of a diverged run are hatched and labelled "diverged": not measurements.

    Parameters
    ----------
    summary : DataFrame
        Rows with ``session``, ``method``, the :data:`STD_COLUMNS` (``std_{x,y,z}_mm`` in mm,
        ``std_{roll,pitch,yaw}_deg`` in deg) and optionally ``diverged`` (bool); only the
        first row of each (session, method) is drawn (the first focal initialisation).

    Returns
    -------
    Figure
        2 axes: translation std (mm, log), rotation std (deg, log).
    """
    table = summary.drop_duplicates(["session", "method"]).reset_index(drop=True)
    bad = _diverged(table)
    labels = [f"{s}\n{m}" + ("\n(diverged)" if b else "")
              for s, m, b in zip(table["session"], table["method"], bad, strict=True)]
    fig = Figure(figsize=(max(6.0, 1.6 * len(labels) + 3), 6.5), layout="constrained")
    ax_t, ax_r = fig.subplots(2, 1)
    x = np.arange(len(labels))
    for ax, cols, unit in ((ax_t, STD_COLUMNS[:3], "mm"), (ax_r, STD_COLUMNS[3:], "deg")):
        width = 0.8 / len(cols)
        for k, col in enumerate(cols):
            bars = ax.bar(x + (k - 1) * width, table[col], width, label=col.split("_")[1],
                          color=f"C{k}")
            for bar, b in zip(bars, bad, strict=True):
                if b:
                    bar.set_hatch("//")
                    bar.set_edgecolor("tab:red")
            ax.bar_label(bars, fmt="%.3g", fontsize=7)
        ax.set_xticks(x, labels)
        ax.set_yscale("log")
        ax.set_ylabel(f"error std ({unit}, log scale)")
        # Plain patches: the legend must not take a diverged bar's hatch.
        ax.legend([Patch(color=f"C{k}") for k in range(len(cols))],
                  [c.split("_")[1] for c in cols], fontsize=8)
        ax.grid(alpha=0.3, axis="y", which="both")
    fig.suptitle("Error spread per session and method (first focal initialisation); "
                 "hatched: diverged, not a measurement")
    return fig
