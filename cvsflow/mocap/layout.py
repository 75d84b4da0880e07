"""Marker tables and rigid-body layouts: where each marker sits in its body's frame.

Inputs are the wide marker tables of :mod:`cvsflow.io.mocap.vicon` (``frame``, ``t_s``,
``{marker}_{x,y,z}_m`` in the Vicon world W, NaN where unseen, ``attrs["rate_hz"]``). Shared
by the gap repair (:mod:`cvsflow.mocap.repair`, rule ``mocap_repair``) and the rigid-body fit
(:mod:`cvsflow.mocap.bodies`, rule ``mocap_bodies``).

A *body spec* describes one rigid body: ``{"names": [marker names], "layout_m": (M, 3) or
None}``; ``layout_m`` is where each marker sits in the body's own frame (``Cm`` for the camera
body, ``Bm`` for the board body). A body spec without a layout gets one learned from a still
period (:func:`learn_layout`); :func:`refine_layout` fits the layout the markers show.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow.exceptions import InputError, MocapError
from cvsflow.geometry import fit_rigid, sample_period, transform_points

log = logging.getLogger(__name__)


AXES = ("x", "y", "z")


def _cols(name):
    return [f"{name}_{a}_m" for a in AXES]


def _rate_hz(markers, where="marker table"):
    rate = markers.attrs.get("rate_hz")
    if rate is None:
        t = markers["t_s"].to_numpy(float)
        if len(t) < 2:
            raise InputError(f"{where}: no rate_hz attribute and fewer than 2 samples")
        rate = 1.0 / sample_period(t)
    return float(rate)


def _xyz(markers, names, where="marker table"):
    """Stack marker coordinates into shape (N, M, 3), metres."""
    missing = [n for n in names if _cols(n)[0] not in markers.columns]
    if missing:
        raise InputError(f"{where}: marker(s) {missing} not in the marker table")
    return np.stack([markers[_cols(n)].to_numpy(float) for n in names], axis=1)


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
