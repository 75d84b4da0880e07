"""The headline numbers of every session, for the report's landing page and headline.csv.

One row per quantity, in report units (px, mm, deg, s, %), with its standard error where the
source gives one, the truth of a rendered session, and the file and key it was read from, so
a reader can check every number. Inputs are the stage outputs as loaded dicts (SI units):
``camera.yaml``, ``corners_summary.yaml``, ``mocap_import.yaml`` (its warnings only),
``mocap_repair.yaml``, ``sync.yaml``, the se3 and
seed ``result.yaml``, ``comparison.yaml``, ``truth.yaml`` and a flight's ``stats.yaml``; any
of them may be missing (a session that only calibrates, a config without the seed method).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from cvsflow.geometry import euler_jacobian, pose6_from_T
from cvsflow.metrics import ERROR_DIMS, REPORT_UNITS

#: Columns of headline.csv.
COLUMNS = ["session", "group", "quantity", "value", "std", "truth", "unit", "text", "source"]
#: Error dimension, display name, unit and SI-to-display factor (:data:`cvsflow.metrics.REPORT_UNITS`).
DIMS = tuple((d, *REPORT_UNITS[d]) for d in ERROR_DIMS)
NAN = float("nan")


def _num(v):
    try:
        v = float(v)
    except (TypeError, ValueError):
        return NAN
    return v


def _fmt(v, digits=4):
    """A number with ``digits`` significant digits, no exponent for report-sized values."""
    v = _num(v)
    if not math.isfinite(v):
        return "n/a"
    if v == 0:
        return "0"
    mag = math.floor(math.log10(abs(v)))
    decimals = max(0, digits - 1 - mag)
    return f"{v:.{decimals}f}"


class _Rows:
    """Collects the rows of one session."""

    def __init__(self, session):
        self.session = session
        self.rows = []

    def add(self, group, quantity, value, unit, source, std=NAN, truth=NAN, text=None, digits=4):
        value, std, truth = _num(value), _num(std), _num(truth)
        if text is None:
            text = _fmt(value, digits)
            if math.isfinite(std):
                text += f" ± {_fmt(std, 2)}"
        self.rows.append({"session": self.session, "group": group, "quantity": quantity,
                          "value": value, "std": std, "truth": truth, "unit": unit, "text": text,
                          "source": source})

    def note(self, group, quantity, text, source):
        self.rows.append({"session": self.session, "group": group, "quantity": quantity,
                          "value": NAN, "std": NAN, "truth": NAN, "unit": "", "text": text,
                          "source": source})


def _pose6(T):
    return pose6_from_T(np.asarray(T, dtype=float))


def _euler_std(T, std, correlation, name, corr_prefix=""):
    """Standard deviations (rad) of a fitted mounting's roll, pitch, yaw.

    The fit's rotation standard errors are of a small rotation about the mounting's own axes
    (``std[<name>_r{x,y,z}_rad]``), not of the Euler angles: with roll near -90 deg the two
    sets of axes differ, and quoting one for the other misstates an angle's uncertainty
    several times over. Their covariance (with ``correlation``, a result's
    ``correlation_total``, where it has ``<corr_prefix><name>_r*_rad``) goes through
    :func:`cvsflow.geometry.euler_jacobian`; NaN where a standard error is missing.
    """
    keys = [f"{name}_r{a}_rad" for a in "xyz"]
    sd = np.array([_num((std or {}).get(k)) for k in keys])
    corr = np.eye(3)
    names = list((correlation or {}).get("names") or [])
    wanted = [corr_prefix + k for k in keys]
    if all(k in names for k in wanted):
        idx = [names.index(k) for k in wanted]
        corr = np.asarray(correlation["matrix"], float)[np.ix_(idx, idx)]
    J = euler_jacobian(np.asarray(T, float)[:3, :3], side="right")
    return np.sqrt(np.diag(J @ (np.outer(sd, sd) * corr) @ J.T))


def session_headline(session, *, camera=None, camera_from=None, sync=None, se3=None, seed=None,
                     comparison=None, truth=None, corners=None, mocap_repair=None, mocap_import=None):
    """The headline rows of one session (see the module docstring for the inputs).

    Parameters
    ----------
    session : str
        Session name, used in the file names of ``source``.
    camera_from : str, optional
        The session whose camera.yaml this one uses (its ``camera:`` key); default ``session``.

    Returns
    -------
    list of dict
        Rows with :data:`COLUMNS`; ``value``, ``std``, ``truth`` in ``unit``; ``text`` the
        value as shown (a diverged seed run shows its reason, not its numbers).
    """
    r = _Rows(session)
    base = f"results/{session}"
    warnings = []
    K_true = np.asarray(truth["camera"]["K"], float) if truth and "camera" in truth else None

    if camera is not None:
        src = f"results/{camera_from or session}/camera.yaml"
        K = np.asarray(camera["K"], float)
        std = camera.get("std", {}) or {}
        for name, (i, j) in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2))):
            r.add("calibration", name, K[i, j], "px", f"{src}: K", std=std.get(name, NAN),
                  truth=K_true[i, j] if K_true is not None else NAN, digits=5)
        r.add("calibration", "reprojection RMS", camera.get("rms_px"), "px", f"{src}: rms_px")
        r.add("calibration", "stills used", camera.get("n_used"), "", f"{src}: n_used",
              text=str(camera.get("n_used", "n/a")))
        inf = (camera.get("projection_uncertainty") or {}).get("at_infinity")
        if inf:
            for name, key in (("centre", "centre"), ("worst where the stills were", "worst_covered"),
                              ("worst over the image", "worst_image")):
                r.add("calibration", f"projection uncertainty at infinity, {name}", inf[key], "px",
                      f"{src}: projection_uncertainty.at_infinity.{key}")
        summary = (camera.get("quality") or {}).get("summary")
        if summary:
            r.note("calibration", "verdicts", summary, f"{src}: quality.verdicts")
        warnings += [("calibration", w, f"{src}: warnings") for w in camera.get("warnings") or []]

    if corners is not None:
        src = f"{base}/corners_summary.yaml"
        n, found = corners.get("n_frames_decoded"), corners.get("n_found")
        r.add("data", "video frames with a board", 100 * _num(found) / max(_num(n), 1), "%",
              f"{src}: n_found, n_frames_decoded", text=f"{found} of {n}")
        r.add("data", "video frames dropped (timestamp gaps)", corners.get("n_dropped"), "",
              f"{src}: n_dropped", text=str(corners.get("n_dropped", "n/a")))
        warnings += [("corners", w, f"{src}: warnings") for w in corners.get("warnings") or []]
    if mocap_import is not None:  # a take cut short: both counts
        warnings += [("vicon", w, f"{base}/mocap_import.yaml: warnings")
                     for w in mocap_import.get("warnings") or []]
    if mocap_repair is not None:
        src = f"{base}/mocap_repair.yaml"
        tot = mocap_repair.get("total") or {}
        n = sum(_num(tot.get(k, 0)) for k in ("measured", "rigid", "interp", "missing"))
        filled = _num(tot.get("rigid", 0)) + _num(tot.get("interp", 0))
        if n > 0:
            r.add("data", "Vicon marker samples filled", 100 * filled / n, "%",
                  f"{src}: total", digits=3,
                  text=f"{_fmt(100 * filled / n, 3)} (rigid {tot.get('rigid', 0)}, interpolated "
                       f"{tot.get('interp', 0)}, left missing {tot.get('missing', 0)})")
        warnings += [("vicon", w, f"{src}: warnings") for w in mocap_repair.get("warnings") or []]

    if sync is not None:
        src = f"{base}/sync.yaml"
        sigma = (sync.get("details") or {}).get("dt_sigma_s", NAN)
        r.add("sync", f"offset t_vicon - t_video ({sync.get('method', '?')})",
              sync.get("dt_offset_s"), "s", f"{src}: dt_offset_s", std=sigma,
              truth=truth.get("dt_offset_s", NAN) if truth else NAN, digits=6)
        r.add("sync", "quality", sync.get("quality"), "[-]", f"{src}: quality",
              text=f"{_fmt(sync.get('quality'), 3)} (minimum "
                   f"{_fmt((sync.get('details') or {}).get('min_quality'), 2)})")
        warnings += [("sync", w, f"{src}: warnings") for w in sync.get("warnings") or []]

    if se3 is not None:
        src = f"{base}/se3/calib/result.yaml"
        std = se3.get("std_errors", {})
        for name in ("fx", "fy"):
            r.add("se3", name, se3.get(f"{name}_px"), "px", f"{src}: {name}_px, std_errors.{name}",
                  std=std.get(name, NAN), digits=5,
                  truth=K_true[(0, 0) if name == "fx" else (1, 1)] if K_true is not None else NAN)
        r.add("se3", "time offset dt", se3.get("dt_offset_s"), "s",
              f"{src}: dt_offset_s, std_errors.dt_offset_s", std=std.get("dt_offset_s", NAN),
              truth=truth.get("dt_offset_s", NAN) if truth else NAN, digits=6)
        for T in ("T_Cm_C", "T_Bm_B"):
            if T in se3:
                _pose_rows(r, "se3", T, se3[T], (truth or {}).get(T), std, f"{T}_", f"{src}: {T}",
                           se3.get("correlation_total"))
        r.add("se3", "corner reprojection RMS", se3.get("rms_px"), "px", f"{src}: rms_px")
        warnings += [("se3", w, f"{src}: warnings") for w in se3.get("warnings") or []]

    if seed is not None:
        src = f"{base}/seed/calib/result.yaml"
        if seed.get("diverged"):
            r.note("seed", "status", f"DIVERGED: {seed.get('diverged_reason', '')}",
                   f"{src}: diverged, diverged_reason")
            warnings.append(("seed", "the seed method diverged; its numbers are not measurements",
                             f"{src}: diverged"))
        else:
            for name in ("fx", "fy"):
                r.add("seed", name, seed.get(f"{name}_px"), "px", f"{src}: {name}_px", digits=5)

    if comparison is not None:
        src = f"{base}/comparison.yaml"
        se3_cmp = comparison.get("se3") or {}
        frame = comparison.get("error_frame", "C")
        for d, name, unit, k in DIMS:
            s = (se3_cmp.get("per_dim") or {}).get(d)
            if s is not None:
                r.add(f"held-out RMS (se3, frame {frame})", name, k * _num(s.get("rmse")), unit,
                      f"{src}: se3.per_dim.{d}.rmse")
        seed_cmp = comparison.get("seed") or {}
        if seed_cmp.get("diverged"):
            r.note(f"held-out RMS (seed, frame {frame})", "all axes",
                   "not shown: the seed run diverged (comparison.yaml lists its numbers under "
                   "seed.statistics_not_measurements)", f"{src}: seed.diverged")
        elif seed_cmp.get("per_dim"):
            for d, name, unit, k in DIMS:
                s = seed_cmp["per_dim"].get(d)
                if s is not None:
                    r.add(f"held-out RMS (seed, frame {frame})", name, k * _num(s.get("rmse")),
                          unit, f"{src}: seed.per_dim.{d}.rmse")
        em = comparison.get("error_model") or {}
        if em:
            r.add("error model (se3, held-out)", "inside the 68 % band", 100 * _num(em.get("inside_68_all")),
                  "%", f"{src}: error_model.inside_68_all", digits=3)
            r.add("error model (se3, held-out)", "inside the 95 % band", 100 * _num(em.get("inside_95_all")),
                  "%", f"{src}: error_model.inside_95_all", digits=3)
            r.add("error model (se3, held-out)", "mean NEES (6 if consistent)", em.get("nees_mean"),
                  "[-]", f"{src}: error_model.nees_mean", digits=3)
    for group, text, source in warnings:
        r.note("warnings", group, text, source)
    if not warnings:
        r.note("warnings", "all stages", "none", "camera.yaml, sync.yaml, result.yaml: warnings")
    return r.rows


def _pose_rows(r, group, name, T, T_true, std, std_prefix, src, correlation=None, corr_prefix=""):
    """Rows of a mounting: x, y, z (mm) and roll, pitch, yaw (deg), with standard errors (the
    angles' through :func:`_euler_std`, with ``correlation`` names ``<corr_prefix><name>_*``)."""
    p = _pose6(T)
    pt = _pose6(T_true) if T_true is not None else np.full(6, NAN)
    for k, a in enumerate("xyz"):
        r.add(group, f"{name} {a}", 1e3 * p[k], "mm", f"{src}, std_errors.{std_prefix}{a}_m",
              std=1e3 * _num(std.get(f"{std_prefix}{a}_m")), truth=1e3 * pt[k])
    sd_euler = _euler_std(T, std, correlation, name, corr_prefix)
    for k, label in enumerate(("roll", "pitch", "yaw")):
        r.add(group, f"{name} {label}", np.degrees(p[3 + k]), "deg",
              f"{src}, std_errors.{std_prefix}r*_rad, correlation_total", std=np.degrees(sd_euler[k]),
              truth=np.degrees(pt[3 + k]))


def _std_si(rec_std, name):
    """A pose_fit record's std of one transform (deg, mm) as se3's std_errors keys (rad, m)."""
    sd = (rec_std or {}).get(name) or {}
    out = {f"{name}_r{a}_rad": math.radians(_num(sd.get(f"r{a}_deg"))) for a in "xyz"}
    out.update({f"{name}_{a}_m": 1e-3 * _num(sd.get(f"{a}_mm")) for a in "xyz"})
    return out


def pose_fit_headline(session, result, heldout=None, truth=None):
    """The headline rows of a camera-pose session's pose-level fit and its held-out evaluation.

    Parameters
    ----------
    session : str
    result : dict
        results/<session>/pose_fit/result.yaml (``dt_offset_s``, ``dt_offset_std_s``,
        ``T_Cm_C``, ``T_Bm_B``, ``std`` in deg and mm, ``observability``, ``split_half``,
        ``std_inflated_by``).
    heldout : dict, optional
        results/<session>/heldout/pose_fit.yaml (``per_dim``, ``error_model``, ``error_frame``).
    truth : dict, optional
        ``dt_offset_s``, ``T_Cm_C``, ``T_Bm_B`` of a simulated session.

    Returns
    -------
    list of dict
        Rows with :data:`COLUMNS`, in report units (s, mm, deg, %); the rotations' standard
        errors as Euler-angle errors (:func:`_euler_std`, without the correlations between
        the three).
    """
    r = _Rows(session)
    src = f"results/{session}/pose_fit/result.yaml"
    truth = truth or {}
    if result.get("dt_offset_s") is None:
        reason = ((result.get("observability") or {}).get("dt") or {}).get("reason") or "unknown"
        r.note("pose fit", "time offset dt", f"not determined ({reason}); held at "
               f"{_fmt(result.get('dt_used_s'), 4)} s", f"{src}: dt_offset_s, observability.dt")
    else:
        r.add("pose fit", "time offset dt", result["dt_offset_s"], "s",
              f"{src}: dt_offset_s, dt_offset_std_s", std=result.get("dt_offset_std_s"),
              truth=truth.get("dt_offset_s", NAN), digits=6)
    for name in ("T_Cm_C", "T_Bm_B"):
        T = result.get(name)
        if T is None:
            reason = ((result.get("observability") or {}).get("hand_eye") or {}).get("reason")
            r.note("pose fit", name, f"not determined ({reason})", f"{src}: observability.hand_eye")
            continue
        std = _std_si(result.get("std"), name)
        p = _pose6(T)
        pt = _pose6(truth[name]) if name in truth else np.full(6, NAN)
        for k, a in enumerate("xyz"):
            r.add("pose fit", f"{name} {a}", 1e3 * p[k], "mm", f"{src}: {name}, std.{name}.{a}_mm",
                  std=1e3 * std[f"{name}_{a}_m"], truth=1e3 * pt[k])
        sd = _euler_std(T, std, None, name)
        for k, label in enumerate(("roll", "pitch", "yaw")):
            r.add("pose fit", f"{name} {label}", np.degrees(p[3 + k]), "deg",
                  f"{src}: {name}, std.{name}.r*_deg", std=np.degrees(sd[k]), truth=np.degrees(pt[3 + k]))
    split = result.get("split_half")
    if split:
        verdict = "agrees" if split.get("agree") else "disagrees"
        text = (f"{verdict}: mean z² {_fmt(split.get('mean_z2'), 3)} "
                f"(limit {_fmt(split.get('mean_z2_limit'), 3)}), "
                f"{split.get('n_agree')} of {split.get('n')} within 2 std; errors widened "
                f"×{_fmt(result.get('std_inflated_by', 1.0), 3)}")
        r.note("pose fit", "split-half check", text, f"{src}: split_half, std_inflated_by")
    if heldout:
        hsrc = f"results/{session}/heldout/pose_fit.yaml"
        group = f"held-out RMS (pose fit, frame {heldout.get('error_frame', 'C')})"
        for d, name, unit, k in DIMS:
            s = (heldout.get("per_dim") or {}).get(d)
            if s is not None:
                r.add(group, name, k * _num(s.get("rmse")), unit, f"{hsrc}: per_dim.{d}.rmse")
        em = heldout.get("error_model") or {}
        for band in ("68", "95"):
            r.add("stated uncertainty (pose fit, held-out)", f"inside the {band} % band",
                  100 * _num(em.get(f"inside_{band}_all")), "%", f"{hsrc}: error_model.inside_{band}_all",
                  digits=3)
        r.add("stated uncertainty (pose fit, held-out)", "mean NEES (6 if consistent)", em.get("nees_mean"),
              "[-]", f"{hsrc}: error_model.nees_mean", digits=3)
        judged = em.get("judgement")
        if judged:
            text = judged["verdict"] + (f" ({'; '.join(judged['reasons'])})" if judged.get("reasons") else "")
            r.note("stated uncertainty (pose fit, held-out)", "against its spread with errors persisting "
                   "in time", text, f"{hsrc}: error_model.judgement")
    return r.rows


def rig_headline(rig, result, heldout=None, truth=None):
    """The headline rows of a rig session: every camera's fit, the board's mounting, held-out scores.

    Parameters
    ----------
    rig : str
        The rig session's name (results/<rig>/rig/).
    result : dict
        results/<rig>/rig/result.yaml (``cameras`` named, with ``std_errors``; ``T_Bm_B``,
        ``T_Bm_B_std_errors``, ``n_rig_frames_by_cameras``, ``warnings``).
    heldout : dict, optional
        results/<rig>/rig/heldout.yaml (``scores``).
    truth : dict, optional
        data/<rig>/truth.yaml of a rendered rig (``cameras`` by ``name``, ``T_Bm_B``).

    Returns
    -------
    list of dict
        Rows with :data:`COLUMNS`, in report units (px, s, mm, deg).
    """
    r = _Rows(rig)
    src = f"results/{rig}/rig/result.yaml"
    true_cams = {c["name"]: c for c in (truth or {}).get("cameras", [])}
    for i, c in enumerate(result.get("cameras", [])):
        name = c.get("name", f"cam{i}")
        t = true_cams.get(name)
        std = c.get("std_errors") or {}
        group = f"se3 rig: {name}"
        K = np.asarray(c["K"], float)
        K_true = np.asarray(t["camera"]["K"], float) if t else None
        for n, (a, b) in (("fx", (0, 0)), ("fy", (1, 1))):
            r.add(group, n, K[a, b], "px", f"{src}: cameras[{i}].K, std_errors.{n}", std=std.get(n, NAN),
                  truth=K_true[a, b] if K_true is not None else NAN, digits=5)
        r.add(group, "time offset dt", c.get("dt_offset_s"), "s",
              f"{src}: cameras[{i}].dt_offset_s, std_errors.dt_offset_s", std=std.get("dt_offset_s", NAN),
              truth=t["dt_offset_s"] if t else NAN, digits=6)
        _pose_rows(r, group, "T_Cm_C", c["T_Cm_C"], t["T_Cm_C"] if t else None, std, "T_Cm_C_",
                   f"{src}: cameras[{i}].T_Cm_C", result.get("correlation_total"), f"cam{i}_")
        r.add(group, "corner reprojection RMS", c.get("rms_px"), "px", f"{src}: cameras[{i}].rms_px")
    if "T_Bm_B" in result:
        _pose_rows(r, "se3 rig: board", "T_Bm_B", result["T_Bm_B"], (truth or {}).get("T_Bm_B"),
                   result.get("T_Bm_B_std_errors") or {}, "T_Bm_B_", f"{src}: T_Bm_B",
                   result.get("correlation_total"))
    by = result.get("n_rig_frames_by_cameras") or {}
    r.note("se3 rig: board", "rig frames by number of cameras",
           ", ".join(f"{k}: {v}" for k, v in sorted(by.items(), key=lambda kv: int(kv[0]))) or "none",
           f"{src}: n_rig_frames_by_cameras")
    scores = (heldout or {}).get("scores") or {}
    hsrc = f"results/{rig}/rig/heldout.yaml: scores"
    for n, s in sorted((scores.get("by_cameras") or {}).items(), key=lambda kv: int(kv[0])):
        group = f"held-out RMS (se3 rig, fused poses seen by {n})"
        r.add(group, "distance", 1e3 * _num(s.get("rms_dist_m")), "mm", f"{hsrc}.by_cameras.{n}.rms_dist_m")
        r.add(group, "angle", np.degrees(_num(s.get("rms_angle_rad"))), "deg",
              f"{hsrc}.by_cameras.{n}.rms_angle_rad")
    for w in result.get("warnings") or []:
        r.note("warnings", "se3 rig", w, f"{src}: warnings")
    return r.rows


def flight_headline(flight, stats):
    """The headline rows of one flight from its ``stats.yaml`` (APE, clock).

    Parameters
    ----------
    flight : str
        Flight name; the rows' session is ``flight {flight}``.
    stats : dict
        The loaded ``results/flights/{flight}/stats.yaml`` (SI: m, rad, s); missing keys give
        NaN values (shown as n/a).

    Returns
    -------
    list of dict
        Rows with :data:`COLUMNS`: APE translation RMSE (mm), APE rotation RMSE (deg), clock
        offset (s) and quality, number of pairs.
    """
    r = _Rows(f"flight {flight}")
    src = f"results/flights/{flight}/stats.yaml"
    ape_t, ape_r = stats.get("ape_trans") or {}, stats.get("ape_rot") or {}
    r.add("on-board vs camera reference", "APE translation RMSE", 1e3 * _num(ape_t.get("rmse")),
          "mm", f"{src}: ape_trans.rmse")
    r.add("on-board vs camera reference", "APE rotation RMSE", np.degrees(_num(ape_r.get("rmse"))),
          "deg", f"{src}: ape_rot.rmse")
    clock = stats.get("clock") or {}
    r.add("clock", "offset", clock.get("dt_offset_s"), "s", f"{src}: clock.dt_offset_s", digits=6)
    r.add("clock", "quality", clock.get("quality"), "[-]", f"{src}: clock.quality", digits=3)
    r.add("on-board vs camera reference", "pairs", stats.get("n_pairs"), "", f"{src}: n_pairs",
          text=str(stats.get("n_pairs", "n/a")))
    return r.rows


def headline_table(rows):
    """The rows as a DataFrame with :data:`COLUMNS` (headline.csv).

    Parameters
    ----------
    rows : list of dict
        Rows of :func:`session_headline` / :func:`flight_headline`.

    Returns
    -------
    DataFrame
        One row per quantity, columns :data:`COLUMNS` in that order.
    """
    return pd.DataFrame(rows, columns=COLUMNS)


def _rst_cell(text):
    # A cell is one line of a list-table; `|` and `*` would start RST markup.
    return str(text).replace("\n", " ").replace("*", "\\*").replace("|", "\\|") or " "


def headline_rst(rows, preambles=None):
    """The rows as reStructuredText: one section and one list-table per session.

    Columns: quantity, value (± standard error), truth (rendered sessions only), unit,
    file: key. The text is meant to be inlined into the report's landing page.

    Parameters
    ----------
    rows : list of dict
        Rows of :func:`session_headline` / :func:`flight_headline`, in display order.
    preambles : dict, optional
        Session (as in the rows) -> reStructuredText put between the section's title and its
        table (the verdict, stage checks and figure of :func:`cvsflow.evaluate.verdict_rst`);
        the table then gets the subtitle "Detailed table".

    Returns
    -------
    str
        The reStructuredText, ending in a newline; the truth column only for sessions with a
        finite truth somewhere.
    """
    table = headline_table(rows)
    out = []
    for session, block in table.groupby("session", sort=False):
        title = f"Session {session}" if not session.startswith("flight ") else session.capitalize()
        out += [title, "-" * len(title), ""]
        if (preambles or {}).get(session):
            out += [preambles[session], "Detailed table", "~" * len("Detailed table"), ""]
        has_truth = bool(np.isfinite(block["truth"].to_numpy(float)).any())
        header = ["quantity", "value ± std. error"] + (["truth"] if has_truth else [])
        header += ["unit", "file: key"]
        widths = "30 22 " + ("10 " if has_truth else "") + "8 30"
        out += [".. list-table::", "   :header-rows: 1", f"   :widths: {widths}", ""]
        out.append("   * - " + "\n     - ".join(header))
        for group, g in block.groupby("group", sort=False):
            for _, row in g.iterrows():
                cells = [f"{group}: {row['quantity']}", row["text"]]
                if has_truth:
                    cells.append(_fmt(row["truth"], 5) if math.isfinite(row["truth"]) else "")
                cells += [row["unit"], f"``{row['source']}``"]
                out.append("   * - " + "\n     - ".join(_rst_cell(c) if not str(c).startswith("``")
                                                      else c for c in cells))
        out.append("")
    return "\n".join(out) + "\n"
