"""What camera.yaml says of a calibration beyond its numbers: outliers, uncertainty, verdicts.

:func:`assess_fit` takes a converged fit (:mod:`.bundle`, :mod:`.outliers`) and returns the
sections ``calibrate_camera`` writes: the corners and stills left out or named (``outliers``),
the projection uncertainty (``projection_uncertainty``), the cross-validation of two halves
(``cross_validation``), each still's influence and the jackknife standard errors, and the
quality block with its plain verdicts.
"""

from __future__ import annotations

import logging

import numpy as np

from cvsflow.calibration.bundle import MIN_CORNERS_PER_STILL, BundleFit
from cvsflow.calibration.cross_validation import (
    INFLUENCE_SIGMA_NAMED,
    cross_validate,
    leave_one_out,
)
from cvsflow.calibration.outliers import still_verdicts
from cvsflow.calibration.projection_uncertainty import uncertainty_summary
from cvsflow.calibration.quality import geometry_quality, quality_verdicts, verdict_line

log = logging.getLogger(__name__)

#: Fewest stills with a fitted pose for the cross-validation (3 per half).
MIN_STILLS_CROSS_VALIDATION = 6

#: What ``projection_uncertainty`` is, written beside its numbers.
UNCERTAINTY_DEFINITION = (
    "1-sigma in the worst direction (px) of where a 3-D point seen at a pixel reprojects when "
    "the stills' corner noise moves the calibration, the board poses free (mrcal's mean-frames "
    "projection uncertainty), at the stills' median board distance and at infinity")


def _corner_record(rc) -> dict:
    """camera.yaml's record of a corner left out (or beyond the threshold)."""
    return {"still": rc.still, "corner": int(rc.corner), "u_px": rc.uv_px[0],
            "v_px": rc.uv_px[1], "residual_px": list(rc.residual_px), "norm_px": rc.norm_px,
            "z": rc.z, "sigma_px": rc.sigma_px, "round": int(rc.round),
            "final_z": rc.final_z, "rejected": bool(rc.round), "reason": rc.reason}


def _still_records(views, fit: BundleFit, rejected, influence) -> list[dict]:
    """Per still: its residual statistics, its influence and the reasons it is named."""
    out = []
    for v, inf in zip(still_verdicts(views, fit, rejected), influence, strict=True):
        rec = {"name": v["name"], "n_corners": v["n_corners"], "n_rejected": v["n_rejected"],
               "rms_px": v["rms_px"], "rms_all_px": v["rms_all_px"],
               "chi2_ratio": v["chi2_ratio"], "p_value": v["p_value"], "max_z": v["max_z"],
               "influence_px": None if inf is None else inf["shift_px"],
               "influence_sigma": None if inf is None else inf["shift_sigma"],
               "influence_ratio": None if inf is None else inf["ratio"],
               "named": v["flagged"], "reasons": list(v["reasons"])}
        out.append(rec)
    return out


def _outliers_section(views, fit, rejected, stills, k_sigma, reject) -> dict:
    """camera.yaml's ``outliers``: the rule, every corner left out, the stills named."""
    n_corners = sum(len(v.ids) for v in views)
    n_rej = sum(1 for r in rejected if r.round)
    fitted = [s for s in stills if s["influence_ratio"] is not None]
    top = max(fitted, key=lambda s: s["influence_ratio"]) if fitted else None
    weakest = max(fitted, key=lambda s: s["chi2_ratio"]) if fitted else None
    return {
        "rule": (f"a corner whose residual exceeds {k_sigma:g} sigma of the fitted corner noise "
                 f"(sigma per coordinate, {fit.sigma_px:.4f} px at the end) is "
                 + ("left out, round after round, until none is" if reject else
                    "named but kept (rejection off)")),
        "k_sigma": float(k_sigma), "rejection": bool(reject), "sigma_px": fit.sigma_px,
        "n_corners": n_corners, "n_rejected": n_rej, "share": n_rej / max(n_corners, 1),
        "corners": [_corner_record(r) for r in rejected],
        "named_stills": [{"name": s["name"], "reasons": s["reasons"]}
                         for s in stills if s["named"]],
        "most_influential": None if top is None else {
            "name": top["name"], "influence_px": top["influence_px"],
            "influence_ratio": top["influence_ratio"],
            "why": (f"leaving it out moves the projection most: {top['influence_px']:.3f} px RMS "
                    f"over the covered area, {top['influence_ratio']:.1f} x the median still's")},
        "weakest": None if weakest is None else {
            "name": weakest["name"], "rms_px": weakest["rms_px"],
            "chi2_ratio": weakest["chi2_ratio"],
            "why": (f"its corners fit worst: RMS {weakest['rms_px']:.3f} px, "
                    f"{weakest['chi2_ratio']:.2f} x the set's noise per degree of freedom")},
    }


def _influence_names(stills) -> list[str]:
    """Stills whose leave-one-out shift exceeds ``INFLUENCE_SIGMA_NAMED`` projection sigmas,
    with a reason added to their record."""
    names = []
    for s in stills:
        z = s["influence_sigma"]
        if z is not None and z > INFLUENCE_SIGMA_NAMED:
            s["reasons"].append(
                f"the calibration hangs on it: leaving it out moves the projection by "
                f"{s['influence_px']:.3f} px, {z:.1f} x its stated uncertainty over the covered "
                f"area (named above {INFLUENCE_SIGMA_NAMED:g})")
            s["named"] = True
            names.append(s["name"])
    return names


def assess_fit(views, fit: BundleFit, rejected, *, k_sigma: float, reject: bool,
               distance_m: float | None = None, cross_validation: bool = True,
               min_coverage: float = 0.3, min_normal_spread_deg: float = 10.0,
               max_rel_std_f: float = 0.01) -> dict:
    """The sections of camera.yaml that judge a fit.

    Parameters
    ----------
    views : list of StillView
    fit : BundleFit
    rejected : list of RejectedCorner
        :func:`cvsflow.calibration.outliers.fit_with_outliers`'s.
    k_sigma : float
        Its threshold (fitted corner sigmas).
    reject : bool
        Whether corners beyond it were left out.
    distance_m : float, optional
        Range of the projection uncertainty's finite distance, m; default the stills' median.
    cross_validation : bool
        Fit two interleaved halves (needs ``MIN_STILLS_CROSS_VALIDATION`` stills).
    min_coverage, min_normal_spread_deg, max_rel_std_f : float
        The quality verdicts' warn boundaries (:func:`cvsflow.calibration.quality.quality_verdicts`).

    Returns
    -------
    dict
        ``stills`` (per still: ``n_corners``, ``n_rejected``, ``rms_px`` of the kept corners,
        ``rms_all_px``, ``chi2_ratio``, ``p_value``, ``max_z``, ``influence_px``,
        ``influence_sigma``, ``influence_ratio``, ``named``, ``reasons``), ``outliers``,
        ``std_jackknife`` (n_theta,), ``projection_uncertainty``, ``cross_validation`` (None
        with too few stills), ``quality`` (geometry, ``verdicts``, ``summary`` line) and
        ``warnings`` (list of str).
    """
    loo = leave_one_out(views, fit)
    stills = _still_records(views, fit, rejected, loo["influence"])
    _influence_names(stills)
    outliers = _outliers_section(views, fit, rejected, stills, k_sigma, reject)
    unc = uncertainty_summary(fit, views, distance_m)
    unc = {"definition": UNCERTAINTY_DEFINITION, **unc}
    active = [i for i, m in enumerate(fit.inlier) if m.sum() >= MIN_CORNERS_PER_STILL]
    cv = None
    if cross_validation and len(active) >= MIN_STILLS_CROSS_VALIDATION:
        cv = {k: v for k, v in cross_validate([views[i] for i in active], _subfit(fit, active)
                                               ).items() if k != "map"}
        cv["halves"] = [list(h) for h in cv["halves"]]
    kept = [views[i].uv_px[fit.inlier[i]] for i in active]
    geometry = geometry_quality(fit.T_C_B()[active], kept, fit.size_wh, fit.theta,
                                fit.theta_std)
    named = [s["name"] for s in stills if s["named"]]
    verdicts = quality_verdicts(geometry, unc, fit.size_wh, cv, outliers["share"], named,
                                [views[i].name for i in active], min_coverage,
                                min_normal_spread_deg, max_rel_std_f)
    warnings = [v["message"] for v in verdicts
                if v["verdict"] == "bad" or (v["verdict"] != "ok" and
                                             v["check"] in ("stills", "outliers"))]
    warnings += [f"{s['name']}: {'; '.join(s['reasons'])}" for s in stills if s["named"]]
    quality = {**geometry, "verdicts": verdicts, "summary": verdict_line(verdicts)}
    return {"stills": stills, "outliers": outliers, "std_jackknife": loo["std"],
            "projection_uncertainty": unc, "cross_validation": cv, "quality": quality,
            "warnings": warnings}


def _subfit(fit: BundleFit, idx: list[int]) -> BundleFit:
    """The fit restricted to the stills ``idx`` (their poses, residuals and inliers; the
    covariance's rows of the others dropped), for the cross-validation's halves to start from."""
    if len(idx) == len(fit.rvecs):
        return fit
    n_theta = fit.model.n_params
    cols = np.r_[np.arange(n_theta), *[n_theta + 6 * i + np.arange(6) for i in idx]]
    return BundleFit(fit.model, fit.size_wh, fit.theta, fit.rvecs[idx], fit.tvecs[idx],
                     [fit.inlier[i] for i in idx], [fit.residual_px[i] for i in idx],
                     fit.sigma_px, fit.cov[np.ix_(cols, cols)], fit.JtJ[np.ix_(cols, cols)],
                     int(sum(fit.inlier[i].sum() for i in idx)), fit.n_iter,
                     [fit.names[i] for i in idx])
