"""The hand-eye's mocap-chain reprojection per view, in the fit and with the view left out
(``cvsflow handeye --stills`` / ``--frames``: ``OUT/handeye_views.png``)."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure


def plot_chain_reprojection(stills: list[dict]) -> Figure:
    """Per view: the target's points projected through the carrier chain, in-sample and left out.

    Parameters
    ----------
    stills : list of dict
        ``handeye.yaml``'s ``stills`` records (``name``, ``used``; for used views ``rms_px``
        the corner RMS under the fit, ``chain_rms_px`` the RMS of the points projected through
        the carrier's pose, the mounting, the intrinsics and the target's pose of the fit,
        ``chain_rms_loo_px`` the same from the fit without that view), in time order.

    Returns
    -------
    Figure
        Bars of the in-sample and left-out chain RMS (px) per used view, the corner RMS as
        dots; the views left out of the fit named below the axis with their count.
    """
    used = [s for s in stills if s.get("used") and "chain_rms_px" in s]
    x = np.arange(len(used))
    chain = np.array([s["chain_rms_px"] for s in used], float)
    loo = np.array([s.get("chain_rms_loo_px", np.nan) for s in used], float)
    rms = np.array([s.get("rms_px", np.nan) for s in used], float)
    fig, ax = plt.subplots(figsize=(max(6.0, 0.28 * len(used) + 2.0), 4.0), layout="constrained")
    ax.bar(x - 0.2, chain, 0.4, label=f"mocap chain, in the fit (median {np.nanmedian(chain):.2f} px)")
    ax.bar(x + 0.2, loo, 0.4, label=f"mocap chain, view left out (median {np.nanmedian(loo):.2f} px)")
    ax.plot(x, rms, "k.", label=f"corners under the fit (median {np.nanmedian(rms):.2f} px)")
    ax.set_xticks(x, [str(i) for i in x], fontsize=7)
    ax.set_xlabel("view (time order)")
    ax.set_ylabel("reprojection RMS (px)")
    dropped = [s["name"] for s in stills if not s.get("used")]
    title = f"{len(used)} views"
    if dropped:
        more = " ..." if len(dropped) > 4 else ""
        title += f"; {len(dropped)} left out: " + ", ".join(dropped[:4]) + more
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    return fig
