"""Figures of the Vicon half: marker gaps and fills, rigid-body fit residuals, synchronisation."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from cvsflow.geometry import sample_period
from cvsflow.plots.decimate import min_max_envelope


def _marker_names(df):
    if "markers" in df.attrs:
        return list(df.attrs["markers"])
    return [c[: -len("_x_m")] for c in df.columns if c.endswith("_x_m")]


def plot_marker_gaps(markers_filled: pd.DataFrame, summary: dict | None = None) -> Figure:
    """Marker state over time: measured, filled (rigid body or interpolation) or missing.

    Parameters
    ----------
    markers_filled : DataFrame
        ``markers_filled`` table (``t_s``, ``{marker}_{x,y,z}_m``, ``{marker}_filled``).
    summary : dict, optional
        The summary of :func:`cvsflow.mocap.repair.fill_marker_gaps`; its per-marker counts are shown
        beside each marker's name (rigid / interpolated / missing samples).

    Returns
    -------
    Figure
        One row per marker against time in s: white measured, blue filled, red missing.
    """
    names = _marker_names(markers_filled)
    t = markers_filled["t_s"].to_numpy(float)
    state = np.zeros((len(names), len(t)), dtype=int)
    for i, n in enumerate(names):
        missing = ~np.isfinite(markers_filled[f"{n}_x_m"].to_numpy(float))
        filled_col = f"{n}_filled"
        filled = markers_filled[filled_col].to_numpy(bool) if filled_col in markers_filled else 0
        state[i] = np.where(missing, 2, np.where(filled, 1, 0))
    fig, ax = plt.subplots(figsize=(10.0, 1.0 + 0.35 * len(names)), layout="constrained")
    cmap = ListedColormap(["white", "tab:blue", "tab:red"])
    dt = sample_period(t, default=1.0)
    ax.imshow(
        state,
        aspect="auto",
        interpolation="nearest",
        cmap=cmap,
        vmin=0,
        vmax=2,
        extent=(t[0] - dt / 2, t[-1] + dt / 2, len(names) - 0.5, -0.5),
    )
    labels = []
    for n in names:
        c = (summary or {}).get("per_marker", {}).get(n)
        labels.append(f"{n}  ({c['rigid']}/{c['interp']}/{c['missing']})" if c else n)
    ax.set_yticks(np.arange(len(names)), labels)
    ax.set_xlabel("Vicon time t (s)")
    title = "Marker samples: measured, filled, missing"
    if summary:
        tot = summary["total"]
        title += (
            f"  [rigid {tot['rigid']}, interpolated {tot['interp']}, missing {tot['missing']} "
            f"samples; max gap {summary['max_gap_s'] * 1000:g} ms]"
        )
    ax.set_title(title, fontsize=9)
    ax.legend(
        handles=[
            Patch(facecolor="white", edgecolor="k", label="measured"),
            Patch(facecolor="tab:blue", label="filled"),
            Patch(facecolor="tab:red", label="missing"),
        ],
        loc="upper right",
        fontsize=8,
        ncols=3,
    )
    return fig


def plot_fit_residuals(bodies: pd.DataFrame) -> Figure:
    """Rigid-body fit RMS residual (mm) and marker counts over time, per body.

    Parameters
    ----------
    bodies : DataFrame
        ``bodies`` table (``t_s``, ``body``, ``valid``, ``fit_rms_m``, ``n_markers``,
        ``n_filled``).

    Returns
    -------
    Figure
        Top: fit RMS in mm (log scale), invalid samples marked at the bottom. Bottom: markers
        used and filled markers used.
    """
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(10.0, 6.0), sharex=True, layout="constrained")
    for body, sub in bodies.groupby("body", sort=False):
        t = sub["t_s"].to_numpy(float)
        rms_mm = sub["fit_rms_m"].to_numpy(float) * 1000.0
        (line,) = ax0.plot(*min_max_envelope(t, rms_mm), lw=0.8,
                           label=f"{body} (median {np.nanmedian(rms_mm):.2f} mm)")
        bad = ~sub["valid"].to_numpy(bool)
        if bad.any():
            ax0.plot(t[bad], np.full(bad.sum(), np.nanmin(rms_mm[~bad]) if (~bad).any() else 1e-3),
                     "|", color=line.get_color(), ms=10, label=f"{body} invalid ({bad.sum()} samples)")
        ax1.step(*min_max_envelope(t, sub["n_markers"]), where="mid", color=line.get_color(), lw=0.8,
                 label=f"{body} used")
        ax1.step(*min_max_envelope(t, sub["n_filled"]), where="mid", color=line.get_color(), lw=0.8,
                 ls="--", label=f"{body} filled")
    ax0.set_yscale("log")
    ax0.set_ylabel("fit RMS residual (mm)")
    ax0.set_title("Rigid-body fit residual of the markers to their layout")
    ax0.legend(fontsize=8)
    ax1.set_ylabel("markers (count)")
    ax1.set_xlabel("Vicon time t (s)")
    ax1.legend(fontsize=8, ncols=2)
    return fig


def plot_stream_bodies(bodies: pd.DataFrame) -> Figure:
    """The bodies of a session whose motion capture is two pose streams (no marker fit to show).

    Parameters
    ----------
    bodies : DataFrame
        ``bodies`` table (``t_s``, ``body``, ``valid``, ``x_m``, ``y_m``, ``z_m``).

    Returns
    -------
    Figure
        Top: each body's distance from its median position (mm, log scale): the camera body's
        path, a still board's jitter. Bottom: the samples where a body's pose is unknown
        (outside its stream or in a gap).
    """
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(10.0, 6.0), sharex=True, layout="constrained",
                                   height_ratios=[3, 1])
    for k, (body, sub) in enumerate(bodies.groupby("body", sort=False)):
        t = sub["t_s"].to_numpy(float)
        xyz = sub[["x_m", "y_m", "z_m"]].to_numpy(float)
        d_mm = 1000.0 * np.linalg.norm(xyz - np.nanmedian(xyz, axis=0), axis=1)
        (line,) = ax0.plot(*min_max_envelope(t, np.maximum(d_mm, 1e-3)), lw=0.8,
                           label=f"{body} (median {np.nanmedian(d_mm):.1f} mm)")
        bad = ~sub["valid"].to_numpy(bool)
        ax1.plot(t[bad], np.full(bad.sum(), k), "|", color=line.get_color(), ms=10,
                 label=f"{body}: {bad.sum()} of {len(t)} samples unknown")
    ax0.set_yscale("log")
    ax0.set_ylabel("distance from its median position (mm)")
    ax0.set_title("Bodies from pose streams (poses as recorded: no marker fit, no residual)")
    ax0.legend(fontsize=8)
    ax1.set_yticks([])
    ax1.set_xlabel("motion-capture time t (s)")
    ax1.legend(fontsize=8, loc="upper right")
    return fig


def plot_sync(poses_raw: pd.DataFrame, bodies: pd.DataFrame, sync: dict, camera: str = "video (PnP)",
              mocap: str = "Vicon") -> Figure:
    """Board angular speed of both systems on the Vicon clock after alignment.

    Parameters
    ----------
    poses_raw : DataFrame
        ``poses_raw`` table (video clock).
    bodies : DataFrame
        Native-rate bodies table (Vicon clock).
    sync : dict
        sync.yaml content: ``dt_offset_s`` (t_vicon_s = t_video_s + dt_offset_s), ``method``,
        ``quality``.
    camera, mocap : str
        What the legends and labels call the camera's stream and the motion capture (a
        camera-pose session: its stream file and "motion capture").

    Returns
    -------
    Figure
        Top: |omega| in deg/s of the video (shifted by the offset) and of the Vicon over the
        video's span. Bottom: their difference in deg/s at the video samples.
    """
    from cvsflow.sync import angular_speed_streams

    return plot_sync_streams(
        angular_speed_streams(poses_raw, bodies), sync["dt_offset_s"], sync.get("quality"),
        sync.get("method"), camera, mocap,
    )


def plot_sync_streams(streams: dict, dt_offset_s: float, quality: float | None = None,
                      method: str | None = None, camera: str = "video (PnP)", mocap: str = "Vicon") -> Figure:
    """:func:`plot_sync` from precomputed streams (:func:`cvsflow.sync.streams.angular_speed_streams`).

    Parameters
    ----------
    streams : dict
        ``t_cvs_s``, ``omega_cvs_rad_s`` (video clock, s and rad/s) and ``t_vicon_s``,
        ``omega_vicon_rad_s`` (Vicon clock, native samples); NaN speeds are left out of the
        difference.
    dt_offset_s : float
        t_vicon_s = t_video_s + dt_offset_s, s: the shift applied to the video stream.
    quality : float, optional
        Sync quality shown in the title; None: not shown.
    method : str, optional
        ``sync.method`` shown in the title; None: not shown.
    camera, mocap : str
        What the legends and labels call the two streams (the title and the difference's label
        leave out the camera's parenthesis).

    Returns
    -------
    Figure
        Top: before the offset, |omega| in deg/s of the video on its own clock and of the Vicon
        over the whole take (what the search started from). Middle: the video shifted by the
        offset and the Vicon over the video's span plus 1 s each side. Bottom: their difference
        in deg/s at the video samples (NaN, not drawn, outside the Vicon samples).
    """
    t_c = streams["t_cvs_s"] + dt_offset_s
    w_c = np.degrees(streams["omega_cvs_rad_s"])
    t_v = streams["t_vicon_s"]
    w_v = np.degrees(streams["omega_vicon_rad_s"])
    span = (t_v >= t_c[0] - 1.0) & (t_v <= t_c[-1] + 1.0)
    fig = plt.figure(figsize=(10.0, 8.5), layout="constrained")
    ax_raw, ax0, ax1 = fig.subplots(3, 1, height_ratios=[1.5, 2, 1])
    ax1.sharex(ax0)
    ax_raw.plot(t_v, w_v, lw=0.6, color="tab:orange", label=f"{mocap} (its clock)")
    ax_raw.plot(streams["t_cvs_s"], w_c, ".", ms=2.0, color="tab:blue",
                label=f"{camera} (its clock, offset 0)")
    ax_raw.set_title("before: both streams on their own clocks")
    ax_raw.set_ylabel("|omega| (deg/s)")
    ax_raw.set_xlabel("time on each stream's clock (s)")
    ax_raw.legend(fontsize=8)
    ax0.plot(t_v[span], w_v[span], lw=0.8, color="tab:orange", label=f"{mocap} (board rel. camera body)")
    ax0.plot(t_c, w_c, ".", ms=2.5, color="tab:blue", label=f"{camera}, shifted")
    ax0.set_ylabel("angular speed |omega| (deg/s)")
    title = f"after: {camera.split(' (')[0]} shifted by dt_offset = {dt_offset_s * 1000:.1f} ms"
    if method:
        title += f" ({method})"
    if quality is not None:
        title += f", quality {quality:.2f}"
    ax0.set_title(title)
    ax0.legend(fontsize=8)
    ok = np.isfinite(w_v)
    w_v_at = np.interp(t_c, t_v[ok], w_v[ok], left=np.nan, right=np.nan)
    ax1.plot(t_c, w_c - w_v_at, ".", ms=2.5, color="k")
    ax1.axhline(0.0, color="grey", lw=0.5)
    diff = f"{camera.split(' (')[0]} - {mocap}"
    ax1.set_ylabel(f"{diff} (deg/s)" if len(diff) < 20 else f"{diff}\n(deg/s)")  # the panel is short
    ax1.set_xlabel(f"{mocap} time t (s)")
    return fig
