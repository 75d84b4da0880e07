"""Motion-capture processing: marker gap repair, low-pass filter, rigid bodies, 30 Hz tables.

The chapter's "Data Processing" (seed section 1.3) made rigorous. Inputs are the wide marker
tables of :mod:`cvsflow.io.vicon` (``frame``, ``t_s``, ``{marker}_{x,y,z}_m`` in the Vicon
world W, NaN where unseen, ``attrs["rate_hz"]``); outputs follow ``docs/contracts.md``
(``markers_filled``, ``bodies``, ``bodies_30hz``).

A *body spec* describes one rigid body: ``{"names": [marker names], "layout_m": (M, 3) or
None}``; ``layout_m`` is where each marker sits in the body's own frame (``Cm`` for the camera
body, ``Bm`` for the board body). A body spec without a layout gets one learned from a still
period (:func:`learn_layout`).
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
from scipy.signal import butter, filtfilt
from scipy.spatial.transform import Rotation

from cvsflow.errors import InputError, MocapError
from cvsflow.geometry import (
    block_mean_quats,
    euler_from_R,
    fit_rigid,
    interpolate_T,
    make_T,
    quat_from_R,
    transform_points,
)

log = logging.getLogger(__name__)

AXES = ("x", "y", "z")
BODY_COLUMNS = [
    "frame",
    "t_s",
    "body",
    "valid",
    "x_m",
    "y_m",
    "z_m",
    "qx",
    "qy",
    "qz",
    "qw",
    "roll_rad",
    "pitch_rad",
    "yaw_rad",
    "fit_rms_m",
    "n_markers",
    "n_filled",
]


def _cols(name):
    return [f"{name}_{a}_m" for a in AXES]


def _rate_hz(markers, where="marker table"):
    rate = markers.attrs.get("rate_hz")
    if rate is None:
        t = markers["t_s"].to_numpy(float)
        if len(t) < 2:
            raise InputError(f"{where}: no rate_hz attribute and fewer than 2 samples")
        rate = 1.0 / float(np.median(np.diff(t)))
    return float(rate)


def _xyz(markers, names, where="marker table"):
    """Stack marker coordinates into shape (N, M, 3), metres."""
    missing = [n for n in names if _cols(n)[0] not in markers.columns]
    if missing:
        raise InputError(f"{where}: marker(s) {missing} not in the marker table")
    return np.stack([markers[_cols(n)].to_numpy(float) for n in names], axis=1)


def _runs(mask):
    """Start (inclusive) and end (exclusive) indices of the True runs of a 1-D bool mask."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(np.int8))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


# The rigid fit (fit_rigid), the quaternion block mean and pose interpolation are
# cvsflow.geometry's; fit_rigid stays importable from here.


# --------------------------------------------------------------------------- layouts


def learn_layout(markers, names, still_s=1.0, still_tol_m=0.001):
    """Learn a body's marker layout from the first still period of the take.

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (metres, W).
    names : sequence of str
        The body's markers; at least three.
    still_s : float
        Length of the still window, seconds.
    still_tol_m : float
        A window is still when every coordinate of every marker has a standard deviation
        below this, metres.

    Returns
    -------
    layout_m : ndarray, shape (M, 3)
        Mean marker positions over the first still window, in a body frame with its origin at
        the first marker, x towards the second, z normal to the plane of the first three
        (right-handed, z along x cross (p3 - p1)), metres.

    Raises
    ------
    MocapError
        Fewer than three markers, or no still window with every marker visible.
    """
    names = list(names)
    if len(names) < 3:
        raise MocapError(f"learn_layout: need at least 3 markers, got {names}")
    rate = _rate_hz(markers)
    n_win = max(2, int(round(still_s * rate)))
    xyz = _xyz(markers, names).reshape(len(markers), -1)
    frame = pd.DataFrame(xyz)
    std = frame.rolling(n_win, min_periods=n_win).std().to_numpy()
    seen = frame.notna().all(axis=1).rolling(n_win, min_periods=n_win).sum().to_numpy()
    still = (np.nan_to_num(std, nan=np.inf) < still_tol_m).all(axis=1) & (seen == n_win)
    if not still.any():
        raise MocapError(
            f"learn_layout: no still window of {still_s} s (every coordinate of {names} with "
            f"std < {still_tol_m * 1000:g} mm and all markers seen) in {len(markers)} frames; "
            "give layout_m in the config"
        )
    end = int(np.flatnonzero(still)[0]) + 1
    mean = xyz[end - n_win : end].mean(axis=0).reshape(len(names), 3)
    p1, p2, p3 = mean[0], mean[1], mean[2]
    x = (p2 - p1) / np.linalg.norm(p2 - p1)
    z = np.cross(x, p3 - p1)
    if np.linalg.norm(z) < 1e-6:
        raise MocapError(f"learn_layout: the first three markers of {names} are collinear")
    z /= np.linalg.norm(z)
    y = np.cross(z, x)
    R_W_body = np.stack([x, y, z], axis=1)
    return (mean - p1) @ R_W_body


def refine_layout(markers, names, layout_m, n_iter=3, max_samples=5000):
    """The body's marker layout as the markers show it, in the frame ``layout_m`` defines.

    A layout from a drawing (or measured by hand) is off by millimetres; fitted to all markers
    the error averages out, but when a marker drops out the remaining ones pull the fitted pose
    by tens of mrad (the demo's static camera jumped 24-38 mrad at every rigid-filled sample).
    The refined layout is the mean of the measured markers in the body frame (a Procrustes mean),
    re-expressed in the frame that a fit of ``layout_m`` gives, so a fully seen body keeps its
    pose and a partly seen one no longer jumps.

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (metres, W); samples with a ``{marker}_filled`` flag set are left out.
    names : sequence of str
        The body's markers, in the order of ``layout_m``.
    layout_m : ndarray, shape (M, 3)
        The given layout, metres.
    n_iter : int
        Fit / average rounds (the mean converges in two or three).
    max_samples : int
        At most this many evenly spaced fully seen samples are used.

    Returns
    -------
    layout_m : ndarray, shape (M, 3)
        The refined layout, metres; ``layout_m`` itself when fewer than 10 samples see every
        marker, or when a marker would move by more than max(2 cm, 10 % of the layout's RMS
        radius): that is a wrong layout or wrong units, which the fit-RMS check must see.
    """
    names = list(names)
    layout_m = np.asarray(layout_m, dtype=float)
    Q = _xyz(markers, names)
    seen = np.isfinite(Q).all(axis=(1, 2))
    flags = [f"{n}_filled" for n in names]
    if all(f in markers.columns for f in flags):
        seen &= ~markers[flags].to_numpy(bool).any(axis=1)
    idx = np.flatnonzero(seen)
    if len(idx) < 10:
        return layout_m
    Q = Q[idx[np.linspace(0, len(idx) - 1, min(len(idx), max_samples)).astype(int)]]
    shape = layout_m
    for _ in range(n_iter):
        T, _, _ = fit_rigid(shape, Q)
        ok = np.isfinite(T).all(axis=(1, 2))
        # markers into the body frame: R^T (q - t)
        P = np.einsum("nji,nmj->nmi", T[ok, :3, :3], Q[ok] - T[ok, None, :3, 3])
        shape = P.mean(axis=0)
    # the frame of layout_m: the rigid transform that best maps the mean shape onto it
    T_given_mean, _, _ = fit_rigid(shape, layout_m[None])
    refined = transform_points(T_given_mean[0], shape)
    radius_m = np.sqrt(np.mean(np.sum((layout_m - layout_m.mean(axis=0)) ** 2, axis=1)))
    moved_m = np.linalg.norm(refined - layout_m, axis=1).max()
    if not np.isfinite(moved_m) or moved_m > max(0.02, 0.1 * radius_m):
        log.warning("layout of %s not refined: the markers would move it by %.1f mm (layout "
                    "radius %.1f mm); check layout_m and the units", names, 1e3 * moved_m, 1e3 * radius_m)
        return layout_m
    return refined


def resolve_layouts(markers, body_specs, still_s=1.0, still_tol_m=0.001, refine=False):
    """Body specs with every ``layout_m`` as an (M, 3) array, learning the missing ones.

    ``refine`` replaces each layout by :func:`refine_layout` (the layout the markers show).

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (``{marker}_x_m ..`` in W, metres; ``attrs["rate_hz"]``).
    body_specs : dict
        Body name -> ``{"names": [...], "layout_m": (M, 3) or None}`` (body frame, metres).
    still_s, still_tol_m : float
        Still window to learn a missing layout from (s) and its tolerance (m)
        (:func:`learn_layout`).
    refine : bool
        Replace every layout by the one the markers show (:func:`refine_layout`).

    Returns
    -------
    specs : dict
        Body name -> ``{"names": list, "layout_m": ndarray (M, 3)}``, metres.

    Raises
    ------
    MocapError
        A layout whose shape does not match its names, or no still window to learn one.
    """
    out = {}
    for body, spec in body_specs.items():
        names = list(spec["names"])
        layout = spec.get("layout_m")
        if layout is None:
            layout = learn_layout(markers, names, still_s=still_s, still_tol_m=still_tol_m)
            log.info("learned the %s layout from a still window: %s", body, layout.tolist())
        layout = np.asarray(layout, dtype=float)
        if layout.shape != (len(names), 3):
            raise MocapError(
                f"body {body!r}: layout_m has shape {layout.shape}, expected "
                f"({len(names)}, 3) for markers {names}"
            )
        if refine:
            refined = refine_layout(markers, names, layout)
            log.info("%s layout refined from the markers: moved by up to %.2f mm", body,
                     1e3 * np.abs(refined - layout).max())
            layout = refined
        out[body] = {"names": names, "layout_m": layout}
    return out


# --------------------------------------------------------------------------- gap repair


def fill_marker_gaps(markers, body_specs, max_gap_s, method="cubic", refine_layout=True):
    """Fill marker gaps from the body's other markers, then by interpolation in time.

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (metres, W), ``attrs["rate_hz"]`` set.
    body_specs : dict
        ``{body: {"names": [...], "layout_m": (M, 3) or None}}``; a missing layout is learned
        (:func:`learn_layout`).
    max_gap_s : float
        Longest gap interpolated in time, seconds; a gap of n missing samples lasts n / rate.
    method : {"cubic", "linear"}
        Temporal interpolation: a cubic spline through every measured-or-rigid-filled sample of
        the marker, or straight lines between the gap's two neighbours.
    refine_layout : bool
        Fill from the layout the markers show (:func:`refine_layout`), not the given one.

    Returns
    -------
    filled : DataFrame
        The table with gaps filled where possible (still NaN elsewhere) plus a bool column
        ``{marker}_filled`` per marker, True on every sample that is not measured.
    summary : dict
        ``{"per_marker": {name: {"measured", "rigid", "interp", "missing"}}, "total": {...},
        "max_gap_s", "method", "warnings"}``: sample counts (plain ints, YAML ready);
        ``warnings`` (list of str) when a marker is never measured or over 20 % of the
        marker samples stay missing (``vicon_repair.yaml``).

    Notes
    -----
    Precedence: the rigid-body fill comes first. Where a marker is missing but at least three
    other markers of its body are *measured*, the layout is fitted to them (:func:`fit_rigid`)
    and the missing marker placed from the fitted pose; for a moving body this uses the
    current frame's data and is better than an interpolation across the gap. The remaining gaps
    of at most ``max_gap_s`` with data on both sides are then interpolated in time; longer
    gaps stay NaN and leave the body invalid where fewer than three markers remain.
    Only measured markers are used for the rigid fill, so filled values never feed each other.
    """
    if method not in ("cubic", "linear"):
        raise MocapError(f"fill_marker_gaps: method {method!r}, expected 'cubic' or 'linear'")
    rate = _rate_hz(markers)
    specs = resolve_layouts(markers, body_specs, refine=refine_layout)
    out = markers.copy()
    out.attrs = dict(markers.attrs)
    all_names = [n for s in specs.values() for n in s["names"]]
    counts = {}
    filled_flags = {}
    for spec in specs.values():
        names, layout = spec["names"], spec["layout_m"]
        Q = _xyz(markers, names)
        measured = np.isfinite(Q).all(axis=2)
        Qf = np.where(measured[..., None], Q, np.nan)
        rigid = np.zeros_like(measured)
        for k in range(len(names)):
            others = [j for j in range(len(names)) if j != k]
            need = ~measured[:, k] & (measured[:, others].sum(axis=1) >= 3)
            if not need.any():
                continue
            T, _, _ = fit_rigid(layout[others], Q[need][:, others])
            p = np.einsum("nij,j->ni", T[:, :3, :3], layout[k]) + T[:, :3, 3]
            good = np.isfinite(p).all(axis=1)
            idx = np.flatnonzero(need)[good]
            Qf[idx, k] = p[good]
            rigid[idx, k] = True
        for k, name in enumerate(names):
            interp = _interpolate_gaps(Qf[:, k], out["t_s"].to_numpy(float), rate, max_gap_s, method)
            missing = ~np.isfinite(Qf[:, k]).all(axis=1)
            out[_cols(name)] = Qf[:, k]
            filled_flags[f"{name}_filled"] = ~measured[:, k] & ~missing
            counts[name] = {
                "measured": int(measured[:, k].sum()),
                "rigid": int(rigid[:, k].sum()),
                "interp": int(interp),
                "missing": int(missing.sum()),
            }
    out = pd.concat([out, pd.DataFrame(filled_flags, index=out.index)], axis=1)
    out.attrs = dict(markers.attrs)
    total = {key: sum(c[key] for c in counts.values()) for key in ("measured", "rigid", "interp", "missing")}
    summary = {
        "per_marker": {n: counts[n] for n in all_names},
        "total": total,
        "max_gap_s": float(max_gap_s),
        "method": method,
    }
    summary["warnings"] = []
    if total["rigid"] or total["interp"] or total["missing"]:
        log.warning(
            "marker gaps: %d samples filled from rigid bodies, %d interpolated, %d left missing",
            total["rigid"],
            total["interp"],
            total["missing"],
        )
    never = [n for n in all_names if counts[n]["measured"] == 0]
    if never:
        summary["warnings"].append(f"markers {never} never measured in {len(markers)} samples")
    n_all = len(markers) * max(len(all_names), 1)
    if total["missing"] > 0.2 * n_all:
        summary["warnings"].append(
            f"{total['missing']} of {n_all} marker samples ({100 * total['missing'] / n_all:.1f} %) "
            f"stay missing after the repair (gaps longer than max_gap_s {max_gap_s:g} s)"
        )
    return out, summary


def repair_markers(markers, body_specs, vicon_cfg):
    """The repair stage: gap fill, then the optional low-pass filter, as the config says.

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (metres, W).
    body_specs : dict
        ``sessions.<s>.markers``: ``{body: {"names": [...], "layout_m": (M, 3) or None}}``.
    vicon_cfg : dict
        The ``vicon`` config block: ``max_gap_s`` (s), ``fill_method`` ("cubic" default or
        "linear"), ``refine_layout`` (default True), ``filter: {enabled, cutoff_hz, order}``.

    Returns
    -------
    filled : DataFrame
        ``markers_filled`` table (:func:`fill_marker_gaps`), filtered if enabled.
    summary : dict
        :func:`fill_marker_gaps` summary plus ``filter`` (the filter settings applied or
        ``None``).
    """
    filled, summary = fill_marker_gaps(
        markers,
        body_specs,
        max_gap_s=float(vicon_cfg.get("max_gap_s", 0.1)),
        method=vicon_cfg.get("fill_method", "cubic"),
        refine_layout=bool(vicon_cfg.get("refine_layout", True)),
    )
    filt = vicon_cfg.get("filter") or {}
    summary["filter"] = None
    if filt.get("enabled", False):
        cutoff_hz, order = float(filt["cutoff_hz"]), int(filt.get("order", 2))
        filled = lowpass_markers(filled, cutoff_hz, order)
        summary["filter"] = {"cutoff_hz": cutoff_hz, "order": order, "zero_lag": True}
    return filled, summary


def _interpolate_gaps(xyz, t_s, rate, max_gap_s, method):
    """Fill, in place, NaN runs of at most max_gap_s bounded by data on both sides; return count.

    ``cubic`` fits a least-squares cubic to the measured samples on both sides of each gap
    (as many on each side as the gap is long, at least 8): an interpolating spline through
    every noisy sample would bend hard at the gap edges, a local fit does not.
    """
    gap = ~np.isfinite(xyz).all(axis=1)
    starts, ends = _runs(gap)
    max_n = int(np.floor(max_gap_s * rate + 1e-9))
    inner = (starts > 0) & (ends < len(gap)) & (ends - starts <= max_n)
    n_filled = 0
    ok_starts, ok_ends = _runs(~gap)
    for s, e in zip(starts[inner], ends[inner], strict=True):
        n_ctx = max(8, e - s)
        # the measured stretches just before and after this gap
        lo = max(s - n_ctx, _stretch_start(ok_starts, s))
        hi = min(e + n_ctx, _stretch_end(ok_ends, ok_starts, e))
        ctx = np.r_[lo:s, e:hi]
        tc = t_s[ctx]
        tg = t_s[s:e]
        if method == "cubic" and (s - lo) >= 2 and (hi - e) >= 2 and len(ctx) >= 6:
            t0, scale = t_s[s - 1], max(t_s[e] - t_s[s - 1], 1e-12)
            V = np.vander((tc - t0) / scale, 4)
            coef, *_ = np.linalg.lstsq(V, xyz[ctx], rcond=None)
            xyz[s:e] = np.vander((tg - t0) / scale, 4) @ coef
        else:
            w = (tg - t_s[s - 1]) / (t_s[e] - t_s[s - 1])
            xyz[s:e] = (1 - w)[:, None] * xyz[s - 1] + w[:, None] * xyz[e]
        n_filled += e - s
    return n_filled


def _stretch_start(ok_starts, s):
    """Start index of the valid stretch that ends right before index s."""
    return int(ok_starts[np.searchsorted(ok_starts, s, side="right") - 1])


def _stretch_end(ok_ends, ok_starts, e):
    """End index (exclusive) of the valid stretch that starts at index e."""
    return int(ok_ends[np.searchsorted(ok_starts, e)])


def lowpass_markers(markers, cutoff_hz, order=2):
    """Zero-lag Butterworth low-pass of every marker coordinate, over valid stretches only.

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (metres), ``attrs["rate_hz"]`` set; ``_filled`` columns pass through.
    cutoff_hz : float
        Cut-off frequency of the Butterworth design, Hz; below the Nyquist rate.
    order : int
        Order of the design (the chapter: 2). Forward-backward filtering (filtfilt) doubles the
        effective order and squares the magnitude response, with zero phase lag.

    Returns
    -------
    filtered : DataFrame
        Same columns; stretches shorter than filtfilt's padding (3 * (order + 1) samples)
        and NaN samples are left unchanged.

    Raises
    ------
    MocapError
        A cut-off at or above the Nyquist rate.
    """
    rate = _rate_hz(markers)
    if not 0 < cutoff_hz < rate / 2:
        raise MocapError(f"lowpass_markers: cutoff {cutoff_hz} Hz, expected 0 < f < {rate / 2} Hz")
    b, a = butter(order, cutoff_hz / (rate / 2))
    padlen = 3 * max(len(a), len(b))
    out = markers.copy()
    out.attrs = dict(markers.attrs)
    for col in [c for c in markers.columns if c.endswith(("_x_m", "_y_m", "_z_m"))]:
        v = markers[col].to_numpy(float).copy()
        starts, ends = _runs(np.isfinite(v))
        for s, e in zip(starts, ends, strict=True):
            if e - s > padlen:
                v[s:e] = filtfilt(b, a, v[s:e])
        out[col] = v
    return out


# --------------------------------------------------------------------------- bodies


def fit_bodies(markers, body_specs, refine_layout=True):
    """Pose of each rigid body in W per native sample, by a least-squares fit to its layout.

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (metres, W), possibly with ``{marker}_filled`` columns.
    body_specs : dict
        ``{body: {"names": [...], "layout_m": (M, 3) or None}}`` (module docstring).
    refine_layout : bool
        Fit the layout the measured markers show (:func:`refine_layout`), in the given
        layout's frame, rather than the given layout itself.

    Returns
    -------
    bodies : DataFrame
        Long table, ``bodies.parquet`` schema (docs/contracts.md): ``frame, t_s, body, valid,
        x_m, y_m, z_m, qx, qy, qz, qw`` (T_W_Cm for ``camera``, T_W_Bm for ``board``; metres,
        scalar-last quaternion), ``roll_rad, pitch_rad, yaw_rad``, ``fit_rms_m`` (RMS marker
        residual), ``n_markers`` (used), ``n_filled`` (used but not measured). A sample is
        valid with at least three non-collinear markers.

    Notes
    -----
    Replaces the chapter's trigonometry on marker pairs with a Kabsch/Umeyama fit of all
    visible markers (:func:`fit_rigid`).
    """
    specs = resolve_layouts(markers, body_specs, refine=refine_layout)
    parts = []
    for body, spec in specs.items():
        names = spec["names"]
        Q = _xyz(markers, names)
        T, rms, n_used = fit_rigid(spec["layout_m"], Q)
        used = np.isfinite(Q).all(axis=2)
        flags = [f"{n}_filled" for n in names]
        if all(f in markers.columns for f in flags):
            n_filled = (markers[flags].to_numpy(bool) & used).sum(axis=1)
        else:
            n_filled = np.zeros(len(markers), dtype=int)
        parts.append(
            _body_frame(markers["frame"].to_numpy(), markers["t_s"].to_numpy(float), body, T, rms,
                        n_used, n_filled)
        )
    out = pd.concat(parts, ignore_index=True)
    out.attrs["rate_hz"] = _rate_hz(markers)
    return out


def _body_frame(frame, t_s, body, T, rms, n_markers, n_filled):
    """Assemble a bodies table (schema BODY_COLUMNS) for one body from (N, 4, 4) transforms."""
    valid = np.isfinite(T).all(axis=(1, 2))
    R = np.where(valid[:, None, None], T[:, :3, :3], np.eye(3))
    q = quat_from_R(R)
    rpy = euler_from_R(R)
    q[~valid] = np.nan
    rpy[~valid] = np.nan
    pos = np.where(valid[:, None], T[:, :3, 3], np.nan)
    return pd.DataFrame(
        {
            "frame": np.asarray(frame, dtype=np.int64),
            "t_s": np.asarray(t_s, dtype=float),
            "body": body,
            "valid": valid,
            "x_m": pos[:, 0],
            "y_m": pos[:, 1],
            "z_m": pos[:, 2],
            "qx": q[:, 0],
            "qy": q[:, 1],
            "qz": q[:, 2],
            "qw": q[:, 3],
            "roll_rad": rpy[:, 0],
            "pitch_rad": rpy[:, 1],
            "yaw_rad": rpy[:, 2],
            "fit_rms_m": np.where(valid, rms, np.nan),
            "n_markers": np.asarray(n_markers, dtype=np.int64),
            "n_filled": np.asarray(n_filled, dtype=np.int64),
        },
        columns=BODY_COLUMNS,
    )


def body_poses(bodies, body):
    """Times, transforms and validity of one body from a bodies table.

    Parameters
    ----------
    bodies : DataFrame
        bodies.parquet (long): ``frame, t_s, body, valid, x_m .. qw``.
    body : str
        ``"camera"`` (T_W_Cm) or ``"board"`` (T_W_Bm).

    Returns
    -------
    t_s : ndarray, shape (N,)
        Sample times, seconds, in frame order.
    T_W_body : ndarray, shape (N, 4, 4)
        NaN where invalid; metres.
    valid : ndarray of bool, shape (N,)

    Raises
    ------
    MocapError
        The body is not in the table.
    """
    sub = bodies[bodies["body"] == body].sort_values("frame", kind="stable")
    if sub.empty:
        raise MocapError(f"bodies table has no body {body!r} (has {sorted(set(bodies['body']))})")
    valid = sub["valid"].to_numpy(bool)
    q = sub[["qx", "qy", "qz", "qw"]].to_numpy(float, copy=True)
    q[~valid] = [0.0, 0.0, 0.0, 1.0]
    T = make_T(Rotation.from_quat(q).as_matrix(), sub[["x_m", "y_m", "z_m"]].to_numpy(float))
    T[~valid] = np.nan
    return sub["t_s"].to_numpy(float), T, valid


def _body_aux(bodies, body):
    sub = bodies[bodies["body"] == body].sort_values("frame", kind="stable")
    return (
        sub["fit_rms_m"].to_numpy(float),
        sub["n_markers"].to_numpy(np.int64),
        sub["n_filled"].to_numpy(np.int64),
    )


def block_average_bodies(bodies, factor):
    """Downsample bodies by the chapter's block mean of ``factor`` consecutive samples.

    Parameters
    ----------
    bodies : DataFrame
        Native-rate bodies table.
    factor : int
        Samples per block (the chapter: 10, 300 Hz to 30 Hz; ``round(rate / fps)``).

    Returns
    -------
    bodies_lo : DataFrame
        Same columns; one row per complete block (a trailing partial block is dropped);
        ``frame`` the block index, ``t_s`` the mean of the block's sample times. Positions are
        averaged; rotations by the quaternion mean (largest eigenvector of sum q q^T, Markley
        et al. 2007), never Euler angles. ``fit_rms_m`` is the RMS of the block's,
        ``n_markers`` the minimum, ``n_filled`` the sum.

    Notes
    -----
    Rule for invalid samples: a block is valid only when all its samples are valid. Averaging
    only the valid part would shift the block's effective time away from its stated time.
    """
    factor = int(factor)
    if factor < 1:
        raise MocapError(f"block_average_bodies: factor {factor}, expected >= 1")
    parts = []
    for body in pd.unique(bodies["body"]):
        t, T, valid = body_poses(bodies, body)
        rms, n_m, n_f = _body_aux(bodies, body)
        nb = len(t) // factor
        if nb == 0:
            raise MocapError(
                f"block_average_bodies: {len(t)} samples of {body!r}, fewer than one block of {factor}"
            )
        sl = slice(0, nb * factor)
        shape = (nb, factor)
        vb = valid[sl].reshape(shape).all(axis=1)
        tb = t[sl].reshape(shape).mean(axis=1)
        pos = T[sl, :3, 3].reshape(nb, factor, 3).mean(axis=1)
        Rn = np.where(valid[sl, None, None], T[sl, :3, :3], np.eye(3))
        q = Rotation.from_matrix(Rn).as_quat().reshape(nb, factor, 4)
        q_mean = block_mean_quats(q)
        Tb = make_T(Rotation.from_quat(q_mean).as_matrix(), pos)
        Tb[~vb] = np.nan
        rms_b = np.sqrt(np.mean(rms[sl].reshape(shape) ** 2, axis=1))
        parts.append(
            _body_frame(
                np.arange(nb),
                tb,
                body,
                Tb,
                rms_b,
                n_m[sl].reshape(shape).min(axis=1),
                n_f[sl].reshape(shape).sum(axis=1),
            )
        )
    return pd.concat(parts, ignore_index=True)


def interpolate_bodies(bodies, t_query_s):
    """Bodies at given times: linear in position, SLERP in rotation.

    Parameters
    ----------
    bodies : DataFrame
        Native-rate bodies table.
    t_query_s : array_like, shape (K,)
        Times on the Vicon clock, seconds.

    Returns
    -------
    bodies_at : DataFrame
        Same columns, one row per query time and body; ``frame`` the query index. A query is
        valid only when both native samples around it are valid and it lies inside the take.
        ``fit_rms_m`` and ``n_filled``/``n_markers`` come from the nearer of the two samples.
    """
    tq = np.asarray(t_query_s, dtype=float)
    parts = []
    for body in pd.unique(bodies["body"]):
        t, T, valid = body_poses(bodies, body)
        rms, n_m, n_f = _body_aux(bodies, body)
        T_at, ok, near = interpolate_T(t, T, valid, tq)
        parts.append(_body_frame(np.arange(len(tq)), tq, body, T_at, rms[near], n_m[near], n_f[near]))
    return pd.concat(parts, ignore_index=True)


def downsample_bodies(bodies, fps, mode="block", rate_hz=None):
    """The 30 Hz bodies table: block mean (chapter) or interpolation on a regular 1/fps grid.

    Parameters
    ----------
    bodies : DataFrame
        Native-rate bodies table.
    fps : float
        Video frame rate, Hz.
    mode : {"block", "interp"}
        ``vicon.resample``. ``block``: :func:`block_average_bodies` with factor
        ``round(rate_hz / fps)``; ``interp``: :func:`interpolate_bodies` at ``t0 + k / fps``
        over the take.
    rate_hz : float, optional
        Native Vicon rate, Hz; default ``attrs["rate_hz"]`` or 1 / median sample spacing.

    Returns
    -------
    bodies_30hz : DataFrame
        ``bodies_30hz.parquet`` schema, Vicon clock.
    """
    if rate_hz is None:
        rate_hz = bodies.attrs.get("rate_hz")
    if rate_hz is None:
        t = np.sort(pd.unique(bodies["t_s"].to_numpy(float)))
        rate_hz = 1.0 / float(np.median(np.diff(t)))
    rate_hz = float(rate_hz)
    if mode == "block":
        factor = int(round(rate_hz / fps))
        if abs(factor - rate_hz / fps) > 1e-3 * factor:
            log.warning("Vicon rate %g Hz is not a multiple of %g fps; blocks of %d", rate_hz, fps, factor)
        return block_average_bodies(bodies, factor)
    if mode == "interp":
        t = bodies["t_s"].to_numpy(float)
        t0, t1 = float(t.min()), float(t.max())
        tq = t0 + np.arange(int(np.floor((t1 - t0) * fps + 1e-9)) + 1) / fps
        return interpolate_bodies(bodies, tq)
    raise MocapError(f"downsample_bodies: mode {mode!r}, expected 'block' or 'interp'")


# --------------------------------------------------------------------------- system bodies


def bodies_from_poses(frame, t_s, body, T_W_body, residual_m, n_markers):
    """A bodies table (``bodies.parquet`` columns) from poses a motion-capture system solved itself.

    Parameters
    ----------
    frame : ndarray of int, shape (N,)
    t_s : ndarray, shape (N,)
        Sample times, seconds.
    body : str
        Body name.
    T_W_body : ndarray, shape (N, 4, 4)
        The system's pose of the body in its world W, metres; rows with any NaN are invalid
        (the system lost the body).
    residual_m : ndarray, shape (N,)
        The system's own residual (Motive Mean Marker Error, QTM 6DOF residual), metres; it goes
        into ``fit_rms_m`` so the plausibility checks and figures treat it as the fit residual.
    n_markers : ndarray of int, shape (N,)
        Markers the system used per sample, -1 where the export does not say.

    Returns
    -------
    bodies : DataFrame
        Schema :data:`BODY_COLUMNS`; ``n_filled`` is 0 (the system does its own gap handling).
        Rotations are re-orthonormalised (exports round them to 5 or 6 decimals).

    Raises
    ------
    MocapError
        A valid rotation far from orthonormal (``|R^T R - I| > 1e-2``): not a rotation matrix
        (a mis-parsed or mis-scaled export).
    """
    T = np.array(T_W_body, dtype=float, copy=True)
    valid = np.isfinite(T).all(axis=(1, 2))
    R = T[valid, :3, :3]
    if len(R):
        err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
        if np.any(err > 1e-2):
            i = int(np.flatnonzero(err > 1e-2)[0])
            raise MocapError(
                f"body {body!r}, frame {int(np.asarray(frame)[valid][i])}: rotation is not "
                f"orthonormal (|R^T R - I| = {err[i]:.3g}, expected below 1e-2)"
            )
        # nearest rotation (polar decomposition), so rounding in the export does not bias
        U, _, Vt = np.linalg.svd(R)
        T[valid, :3, :3] = U @ Vt
    T[~valid] = np.nan
    residual = np.where(valid, np.asarray(residual_m, dtype=float), np.nan)
    out = _body_frame(frame, t_s, body, T, residual, np.asarray(n_markers, dtype=np.int64),
                      np.zeros(len(T), dtype=np.int64))
    return out


def select_system_bodies(bodies, names, source="export"):
    """The system's bodies renamed to the pipeline's bodies (``camera``, ``board``).

    Parameters
    ----------
    bodies : DataFrame
        System bodies table (``body`` as named in the export), ``attrs["rate_hz"]`` optional.
    names : dict
        ``{"camera": <system body name>, "board": <system body name>}``.
    source : str
        The export, for messages.

    Returns
    -------
    bodies : DataFrame
        ``bodies.parquet`` table with ``body`` in ``names``' keys, in that order.

    Raises
    ------
    MocapError
        A named body absent from the export (lists what it has) or never tracked.
    """
    have = list(pd.unique(bodies["body"])) if bodies is not None else []
    parts = []
    for ours, theirs in names.items():
        if theirs not in have:
            raise MocapError(
                f"{source}: no rigid body {theirs!r} for the {ours} (the export has "
                f"{len(have)} bodies: {', '.join(map(repr, have)) or 'none'})"
            )
        sub = bodies[bodies["body"] == theirs].copy()
        if not sub["valid"].any():
            raise MocapError(
                f"{source}: rigid body {theirs!r} ({ours}) is not tracked in any of its "
                f"{len(sub)} frames; expected it tracked in at least one"
            )
        sub["body"] = ours
        parts.append(sub)
    out = pd.concat(parts, ignore_index=True)
    out.attrs = dict(bodies.attrs)
    return out
