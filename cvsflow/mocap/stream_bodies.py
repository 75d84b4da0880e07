"""A session's camera and board bodies from two pose streams (one body per stream, own times).

A pose stream (ASL/EuRoC, TUM or ETH CSV) gives one body's pose per row at its own timestamps;
the bodies table the later stages read holds both bodies on one time grid. The grid is the
camera body's stream (the moving one, whose own samples are then used as recorded); the board's
pose is interpolated at those times (linear + SLERP), invalid outside its stream or in its gaps.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow.exceptions import MocapError
from cvsflow.geometry import PoseCurve, make_T
from cvsflow.mocap.bodies import bodies_from_poses

log = logging.getLogger(__name__)


def bodies_from_streams(t_camera_ns, T_W_Cm, t_board_ns, T_W_Bm, max_gap_s=None, source="pose streams"):
    """The bodies table of a session whose motion capture is two pose streams.

    Parameters
    ----------
    t_camera_ns : ndarray of int64, shape (N,)
        The camera body's sample times, ns, strictly increasing.
    T_W_Cm : ndarray, shape (N, 4, 4)
        The camera marker body in the mocap world, m (rows with NaN: not tracked).
    t_board_ns : ndarray of int64, shape (M,)
        The board body's sample times, ns, on the camera stream's clock.
    T_W_Bm : ndarray, shape (M, 4, 4)
        The board marker body in the mocap world, m. One sample is a static board held at it.
    max_gap_s : float, optional
        Longest board interval interpolated over (default 3 times its median interval).
    source : str
        The streams' names, for messages.

    Returns
    -------
    bodies : DataFrame
        ``bodies.parquet`` columns (:data:`cvsflow.mocap.bodies.BODY_COLUMNS`) plus ``t_ns``
        (int64, exact): both bodies at the camera stream's times, ``t_s = t_ns / 1e9``; the
        board valid only inside its stream and outside its gaps. ``fit_rms_m`` NaN and
        ``n_markers`` -1 (a stream carries no residual); ``attrs["rate_hz"]`` the camera
        stream's rate.

    Raises
    ------
    MocapError
        The board's stream covers none of the camera stream's times (both spans named).
    """
    t_c = np.asarray(t_camera_ns, np.int64)
    t_b = np.asarray(t_board_ns, np.int64)
    # times relative to the camera stream's first sample: exact in float64 at ns resolution
    t_rel = (t_c - t_c[0]) / 1e9
    if len(t_b) == 1:
        at = np.repeat(np.asarray(T_W_Bm, float)[:1], len(t_c), axis=0)
        n_ok = len(t_c)
    else:
        R, p, _, _, status = PoseCurve((t_b - t_c[0]) / 1e9, T_W_Bm, max_gap_s=max_gap_s).at(t_rel)
        at = make_T(R, p)
        at[status != 0] = np.nan
        n_ok = int((status == 0).sum())
        if n_ok == 0:
            raise MocapError(
                f"{source}: the board's stream ({t_b[0]} to {t_b[-1]} ns) covers none of the camera "
                f"body's samples ({t_c[0]} to {t_c[-1]} ns); expected streams on one clock that overlap"
            )
    if n_ok < len(t_c):
        log.warning("%s: the board's pose is unknown at %d of the camera body's %d samples "
                    "(outside its stream or in its gaps): left invalid", source, len(t_c) - n_ok,
                    len(t_c))  # fmt: skip
    frame = np.arange(len(t_c))
    t_s = t_c / 1e9
    nan, none = np.full(len(t_c), np.nan), np.full(len(t_c), -1)
    parts = [bodies_from_poses(frame, t_s, body, T, nan, none)
             for body, T in (("camera", T_W_Cm), ("board", at))]
    out = pd.concat(parts, ignore_index=True)
    out["t_ns"] = np.concatenate([t_c, t_c])
    out.attrs["rate_hz"] = 1e9 / float(np.median(np.diff(t_c))) if len(t_c) > 1 else float("nan")
    return out
