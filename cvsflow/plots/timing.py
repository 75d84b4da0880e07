"""How each pipeline stage's cost grows with the session: the figure of bench/bench_scaling.py.

Takes the benchmark table that script writes (one row per case and stage: ``case``,
``duration_s``, ``width_px``, ``height_px``, ``stage``, ``s`` wall seconds, ``cpu_s``,
``max_rss_MB``), read from Snakemake's per-job benchmark files (the CPU seconds from the
jobs' logs: bench/job_times.py).
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

#: Stages drawn at most, the costliest first (the rest are summed into "other stages").
MAX_STAGES = 10
#: Columns of bench/bench_scaling.py's table that the figure reads.
BENCHMARK_COLUMNS = ("duration_s", "width_px", "height_px", "stage", "s", "cpu_s", "max_rss_MB")


def prefer_whole_runs(table):
    """One stage set per stage: the one run at the most lengths, a whole run's on a tie.

    A stage measured both in whole runs (``stages == "all"``) and in front-only runs keeps
    the rows of one kind only, so that its lengths come from runs made alike (the exponent
    compares them).

    Parameters
    ----------
    table : pandas.DataFrame
        bench/bench_scaling.py's CSV; without a ``stages`` column it is returned as it is.

    Returns
    -------
    pandas.DataFrame
        The rows kept, in their order.
    """
    if "stages" not in table:
        return table
    counts = table.groupby(["stage", "stages"])["duration_s"].nunique().reset_index()
    counts["whole"] = counts["stages"] == "all"
    best = counts.sort_values(["duration_s", "whole"], ascending=False).drop_duplicates("stage")
    keep = table.set_index(["stage", "stages"]).index.isin(best.set_index(["stage", "stages"]).index)
    return table[keep]


def plot_stage_scaling(table, height_px=480):
    """CPU seconds, wall seconds and peak memory per stage against session length (log-log).

    Parameters
    ----------
    table : pandas.DataFrame
        bench/bench_scaling.py's CSV: ``duration_s``, ``height_px``, ``stage``, ``cpu_s``,
        ``s`` (wall), ``max_rss_MB``. Only the rows at ``height_px`` are drawn against length.
    height_px : int
        Image height of the cases drawn (640x480 by default).

    Returns
    -------
    Figure
        Three log-log axes (CPU s, wall s, peak RSS MB against session length in s), one line
        per stage, with dotted guides of slope 1 (linear) in the time panels; the legend gives
        each stage's fitted exponent of CPU time (least squares in log-log).
    """
    rows = table[table["height_px"] == height_px]
    if rows.empty:
        raise ValueError(f"benchmark table: no case at height {height_px} px")
    order = list(rows.groupby("stage")["cpu_s"].max().sort_values(ascending=False).index)
    fig = Figure(figsize=(15.0, 5.0), layout="constrained")
    axes = fig.subplots(1, 3)
    fig.suptitle(f"Cost of each stage against session length ({rows['width_px'].iloc[0]}x{height_px}, "
                 "rendering excluded; from the jobs' benchmark files and logs)")
    lengths = np.sort(rows["duration_s"].unique())
    for stage in order[:MAX_STAGES]:
        g = rows[rows["stage"] == stage].sort_values("duration_s")
        b = _slope(g["duration_s"], g["cpu_s"])
        label = stage if b is None else f"{stage} (b = {b:.2f})"
        for ax, col in zip(axes, ("cpu_s", "s", "max_rss_MB"), strict=True):
            ax.plot(g["duration_s"], g[col], "o-", ms=4, label=label)
    if len(order) > MAX_STAGES:
        rest = rows[rows["stage"].isin(order[MAX_STAGES:])].groupby("duration_s")
        for ax, col, agg in zip(axes, ("cpu_s", "s", "max_rss_MB"), ("sum", "sum", "max"), strict=True):
            r = rest[col].agg(agg)
            ax.plot(r.index, r.to_numpy(), "o--", color="grey", ms=3,
                    label=f"{len(order) - MAX_STAGES} other stages ({agg})")
    for ax, ylabel in zip(axes, ("CPU time (s)", "wall time (s)", "peak RSS (MB)"), strict=True):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("session length (s)")
        ax.set_ylabel(ylabel)
        ax.set_xticks(lengths, [f"{v:g}" for v in lengths])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.grid(True, which="both", alpha=0.3)
    for ax, col in zip(axes[:2], ("cpu_s", "s"), strict=True):
        # slope-1 guides through the largest stage's first point: parallel lines are linear
        y0 = rows[rows["stage"] == order[0]].sort_values("duration_s")[col].iloc[0]
        ax.plot(lengths, y0 * lengths / lengths[0], "k:", lw=1, label="slope 1 (linear)")
    axes[0].set_title("CPU time (b: fitted exponent)")
    axes[1].set_title("wall time (the machine's load included)")
    axes[2].set_title("peak memory of the job")
    axes[0].legend(fontsize=7, loc="upper left")
    return fig


def stage_exponents(table, height_px=480):
    """Per stage, the exponent b of ``cost = a * duration_s**b`` (log-log least squares).

    Parameters
    ----------
    table : pandas.DataFrame
        bench/bench_scaling.py's CSV (``duration_s``, ``height_px``, ``stage``, ``cpu_s``,
        ``s``, ``max_rss_MB``).
    height_px : int
        Only the cases at this image height enter the fit.

    Returns
    -------
    pandas.DataFrame
        ``stage``, ``n_lengths``, ``b_cpu``, ``b_wall``, ``b_rss`` (1: linear, 0: flat),
        stages with fewer than two session lengths left out, steepest CPU exponent first.
    """
    import pandas as pd

    out = []
    for stage, g in table[table["height_px"] == height_px].groupby("stage"):
        n = g["duration_s"].nunique()
        if n < 2:
            continue
        out.append({"stage": stage, "n_lengths": n, "b_cpu": _slope(g["duration_s"], g["cpu_s"]),
                    "b_wall": _slope(g["duration_s"], g["s"]),
                    "b_rss": _slope(g["duration_s"], g["max_rss_MB"])})
    cols = ["stage", "n_lengths", "b_cpu", "b_wall", "b_rss"]
    return pd.DataFrame(out, columns=cols).sort_values("b_cpu", ascending=False, ignore_index=True)


def _slope(x, y):
    """Least-squares slope of log y against log x, or None with fewer than two lengths."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if np.unique(x).size < 2:
        return None
    return float(np.polyfit(np.log(x), np.log(np.maximum(y, 1e-3)), 1)[0])
