"""The report's answer first: a verdict per session and flight, and a pass / warn / fail per stage.

The verdict is one or two sentences: how large the held-out pose error is per axis (RMS) and
whether the stated per-frame uncertainty holds (mean NEES and the share of held-out errors
inside the stated 95 % band). The stage checks compare what each stage measured with a
threshold, scaled where the measurement scales: reprojection errors with the image size
(:data:`REFERENCE_DIAGONAL_PX`), the held-out translation error with the board's distance.
Inputs are the stage outputs as loaded dicts (SI units), as for
:func:`cvsflow.evaluate.session_headline`; any may be missing.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from cvsflow.metrics import ERROR_DIMS, REPORT_UNITS
from cvsflow.uncertainty import TARGETS

#: The image diagonal (px) at which the pixel thresholds hold as written: 640x480.
REFERENCE_DIAGONAL_PX = 800.0
#: Pass / warn limits of each check, in the units of its value. A value beyond the warn limit fails.
THRESHOLDS = {
    # corner reprojection RMS (px at 640x480; scaled by the image diagonal)
    "calibration_rms_px": (0.5, 1.0),
    "se3_rms_px": (0.5, 2.0),
    # share of video frames with a board pose (low is bad)
    "board_share": (0.8, 0.2),
    # share of motion-capture marker samples filled (gap repair)
    "filled_share": (0.05, 0.2),
    # sync quality (low is bad; the warn limit is sync.min_quality when known)
    "sync_quality": (0.5, 0.25),
    # held-out RMS translation error over the median board distance
    "heldout_trans_share": (0.005, 0.02),
    # held-out RMS rotation error (rad)
    "heldout_rot_rad": (math.radians(0.5), math.radians(2.0)),
}
#: A calibrated error model: mean NEES (6 when right) and share inside the 95 % band, pass and warn.
NEES_PASS, NEES_WARN = TARGETS["nees"], (3.0, 12.0)
INSIDE_95_PASS, INSIDE_95_WARN = TARGETS["inside_95"], (0.88, 0.99)
#: Error dimensions (SI) with display name, unit and factor.
DIMS = tuple((d, *REPORT_UNITS[d]) for d in ERROR_DIMS)


def _num(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def _g(v, digits=2):
    """A report number with ``digits`` decimals; n/a when not finite."""
    v = _num(v)
    if not math.isfinite(v):
        return "n/a"
    return f"{v:.{digits}f}"


def _grade(value, limits, high_is_bad=True):
    """'pass', 'warn' or 'fail' of ``value`` against (pass limit, warn limit)."""
    if not math.isfinite(value):
        return "n/a"
    ok, warn = limits
    if high_is_bad:
        return "pass" if value <= ok else "warn" if value <= warn else "fail"
    return "pass" if value >= ok else "warn" if value >= warn else "fail"


def _band(value, ok, warn):
    """'pass' inside ``ok`` (lo, hi), 'warn' inside ``warn``, else 'fail'."""
    if not math.isfinite(value):
        return "n/a"
    return "pass" if ok[0] <= value <= ok[1] else "warn" if warn[0] <= value <= warn[1] else "fail"


def median_distance_m(heldout: pd.DataFrame | None) -> float:
    """Median distance (m) from the camera to the board over the held-out frames.

    Parameters
    ----------
    heldout : DataFrame or None
        ``heldout/se3.parquet``: the reference pose T_C_B's translation ``ref_x_m``,
        ``ref_y_m``, ``ref_z_m`` (m, camera frame) per frame.

    Returns
    -------
    float
        The median of the translation's norm (m); NaN without frames.
    """
    if heldout is None or len(heldout) == 0 or "ref_z_m" not in heldout:
        return float("nan")
    xyz = heldout[["ref_x_m", "ref_y_m", "ref_z_m"]].to_numpy(float)
    return float(np.nanmedian(np.linalg.norm(xyz, axis=1)))


def session_verdict(session, *, camera=None, corners=None, mocap_repair=None, sync=None, se3=None,
                    seed=None, comparison=None, distance_m=float("nan")):
    """The verdict of one session and its stage checks.

    Parameters
    ----------
    session : str
        Session name.
    camera, corners, mocap_repair, sync, se3, seed, comparison : dict, optional
        ``camera.yaml``, ``corners_summary.yaml``, ``mocap_repair.yaml``, ``sync.yaml``, the se3
        and seed ``result.yaml`` and ``comparison.yaml`` (SI units).
    distance_m : float
        Median camera-to-board distance of the held-out frames (m,
        :func:`median_distance_m`); NaN when unknown (the distance check is then n/a).

    Returns
    -------
    dict
        ``session``; ``text`` (the verdict, one or two sentences; None without held-out
        errors); ``checks``: list of dicts ``stage``, ``status`` ('pass', 'warn', 'fail',
        'info' or 'n/a'), ``measured`` and ``threshold`` (text, report units).
    """
    checks = []
    scale = _image_scale(camera)
    if camera is not None:
        checks.append(_rms_check("calibration", camera, THRESHOLDS["calibration_rms_px"], scale,
                                 "reprojection RMS", f" over {camera.get('n_used', '?')} stills"))
    if corners is not None:
        n, found = _num(corners.get("n_frames_decoded")), _num(corners.get("n_found"))
        share = found / n if n > 0 else float("nan")
        ok, warn = THRESHOLDS["board_share"]
        checks.append({"stage": "corners", "status": _grade(share, (ok, warn), high_is_bad=False),
                       "measured": f"board in {int(found)} of {int(n)} frames ({_g(100 * share, 1)} %)",
                       "threshold": f"pass ≥ {100 * ok:.0f} %, warn ≥ {100 * warn:.0f} %"})
    if mocap_repair is not None:
        tot = mocap_repair.get("total") or {}
        n = sum(_num(tot.get(k, 0)) for k in ("measured", "rigid", "interp", "missing"))
        share = (_num(tot.get("rigid", 0)) + _num(tot.get("interp", 0))) / n if n > 0 else float("nan")
        ok, warn = THRESHOLDS["filled_share"]
        checks.append({"stage": "motion capture", "status": _grade(share, (ok, warn)),
                       "measured": f"{_g(100 * share, 2)} % of marker samples filled",
                       "threshold": f"pass ≤ {100 * ok:.0f} %, warn ≤ {100 * warn:.0f} %"})
    if sync is not None:
        checks.append(_sync_check(sync))
    if se3 is not None:
        checks.append(_rms_check("se3 fit", se3, THRESHOLDS["se3_rms_px"], scale, "corner RMS"))
    if seed is not None:
        checks.append({"stage": "seed (the chapter's method)", "status": "info",
                       "measured": "diverged: its numbers are not measurements" if seed.get("diverged")
                       else "converged", "threshold": "compared, not graded"})
    text = None
    se3_cmp = (comparison or {}).get("se3") or {}
    per_dim = se3_cmp.get("per_dim") or {}
    if per_dim:
        checks += _heldout_checks(per_dim, distance_m)
        em = (comparison or {}).get("error_model") or {}
        if em:
            checks.append(_error_model_check(em))
        text = _verdict_text(per_dim, em, se3_cmp.get("n"), distance_m, comparison.get("error_frame", "C"))
    return {"session": session, "text": text, "checks": checks}


def _image_scale(camera):
    """Image diagonal over :data:`REFERENCE_DIAGONAL_PX` (1 when the size is unknown)."""
    w, h = _num((camera or {}).get("width")), _num((camera or {}).get("height"))
    if not (math.isfinite(w) and math.isfinite(h)) or w <= 0 or h <= 0:
        return 1.0
    return math.hypot(w, h) / REFERENCE_DIAGONAL_PX


def _rms_check(stage, result, limits_px, scale, what, where=""):
    """A reprojection RMS (``result['rms_px']``) against ``limits_px`` scaled by the image;
    any of the result's ``warnings`` turns a pass into a warn."""
    ok, warn = (scale * t for t in limits_px)
    rms = _num(result.get("rms_px"))
    status = _grade(rms, (ok, warn))
    n_warn = len(result.get("warnings") or [])
    if status == "pass" and n_warn:
        status = "warn"
    size = f" at {result.get('width')}x{result.get('height')} px" if result.get("width") else ""
    return {"stage": stage, "status": status,
            "measured": f"{what} {_g(rms, 3)} px{where}" + (f"; {n_warn} warning(s)" if n_warn else ""),
            "threshold": f"pass ≤ {_g(ok, 2)} px and no warning, warn ≤ {_g(warn, 2)} px{size}"}


def _sync_check(sync):
    q = _num(sync.get("quality"))
    ok = THRESHOLDS["sync_quality"][0]
    warn = _num((sync.get("details") or {}).get("min_quality"))
    warn = warn if math.isfinite(warn) else THRESHOLDS["sync_quality"][1]
    status = _grade(q, (ok, warn), high_is_bad=False)
    overlap = _num(sync.get("overlap_share"))
    measured = f"quality {_g(q, 2)}, offset {_num(sync.get('dt_offset_s')):.4f} s"
    if math.isfinite(overlap):
        measured += f", {_g(100 * overlap, 1)} % of the video inside the take"
    if status == "pass" and sync.get("warnings"):
        status = "warn"
    return {"stage": "sync", "status": status, "measured": measured,
            "threshold": f"quality: pass ≥ {ok}, warn ≥ {_g(warn, 2)} (sync.min_quality); no warning"}


def _heldout_checks(per_dim, distance_m):
    rms = {d: _num((per_dim.get(d) or {}).get("rmse")) for d, *_ in DIMS}
    trans = math.sqrt(sum(rms[d] ** 2 for d in ("x_m", "y_m", "z_m")))
    rot = math.sqrt(sum(rms[d] ** 2 for d in ("roll_rad", "pitch_rad", "yaw_rad")))
    ok, warn = THRESHOLDS["heldout_trans_share"]
    share = trans / distance_m if distance_m > 0 else float("nan")
    rok, rwarn = THRESHOLDS["heldout_rot_rad"]
    return [
        {"stage": "held-out accuracy: position", "status": _grade(share, (ok, warn)),
         "measured": f"{_g(1e3 * trans, 2)} mm RMS at a median {_g(distance_m, 2)} m "
                     f"({_g(100 * share, 3)} % of the distance)",
         "threshold": f"pass ≤ {100 * ok:.1f} % of the distance ({_g(1e3 * ok * distance_m, 1)} mm), "
                      f"warn ≤ {100 * warn:.0f} % ({_g(1e3 * warn * distance_m, 1)} mm)"},
        {"stage": "held-out accuracy: attitude", "status": _grade(rot, (rok, rwarn)),
         "measured": f"{_g(math.degrees(rot), 3)} deg RMS",
         "threshold": f"pass ≤ {math.degrees(rok):.1f} deg, warn ≤ {math.degrees(rwarn):.1f} deg"},
    ]


def _error_model_check(em):
    nees, inside = _num(em.get("nees_mean")), _num(em.get("inside_95_all"))
    a, b = _band(nees, NEES_PASS, NEES_WARN), _band(inside, INSIDE_95_PASS, INSIDE_95_WARN)
    order = ["pass", "warn", "fail"]
    status = max((a, b), key=lambda s: order.index(s) if s in order else -1)
    return {"stage": "stated uncertainty (error model)", "status": status,
            "measured": f"mean NEES {_g(nees, 2)}, {_g(100 * inside, 1)} % inside the 95 % band",
            "threshold": f"pass: NEES {NEES_PASS[0]}-{NEES_PASS[1]} and {100 * INSIDE_95_PASS[0]:.0f}-"
                         f"{100 * INSIDE_95_PASS[1]:.0f} %; warn: NEES {NEES_WARN[0]:g}-{NEES_WARN[1]:g} "
                         f"and {100 * INSIDE_95_WARN[0]:.0f}-{100 * INSIDE_95_WARN[1]:.0f} %"}


def _verdict_text(per_dim, em, n, distance_m, frame):
    vals = [k * _num((per_dim.get(d) or {}).get("rmse")) for d, _, _, k in DIMS]
    text = (f"Held-out pose error x/y/z {'/'.join(_g(v) for v in vals[:3])} mm, "
            f"roll/pitch/yaw {'/'.join(_g(v) for v in vals[3:])} deg RMS")
    extra = [f"{int(n)} frames" if n else None,
             f"median distance {_g(distance_m, 1)} m" if math.isfinite(distance_m) else None,
             f"camera frame {frame}"]
    text += f" ({', '.join(e for e in extra if e)})"
    if not em:
        return text + "; no error model was scored."
    nees, inside = _num(em.get("nees_mean")), _num(em.get("inside_95_all"))
    state = _band(nees, NEES_PASS, NEES_PASS) == "pass" and _band(inside, INSIDE_95_PASS,
                                                                   INSIDE_95_PASS) == "pass"
    if state:
        how = "is consistent"
    elif nees > NEES_PASS[1] or inside < INSIDE_95_PASS[0]:
        how = "understates the error"
    else:
        how = "overstates the error (conservative)"
    return (f"{text}; the stated per-frame uncertainty {how} "
            f"(mean NEES {_g(nees, 1)}, 6 if right; {_g(100 * inside, 1)} % inside the 95 % band).")


def flight_verdict(flight, stats):
    """The verdict of one flight from its ``stats.yaml``.

    Parameters
    ----------
    flight : str
        Flight name.
    stats : dict
        ``results/flights/{flight}/stats.yaml`` (SI: m, rad, s).

    Returns
    -------
    dict
        ``session`` (``flight {flight}``), ``text`` (APE and RPE, per-axis RMSE, the share the
        reference cannot resolve, the clock), ``checks`` (the clock's quality).
    """
    ape_t, ape_r = stats.get("ape_trans") or {}, stats.get("ape_rot") or {}
    rpe_t, rpe_r = stats.get("rpe_trans") or {}, stats.get("rpe_rot") or {}
    axes = stats.get("axes") or {}
    vals = []
    for d, _, _, k in DIMS:
        vals.append(k * _num((axes.get(d) or {}).get("rmse")))
    unresolved = [_num((axes.get(a) or {}).get("unresolved_fraction")) for a in axes]
    clock = stats.get("clock") or {}
    text = (f"On-board pose error against the camera reference: APE "
            f"{_g(1e3 * _num(ape_t.get('rmse')), 1)} mm, "
            f"{_g(math.degrees(_num(ape_r.get('rmse'))), 2)} deg RMSE; RPE "
            f"{_g(1e3 * _num(rpe_t.get('rmse')), 1)} mm, {_g(math.degrees(_num(rpe_r.get('rmse'))), 2)} deg; "
            f"per axis x/y/z {'/'.join(_g(v, 1) for v in vals[:3])} mm, roll/pitch/yaw "
            f"{'/'.join(_g(v) for v in vals[3:])} deg RMSE ({stats.get('n_pairs', '?')} pairs).")
    finite = [u for u in unresolved if math.isfinite(u)]
    if finite:
        text += (f" The reference resolves it on {_g(100 * (1 - max(finite)), 0)}-"
                 f"{_g(100 * (1 - min(finite)), 0)} % of the samples per axis;")
    text += (f" log clock offset {_num(clock.get('dt_offset_s')):.4f} s, skew "
             f"{_g(1e6 * _num(clock.get('skew')), 0)} ppm.")
    q = _num(clock.get("quality"))
    ok, warn = THRESHOLDS["sync_quality"]
    checks = [{"stage": "clock", "status": _grade(q, (ok, warn), high_is_bad=False),
               "measured": f"quality {_g(q, 2)}", "threshold": f"pass ≥ {ok}, warn ≥ {warn}"}]
    return {"session": f"flight {flight}", "text": text, "checks": checks}


def _rst_cell(text):
    return str(text).replace("\n", " ").replace("*", "\\*").replace("|", "\\|") or " "


#: Status as shown in the report.
STATUS_TEXT = {"pass": "✔ pass", "warn": "⚠ warn", "fail": "✘ FAIL", "info": "info", "n/a": "n/a"}


def verdict_rst(verdict, figure=None, figure_alt="figure"):
    """A session's verdict, stage checks and figure as reStructuredText, for the landing page.

    Parameters
    ----------
    verdict : dict
        :func:`session_verdict` or :func:`flight_verdict`.
    figure : str, optional
        The figure's URI: a ``data:`` URI (:func:`cvsflow.io.files.image_data_uri`) keeps the
        report one self-contained file.
    figure_alt : str
        The figure's text alternative.

    Returns
    -------
    str
        The verdict paragraph, a list-table of the stage checks (stage, status, measured,
        threshold) and the figure, ending in a blank line.
    """
    out = []
    if verdict.get("text"):
        out += [f"**Verdict.** {verdict['text']}", ""]
    if verdict.get("checks"):
        out += [".. list-table:: Stage checks", "   :header-rows: 1", "   :widths: 22 10 38 30", "",
                "   * - stage\n     - status\n     - measured\n     - threshold"]
        for c in verdict["checks"]:
            cells = [c["stage"], STATUS_TEXT.get(c["status"], c["status"]), c["measured"], c["threshold"]]
            out.append("   * - " + "\n     - ".join(_rst_cell(x) for x in cells))
        out.append("")
    if figure:
        # docutils refuses lines over 10 000 characters; a directive's argument may go on over
        # indented lines, and a URI's whitespace is dropped
        lines = [figure[i:i + 76] for i in range(0, len(figure), 76)]
        out += [f".. image:: {lines[0]}", *(f"   {x}" for x in lines[1:]),
                f"   :alt: {figure_alt}", "   :width: 100%", ""]
    return "\n".join(out) + "\n"
