"""Is a calibration good? Its stills' geometry, and plain verdicts with thresholds scaled to the image.

Each check gives ``ok``, ``warn`` or ``bad`` with a sentence naming the number, its threshold and
what to do. Pixel thresholds scale with the image diagonal (a 1920x1080 camera is allowed 2.75
times the pixels of a 640x480 one: the same angle for the same field of view); shares and
angles are scale-free.

=====================  ==========================================  =================  ===========
check                  quantity                                    ok                 warn (else
                                                                                      bad)
=====================  ==========================================  =================  ===========
coverage               share of the image in the stills' hulls     >= 0.5             >= 0.3
coverage_cells         cells of a 3x3 grid holding corners         9 of 9             >= 7
tilt                   largest board tilt from the optical axis    >= 30 deg          >= 15 deg
normal_spread          largest angle between two board normals     >= 20 deg          >= 10 deg
focal_std              std of fx or fy over its value              <= 0.2 %           <= 1 %
uncertainty_covered    worst projection sigma at infinity in the   <= 2.5e-4 x diag   <= 1e-3 x
                       covered area                                (0.2 px at VGA)    diag
uncertainty_image      worst projection sigma at infinity over     <= 1e-3 x diag     <= 5e-3 x
                       the whole image                             (0.8 px at VGA)    diag
cross_validation       ratio of the halves' difference to its      <= 1.5             <= 3
                       prediction (:mod:`.cross_validation`)
outliers               share of the corners left out               <= 2 %             <= 10 %
stills                 stills named (:mod:`.outliers`)             none               (warn)
=====================  ==========================================  =================  ===========

The ``warn`` boundaries of coverage, normal_spread and focal_std are the config's
``calibrate.min_coverage``, ``min_normal_spread_deg`` and ``max_rel_std_f``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cvsflow.calibration.projection_uncertainty import coverage_mask

#: check -> (ok at, warn at); pixel thresholds as shares of the image diagonal.
THRESHOLDS = {
    "coverage": (0.5, 0.3),
    "coverage_cells": (9, 7),
    "tilt_deg": (30.0, 15.0),
    "normal_spread_deg": (20.0, 10.0),
    "focal_std": (0.002, 0.01),
    "uncertainty_covered_diag": (2.5e-4, 1e-3),
    "uncertainty_image_diag": (1e-3, 5e-3),
    "cross_validation_ratio": (1.5, 3.0),
    "outlier_share": (0.02, 0.10),
}

_CELL_NAMES = [["top-left", "top", "top-right"], ["left", "centre", "right"],
               ["bottom-left", "bottom", "bottom-right"]]


def geometry_quality(T_C_B: np.ndarray, corner_sets: Sequence[np.ndarray], size_wh: tuple,
                     theta: np.ndarray, theta_std: np.ndarray) -> dict:
    """How well the stills' views constrain the intrinsics: coverage, tilt, focal uncertainty.

    Parameters
    ----------
    T_C_B : ndarray, shape (N, 4, 4)
        Each used still's board pose, ``p_C = T_C_B p_B`` (m).
    corner_sets : sequence of ndarray, shape (n_i, 2)
        Each still's kept corners, px.
    size_wh : (int, int)
        Image width, height, px.
    theta, theta_std : ndarray, shape (n_theta,)
        The intrinsics (``fx fy cx cy`` px first) and their 1-sigma.

    Returns
    -------
    dict
        ``coverage_share`` (share of the image inside the union of the stills' corner hulls),
        ``coverage_cells`` (cells of a 3x3 grid of the image holding a corner),
        ``empty_cells`` (their names), ``tilt_min_deg``, ``tilt_max_deg`` (angle between a
        board's normal and the optical axis), ``normal_spread_deg`` (largest angle between
        two boards' normals), ``rel_std_fx``, ``rel_std_fy`` (std of fx, fy over fx, fy).

    Notes
    -----
    Zhang's method needs views of the plane in different orientations: with parallel board
    normals the focal length trades off against distance, which ``normal_spread_deg`` and the
    relative std of fx reveal. Corners over a small part of the image leave the distortion
    unconstrained elsewhere (``coverage_share``, ``coverage_cells``).
    """
    w, h = size_wh
    mask = coverage_mask(corner_sets, size_wh)
    uv = np.concatenate([np.asarray(c, float).reshape(-1, 2) for c in corner_sets])
    seen = np.zeros((3, 3), bool)
    seen[np.clip((uv[:, 1] * 3 // h).astype(int), 0, 2),
         np.clip((uv[:, 0] * 3 // w).astype(int), 0, 2)] = True
    normals = np.asarray(T_C_B)[:, :3, 2]
    tilt = np.degrees(np.arccos(np.clip(np.abs(normals[:, 2]), 0.0, 1.0)))
    cosines = np.clip(np.abs(normals @ normals.T), 0.0, 1.0)
    return {
        "coverage_share": float(mask.mean()),
        "coverage_cells": int(seen.sum()),
        "empty_cells": [_CELL_NAMES[j][i] for j in range(3) for i in range(3) if not seen[j, i]],
        "tilt_min_deg": float(tilt.min()),
        "tilt_max_deg": float(tilt.max()),
        "normal_spread_deg": float(np.degrees(np.arccos(cosines.min()))),
        "rel_std_fx": float(theta_std[0] / theta[0]),
        "rel_std_fy": float(theta_std[1] / theta[1]),
    }


def _grade(value: float, ok: float, warn: float, higher_is_better: bool) -> str:
    """'ok', 'warn' or 'bad' of a value against its two thresholds."""
    if not np.isfinite(value):
        return "bad"
    if higher_is_better:
        return "ok" if value >= ok else ("warn" if value >= warn else "bad")
    return "ok" if value <= ok else ("warn" if value <= warn else "bad")


def _thresholds(size_wh, min_coverage, min_normal_spread_deg, max_rel_std_f):
    """THRESHOLDS with the config's warn boundaries and the pixel ones scaled to the image."""
    t = dict(THRESHOLDS)
    t["coverage"] = (max(t["coverage"][0], min_coverage), min_coverage)
    t["normal_spread_deg"] = (max(t["normal_spread_deg"][0], min_normal_spread_deg),
                              min_normal_spread_deg)
    t["focal_std"] = (min(t["focal_std"][0], max_rel_std_f), max_rel_std_f)
    diag = float(np.hypot(*size_wh))
    t["uncertainty_covered_px"] = tuple(x * diag for x in t["uncertainty_covered_diag"])
    t["uncertainty_image_px"] = tuple(x * diag for x in t["uncertainty_image_diag"])
    return t, diag


def quality_verdicts(geometry: dict, uncertainty: dict, size_wh: tuple,
                     cross_validation: dict | None = None, outlier_share: float = 0.0,
                     named_stills: Sequence[str] = (), still_names: Sequence[str] = (),
                     min_coverage: float = 0.3,
                     min_normal_spread_deg: float = 10.0, max_rel_std_f: float = 0.01
                     ) -> list[dict]:
    """Plain verdicts of a calibration (the module's table).

    Parameters
    ----------
    geometry : dict
        :func:`geometry_quality`.
    uncertainty : dict
        :func:`cvsflow.calibration.projection_uncertainty.uncertainty_summary`.
    size_wh : (int, int)
        Image width, height, px.
    cross_validation : dict, optional
        :func:`cvsflow.calibration.cross_validation.cross_validate` (no check without it).
    outlier_share : float
        Share of the corners left out.
    named_stills : sequence of str
        Stills :func:`cvsflow.calibration.outliers.still_verdicts` named.
    still_names : sequence of str
        The stills used (named when their board normals barely differ).
    min_coverage, min_normal_spread_deg, max_rel_std_f : float
        The config's warn boundaries: share of the image, deg, std of fx or fy over its value.

    Returns
    -------
    list of dict
        One per check: ``check``, ``value``, ``ok_at``, ``warn_at`` (thresholds, px for the
        uncertainty checks), ``verdict`` (``ok``, ``warn``, ``bad``) and ``message``.
    """
    t, diag = _thresholds(size_wh, min_coverage, min_normal_spread_deg, max_rel_std_f)
    out = []

    def add(check, value, key, higher, message, advice=""):
        ok, warn = t[key]
        verdict = _grade(value, ok, warn, higher)
        out.append({"check": check, "value": float(value), "ok_at": float(ok),
                    "warn_at": float(warn), "verdict": verdict,
                    "message": message + (f": {advice}" if advice and verdict != "ok" else "")})

    g = geometry
    add("coverage", g["coverage_share"], "coverage", True,
        f"the board covers {100 * g['coverage_share']:.0f} % of the image over all stills (ok from "
        f"{100 * t['coverage'][0]:.0f} %, bad below {100 * t['coverage'][1]:.0f} %)",
        "the distortion is extrapolated elsewhere; add stills with the board near the edges")
    add("coverage_cells", g["coverage_cells"], "coverage_cells", True,
        f"{g['coverage_cells']} of 9 image cells (3x3) hold corners",
        f"none in {', '.join(g['empty_cells'])}; add stills there")
    add("tilt", g["tilt_max_deg"], "tilt_deg", True,
        f"the most tilted board is {g['tilt_max_deg']:.0f} deg from facing the camera (ok from "
        f"{t['tilt_deg'][0]:g} deg)",
        "tilted views fix the focal length against the distance; tilt the board 30-45 deg")
    add("normal_spread", g["normal_spread_deg"], "normal_spread_deg", True,
        f"the board normals of the stills ({', '.join(still_names)}) span "
        f"{g['normal_spread_deg']:.1f} deg (tilt {g['tilt_min_deg']:.1f} to "
        f"{g['tilt_max_deg']:.1f} deg; ok from {t['normal_spread_deg'][0]:g} deg, bad below "
        f"{t['normal_spread_deg'][1]:g})",
        "the focal length trades off against distance; add stills with the board tilted 20 to "
        "45 deg in different directions")
    rel = max(g["rel_std_fx"], g["rel_std_fy"])
    add("focal_std", rel, "focal_std", False,
        f"std of fx {100 * g['rel_std_fx']:.2f} %, fy {100 * g['rel_std_fy']:.2f} % (ok up to "
        f"{100 * t['focal_std'][0]:g} %, bad above {100 * t['focal_std'][1]:g} %)")
    inf = uncertainty["at_infinity"]
    add("uncertainty_covered", inf["worst_covered"], "uncertainty_covered_px", False,
        f"projection uncertainty (1-sigma, worst direction, at infinity) up to "
        f"{inf['worst_covered']:.3f} px where the boards were (ok up to "
        f"{t['uncertainty_covered_px'][0]:.2f} px, {t['uncertainty_covered_diag'][0]:g} of the "
        f"{diag:.0f} px diagonal)", "add stills, or sharper ones")
    folds = inf.get("not_invertible_share", 0.0)
    add("uncertainty_image", inf["worst_image"], "uncertainty_image_px", False,
        (f"the lens model does not invert over {100 * folds:.0f} % of the image (its polynomial "
         "folds back beyond the angles the boards covered): no projection there is defined"
         if folds > 0 else
         f"projection uncertainty up to {inf['worst_image']:.2f} px over the whole image (ok up "
         f"to {t['uncertainty_image_px'][0]:.2f} px)"),
        "the distortion is extrapolated where no board was; add stills with the board in the "
        "image corners")
    if cross_validation is not None:
        add("cross_validation", cross_validation["ratio"], "cross_validation_ratio", False,
            f"the two interleaved halves' projections differ by {cross_validation['ratio']:.2f} "
            f"times what their uncertainty predicts (ok up to "
            f"{t['cross_validation_ratio'][0]:g})",
            "the lens model or the data are not good enough: the stated uncertainty is too "
            "small; try a richer --model, or look at the stills named")
    add("outliers", outlier_share, "outlier_share", False,
        f"{100 * outlier_share:.1f} % of the corners left out (ok up to "
        f"{100 * t['outlier_share'][0]:g} %)", "look at the stills named")
    named = list(named_stills)
    out.append({"check": "stills", "value": float(len(named)), "ok_at": 0.0, "warn_at": None,
                "verdict": "warn" if named else "ok",
                "message": f"stills named: {', '.join(named)}" if named else "no still named"})
    return out


def verdict_line(verdicts: Sequence[dict]) -> str:
    """One line of every check's verdict, for the CLI's summary and the report.

    Parameters
    ----------
    verdicts : sequence of dict
        :func:`quality_verdicts`.

    Returns
    -------
    str
        e.g. ``coverage ok (0.54), tilt ok (47), ..., stills ok (0)``; checks that are not ok
        in capitals.
    """
    parts = []
    for v in verdicts:
        value = v["value"]
        shown = f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"
        word = v["verdict"] if v["verdict"] == "ok" else v["verdict"].upper()
        parts.append(f"{v['check']} {word} ({shown})")
    return ", ".join(parts)
