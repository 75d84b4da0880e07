"""Figures of flight sessions: on-board error per axis with the reference's uncertainty band,
the aligned trajectories, and the absolute position error. Millimetres and degrees only here."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from cvsflow.metrics import ERROR_DIMS, REPORT_UNITS

#: Per axis: error column, standard-deviation column, label, unit, factor from SI.
_AXES = [(f"err_{d}", f"sigma_{d}", *REPORT_UNITS[d]) for d in ERROR_DIMS]


def plot_flight_errors(
    errors: pd.DataFrame,
    k_sigma: float = 2.0,
    injected=None,
    title: str = "On-board pose error against the camera reference",
) -> Figure:
    """On-board error per axis over time, with the reference's ±k·σ band.

    Parameters
    ----------
    errors : DataFrame
        ``FlightResult.errors``: ``t_s``, ``err_x_m .. err_yaw_rad`` (axes of L, m and rad) and
        ``sigma_x_m .. sigma_yaw_rad`` (reference standard deviations; NaN: no band).
    k_sigma : float
        Half-width of the band in standard deviations.
    injected : DataFrame, optional
        ``t_s`` and the same error columns: the known error of a rendered flight, drawn thin.
    title : str

    Returns
    -------
    Figure
        Six panels (x, y, z in mm; roll, pitch, yaw in degrees) against time in s; where the
        error lies inside the grey band, the reference cannot resolve it.
    """
    fig, axs = plt.subplots(6, 1, figsize=(9.0, 11.0), sharex=True, layout="constrained")
    t = errors["t_s"].to_numpy()
    for ax, (ec, sc, name, unit, f) in zip(axs, _AXES, strict=True):
        e = errors[ec].to_numpy() * f
        s = errors[sc].to_numpy() * f if sc in errors else np.full_like(e, np.nan)
        if np.isfinite(s).any():
            ax.fill_between(
                t,
                -k_sigma * s,
                k_sigma * s,
                color="0.8",
                step="mid",
                label=f"reference ±{k_sigma:g}σ",
            )
        ax.plot(t, e, lw=0.8, color="tab:blue", label="on-board − reference")
        if injected is not None and ec in injected:
            ax.plot(
                injected["t_s"],
                injected[ec] * f,
                lw=0.6,
                color="tab:red",
                alpha=0.8,
                label="injected (truth)",
            )
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_ylabel(f"{name} error ({unit})")
    axs[0].legend(loc="upper right", fontsize=8, ncol=3)
    axs[-1].set_xlabel("time, reference clock (s)")
    fig.suptitle(title)
    return fig


def plot_flight_trajectories(ref_aligned: pd.DataFrame, est_aligned: pd.DataFrame) -> Figure:
    """The reference and the aligned on-board body positions in the camera frame (metres).

    Parameters
    ----------
    ref_aligned, est_aligned : DataFrame
        ``FlightResult.ref_aligned`` / ``est_aligned`` (common form, T_C_Q, metres).

    Returns
    -------
    Figure
        Top view (camera x right against z forward) and side view (z forward against y down).
    """
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11.0, 4.5), layout="constrained")
    for df, lab, c in (
        (ref_aligned, "camera reference", "k"),
        (est_aligned, "on-board, aligned", "tab:orange"),
    ):
        a1.plot(df["x_m"], df["z_m"], lw=0.8, color=c, label=lab)
        a2.plot(df["z_m"], df["y_m"], lw=0.8, color=c, label=lab)
    a1.plot([0], [0], "k^", label="camera")
    a2.plot([0], [0], "k^")
    a1.set_xlabel("camera x, right (m)")
    a1.set_ylabel("camera z, forward (m)")
    a2.set_xlabel("camera z, forward (m)")
    a2.set_ylabel("camera y, down (m)")
    a2.invert_yaxis()
    a1.set_aspect("equal", adjustable="datalim")
    a1.legend(fontsize=8)
    a1.set_title("top view")
    a2.set_title("side view")
    return fig


def plot_ape(errors: pd.DataFrame, stats: dict | None = None) -> Figure:
    """Absolute position error (mm) over time and its histogram, with evo-style statistics.

    Parameters
    ----------
    errors : DataFrame
        ``t_s``, ``ape_m``.
    stats : dict, optional
        ``FlightResult.stats``; its ``ape_trans`` rmse/mean/median are drawn as lines.

    Returns
    -------
    Figure
    """
    fig, (a1, a2) = plt.subplots(
        1, 2, figsize=(11.0, 4.0), layout="constrained", gridspec_kw={"width_ratios": [3, 1]}
    )
    e = errors["ape_m"].to_numpy() * 1e3
    a1.plot(errors["t_s"], e, lw=0.8)
    a1.set_xlabel("time, reference clock (s)")
    a1.set_ylabel("absolute position error (mm)")
    a2.hist(e[np.isfinite(e)], bins=40, orientation="horizontal", color="tab:blue")
    a2.set_xlabel("frames")
    a2.set_ylabel("absolute position error (mm)")
    if stats is not None and "ape_trans" in stats:
        for k, c in (("rmse", "tab:red"), ("mean", "tab:green"), ("median", "tab:purple")):
            v = stats["ape_trans"][k] * 1e3
            a1.axhline(v, color=c, ls="--", lw=0.8, label=f"{k} {v:.1f} mm")
        a1.legend(fontsize=8)
    a1.set_title("APE (translation)")
    return fig
