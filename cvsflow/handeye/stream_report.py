"""What the stream fit reports: the split-half check and the result as plain numbers for handeye.yaml.

Split-half check: do a recording's halves agree within their stated errors?

The camera stream is cut at its middle time and each half fitted alone
(:func:`cvsflow.handeye.stream_fit.estimate_streams`, the motion capture given whole to both);
per parameter the two estimates' difference over their combined standard error,
``z = (theta_2 - theta_1) / sqrt(std_1^2 + std_2^2)``, is about standard normal when the stated
errors are honest and the set-up did not change. Rotations are compared as ``log(R_1^T R_2)`` in
the frame the errors refer to (C for T_Cm_C, B for T_W_B), translations and dt as differences.
The summary's ``mean_z2`` is about 1 (chi-square(13)/13: above 1.72 in 5 % of honest cases).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cvsflow.geometry import rvec_from_R
from cvsflow.handeye.closed_form import pose_std_record
from cvsflow.handeye.stream_fit import StreamsOptions, StreamsResult, estimate_streams
from cvsflow.uncertainty import chi2_quantile

#: How the stated standard errors are made (handeye.yaml's ``std_method``).
STD_METHOD = (
    "cluster-robust sandwich of the robust fit over time blocks (twice the residuals' correlation "
    "length; CR2 leverage correction; neighbouring blocks' cross terms), times sqrt(nu / (nu - 2)) "
    "with nu its Satterthwaite degrees of freedom per parameter (the spread of an estimate over its "
    "noisy sandwich error), at least the independent-residual Gauss-Newton error; times the "
    "split-half check's Birge ratio sqrt(mean z^2) when the recording's halves disagree beyond them "
    "(std_inflated_by)"
)


def parameter_differences(a: StreamsResult, b: StreamsResult) -> dict:
    """``b - a`` per parameter in the local coordinates of the stated errors (rad, m, s).

    Parameters
    ----------
    a, b : StreamsResult
        Two fits (their ``estimate``, observable or not).

    Returns
    -------
    dict
        name of :data:`cvsflow.handeye.stream_model.PARAM_NAMES` -> difference.
    """
    out = {"dt_offset_s": b.estimate["dt_s"] - a.estimate["dt_s"]}
    for name in ("T_Cm_C", "T_W_B"):
        Ta, Tb = a.estimate[name], b.estimate[name]
        dr = rvec_from_R(Ta[:3, :3].T @ Tb[:3, :3])
        for k, axis in enumerate("xyz"):
            out[f"{name}_r{axis}"] = float(dr[k])
            out[f"{name}_{axis}"] = float(Tb[k, 3] - Ta[k, 3])
    return out


def compare_estimates(a: StreamsResult, b: StreamsResult, which: str = "std") -> list[dict]:
    """Each parameter's difference between two fits against their combined standard error.

    Parameters
    ----------
    a, b : StreamsResult
        Fits of disjoint data.
    which : {"std", "std_sandwich", "std_gn"}
        The standard errors compared.

    Returns
    -------
    list of dict
        Per parameter both fits carry: ``name``, ``diff``, ``std_a``, ``std_b``, ``std_diff``,
        ``z``, ``agree`` (``|z| < 2``); rad, m or s.
    """
    diff = parameter_differences(a, b)
    sa, sb = getattr(a, which), getattr(b, which)
    rows = []
    for name in a.param_names:
        if name not in sb:
            continue
        sd = float(np.hypot(sa[name], sb[name]))
        z = diff[name] / sd
        rows.append({"name": name, "diff": diff[name], "std_a": sa[name], "std_b": sb[name],
                     "std_diff": sd, "z": float(z), "agree": bool(abs(z) < 2)})  # fmt: skip
    return rows


def split_half_check(t_cam_ns, T_B_C, t_mocap_ns, T_W_Cm, options: StreamsOptions | None = None) -> dict:
    """Fit the first and the second half of the camera stream alone and compare.

    Parameters
    ----------
    t_cam_ns, T_B_C, t_mocap_ns, T_W_Cm
        As :func:`cvsflow.handeye.stream_fit.estimate_streams`.
    options : StreamsOptions, optional

    Returns
    -------
    dict
        ``first``, ``second`` (StreamResult), ``rows`` (:func:`compare_estimates` of the stated
        errors, and ``rows_sandwich`` of the sandwich's alone), ``n_agree``, ``n``, ``mean_z2``,
        ``mean_z2_limit`` (its 95 % point for honest errors), ``agree`` (``mean_z2`` below it).
    """
    t_cam_ns = np.asarray(t_cam_ns, np.int64)
    mid = t_cam_ns[0] + (t_cam_ns[-1] - t_cam_ns[0]) // 2
    first_half = t_cam_ns < mid
    halves = [estimate_streams(t_cam_ns[m], T_B_C[m], t_mocap_ns, T_W_Cm, options, t_ref_ns=int(t_cam_ns[0]))
              for m in (first_half, ~first_half)]  # fmt: skip
    rows = compare_estimates(*halves) if all(h.T_Cm_C is not None for h in halves) else []
    n = len(rows)
    mean_z2 = float(np.mean([r["z"] ** 2 for r in rows])) if rows else float("nan")
    limit = float(chi2_quantile(0.95, n) / n) if n else float("nan")
    return {"first": halves[0], "second": halves[1], "rows": rows,
            "rows_sandwich": compare_estimates(*halves, "std_sandwich") if rows else [],
            "n_agree": int(sum(r["agree"] for r in rows)), "n": n, "mean_z2": mean_z2,
            "mean_z2_limit": limit, "agree": bool(rows) and mean_z2 <= limit}  # fmt: skip


def _std_of(values: dict, name: str):
    """A transform's six standard errors from a per-parameter dict (None when absent)."""
    keys = [f"{name}_r{a}" for a in "xyz"] + [f"{name}_{a}" for a in "xyz"]
    return pose_std_record([values[k] for k in keys]) if all(k in values for k in keys) else None


def _unit(name: str):
    """(factor, unit) of a parameter for a report: ms, deg or mm."""
    if name == "dt_offset_s":
        return 1e3, "ms"
    return (float(np.degrees(1.0)), "deg") if "_r" in name else (1e3, "mm")


def split_half_record(split: dict) -> dict:
    """The split-half check as plain numbers (report units: ms, deg, mm).

    Parameters
    ----------
    split : dict
        :func:`split_half_check`'s result.

    Returns
    -------
    dict
        ``agree``, ``n_agree``, ``n``, ``mean_z2``, ``mean_z2_limit``, ``mean_z2_sandwich``
        (with the sandwich's errors alone), ``rows`` (``name``, ``diff``, ``std_diff``, ``unit``,
        ``z``), ``dt_offset_s`` of each half.
    """
    rows = []
    for r in split["rows"]:
        f, unit = _unit(r["name"])
        rows.append({"name": r["name"], "diff": f * r["diff"], "std_diff": f * r["std_diff"], "unit": unit,
                     "z": r["z"]})  # fmt: skip
    z2_cl = [r["z"] ** 2 for r in split["rows_sandwich"]]
    return {"agree": split["agree"], "n_agree": split["n_agree"], "n": split["n"],
            "mean_z2": split["mean_z2"], "mean_z2_limit": split["mean_z2_limit"],
            "mean_z2_sandwich": float(np.mean(z2_cl)) if z2_cl else None, "rows": rows,
            "dt_offset_s": [h.dt_offset_s for h in (split["first"], split["second"])]}  # fmt: skip


def streams_record(res: StreamsResult, split: dict | None = None) -> dict:
    """A stream fit as handeye.yaml holds it: plain numbers, null with a reason where undetermined.

    Parameters
    ----------
    res : StreamsResult
        :func:`cvsflow.handeye.stream_fit.estimate_streams`' result.
    split : dict, optional
        :func:`split_half_check`'s result.

    Returns
    -------
    dict
        ``mode``, ``frames``, ``T_Cm_C``, ``T_W_B`` (4x4 lists, m, or null), ``dt_offset_s``,
        ``dt_offset_std_s`` (s, or null), ``dt_used_s``, ``std`` (of each transform: deg about
        the child axes, mm in the parent), ``std_method``, ``std_gauss_newton``,
        ``std_sandwich``, ``dof``, ``observability``, ``counts``, ``residual_sigma`` (deg, mm
        per component in C), ``block_s``, ``corr_len_s``, ``offset`` (coarse and refined
        starts), ``std_inflated_by`` (:func:`split_half_inflation`, 1 when not) and
        ``split_half`` when given.
    """
    out = {
        "mode": "eye_in_hand",
        "frames": "T_Cm_C: camera optical frame C in its marker body Cm; T_W_B: the target B in the "
                  "motion-capture world W; t_mocap = t_camera + dt_offset_s",
        "T_Cm_C": None if res.T_Cm_C is None else res.T_Cm_C.tolist(),
        "T_W_B": None if res.T_W_B is None else res.T_W_B.tolist(),
        "dt_offset_s": res.dt_offset_s, "dt_offset_std_s": res.dt_offset_std_s, "dt_used_s": res.dt_used_s,
        "std": {n: _std_of(res.std, n) for n in ("T_Cm_C", "T_W_B")},
        "std_method": STD_METHOD,
        "std_gauss_newton": {n: _std_of(res.std_gn, n) for n in ("T_Cm_C", "T_W_B")},
        "std_sandwich": {n: _std_of(res.std_sandwich, n) for n in ("T_Cm_C", "T_W_B")},
        "dof": dict(res.dof),
        "observability": res.observability,
        "counts": dict(res.counts),
        "residual_sigma": {k: float(np.degrees(v)) if k.startswith("rot") else 1e3 * v
                           for k, v in res.sigma.items()},
        "residual_sigma_units": "deg (rot_*), mm (trans_*), in C",
        "block_s": res.block_s, "corr_len_s": res.corr_len_s,
        "offset": res.offset,
        "std_inflated_by": res.estimate.get("std_inflated_by", 1.0),
    }  # fmt: skip
    if split is not None:
        out["split_half"] = split_half_record(split)
    return out


def split_half_inflation(split: dict | None) -> float:
    """The factor on the stated errors when the recording's halves disagree beyond them (else 1).

    When the split-half check fails (``mean_z2`` above its 95 % point for honest errors), the
    halves' dispersion is direct evidence of an error the time blocks do not see (a viewpoint-
    dependent detector bias, a change between the halves): the stated errors are scaled by the
    Birge ratio ``sqrt(mean_z2)``, which makes the halves agree on average. Honest errors fail
    the check in 5 % of recordings and are then widened by at least ``sqrt(limit)`` (1.31 for 13
    parameters).

    Parameters
    ----------
    split : dict or None
        :func:`split_half_check`'s result.

    Returns
    -------
    float
        ``sqrt(mean_z2)`` when the check fails, else 1.
    """
    if not split or not split["rows"] or split["agree"]:
        return 1.0
    return float(np.sqrt(split["mean_z2"]))


def inflate(res: StreamsResult, factor: float) -> StreamsResult:
    """The result with its stated errors (``std``, ``cov``, ``dt_offset_std_s``) times ``factor``.

    Parameters
    ----------
    res : StreamsResult
    factor : float

    Returns
    -------
    StreamsResult
        A copy; ``estimate["std_inflated_by"]`` records the factor.
    """
    std = {k: v * factor for k, v in res.std.items()}
    dt_std = None if res.dt_offset_std_s is None else res.dt_offset_std_s * factor
    return replace(res, std=std, cov=res.cov * factor**2, dt_offset_std_s=dt_std,
                   estimate={**res.estimate, "std_inflated_by": float(factor)})  # fmt: skip
