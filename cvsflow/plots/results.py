"""Figures of the error analysis (seed section 1.4): figures 1.6 to 1.9, Q-Q plots, Sigma.

Each function takes the data returned by :mod:`cvsflow.evaluate.analyse` (SI units) and returns a
:class:`matplotlib.figure.Figure` in millimetres and degrees, axes labelled with units.
Figures are built without pyplot, so nothing stays registered in a global figure list.
"""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from cvsflow.metrics import ERROR_DIMS, REPORT_UNITS

_SYMBOL = {"roll": "θ", "pitch": "φ", "yaw": "ψ"}

#: Display name (with the chapter's symbol of an angle), unit and SI-to-display factor of each dimension.
DISPLAY = {d: (f"{label} {_SYMBOL[label]}" if label in _SYMBOL else label, unit, k)
           for d, (label, unit, k) in REPORT_UNITS.items()}


def _six_axes(title, figsize=(13.0, 7.0)):
    """A figure with a 2 x 3 grid of axes, one per pose dimension."""
    fig = Figure(figsize=figsize, layout="constrained")
    axes = fig.subplots(2, 3).ravel()
    fig.suptitle(title)
    return fig, axes


def plot_convergence(conv, f_bounds_px=None, diverged_reason=None):
    """Per-dimension RMS error of eps against iteration, plus fx, fy (seed figure 1.6).

    Parameters
    ----------
    conv : pandas.DataFrame
        :func:`cvsflow.evaluate.analyse.convergence` output (SI).
    f_bounds_px : (float, float), optional
        The grid search's bounds (px, result.yaml ``f_bounds_px``): drawn on the focal-length
        panel when the focal lengths come within 10 % of the range of one of them; the
        panel's title states both.
    diverged_reason : str, optional
        result.yaml ``diverged_reason`` of a diverged run: the title says it diverged.

    Returns
    -------
    Figure
        8 axes: six dimensions (mm or deg), focal lengths (px), normalised norm (mm).
    """
    fig = Figure(figsize=(15.0, 7.0), layout="constrained")
    axes = fig.subplots(2, 4).ravel()
    title = "Convergence of the seed optimiser (eps after each iteration)"
    if diverged_reason:
        title += "\nDIVERGED: " + _short(diverged_reason)
    fig.suptitle(title, color="tab:red" if diverged_reason else "black")
    it = conv["iteration"].to_numpy()
    for ax, d in zip(axes[:6], ERROR_DIMS, strict=True):
        name, unit, k = DISPLAY[d]
        ax.plot(it, conv[f"eps_rmse_{d}"] * k, label="RMS")
        ax.plot(it, conv[f"eps_std_{d}"] * k, "--", label="std")
        ax.set(xlabel="iteration [-]", ylabel=f"error in {name} [{unit}]", title=name)
        ax.legend(fontsize="small")
    axes[6].plot(it, conv["fx_px"], label="fx")
    axes[6].plot(it, conv["fy_px"], label="fy")
    axes[6].set(xlabel="iteration [-]", ylabel="focal length [px]", title="focal lengths")
    if f_bounds_px is not None:
        axes[6].set_title(f"focal lengths (grid bounds {f_bounds_px[0]:g} to {f_bounds_px[1]:g} px)")
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
        :func:`cvsflow.evaluate.analyse.normality_tests` output; p-values go in the titles.
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
    for ax, d in zip(axes, ERROR_DIMS, strict=True):
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
        :func:`cvsflow.evaluate.analyse.qq_data` output (SI).

    Returns
    -------
    Figure
        6 axes: standard normal quantiles against ordered errors (mm or deg).
    """
    fig, axes = _six_axes("Normal Q-Q plots of the errors")
    for ax, d in zip(axes, ERROR_DIMS, strict=True):
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


def _short(text, n=110):
    """The first ``n`` characters of a reason, for a title."""
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def mark_diverged(fig, reason):
    """Add "DIVERGED: reason" in red under a figure's title (a diverged seed run); returns fig.

    Parameters
    ----------
    fig : Figure
        The figure, changed in place.
    reason : str or None
        The optimiser's divergence reason (shortened for the title); empty or None: the
        figure is left as it is.

    Returns
    -------
    Figure
        ``fig`` itself.
    """
    if reason:
        title = fig.get_suptitle()
        fig.suptitle((title + "\n" if title else "") + "DIVERGED: " + _short(reason),
                     color="tab:red")
    return fig


def break_gaps(t, *columns, factor=1.5):
    """Insert a NaN row wherever the time step exceeds ``factor`` times the median step.

    Matplotlib joins consecutive points; a NaN between two samples stops the line there, so a
    missing stretch (no board, no Vicon) shows as a gap instead of a straight line across it.

    Parameters
    ----------
    t : array_like, shape (N,)
        Sample times, increasing, s (any unit: only ratios of steps matter).
    *columns : array_like, shape (N,)
        Values at those times, one array per series.
    factor : float
        A step longer than ``factor`` times the median positive step is a gap. Fewer than
        three samples, or no positive step: nothing is inserted.

    Returns
    -------
    tuple of ndarray
        ``t`` and each column with the NaN rows inserted (float).
    """
    t = np.asarray(t, dtype=float)
    cols = [np.asarray(c, dtype=float) for c in columns]
    if t.size < 3:
        return (t, *cols)
    dt = np.diff(t)
    step = np.median(dt[dt > 0]) if np.any(dt > 0) else 0.0
    gaps = np.flatnonzero(dt > factor * step) + 1 if step > 0 else np.array([], int)
    return (np.insert(t, gaps, np.nan), *[np.insert(c, gaps, np.nan) for c in cols])


def plot_vicon_vs_cvs(tracks, labels=SEED_LABELS, diverged_reason=None):
    """Vicon against the original and improved CVS estimate over time, and their errors (figure 1.8).

    Parameters
    ----------
    tracks : pandas.DataFrame
        :func:`cvsflow.evaluate.analyse.mocap_vs_cvs` output (SI).
    labels : tuple of str
        Legend of the Vicon, original and improved tracks (``SEED_LABELS``, ``SE3_LABELS``).
    diverged_reason : str, optional
        Of a diverged seed run: the title says so.

    Returns
    -------
    Figure
        12 axes in 4 rows of 3: translation tracks (mm), their errors CVS - Vicon (mm),
        rotation tracks (deg), their errors (deg); time in s, shared per column. Lines break
        where frames are missing (:func:`break_gaps`).
    """
    fig = Figure(figsize=(15.0, 11.0), layout="constrained")
    axes = fig.subplots(4, 3, sharex=True, gridspec_kw={"height_ratios": [3, 2, 3, 2]})
    title = "Vicon against the original and improved CVS estimates, and the errors CVS - Vicon"
    if diverged_reason:
        title += "\nDIVERGED: " + _short(diverged_reason)
    fig.suptitle(title, color="tab:red" if diverged_reason else "black")
    t = tracks["t_s"].to_numpy(dtype=float)
    for k, d in enumerate(ERROR_DIMS):
        name, unit, f = DISPLAY[d]
        row = 0 if k < 3 else 2
        ax, ax_e = axes[row, k % 3], axes[row + 1, k % 3]
        vic, orig, impr = (tracks[f"{p}_{d}"].to_numpy(float) * f
                           for p in ("vicon", "original", "improved"))
        err_o, err_i = orig - vic, impr - vic
        if k >= 3:  # angle differences wrapped to (-180, 180] deg
            err_o, err_i = (np.degrees(np.angle(np.exp(1j * np.radians(e)))) for e in (err_o, err_i))
        tt, vic, orig, impr, err_o, err_i = break_gaps(t, vic, orig, impr, err_o, err_i)
        ax.plot(tt, vic, "k", lw=1.2, label=labels[0])
        ax.plot(tt, orig, lw=0.8, alpha=0.8, label=labels[1])
        ax.plot(tt, impr, lw=0.8, alpha=0.8, label=labels[2])
        ax.set(ylabel=f"{name} [{unit}]", title=name)
        ax_e.axhline(0.0, color="k", lw=0.6)
        ax_e.plot(tt, err_o, lw=0.7, color="C0", label=f"{labels[1]} - Vicon")
        ax_e.plot(tt, err_i, lw=0.7, color="C1", label=f"{labels[2]} - Vicon")
        ax_e.set(ylabel=f"CVS - Vicon, {name} [{unit}]")
        for a in (ax, ax_e):
            a.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    # One legend: an error line has the colour of its CVS track.
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside lower center", ncol=3, fontsize="small")
    return fig


def _to_display(Sigma):
    """Sigma (SI) in mm and deg: scale by the outer product of the display factors."""
    k = np.array([DISPLAY[d][2] for d in ERROR_DIMS])
    return np.asarray(Sigma) * np.outer(k, k)


def plot_covariance(Sigma, corr):
    """The 6x6 error covariance (eq. 1.14, in mm and deg) and correlation heat map.

    Parameters
    ----------
    Sigma : ndarray, shape (6, 6)
        Covariance in SI (:func:`cvsflow.evaluate.analyse.sample_error_covariance`).
    corr : ndarray, shape (6, 6)
        Correlation matrix.

    Returns
    -------
    Figure
        2 axes (covariance in mm², mm·deg, deg²; correlation) plus 1 colour bar axis.
    """
    fig = Figure(figsize=(14.0, 6.0), layout="constrained")
    ax_cov, ax_corr = fig.subplots(1, 2)
    labels = [f"{DISPLAY[d][0]} [{DISPLAY[d][1]}]" for d in ERROR_DIMS]
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

    One row per error dimension, one column per pose pair, and one colour scale per row (shared
    by its pose pairs, symmetric about zero, clipped at the 98th percentile of |mean| so that a
    single extreme bin does not wash out the rest): a row reads as one quantity.

    Parameters
    ----------
    maps : list of dict
        :func:`cvsflow.evaluate.analyse.error_maps` output (SI), pair-major, 6 error dims per pair.

    Returns
    -------
    Figure
        One axis per map (rows: error dimension, columns: pose pair) plus one colour bar axis
        per row; pose axes and errors in mm or deg.
    """
    pairs = list(dict.fromkeys((m["pose_dim_a"], m["pose_dim_b"]) for m in maps))
    dims = list(dict.fromkeys(m["error_dim"] for m in maps))
    by_key = {(m["pose_dim_a"], m["pose_dim_b"], m["error_dim"]): m for m in maps}
    fig = Figure(figsize=(3.6 * len(pairs) + 1.2, 2.5 * len(dims) + 0.6), layout="constrained")
    axes = np.atleast_2d(fig.subplots(len(dims), len(pairs), squeeze=False))
    fig.suptitle("Mean error in bins of the board pose (CVS, optimised f); one colour scale per row")
    for i, d in enumerate(dims):
        ne, ue, ke = DISPLAY[d]
        row_maps = [by_key.get((a, b, d)) for a, b in pairs]
        values = np.concatenate([np.ravel(m["mean"]) * ke for m in row_maps if m is not None])
        values = values[np.isfinite(values)]
        lim = float(np.percentile(np.abs(values), 98)) if values.size else 1.0
        lim = lim if lim > 0 else 1.0
        style = {"cmap": "RdBu_r", "vmin": -lim, "vmax": lim}
        mappable = None
        for j, m in enumerate(row_maps):
            ax = axes[i, j]
            if m is None:
                ax.set_axis_off()
                continue
            na, ua, ka = DISPLAY[m["pose_dim_a"]]
            nb, ub, kb = DISPLAY[m["pose_dim_b"]]
            z = np.clip(m["mean"].T * ke, -lim, lim)  # rows: b, columns: a
            finite = np.isfinite(z)
            ax.set_facecolor("0.85")  # empty bins grey, distinct from a zero mean (white)
            if finite.mean() >= 0.6:  # contours only where the bins are well filled
                mappable = ax.contourf(m["centres_a"] * ka, m["centres_b"] * kb,
                                       np.ma.masked_invalid(z),
                                       levels=np.linspace(-lim, lim, 13), **style)
            else:  # sparse bins: draw the bins themselves rather than contour across holes
                mappable = ax.pcolormesh(m["edges_a"] * ka, m["edges_b"] * kb,
                                         np.ma.masked_invalid(z), **style)
            ax.set(xlabel=f"{na} [{ua}]", ylabel=f"{nb} [{ub}]")
            if i == 0:
                ax.set_title(f"over {na} and {nb}")
        if mappable is not None:
            fig.colorbar(mappable, ax=list(axes[i]), label=f"mean error\nin {ne} [{ue}]",
                         extend="both")
    return fig
