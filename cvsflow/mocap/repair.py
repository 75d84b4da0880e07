"""Marker repair (rule ``mocap_repair``): gap filling and the zero-lag low-pass filter.

The chapter's "Data Processing" (seed section 1.3) made rigorous, on the wide marker tables of
:mod:`cvsflow.io.mocap.vicon` (metres, W, NaN where unseen); output ``markers_filled`` of
``docs/contracts.md`` with a ``{marker}_filled`` flag per marker. Body specs and layouts are
:mod:`cvsflow.mocap.layout`'s; the rigid bodies fitted to the repaired markers are
:mod:`cvsflow.mocap.bodies`'s.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow.exceptions import MocapError
from cvsflow.geometry import fit_rigid
from cvsflow.mocap.layout import _cols, _rate_hz, _xyz, resolve_layouts

log = logging.getLogger(__name__)


def _runs(mask):
    """Start (inclusive) and end (exclusive) indices of the True runs of a 1-D bool mask."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(np.int8))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


# --------------------------------------------------------------------------- gap repair


def fill_marker_gaps(markers, body_specs, max_gap_s, method="cubic", refine_layout=True):
    """Fill marker gaps from the body's other markers, then by interpolation in time.

    Parameters
    ----------
    markers : DataFrame
        Wide marker table (metres, W), ``attrs["rate_hz"]`` set.
    body_specs : dict
        ``{body: {"names": [...], "layout_m": (M, 3) or None}}``; a missing layout is learned
        (:func:`cvsflow.mocap.layout.learn_layout`).
    max_gap_s : float
        Longest gap interpolated in time, seconds; a gap of n missing samples lasts n / rate.
    method : {"cubic", "linear"}
        Temporal interpolation: a cubic spline through every measured-or-rigid-filled sample of
        the marker, or straight lines between the gap's two neighbours.
    refine_layout : bool
        Fill from the layout the markers show (:func:`cvsflow.mocap.layout.refine_layout`), not the given one.

    Returns
    -------
    filled : DataFrame
        The table with gaps filled where possible (still NaN elsewhere) plus a bool column
        ``{marker}_filled`` per marker, True on every sample that is not measured.
    summary : dict
        ``{"per_marker": {name: {"measured", "rigid", "interp", "missing"}}, "total": {...},
        "max_gap_s", "method", "warnings"}``: sample counts (plain ints, YAML ready);
        ``warnings`` (list of str) when a marker is never measured or over 20 % of the
        marker samples stay missing (``mocap_repair.yaml``).

    Notes
    -----
    Precedence: the rigid-body fill comes first. Where a marker is missing but at least three
    other markers of its body are *measured*, the layout is fitted to them
    (:func:`cvsflow.geometry.fit_rigid`) and the missing marker placed from the fitted pose; for
    a moving body this uses the current frame's data and is better than an interpolation across
    the gap. The remaining gaps of at most ``max_gap_s`` with data on both sides are then
    interpolated in time; longer gaps stay NaN and leave the body invalid where fewer than three
    markers remain.
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
    # scipy.signal loads scipy.stats with it (~0.5 s of CPU per process): imported where it is
    # used, so that jobs which only import this subpackage do not pay for it
    from scipy.signal import butter, filtfilt

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
