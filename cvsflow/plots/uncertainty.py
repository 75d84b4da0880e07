"""Figures of the error model (T): its calibration table and the NEES histogram.

Every function takes tables/dicts in SI units and returns a Figure; millimetres and degrees
appear only here.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from cvsflow.metrics import ERROR_DIMS as DIMS
from cvsflow.uncertainty import TARGETS, chi2_pdf, chi2_quantile

NAMES = ("x", "y", "z", "roll", "pitch", "yaw")


def _rows(score, label):
    """Table rows (label, NEES, 68 % per axis, 95 % per axis) of one score dict."""
    return [label, f"{score['nees_mean']:.2f}",
            *[f"{100 * score['inside_68'][d]:.0f}" for d in DIMS],
            *[f"{100 * score['inside_95'][d]:.0f}" for d in DIMS], str(score["n"])]


def plot_calibration_table(comparison: dict) -> Figure:
    """The error model's calibration per held-out fold and pooled, as a table.

    Parameters
    ----------
    comparison : dict
        comparison.yaml: ``error_model`` (within-session cross-fit, with ``folds``), optional
        ``error_model_transfer`` (fitted on other sessions) and ``cramer_rao``.

    Returns
    -------
    Figure
        One row per fold and model, columns NEES mean, % inside the 68 % and 95 % bands per
        axis, n; cells outside the targets (NEES 4.5-7.5, 64-72 %, 93-97 %) in red. Below,
        the held-out error / Cramer-Rao bound per axis.
    """
    rows, keys = [], []
    for key, name in (("error_model", "within session"), ("error_model_transfer", "transfer")):
        sc = comparison.get(key)
        if not sc:
            continue
        for f in sc.get("folds", []):
            rows.append(_rows(f, f"{name}, fold {f['fold']}"))
            keys.append(f)
        rows.append(_rows(sc, f"{name}, all"))
        keys.append(sc)
    cols = ["model / fold", "NEES", *[f"68 {n}" for n in NAMES], *[f"95 {n}" for n in NAMES], "n"]
    fig, ax = plt.subplots(figsize=(13, 0.7 + 0.2 * (len(rows) + 2)), layout="constrained")
    ax.axis("off")
    table = ax.table(cellText=rows, colLabels=cols, loc="upper center", cellLoc="center")
    table.auto_set_font_size(False)
    table.set_fontsize(8)
    for i, sc in enumerate(keys, start=1):
        lo, hi = TARGETS["nees"]
        if not lo <= sc["nees_mean"] <= hi:
            table[i, 1].set_facecolor("#f4c7c3")
        for j, d in enumerate(DIMS):
            for off, band in ((2, "inside_68"), (8, "inside_95")):
                lo, hi = TARGETS[band]
                if not lo <= sc[band][d] <= hi:
                    table[i, off + j].set_facecolor("#f4c7c3")
    table.auto_set_column_width(list(range(len(cols))))
    cr = comparison.get("cramer_rao")
    title = "error model calibration (% of held-out errors inside the predicted bands)"
    if cr:
        title += "\nheld-out error / Cramer-Rao bound: " + ", ".join(
            f"{n} {cr['error_over_crb'][d]:.2f}" for n, d in zip(NAMES, DIMS, strict=True))
    ax.set_title(title, fontsize=9)
    return fig


def plot_nees_histogram(errors: pd.DataFrame) -> Figure:
    """Histogram of the held-out NEES against the chi-square(6) density.

    Parameters
    ----------
    errors : DataFrame
        Held-out rows with ``nees`` and ``fold`` (:func:`cvsflow.evaluate.heldout.compare_heldout`
        with corners).

    Returns
    -------
    Figure
        Left: all frames, density, with chi-square(6) and the means; right: the mean NEES per
        fold with the target band 4.5-7.5.
    """
    nees = errors["nees"].to_numpy(float)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4), layout="constrained",
                                  gridspec_kw={"width_ratios": [2, 1]})
    top = max(float(np.nanpercentile(nees, 99)), chi2_quantile(0.99, 6))
    bins = np.linspace(0.0, top, 40)
    ax.hist(np.clip(nees, 0, top), bins=bins, density=True, alpha=0.7,
            label=f"held-out frames (mean {np.nanmean(nees):.2f}, median {np.nanmedian(nees):.2f})")
    x = np.linspace(0.0, top, 200)
    ax.plot(x, chi2_pdf(x, 6), "k-", label="chi-square(6) (mean 6, median 5.35)")
    ax.axvline(chi2_quantile(0.95, 6), color="grey", ls=":", label="chi-square(6) 95 %")
    ax.set_xlabel("NEES  e^T Sigma^-1 e  (last bin: everything above)")
    ax.set_ylabel("density")
    ax.legend(fontsize=8)
    folds = errors.groupby("fold")["nees"].mean()
    ax2.axhspan(*TARGETS["nees"], color="tab:green", alpha=0.15, label="target 4.5-7.5")
    ax2.bar(folds.index.astype(str), folds.to_numpy(), color="tab:blue")
    ax2.axhline(6.0, color="k", lw=0.8)
    ax2.set_xlabel("held-out fold")
    ax2.set_ylabel("mean NEES")
    ax2.legend(fontsize=8)
    return fig
