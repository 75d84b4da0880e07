"""Error analysis of an optimiser's result (seed section 1.4): the data behind every figure.

Inputs are the optimiser's tables (:class:`cvsflow.optimise.OptimiseResult`):
``iterations`` (one row per iteration) and ``errors`` (one row per frame, with
``vic_*`` = P*, ``cvs_orig_*`` = F(f_init), ``cvs_*`` = F(f_final), ``eps_orig_*`` and
``eps_*``; dimension suffixes ``x_m, y_m, z_m, roll_rad, pitch_rad, yaw_rad``).
Everything here is SI (metres, radians); conversion to mm and degrees happens only in
``cvsflow.plots.results``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow.exceptions import InputError
from cvsflow.metrics import ERROR_DIMS, STATISTICS, error_statistics


def _require(df, cols, where):
    """Raise InputError naming the table and the missing columns."""
    missing = [c for c in cols if c not in df.columns]
    if missing:
        raise InputError(f"{where}: missing columns {missing}")


def _eps(errors, prefix="eps"):
    """(N, 6) array of an error block, after checking its columns."""
    cols = [f"{prefix}_{d}" for d in ERROR_DIMS]
    _require(errors, cols, "errors table")
    e = errors[cols].to_numpy(dtype=float)
    if len(e) < 3:
        raise InputError(f"errors table: {len(e)} rows; the analysis needs at least 3")
    return e


def convergence(iterations):
    """Per-dimension error over the iterations (seed figure 1.6).

    Parameters
    ----------
    iterations : pandas.DataFrame
        ``iterations.parquet`` of the optimiser.

    Returns
    -------
    pandas.DataFrame
        ``iteration, fx_px, fy_px, norm_normalised`` and ``eps_rmse_*``, ``eps_std_*`` per
        dimension (metres, radians).
    """
    cols = ["iteration", "fx_px", "fy_px", "norm_normalised"]
    cols += [f"eps_{s}_{d}" for s in ("rmse", "std") for d in ERROR_DIMS]
    _require(iterations, cols, "iterations table")
    return iterations[cols].reset_index(drop=True)


def normality_tests(errors, prefix="eps"):
    """Per-dimension moments and normality tests of eps (seed figure 1.7 and eq. 1.10's assumption).

    Parameters
    ----------
    errors : pandas.DataFrame
        Per-frame errors.
    prefix : str
        ``eps`` (final) or ``eps_orig`` (at the initial focal lengths).

    Returns
    -------
    pandas.DataFrame
        Index: dimension. Columns ``n`` and the statistics of :data:`cvsflow.metrics.STATISTICS`
        (``rmse, mean, median, std`` (ddof 1), ``min, max, sse``), ``skew,
        kurtosis`` (excess), ``dagostino_k2, dagostino_p`` (scipy.stats.normaltest),
        ``anderson_stat, anderson_p`` (scipy.stats.anderson, dist="norm", p-value
        interpolated from its tables, so clipped to [0.01, 0.15]) and
        ``normal_at_5pct`` (both tests fail to reject at 5 %). SI units.

    Notes
    -----
    The chapter judged normality by eye because a chi-squared test was too sensitive at
    n ~ 2400; D'Agostino-Pearson and Anderson-Darling are the tests it could have made.
    At such n they reject for small departures, which is itself a finding.
    """
    # scipy.stats costs ~0.35 s of CPU to import: loaded by the figures that use it, not by
    # every job that imports this module (an analyse job with figures: false)
    from scipy import stats

    e = _eps(errors, prefix)
    rows = []
    for i, d in enumerate(ERROR_DIMS):
        x = e[:, i]
        k2, p = stats.normaltest(x)
        ad = stats.anderson(x, dist="norm", method="interpolate")
        rows.append({
            "dim": d, **error_statistics(x),
            "skew": float(stats.skew(x)), "kurtosis": float(stats.kurtosis(x)),
            "dagostino_k2": float(k2), "dagostino_p": float(p),
            "anderson_stat": float(ad.statistic), "anderson_p": float(ad.pvalue),
            "normal_at_5pct": bool(p > 0.05 and ad.pvalue > 0.05),
        })
    return pd.DataFrame(rows).set_index("dim")


def qq_data(errors, prefix="eps"):
    """Normal Q-Q points of each dimension of eps.

    Parameters
    ----------
    errors : pandas.DataFrame
        Per-frame errors with ``{prefix}_{dim}`` columns (m, rad), at least 3 rows.
    prefix : str
        ``eps`` (final) or ``eps_orig`` (at the initial focal lengths).

    Returns
    -------
    dict
        dimension -> {"theoretical": ndarray (N,), standard normal quantiles;
        "ordered": ndarray (N,), sorted errors (SI); "slope", "intercept": least-squares
        line (SI per standard deviation)}.
    """
    # scipy.stats costs ~0.35 s of CPU to import: loaded by the figures that use it, not by
    # every job that imports this module (an analyse job with figures: false)
    from scipy import stats

    e = _eps(errors, prefix)
    out = {}
    for i, d in enumerate(ERROR_DIMS):
        (osm, osr), (slope, intercept, _) = stats.probplot(e[:, i], dist="norm")
        out[d] = {"theoretical": osm, "ordered": osr, "slope": float(slope),
                  "intercept": float(intercept)}
    return out


def optimum_summary(result):
    """Optimal focal lengths and offset (seed eq. 1.13) and the error norm before and after.

    Parameters
    ----------
    result : dict
        The optimiser's ``result.yaml`` content.

    Returns
    -------
    dict
        ``fx_px, fy_px, f_init_px, P_bar`` (6 values, m and rad),
        ``norm_normalised_init_m, norm_normalised_final_m`` and their ratio.

    Notes
    -----
    The chapter reports a "normalised" error two-norm (1.15 -> 0.81) without defining the
    normalisation. Ours: the RMS over frames of the translation error norm,
    sqrt(mean_i ||eps_i[x, y, z]||^2), in metres.
    """
    keys = ["fx_px", "fy_px", "norm_normalised_init_m", "norm_normalised_final_m"]
    missing = [k for k in keys if k not in result]
    if missing:
        raise InputError(f"result.yaml: missing keys {missing}")
    init, final = result["norm_normalised_init_m"], result["norm_normalised_final_m"]
    return {
        "fx_px": float(result["fx_px"]), "fy_px": float(result["fy_px"]),
        "f_init_px": [float(v) for v in result.get("f_init_px", [np.nan, np.nan])],
        "P_bar": [float(v) for v in result.get("P_bar", [np.nan] * 6)],
        "norm_normalised_init_m": float(init), "norm_normalised_final_m": float(final),
        "norm_ratio": float(final / init) if init else float("nan"),
    }


def mocap_vs_cvs(errors, result):
    """Vicon against the original and improved CVS estimates over time (seed figure 1.8).

    Parameters
    ----------
    errors : pandas.DataFrame
        Per-frame table with ``t_s``, ``vic_*``, ``cvs_orig_*``, ``cvs_*``.
    result : dict
        ``P_bar`` (final) and ``P_bar_init`` (at the initial f), m and rad.

    Returns
    -------
    pandas.DataFrame
        ``t_s`` and per dimension ``vicon_*`` = P* + P_bar (the Vicon in CVS coordinates),
        ``original_*`` = F(f_init) - P_bar_init + P_bar and ``improved_*`` = F(f_final);
        each CVS track minus the Vicon track is exactly its eps (eq. 1.11), angles wrapped.
    """
    # se3 compares poses in one frame and has no 6-vector offset: P_bar is then zero.
    P_bar = np.asarray(result.get("P_bar", np.zeros(6)), dtype=float)
    P_bar0 = np.asarray(result.get("P_bar_init", P_bar), dtype=float)
    vic = _eps(errors, "vic") + P_bar
    orig = _eps(errors, "cvs_orig") - P_bar0 + P_bar
    impr = _eps(errors, "cvs")
    out = pd.DataFrame({"t_s": errors["t_s"].to_numpy(dtype=float)
                        if "t_s" in errors else np.arange(len(errors), dtype=float)})
    for i, d in enumerate(ERROR_DIMS):
        wrap = (lambda a: np.angle(np.exp(1j * a))) if i >= 3 else (lambda a: a)
        out[f"vicon_{d}"] = wrap(vic[:, i])
        out[f"original_{d}"] = wrap(orig[:, i])
        out[f"improved_{d}"] = wrap(impr[:, i])
    return out


def sample_error_covariance(errors, prefix="eps"):
    """6x6 covariance Sigma of eps (seed eq. 1.14) and its correlation matrix, in SI.

    Not :func:`cvsflow.uncertainty.propagated_pose_covariance` (the propagated covariance of each pose).

    Parameters
    ----------
    errors : pandas.DataFrame
        Per-frame errors with ``{prefix}_{dim}`` columns (m, rad), at least 3 rows.
    prefix : str
        Column prefix, ``eps`` by default.

    Returns
    -------
    Sigma : ndarray, shape (6, 6)
        Sample covariance (ddof=1) of [x, y, z, roll, pitch, yaw]: m^2, m rad, rad^2.
    corr : ndarray, shape (6, 6)
        Correlation coefficients (unitless).

    Notes
    -----
    The chapter's eq. 1.14 mixes mm and degrees; here Sigma is SI and
    :func:`cvsflow.plots.results.plot_covariance` presents it in mm and deg.
    """
    e = _eps(errors, prefix)
    Sigma = np.cov(e, rowvar=False, ddof=1)  # eq. 1.14
    sd = np.sqrt(np.diag(Sigma))
    corr = Sigma / np.outer(sd, sd)
    return Sigma, corr


def binned_error_map(errors, pose_dim_a, pose_dim_b, error_dim, bins=12, min_count=3,
                     pose_prefix="cvs"):
    """Binned mean of one error dimension over a 2-D grid of two pose dimensions (figure 1.9).

    Parameters
    ----------
    errors : pandas.DataFrame
        Per-frame table with ``{pose_prefix}_*`` and ``eps_*``.
    pose_dim_a, pose_dim_b, error_dim : str
        Dimension suffixes, e.g. ``"x_m"``, ``"z_m"``, ``"y_m"``.
    bins : int
        Bins per axis (equal width over the data's range).
    min_count : int
        Cells with fewer samples are NaN.
    pose_prefix : str
        Which pose to bin on: ``cvs`` (board in camera, final f) by default.

    Returns
    -------
    dict
        ``edges_a, edges_b`` (bins + 1,), ``centres_a, centres_b`` (bins,),
        ``mean`` (bins, bins) indexed [a, b], ``count`` (bins, bins), and the three
        dimension names. SI units.
    """
    for d in (pose_dim_a, pose_dim_b, error_dim):
        if d not in ERROR_DIMS:
            raise InputError(f"binned_error_map: dimension {d!r}, expected one of {ERROR_DIMS}")
    cols = [f"{pose_prefix}_{pose_dim_a}", f"{pose_prefix}_{pose_dim_b}", f"eps_{error_dim}"]
    _require(errors, cols, "errors table")
    a, b, e = (errors[c].to_numpy(dtype=float) for c in cols)
    edges_a = np.linspace(a.min(), a.max(), bins + 1)
    edges_b = np.linspace(b.min(), b.max(), bins + 1)
    count, _, _ = np.histogram2d(a, b, bins=[edges_a, edges_b])
    total, _, _ = np.histogram2d(a, b, bins=[edges_a, edges_b], weights=e)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count >= min_count, total / count, np.nan)
    return {"edges_a": edges_a, "edges_b": edges_b,
            "centres_a": 0.5 * (edges_a[1:] + edges_a[:-1]),
            "centres_b": 0.5 * (edges_b[1:] + edges_b[:-1]),
            "mean": mean, "count": count.astype(int),
            "pose_dim_a": pose_dim_a, "pose_dim_b": pose_dim_b, "error_dim": error_dim}


#: Default pose-dimension pairs of the contour figure (x-z, y-z, roll-pitch).
CONTOUR_PAIRS = (("x_m", "z_m"), ("y_m", "z_m"), ("roll_rad", "pitch_rad"))


def error_maps(errors, pairs=CONTOUR_PAIRS, bins=12, min_count=3):
    """:func:`binned_error_map` of every error dimension over each pose pair (figure 1.9).

    Parameters
    ----------
    errors : pandas.DataFrame
        Per-frame table with ``cvs_{dim}`` and ``eps_{dim}`` columns (m, rad).
    pairs : sequence of (str, str)
        Pose-dimension pairs to bin over (default x-z, y-z, roll-pitch).
    bins, min_count : int
        As :func:`binned_error_map`.

    Returns
    -------
    list of dict
        len(pairs) * 6 maps, pair-major.
    """
    return [binned_error_map(errors, a, b, d, bins=bins, min_count=min_count)
            for a, b in pairs for d in ERROR_DIMS]


def run_statistics(errors, prefix="eps"):
    """``stats.json``-ready summary of eps: plain floats and lists, SI units.

    Parameters
    ----------
    errors : pandas.DataFrame
        Per-frame errors with ``{prefix}_{dim}`` columns (m, rad), at least 3 rows.
    prefix : str
        Column prefix, ``eps`` by default.

    Returns
    -------
    dict
        ``n``, ``dims``, ``per_dim`` (dimension -> the statistics of
        :data:`cvsflow.metrics.STATISTICS`, skew, kurtosis, dagostino_k2, dagostino_p,
        anderson_stat, anderson_p, normal_at_5pct), ``Sigma`` (6x6, SI, eq. 1.14),
        ``corr`` (6x6) and ``units``.
    """
    tests = normality_tests(errors, prefix)
    Sigma, corr = sample_error_covariance(errors, prefix)
    keys = [*STATISTICS, "skew", "kurtosis", "dagostino_k2", "dagostino_p", "anderson_stat",
            "anderson_p"]
    per_dim = {d: {k: float(tests.loc[d, k]) for k in keys} for d in ERROR_DIMS}
    for d in ERROR_DIMS:
        per_dim[d]["normal_at_5pct"] = bool(tests.loc[d, "normal_at_5pct"])
    return {
        "n": int(tests["n"].iloc[0]),
        "dims": list(ERROR_DIMS),
        "per_dim": per_dim,
        "Sigma": Sigma.tolist(),
        "corr": corr.tolist(),
        "units": "SI: metres and radians (Sigma: m^2, m*rad, rad^2)",
    }
