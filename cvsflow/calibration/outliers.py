"""Outlying corners and stills of a calibration: found, left out by a stated rule, and named.

Corners (:func:`fit_with_outliers`): round after round the fit is run, its corner noise
``sigma`` (per coordinate, degrees of freedom counted) computed, and every kept corner whose
residual is above ``K_SIGMA`` sigmas left out, until none is (mrcal's scheme). Under Gaussian
corner noise ``|r|^2 / sigma^2`` is chi-square with 2 dof, so ``P(|r| > 4 sigma) = exp(-8)``:
0.24 of 702 clean corners left out by chance. Each corner left out is named with its residual,
the sigma and round it fell in, and how far it lies from the final fit; with rejection off the
corners beyond the threshold are named all the same. Nothing is dropped silently.

Stills (:func:`still_verdicts`): a still is named when a large share of its corners was left
out, when its kept corners fit worse than the set's sigma allows (a chi-square test: a still
whose corners are uniformly off, which per-corner rejection cannot see), or when too few
corners remain to fit its pose. Named stills stay in the fit; their reasons go to camera.yaml
and the log. A pose-like error of a still (a scale or a shift of all its corners) is absorbed by
its pose and no residual test can see it: :func:`cvsflow.calibration.cross_validation.leave_one_out`
says how far each still moves the projection, so that the still a calibration leans on most is
named too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import gammaincc

from cvsflow.calibration.bundle import (
    MIN_CORNERS_PER_STILL,
    BundleFit,
    StillView,
    initial_fit,
    refine_fit,
)
from cvsflow.calibration.lens import LensModel
from cvsflow.exceptions import CalibrationError

#: A corner is an outlier when |r| > K_SIGMA * sigma: for Gaussian corner noise of sigma per
#: coordinate, |r|^2 / sigma^2 is chi-square with 2 dof, so P(|r| > k sigma) = exp(-k^2 / 2):
#: 3.4e-4 at k = 4, i.e. 0.24 of 702 corners rejected by chance.
K_SIGMA = 4.0
#: A still is named when at least this share of its corners was rejected (at K_SIGMA = 4 a
#: still of 54 clean corners loses one by chance with probability 0.02).
STILL_REJECTED_SHARE = 0.10
#: ... or when its kept corners' chi-square against the set's sigma is at least STILL_CHI2_RATIO
#: times its dof (an RMS at least sqrt(2) times the set's) with a p-value below STILL_CHI2_P.
#: (OpenCV's left08 has 1.8 times, p = 1.5e-6, with every refinement: a blurrier still, not a
#: wrong one.)
STILL_CHI2_RATIO = 2.0
STILL_CHI2_P = 1e-3
#: ... and only when its kept corners' RMS is at least this (px): on clean renders (set sigma
#: 0.024 px) a still at 0.045 px passed the ratio test, a difference no user needs to see.
STILL_RMS_FLOOR_PX = 0.1

@dataclass
class RejectedCorner:
    """One corner left out of the fit, and why.

    Attributes
    ----------
    still : str
    corner : int
        Board corner index k.
    uv_px : (float, float)
        Its refined position, px.
    residual_px : (float, float)
        ``uv_fit - uv_obs`` when it was rejected, px.
    norm_px : float
        ``|residual|``, px.
    z : float
        ``norm_px / sigma_px`` at rejection.
    sigma_px : float
        The fit's corner sigma at rejection, px.
    round : int
        Rejection round (1 = first fit).
    final_z : float
        ``|residual| / sigma`` against the final fit (is it still an outlier?).
    reason : str
    """

    still: str
    corner: int
    uv_px: tuple
    residual_px: tuple
    norm_px: float
    z: float
    sigma_px: float
    round: int
    final_z: float = float("nan")
    reason: str = ""


#: Fewest stills with a fitted pose for any fit (Zhang's method needs three views of a plane).
MIN_POSED_STILLS = 3


def _check_enough_left(views, inlier, model, k_sigma) -> None:
    """A CalibrationError when the corners kept leave too few posed stills or too few data for
    the model's parameters (each still that lost its pose named with its corners kept)."""
    kept = [int(m.sum()) for m in inlier]
    posed = [k for k in kept if k >= MIN_CORNERS_PER_STILL]
    n_params = model.n_params + 6 * len(posed)
    if len(posed) >= MIN_POSED_STILLS and 2 * sum(posed) > n_params:
        return
    lost = [(v.name, k, len(v.ids)) for v, k in zip(views, kept, strict=True)
            if k < MIN_CORNERS_PER_STILL]
    why = "; ".join(f"{n}: {k} of {t} corners kept" for n, k, t in lost[:4]) + (
        f"; and {len(lost) - 4} more" if len(lost) > 4 else "")
    head = ("every still lost its corners to the outlier rejection" if not posed else
            f"after outlier rejection {len(posed)} stills keep a pose (the {model.name} model "
            f"needs at least {MIN_POSED_STILLS} and more corner coordinates than its "
            f"{n_params} parameters)")
    raise CalibrationError(
        f"calibration: {head} ({why}; threshold {k_sigma:g} sigma of the fitted corner noise): "
        "the board's size or the stills are wrong (blur, a damaged board); try "
        "--no-outlier-rejection to see every residual")


def fit_with_outliers(views: list[StillView], size_wh: tuple, model: LensModel,
                      k_sigma: float = K_SIGMA, reject: bool = True, max_rounds: int = 30,
                      start=None):
    """The fit with corners beyond ``k_sigma`` fitted sigmas left out, round after round.

    Parameters
    ----------
    views : list of StillView
    size_wh : (int, int)
    model : LensModel
    k_sigma : float
        Threshold on ``|r| / sigma_px`` (both coordinates' residual over the fit's corner
        sigma per coordinate).
    reject : bool
        False: one fit with every corner; the corners beyond the threshold are still named
        (``round = 0``: reported, not rejected).
    max_rounds : int
    start : (theta, rvecs, tvecs), optional
        Start of the first fit; default ``initial_fit``.

    Returns
    -------
    fit : BundleFit
    rejected : list of RejectedCorner
        Every corner left out (or, with ``reject=False``, beyond the threshold), in order.

    Raises
    ------
    CalibrationError
        The rejection leaving fewer than ``MIN_POSED_STILLS`` stills with a pose, or fewer
        corner coordinates than parameters (each still that lost its pose named).

    Notes
    -----
    Each round fits the kept corners, computes ``sigma_px`` from them with the correct
    degrees of freedom, and leaves out every kept corner above ``k_sigma * sigma_px``; it
    stops when none is. A left-out corner is not taken back (mrcal does the same); its
    ``final_z`` tells how far it is from the final fit.
    """
    theta, rvecs, tvecs = start if start is not None else initial_fit(views, size_wh, model)
    inlier = [np.ones(len(v.ids), bool) for v in views]
    rejected: list[RejectedCorner] = []
    fit = None
    for rnd in range(1, max_rounds + 1):
        fit = refine_fit(views, size_wh, model, theta, rvecs, tvecs, inlier)
        theta, rvecs, tvecs = fit.theta, fit.rvecs, fit.tvecs
        new = []
        for i, v in enumerate(views):
            r = fit.residual_px[i]
            norm = np.linalg.norm(r, axis=1)
            bad = fit.inlier[i] & (norm > k_sigma * fit.sigma_px)
            for k in np.flatnonzero(bad):
                new.append(RejectedCorner(
                    v.name, int(v.ids[k]), (float(v.uv_px[k, 0]), float(v.uv_px[k, 1])),
                    (float(r[k, 0]), float(r[k, 1])), float(norm[k]),
                    float(norm[k] / fit.sigma_px), float(fit.sigma_px), rnd if reject else 0))
                if reject:
                    inlier[i][k] = False
        rejected += new
        if not new or not reject:
            break
        _check_enough_left(views, inlier, model, k_sigma)
    for rc in rejected:
        i = fit.names.index(rc.still)
        k = int(np.flatnonzero(views[i].ids == rc.corner)[0])
        rc.final_z = float(np.linalg.norm(fit.residual_px[i][k]) / fit.sigma_px)
        what = "rejected" if rc.round else "beyond the threshold (rejection off)"
        rc.reason = (f"{what}: residual {rc.norm_px:.2f} px = {rc.z:.1f} sigma > {k_sigma:g} "
                     f"sigma (sigma {rc.sigma_px:.3f} px, round {rc.round}); against the final "
                     f"fit {rc.final_z:.1f} sigma")
    return fit, rejected


def still_verdicts(views, fit: BundleFit, rejected, max_rejected_share=STILL_REJECTED_SHARE,
                   chi2_ratio=STILL_CHI2_RATIO, chi2_p=STILL_CHI2_P) -> list[dict]:
    """Per still: corners kept and rejected, RMS, its chi-square against the set, and a verdict.

    Parameters
    ----------
    views : list of StillView
    fit : BundleFit
    rejected : list of RejectedCorner
    max_rejected_share : float
        A still with at least this share of its corners rejected is named.
    chi2_ratio, chi2_p : float
        A still whose kept corners give ``chi2 = sum |r|^2 / sigma^2`` of at least
        ``chi2_ratio`` times its dof (``2 n_kept - 6 - n_theta n_kept / n_used``: its pose and
        its share of the intrinsics) with an upper-tail p-value below ``chi2_p``, and an RMS of
        at least ``STILL_RMS_FLOOR_PX``, is named.

    Returns
    -------
    list of dict
        ``name, n_corners, n_rejected, rejected_share, rms_px`` (kept corners), ``rms_all_px``
        (every corner), ``chi2_ratio`` (chi-square over its dof, ~1), ``p_value``, ``max_z``
        (largest ``|r| / sigma`` of any of its corners), ``flagged`` (bool) and ``reasons``
        (list of str).
    """
    by_still: dict = {}
    for rc in rejected:
        by_still.setdefault(rc.still, []).append(rc)
    out = []
    for i, v in enumerate(views):
        r = fit.residual_px[i]
        m = fit.inlier[i]
        n, n_kept = len(v.ids), int(m.sum())
        n_rej = sum(1 for rc in by_still.get(v.name, []) if rc.round)
        sq = np.sum(r**2, axis=1)
        chi2 = float(np.sum(sq[m]) / fit.sigma_px**2)
        dof = max(2 * n_kept - 6 - fit.model.n_params * n_kept / fit.n_used, 1.0)
        p = float(gammaincc(dof / 2.0, chi2 / 2.0))
        rec = {
            "name": v.name, "n_corners": n, "n_rejected": n_rej,
            "rejected_share": n_rej / n if n else 0.0,
            "rms_px": float(np.sqrt(np.mean(sq[m]))) if n_kept else float("nan"),
            "rms_all_px": float(np.sqrt(np.mean(sq))),
            "chi2_ratio": chi2 / dof, "p_value": p,
            "max_z": float(np.sqrt(sq.max()) / fit.sigma_px) if n else float("nan"),
            "flagged": False, "reasons": [],
        }
        if n and n_rej / n >= max_rejected_share:
            rec["reasons"].append(
                f"largely rejected: {n_rej} of {n} corners ({100 * n_rej / n:.0f} % >= "
                f"{100 * max_rejected_share:.0f} %)")
        if (n_kept >= MIN_CORNERS_PER_STILL and p < chi2_p and chi2 / dof >= chi2_ratio
                and rec["rms_px"] >= STILL_RMS_FLOOR_PX):
            rec["reasons"].append(
                f"its kept corners fit worse than the set: RMS {rec['rms_px']:.3f} px "
                f"(>= {STILL_RMS_FLOOR_PX:g}), "
                f"chi-square {rec['chi2_ratio']:.2f} x its dof (>= {chi2_ratio:g}, p = {p:.1e} "
                f"< {chi2_p:g})")
        if n_kept < MIN_CORNERS_PER_STILL:
            rec["reasons"].append(f"only {n_kept} corners kept (< {MIN_CORNERS_PER_STILL}): "
                                  "its pose is not fitted")
        rec["flagged"] = bool(rec["reasons"])
        out.append(rec)
    return out
