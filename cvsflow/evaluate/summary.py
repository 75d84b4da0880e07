"""One row of the cross-run summary table per optimiser run (rule summary).

:func:`summary_row` turns a run's ``result.yaml`` and ``stats.json`` (and a rendered
session's truth) into report units (px, mm, deg). Kept apart from :mod:`cvsflow.evaluate.analyse` so
that the summary job does not import scipy.stats, which only the per-run analysis needs.
"""

from __future__ import annotations

import numpy as np

from cvsflow.metrics import ERROR_DIMS, REPORT_UNITS, report_name
from cvsflow.optimise import compute_p_bar


def summary_row(session, method, finit, result, stats, truth=None, pairs=None, truth_frames=None):
    """One row of the cross-run summary table (report units: px, mm, deg).

    Parameters
    ----------
    session, method, finit : str
        Identify the run (``results/{session}/{method}/{finit}``).
    result : dict
        The optimiser's ``result.yaml``.
    stats : dict
        The run's ``stats.json`` (``run_statistics`` plus ``optimum``).
    truth : dict, optional
        ``truth.yaml`` of a rendered session: adds the true focal lengths.
    pairs, truth_frames : DataFrame, optional
        With ``truth``: the true P̄ of the chapter's convention, mean(F_true - P*) over the pair
        frames (seed eq. 1.10 with the true CVS poses), to compare with the estimate.

    Returns
    -------
    dict
        Flat mapping of column name (unit in the name) to value.
    """
    row = {"session": session, "method": method, "f_init": finit,
           "n_pairs": int(result.get("n_pairs", stats.get("n", 0))),
           "fx_px": float(result["fx_px"]), "fy_px": float(result["fy_px"]),
           # A diverged run (seed's own check) is listed but its numbers are not measurements.
           "diverged": bool(result.get("diverged", False)),
           "diverged_reason": result.get("diverged_reason") or ""}
    f_init = result.get("f_init_px", [np.nan, np.nan])
    row["fx_init_px"], row["fy_init_px"] = float(f_init[0]), float(f_init[1])
    if truth is not None:
        K = np.asarray(truth["camera"]["K"], dtype=float)
        row["fx_true_px"], row["fy_true_px"] = float(K[0, 0]), float(K[1, 1])
    scale = {d: k for d, (_, _, k) in REPORT_UNITS.items()}
    for d, v in zip(ERROR_DIMS, result.get("P_bar", [np.nan] * 6), strict=True):
        row[f"P_bar_{report_name(d)}"] = float(v) * scale[d]
    if truth is not None and pairs is not None and truth_frames is not None:
        true = truth_frames.set_index("frame").loc[pairs["frame"].to_numpy()]
        F_true = true[list(ERROR_DIMS)].to_numpy(float)
        P_star = pairs[[f"vic_{d}" for d in ERROR_DIMS]].to_numpy(float)
        for d, v in zip(ERROR_DIMS, compute_p_bar(F_true, P_star), strict=True):
            row[f"P_bar_true_{report_name(d)}"] = float(v) * scale[d]
    opt = stats.get("optimum", {})
    row["norm_init_mm"] = 1e3 * float(opt.get("norm_normalised_init_m", np.nan))
    row["norm_final_mm"] = 1e3 * float(opt.get("norm_normalised_final_m", np.nan))
    for d in ERROR_DIMS:
        row[f"std_{report_name(d)}"] = stats["per_dim"][d]["std"] * scale[d]
    return row
