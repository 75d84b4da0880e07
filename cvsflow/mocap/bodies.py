"""Rigid bodies from markers (rule ``mocap_bodies``) and their 30 Hz tables (rule ``mocap_resample``).

The chapter's "Data Processing" (seed section 1.3) made rigorous. Inputs are the repaired
marker tables of :mod:`cvsflow.mocap.repair` and the body specs of :mod:`cvsflow.mocap.layout`
(or poses the mocap system solved itself, :func:`bodies_from_poses`); outputs follow
``docs/contracts.md`` (``bodies``, ``bodies_30hz``).
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import MocapError
from cvsflow.geometry import (
    R_from_quat,
    block_mean_quats,
    euler_from_R,
    fit_rigid,
    interpolate_T,
    make_T,
    project_SO3,
    quat_from_R,
    sample_period,
)
from cvsflow.mocap.layout import _rate_hz, _xyz, resolve_layouts

log = logging.getLogger(__name__)


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
        Fit the layout the measured markers show
        (:func:`cvsflow.mocap.layout.refine_layout`), in the given layout's frame, rather than
        the given layout itself.

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
    visible markers (:func:`cvsflow.geometry.fit_rigid`).
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


#: The columns of a bodies table (:data:`BODY_COLUMNS`) :func:`body_poses` reads.
POSE_COLUMNS = ("t_s", "body", "valid", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw")


def body_poses(bodies, body, *, invalid="nan", min_valid=0, track=False):
    """Times, transforms and validity of one body from a bodies table: the one reader of it.

    Parameters
    ----------
    bodies : DataFrame
        bodies.parquet (long): ``t_s, body, valid, x_m, y_m, z_m, qx, qy, qz, qw``
        (:data:`POSE_COLUMNS`; ``frame`` and the fit's columns are not needed).
    body : str
        ``"camera"`` (T_W_Cm) or ``"board"`` (T_W_Bm).
    invalid : {"nan", "identity"}
        What an invalid sample's transform is: NaN, or the identity (for smoothing, which
        weights samples and must not meet a NaN).
    min_valid : int
        Fewest valid samples accepted.
    track : bool
        The rows are a track to interpolate: their times must increase strictly.

    Returns
    -------
    t_s : ndarray, shape (N,)
        Sample times (mocap clock), seconds, in ``frame`` order (time order without one).
    T_W_body : ndarray, shape (N, 4, 4)
        Body pose in the mocap world W, metres.
    valid : ndarray of bool, shape (N,)
        The table's ``valid`` flag and a finite pose with a quaternion of norm above 0.5.

    Raises
    ------
    MocapError
        Missing columns, no such body, fewer than ``min_valid`` valid samples, or a track
        whose times do not increase.
    """
    missing = set(POSE_COLUMNS) - set(bodies.columns)
    if missing:
        raise MocapError(f"bodies table lacks columns {sorted(missing)} (docs/contracts.md bodies.parquet)")
    sub = bodies[bodies["body"] == body].sort_values(_order(bodies), kind="stable")
    if sub.empty:
        raise MocapError(f"bodies table has no body {body!r} (has {sorted(set(bodies['body']))})")
    t = sub["t_s"].to_numpy(float)
    q = sub[["qx", "qy", "qz", "qw"]].to_numpy(float, copy=True)
    p = sub[["x_m", "y_m", "z_m"]].to_numpy(float, copy=True)
    valid = sub["valid"].to_numpy(bool) & np.isfinite(q).all(axis=1) & np.isfinite(p).all(axis=1)
    valid &= np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1) > 0.5
    if valid.sum() < min_valid:
        raise MocapError(f"body {body!r} has {int(valid.sum())} valid samples; need >= {min_valid}")
    if track and np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise MocapError(f"body {body!r}: t_s not strictly increasing at row {i + 1} ({t[i]} -> {t[i + 1]})")
    q[~valid] = [0.0, 0.0, 0.0, 1.0]
    p[~valid] = 0.0
    T = make_T(R_from_quat(q), p)
    if invalid == "nan":
        T[~valid] = np.nan
    return t, T, valid


def _order(bodies):
    """The column a body's rows are read in: ``frame`` when the table has one, else ``t_s``."""
    return "frame" if "frame" in bodies.columns else "t_s"


def _body_aux(bodies, body):
    """Fit RMS, marker count and filled count of one body, in :func:`body_poses`' order."""
    sub = bodies[bodies["body"] == body].sort_values(_order(bodies), kind="stable")
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
        rate_hz = 1.0 / sample_period(pd.unique(bodies["t_s"].to_numpy(float)))
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
        T[valid, :3, :3] = project_SO3(R)
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
