"""Figures of the camera half: calibration errors and coverage, PnP pose time series."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from cvsflow.plots.decimate import min_max_envelope


def plot_calibration_errors(camera: dict) -> Figure:
    """Bar chart of the per-still reprojection RMS (px) of a calibration.

    Parameters
    ----------
    camera : dict
        camera.yaml content (``images``: list of ``{name, used, reason, rms_px}``, ``rms_px``).

    Returns
    -------
    Figure
        Used stills as bars, unused ones as grey marks at zero labelled with their reason; the
        overall RMS as a dashed line.
    """
    images = camera["images"]
    names = [im["name"] for im in images]
    rms = [im["rms_px"] if im["used"] and im["rms_px"] is not None else 0.0 for im in images]
    colours = ["tab:blue" if im["used"] else "lightgrey" for im in images]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.45 * len(names) + 2.0), 4.0), layout="constrained")
    x = np.arange(len(names))
    ax.bar(x, rms, color=colours)
    for xi, im in zip(x, images, strict=True):
        if not im["used"]:
            ax.text(xi, 0.0, f" {im['reason']}", rotation=90, va="bottom", ha="center", fontsize=7)
    ax.axhline(
        camera["rms_px"], color="tab:red", ls="--", label=f"overall RMS {camera['rms_px']:.3f} px"
    )
    ax.set_xticks(x, names, rotation=60, ha="right", fontsize=8)
    ax.set_xlabel("calibration still")
    ax.set_ylabel("reprojection RMS (px)")
    ax.set_title(f"Calibration reprojection error ({camera['n_used']} of {len(names)} stills used)")
    ax.legend()
    return fig


def _image_axes(ax, w, h):
    """Axes over the image: its outline, pixels with v down, equal aspect."""
    ax.add_patch(plt.Rectangle((0, 0), w, h, fill=False, color="black", lw=1.0))
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")


def plot_calibration_coverage(calib_corners: pd.DataFrame, camera: dict) -> Figure:
    """Where the calibration corners fell in the image, coloured by still.

    Parameters
    ----------
    calib_corners : DataFrame
        ``image, corner, u_px, v_px`` (calib_corners.parquet).
    camera : dict
        camera.yaml content (``width``, ``height`` in px).

    Returns
    -------
    Figure
        Scatter over the image frame (pixels, v down), one colour per still.
    """
    w, h = camera["width"], camera["height"]
    # the axes get ~5.3 in of the width beside the legend and equal aspect sets their height;
    # a figure too short for that would let constrained layout clip the labels
    fig, ax = plt.subplots(figsize=(7.0, 5.6 * h / w + 1.0), layout="constrained")
    cmap = plt.get_cmap("tab20")
    for i, (name, block) in enumerate(calib_corners.groupby("image", sort=True)):
        ax.scatter(block["u_px"], block["v_px"], s=8, color=cmap(i % 20), label=name)
    _image_axes(ax, w, h)
    ax.set_title("Calibration corner coverage of the image")
    ax.legend(fontsize=6, ncol=2, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return fig


def plot_image_coverage(corners: pd.DataFrame, calib_corners: pd.DataFrame, camera: dict) -> Figure:
    """Where the video's corners and the calibration stills' corners fell in the image.

    Parameters
    ----------
    corners : DataFrame
        ``found, u_px, v_px`` (corners.parquet: every video frame's corners).
    calib_corners : DataFrame
        ``u_px, v_px`` (calib_corners.parquet of the camera's calibration).
    camera : dict
        camera.yaml content (``width``, ``height`` in px).

    Returns
    -------
    Figure
        The video's corners as a density (corners per 20 px cell, log scale) over the image
        (pixels, v down), the stills' corners as red dots over it.
    """
    from matplotlib.colors import LogNorm

    w, h = camera["width"], camera["height"]
    seen = corners[corners["found"].astype(bool)].dropna(subset=["u_px", "v_px"])
    fig, ax = plt.subplots(figsize=(7.0, 5.6 * h / w + 1.0), layout="constrained")
    bins = (max(1, int(w // 20)), max(1, int(h // 20)))
    *_, image = ax.hist2d(seen["u_px"], seen["v_px"], bins=bins, range=[[0, w], [0, h]], cmap="viridis",
                          norm=LogNorm(), cmin=1)
    fig.colorbar(image, ax=ax, label="video corners per 20 px cell", shrink=0.8)
    ax.scatter(calib_corners["u_px"], calib_corners["v_px"], s=5, color="tab:red", edgecolors="none",
               label="calibration stills' corners")
    _image_axes(ax, w, h)
    ax.set_facecolor("0.85")
    ax.set_title(f"Image coverage: the video's corners ({len(seen)}) and the stills' ({len(calib_corners)})")
    ax.legend(fontsize=7, loc="lower right")
    return fig


def plot_projection_uncertainty(maps: list[dict], camera: dict) -> Figure:
    """Projection uncertainty over the image: pixels coloured by it, the stills' corners on top.

    Parameters
    ----------
    maps : list of dict
        :func:`cvsflow.calibration.projection_uncertainty.uncertainty_map_of` at one or more
        distances (one panel each): ``u_px``, ``v_px``, ``sigma_px`` (nv, nu; NaN where the
        model does not invert), ``covered``, ``corners_uv_px``, ``distance_m``.
    camera : dict
        camera.yaml content (``width``, ``height``, ``model``; ``quality.summary`` when present).

    Returns
    -------
    Figure
        One panel per distance: the worst-direction 1-sigma (px, logarithmic colours, contours
        at 0.1, 0.3, 1, 3, 10 px), the area the stills covered outlined, the used corners as
        dots.
    """
    from matplotlib.colors import LogNorm

    w, h = camera["width"], camera["height"]
    finite = np.concatenate([m["sigma_px"][np.isfinite(m["sigma_px"])] for m in maps])
    lo = max(float(finite.min()), 1e-3) if finite.size else 1e-3
    hi = max(float(finite.max()), lo * 10) if finite.size else 1.0
    fig, axes = plt.subplots(1, len(maps), figsize=(6.0 * len(maps), 5.2 * h / w + 1.2),
                             layout="constrained", squeeze=False)
    for ax, m in zip(axes[0], maps, strict=True):
        mesh = ax.pcolormesh(m["u_px"], m["v_px"], m["sigma_px"], norm=LogNorm(lo, hi),
                             cmap="viridis", shading="nearest")
        levels = [x for x in (0.1, 0.3, 1.0, 3.0, 10.0) if lo < x < hi]
        if levels:
            cs = ax.contour(m["u_px"], m["v_px"], m["sigma_px"], levels=levels, colors="white",
                            linewidths=0.7)
            ax.clabel(cs, fmt="%g px", fontsize=7)
        ax.contour(m["u_px"], m["v_px"], m["covered"].astype(float), levels=[0.5],
                   colors="tab:red", linewidths=1.2)
        uv = m["corners_uv_px"]
        ax.scatter(uv[:, 0], uv[:, 1], s=2, color="black", alpha=0.5)
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_xlabel("u (px)")
        ax.set_ylabel("v (px)")
        d = m["distance_m"]
        ax.set_title(f"at {'infinity' if not np.isfinite(d) else f'{d:.2f} m'}", fontsize=10)
        fig.colorbar(mesh, ax=ax, shrink=0.8, label="projection 1-sigma, worst direction (px)")
    fig.suptitle(f"Projection uncertainty of the calibration ({camera.get('model', 'opencv5')}); "
                 "red: area the stills covered, dots: their corners", fontsize=10)
    return fig


def plot_pose_timeseries(poses: pd.DataFrame) -> Figure:
    """The six pose dimensions of T_C_B over time (mm and degrees), from poses_raw.

    Parameters
    ----------
    poses : DataFrame
        ``t_s, valid, x_m, y_m, z_m, roll_rad, pitch_rad, yaw_rad`` (poses_raw.parquet).

    Returns
    -------
    Figure
        Six stacked panels sharing the time axis; frames without a valid pose are gaps. Over
        4000 frames a line is drawn from each of 2000 time bins' lowest and highest sample
        (:func:`cvsflow.plots.decimate.min_max_envelope`: the same pixels, fewer points).
    """
    valid = poses["valid"].astype(bool).to_numpy()
    t_s = poses["t_s"].to_numpy(dtype=float)
    panels = [
        ("x_m", "x (mm)", 1e3),
        ("y_m", "y (mm)", 1e3),
        ("z_m", "z (mm)", 1e3),
        ("roll_rad", "roll (deg)", np.degrees(1.0)),
        ("pitch_rad", "pitch (deg)", np.degrees(1.0)),
        ("yaw_rad", "yaw (deg)", np.degrees(1.0)),
    ]
    fig, axes = plt.subplots(6, 1, sharex=True, figsize=(9.0, 10.0), layout="constrained")
    for ax, (col, label, scale) in zip(axes, panels, strict=True):
        y = np.where(valid, poses[col].to_numpy(dtype=float) * scale, np.nan)
        # a long session has more frames than the panel has pixel columns: its envelope
        ax.plot(*min_max_envelope(t_s, y), lw=0.8, color="tab:blue")
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("video time (s)")
    axes[0].set_title(
        f"CVS pose of the board in the camera, T_C_B ({int(valid.sum())} of {len(valid)} "
        "frames valid)"
    )
    return fig
