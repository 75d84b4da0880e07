"""Figures of the se3 method: held-out errors, predicted bands, parameter correlations.

Every function takes tables/arrays in SI units and returns a Figure; millimetres and degrees
appear only here, in the axis labels.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

DIMS = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
LABELS = ("x (mm)", "y (mm)", "z (mm)", "roll (deg)", "pitch (deg)", "yaw (deg)")
SCALE = (1e3, 1e3, 1e3, np.degrees(1.0), np.degrees(1.0), np.degrees(1.0))


def plot_heldout_errors(errors: pd.DataFrame) -> Figure:
    """Histograms of the held-out composed errors per dimension, beside the 6-vector ones.

    Parameters
    ----------
    errors : DataFrame
        ``err_{dim}`` (composed, :func:`cvsflow.evaluate.heldout.pose_errors`) and optionally
        ``d6_{dim}`` (chapter-style 6-vector differences) per frame; SI units.

    Returns
    -------
    Figure
        2 x 3 panels (x, y, z in mm; roll, pitch, yaw in deg); the legend gives mean and std.
    """
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5), layout="constrained")
    frame = errors["error_frame"].iloc[0] if "error_frame" in errors else "C"
    for ax, d, label, k in zip(axes.ravel(), DIMS, LABELS, SCALE, strict=True):
        e = errors[f"err_{d}"].to_numpy(float) * k
        bins = np.histogram_bin_edges(e[np.isfinite(e)], bins=40)
        ax.hist(e, bins=bins, alpha=0.7, label=f"composed: {e.mean():+.3f} ± {e.std(ddof=1):.3f}")
        if f"d6_{d}" in errors:
            e6 = errors[f"d6_{d}"].to_numpy(float) * k
            ax.hist(e6, bins=bins, histtype="step", color="k",
                    label=f"6-vector: {e6.mean():+.3f} ± {e6.std(ddof=1):.3f}")  # fmt: skip
        ax.set_xlabel(f"error {label}")
        ax.set_ylabel("frames")
        ax.legend(fontsize=7)
    fig.suptitle(f"Held-out CVS pose errors (estimate - Vicon reference), frame {frame}")
    return fig


def plot_error_bands(errors: pd.DataFrame, sigma: np.ndarray, mu=None) -> Figure:
    """Held-out errors against the error model's predicted 68 % and 95 % bands.

    Parameters
    ----------
    errors : DataFrame
        ``t_s`` (s) and ``err_{dim}`` (SI) per frame.
    sigma : ndarray, shape (N, 6)
        Predicted standard deviation per frame and dimension (m, rad).
    mu : ndarray, shape (6,), optional
        Predicted bias (m, rad); default zero.

    Returns
    -------
    Figure
        One panel per dimension over time: errors as dots, bands as shaded areas, with the
        share inside the 95 % band in the title.
    """
    sigma = np.asarray(sigma, float)
    mu = np.zeros(6) if mu is None else np.asarray(mu, float)
    t = errors["t_s"].to_numpy(float)
    order = np.argsort(t)
    fig, axes = plt.subplots(6, 1, figsize=(11, 12), sharex=True, layout="constrained")
    for j, (ax, d, label, k) in enumerate(zip(axes, DIMS, LABELS, SCALE, strict=True)):
        e = errors[f"err_{d}"].to_numpy(float)[order] * k
        s = sigma[order, j] * k
        m = mu[j] * k
        ax.fill_between(t[order], m - 1.96 * s, m + 1.96 * s, color="tab:blue", alpha=0.15,
                        step="mid", label="95 % band")  # fmt: skip
        ax.fill_between(t[order], m - s, m + s, color="tab:blue", alpha=0.3, step="mid",
                        label="68 % band")  # fmt: skip
        ax.plot(t[order], e, ".", ms=2, color="k", label="held-out error")
        inside = np.mean(np.abs(e - m) <= 1.96 * s)
        ax.set_ylabel(f"error {label}")
        ax.set_title(f"{label.split()[0]}: {100 * inside:.1f} % inside the 95 % band", fontsize=9)
    axes[0].legend(fontsize=7, ncol=3)
    axes[-1].set_xlabel("video time (s)")
    return fig


def plot_parameter_correlation(result: dict) -> Figure:
    """Heat map of the correlations between the se3 estimates.

    Parameters
    ----------
    result : dict
        se3 result.yaml content (``correlation``: ``names``, ``matrix``).

    Returns
    -------
    Figure
        Correlation matrix (-1 to 1), cells beyond |0.95| outlined and annotated.
    """
    names = result["correlation"]["names"]
    C = np.asarray(result["correlation"]["matrix"], float)
    fig, ax = plt.subplots(figsize=(9, 8), layout="constrained")
    im = ax.imshow(C, vmin=-1, vmax=1, cmap="RdBu_r")
    for i, j in zip(*np.nonzero((np.abs(C) > 0.95) & ~np.eye(len(C), dtype=bool)), strict=True):
        ax.text(j, i, f"{C[i, j]:.2f}", ha="center", va="center", fontsize=6)
    ax.set_xticks(range(len(names)), names, rotation=90, fontsize=7)
    ax.set_yticks(range(len(names)), names, fontsize=7)
    fig.colorbar(im, ax=ax, label="correlation (dimensionless)")
    ax.set_title("se3 estimate correlations (from (J^T J)^-1)")
    return fig


def plot_solver_convergence(iterations: pd.DataFrame) -> Figure:
    """The se3 solver's steps: robust cost, reprojection RMS (px), fx, fy (px) and time offset (ms).

    Parameters
    ----------
    iterations : DataFrame
        One row per solver step: ``iteration``, ``cost`` (robust cost, > 0: drawn on a log
        axis), ``rms_px``, ``fx_px``, ``fy_px`` (px) and ``dt_offset_s`` (s).

    Returns
    -------
    Figure
        2 x 2 axes against the solver step: cost, reprojection RMS, fx and fy, time offset.
    """
    fig = Figure(figsize=(10.0, 6.0), layout="constrained")
    ax = fig.subplots(2, 2).ravel()
    it = iterations["iteration"].to_numpy()
    ax[0].semilogy(it, iterations["cost"], "o-")
    ax[0].set(ylabel="robust cost", title="cost")
    ax[1].plot(it, iterations["rms_px"], "o-")
    ax[1].set(ylabel="reprojection RMS (px)", title="corner residuals")
    ax[2].plot(it, iterations["fx_px"], "o-", label="fx")
    ax[2].plot(it, iterations["fy_px"], "s-", label="fy")
    ax[2].set(ylabel="focal length (px)", title="focal lengths")
    ax[2].legend()
    ax[3].plot(it, 1e3 * iterations["dt_offset_s"], "o-")
    ax[3].set(ylabel="time offset (ms)", title="video to Vicon offset")
    for a in ax:
        a.set_xlabel("solver step")
        a.grid(alpha=0.3)
    fig.suptitle("se3: convergence of the joint calibration")
    return fig


def plot_errors_by_view(binned: pd.DataFrame) -> Figure:
    """Held-out RMS error per axis against the board's distance and against its tilt.

    Parameters
    ----------
    binned : DataFrame
        :func:`cvsflow.evaluate.by_view.errors_by_view`: rows ``by`` (``distance_m`` or
        ``tilt_rad``), ``centre``, ``n`` and the RMS of each error dimension (SI).

    Returns
    -------
    Figure
        Two rows (translation in mm, rotation in deg) by two columns (distance in m, tilt in
        deg); one line per axis through the bins' medians.
    """
    from cvsflow.metrics import ERROR_DIMS, REPORT_UNITS

    fig, axes = plt.subplots(2, 2, figsize=(10.0, 6.5), layout="constrained", sharex="col")
    for col, (by, xlabel, xk) in enumerate((("distance_m", "board distance (m)", 1.0),
                                            ("tilt_rad", "board tilt from facing the camera (deg)",
                                             180.0 / np.pi))):
        part = binned[binned["by"] == by]
        for row, dims in enumerate((ERROR_DIMS[:3], ERROR_DIMS[3:])):
            ax = axes[row, col]
            for d in dims:
                label, unit, k = REPORT_UNITS[d]
                ax.plot(xk * part["centre"], k * part[d], "o-", ms=3, label=label)
            ax.set_ylabel(f"held-out RMS ({unit})")
            ax.set_ylim(bottom=0.0)
            ax.legend(fontsize=8)
            if row == 1:
                ax.set_xlabel(xlabel)
    n = int(binned[binned["by"] == "distance_m"]["n"].sum()) if len(binned) else 0
    fig.suptitle(f"Held-out error against the board's distance and tilt ({n} frames, equal-count bins)")
    return fig
