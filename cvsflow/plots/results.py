"""Figures of the error analysis (seed section 1.4): figures 1.6 to 1.9, Q-Q plots, Sigma.

Each function takes the data returned by :mod:`cvsflow.analyse` (SI units) and returns a
:class:`matplotlib.figure.Figure` in millimetres and degrees, axes labelled with units.
Figures are built without pyplot, so nothing stays registered in a global figure list.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

POSE_DIMS = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
#: Display name, unit and SI-to-display factor of each dimension.
DISPLAY = {
    "x_m": ("x", "mm", 1e3), "y_m": ("y", "mm", 1e3), "z_m": ("z", "mm", 1e3),
    "roll_rad": ("roll θ", "deg", 180.0 / np.pi), "pitch_rad": ("pitch φ", "deg", 180.0 / np.pi),
    "yaw_rad": ("yaw ψ", "deg", 180.0 / np.pi),
}


def _six_axes(title, figsize=(13.0, 7.0)):
    """A figure with a 2 x 3 grid of axes, one per pose dimension."""
    fig = Figure(figsize=figsize, layout="constrained")
    axes = fig.subplots(2, 3).ravel()
    fig.suptitle(title)
    return fig, axes


def plot_convergence(conv, f_bounds_px=None):
    """Per-dimension RMS error of eps against iteration, plus fx, fy (seed figure 1.6).

    Parameters
    ----------
    conv : pandas.DataFrame
        :func:`cvsflow.analyse.convergence` output (SI).
    f_bounds_px : (float, float), optional
        The grid search's bounds (px, result.yaml ``f_bounds_px``): drawn on the focal-length
        panel when the focal lengths come within 10 % of the range of one of them.

    Returns
    -------
    Figure
        8 axes: six dimensions (mm or deg), focal lengths (px), normalised norm (mm).
    """
    fig = Figure(figsize=(15.0, 7.0), layout="constrained")
    axes = fig.subplots(2, 4).ravel()
    fig.suptitle("Convergence of the seed optimiser (eps after each iteration)")
    it = conv["iteration"].to_numpy()
    for ax, d in zip(axes[:6], POSE_DIMS, strict=True):
        name, unit, k = DISPLAY[d]
        ax.plot(it, conv[f"eps_rms_{d}"] * k, label="RMS")
        ax.plot(it, conv[f"eps_std_{d}"] * k, "--", label="std")
        ax.set(xlabel="iteration [-]", ylabel=f"error in {name} [{unit}]", title=name)
        ax.legend(fontsize="small")
    axes[6].plot(it, conv["fx_px"], label="fx")
    axes[6].plot(it, conv["fy_px"], label="fy")
    axes[6].set(xlabel="iteration [-]", ylabel="focal length [px]", title="focal lengths")
    if f_bounds_px is not None:
        f_all = np.r_[conv["fx_px"].to_numpy(float), conv["fy_px"].to_numpy(float)]
        span = max(float(np.ptp(f_all)), 1.0)
        for b in f_bounds_px:
            if np.min(np.abs(f_all - b)) <= 0.1 * span + 16.0:
                axes[6].axhline(b, color="tab:red", ls=":", lw=1.0, label=f"grid bound {b:g} px")
    axes[6].legend(fontsize="small")
    axes[7].plot(it, conv["norm_normalised"] * 1e3)
    axes[7].set(xlabel="iteration [-]", ylabel="RMS translation error norm [mm]",
                title="normalised error norm")
    return fig


def plot_error_histograms(errors, tests, prefix="eps", bins=60):
    """Histograms of eps per dimension with the normal density of its mean and std (figure 1.7).

    Parameters
    ----------
    errors : pandas.DataFrame
        Per-frame errors (SI).
    tests : pandas.DataFrame
        :func:`cvsflow.analyse.normality_tests` output; p-values go in the titles.
    prefix : str
        ``eps`` or ``eps_orig``.
    bins : int
        Histogram bins.

    Returns
    -------
    Figure
        6 axes, errors in mm or deg, density in 1/mm or 1/deg.
    """
    fig, axes = _six_axes("Error histograms with fitted normal density")
    for ax, d in zip(axes, POSE_DIMS, strict=True):
        name, unit, k = DISPLAY[d]
        x = errors[f"{prefix}_{d}"].to_numpy(dtype=float) * k
        mu, sd = x.mean(), x.std(ddof=1)
        ax.hist(x, bins=bins, density=True, alpha=0.6, label="eps")
        grid = np.linspace(x.min(), x.max(), 200)
        if sd > 0:
            ax.plot(grid, np.exp(-0.5 * ((grid - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi)),
                    "r", label="normal(mean, std)")
        p = tests.loc[d, "dagostino_p"]
        ad = tests.loc[d, "anderson_stat"]
        ax.set(xlabel=f"error in {name} [{unit}]", ylabel=f"density [1/{unit}]",
               title=f"{name}: mean {mu:.3g} {unit}, std {sd:.3g} {unit}\n"
                     f"D'Agostino p = {p:.2g}, A-D = {ad:.3g}")
        ax.legend(fontsize="small")
    return fig


def plot_qq(qq):
    """Normal Q-Q plots of eps per dimension.

    Parameters
    ----------
    qq : dict
        :func:`cvsflow.analyse.qq_data` output (SI).

    Returns
    -------
    Figure
        6 axes: standard normal quantiles against ordered errors (mm or deg).
    """
    fig, axes = _six_axes("Normal Q-Q plots of the errors")
    for ax, d in zip(axes, POSE_DIMS, strict=True):
        name, unit, k = DISPLAY[d]
        q = qq[d]
        ax.plot(q["theoretical"], q["ordered"] * k, ".", ms=2)
        line = (q["slope"] * q["theoretical"] + q["intercept"]) * k
        ax.plot(q["theoretical"], line, "r")
        ax.set(xlabel="standard normal quantile [-]", ylabel=f"ordered error in {name} [{unit}]",
               title=name)
    return fig


SEED_LABELS = ("Vicon (P* + P̄)", "CVS original f", "CVS optimised f")
SE3_LABELS = ("Vicon via the fitted mountings", "CVS, calibrated intrinsics", "CVS, se3 intrinsics")


def plot_vicon_vs_cvs(tracks, labels=SEED_LABELS):
    """Vicon against the original and improved CVS estimate over time (figure 1.8).

    Parameters
    ----------
    tracks : pandas.DataFrame
        :func:`cvsflow.analyse.vicon_vs_cvs` output (SI).
    labels : tuple of str
        Legend of the Vicon, original and improved tracks (``SEED_LABELS``, ``SE3_LABELS``).

    Returns
    -------
    Figure
        6 axes, time in s against pose in mm or deg.
    """
    fig, axes = _six_axes("Vicon against the original and improved CVS estimates", (15.0, 8.0))
    t = tracks["t_s"].to_numpy()
    for ax, d in zip(axes, POSE_DIMS, strict=True):
        name, unit, k = DISPLAY[d]
        ax.plot(t, tracks[f"vicon_{d}"] * k, "k", lw=1.2, label=labels[0])
        ax.plot(t, tracks[f"original_{d}"] * k, lw=0.8, alpha=0.8, label=labels[1])
        ax.plot(t, tracks[f"improved_{d}"] * k, lw=0.8, alpha=0.8, label=labels[2])
        ax.set(xlabel="time [s]", ylabel=f"{name} [{unit}]", title=name)
        ax.legend(fontsize="small")
    return fig


def _to_display(Sigma):
    """Sigma (SI) in mm and deg: scale by the outer product of the display factors."""
    k = np.array([DISPLAY[d][2] for d in POSE_DIMS])
    return np.asarray(Sigma) * np.outer(k, k)


def plot_covariance(Sigma, corr):
    """The 6x6 error covariance (eq. 1.14, in mm and deg) and correlation heat map.

    Parameters
    ----------
    Sigma : ndarray, shape (6, 6)
        Covariance in SI (:func:`cvsflow.analyse.error_covariance`).
    corr : ndarray, shape (6, 6)
        Correlation matrix.

    Returns
    -------
    Figure
        2 axes (covariance in mm², mm·deg, deg²; correlation) plus 1 colour bar axis.
    """
    fig = Figure(figsize=(14.0, 6.0), layout="constrained")
    ax_cov, ax_corr = fig.subplots(1, 2)
    labels = [f"{DISPLAY[d][0]} [{DISPLAY[d][1]}]" for d in POSE_DIMS]
    S = _to_display(Sigma)
    ax_cov.axis("off")
    table = ax_cov.table(cellText=[[f"{v:.4g}" for v in row] for row in S], rowLabels=labels,
                         colLabels=labels, loc="center")
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    ax_cov.set_title("Σ (eq. 1.14) in mm², mm·deg, deg²")
    im = ax_corr.imshow(corr, cmap="RdBu_r", vmin=-1, vmax=1)
    for i in range(6):
        for j in range(6):
            ax_corr.text(j, i, f"{corr[i, j]:.2f}", ha="center", va="center", fontsize=8)
    ax_corr.set_xticks(range(6), labels, rotation=45, ha="right")
    ax_corr.set_yticks(range(6), labels)
    ax_corr.set(xlabel="error dimension", ylabel="error dimension",
                title="correlation of the errors [-]")
    fig.colorbar(im, ax=ax_corr, label="correlation coefficient [-]")
    return fig


def plot_error_maps(maps):
    """Maps of binned mean errors over pairs of pose dimensions (figure 1.9): contours where
    the bins are well filled, the bins themselves where they are sparse (grey: too few samples).

    Parameters
    ----------
    maps : list of dict
        :func:`cvsflow.analyse.error_maps` output (SI), pair-major, 6 error dims per pair.

    Returns
    -------
    Figure
        One axis per map (rows: pose pairs, columns: error dimension) plus one colour bar
        axis each; pose axes and errors in mm or deg.
    """
    n_rows = max(1, len(maps) // 6)
    n_cols = min(6, len(maps))
    fig = Figure(figsize=(3.4 * n_cols, 3.0 * n_rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(n_rows, n_cols)).ravel()
    fig.suptitle("Mean error in bins of the board pose (CVS, optimised f)")
    for ax, m in zip(axes, maps, strict=False):
        na, ua, ka = DISPLAY[m["pose_dim_a"]]
        nb, ub, kb = DISPLAY[m["pose_dim_b"]]
        ne, ue, ke = DISPLAY[m["error_dim"]]
        z = m["mean"].T * ke  # rows: b, columns: a
        finite = np.isfinite(z)
        # signed errors: a diverging map centred on zero
        lim = float(np.nanmax(np.abs(z))) if finite.any() else 1.0
        style = {"cmap": "RdBu_r", "vmin": -lim, "vmax": lim}
        ax.set_facecolor("0.85")  # empty bins grey, distinct from a zero mean (white)
        if finite.mean() >= 0.6:  # contours only where the bins are well filled
            cs = ax.contourf(m["centres_a"] * ka, m["centres_b"] * kb, np.ma.masked_invalid(z),
                             levels=np.linspace(-lim, lim, 13), **style)
        else:  # sparse bins: draw the bins themselves rather than contour across holes
            cs = ax.pcolormesh(m["edges_a"] * ka, m["edges_b"] * kb, np.ma.masked_invalid(z),
                               **style)
        fig.colorbar(cs, ax=ax, label=f"mean error in {ne} [{ue}]")
        ax.set(xlabel=f"{na} [{ua}]", ylabel=f"{nb} [{ub}]", title=f"error in {ne}")
    return fig
