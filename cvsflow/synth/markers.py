"""Vicon side of the demo session: marker placement, true body frames, 300 Hz marker table."""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow.geometry import invert_T, transform_points, umeyama


def true_mounting(T_body_obj_design, layout_m, placement_error_m):
    """True body frame, marker positions and mounting from the designed ones.

    The markers are stuck at ``layout + error`` in the designed body frame. The true body
    frame is defined as what a least-squares fit of the nominal layout to those real markers
    gives, so that a perfect rigid fit of the layout to noise-free markers recovers it.

    Parameters
    ----------
    T_body_obj_design : ndarray, shape (4, 4)
        Designed pose of the object frame (C or B) in the marker body frame (Cm or Bm).
    layout_m : ndarray, shape (M, 3)
        Nominal marker layout in the body frame, metres.
    placement_error_m : ndarray, shape (M, 3)
        Placement error of each marker in the designed body frame, metres.

    Returns
    -------
    T_body_obj : ndarray, shape (4, 4)
        True mounting (what an ideal calibration must find).
    markers_body_m : ndarray, shape (M, 3)
        Real marker positions in the true body frame, metres.
    """
    layout_m = np.asarray(layout_m, dtype=float)
    real_design = layout_m + placement_error_m
    T_design_true, _ = umeyama(layout_m, real_design)
    markers_body_m = transform_points(invert_T(T_design_true), real_design)
    return invert_T(T_design_true) @ T_body_obj_design, markers_body_m


def add_dropouts(xyz, rng, rate_hz, max_s, sample_rate_hz):
    """Blank short runs of samples (NaN), as occluded markers give.

    Parameters
    ----------
    xyz : ndarray, shape (N, M, 3)
        Marker positions; modified copy returned.
    rng : numpy.random.Generator
    rate_hz : float
        Expected number of new dropouts per second, all markers together.
    max_s : float
        Longest dropout, seconds (each is uniform in 1 sample .. max_s).
    sample_rate_hz : float

    Returns
    -------
    xyz : ndarray, shape (N, M, 3)
    n_dropouts : int
    """
    xyz = xyz.copy()
    n, m = xyz.shape[:2]
    n_dropouts = int(rng.poisson(rate_hz * n / sample_rate_hz))
    max_len = max(int(round(max_s * sample_rate_hz)), 1)
    for _ in range(n_dropouts):
        start = int(rng.integers(0, n))
        length = int(rng.integers(1, max_len + 1))
        xyz[start : start + length, int(rng.integers(0, m))] = np.nan
    return xyz, n_dropouts


def marker_table(xyz_W, names, rate_hz):
    """Wide marker table as ``cvsflow.io.mocap.vicon`` expects (frame, t_s, {name}_x_m ...).

    Parameters
    ----------
    xyz_W : ndarray, shape (N, M, 3)
        Marker positions in W, metres (NaN where not seen).
    names : list of str
        Marker names, length M.
    rate_hz : float

    Returns
    -------
    pandas.DataFrame
        With ``attrs["rate_hz"]`` and ``attrs["markers"]``.
    """
    n = xyz_W.shape[0]
    data = {"frame": np.arange(n), "t_s": np.arange(n) / rate_hz}
    for j, name in enumerate(names):
        for a, axis in enumerate("xyz"):
            data[f"{name}_{axis}_m"] = xyz_W[:, j, a]
    df = pd.DataFrame(data)
    df.attrs["rate_hz"] = float(rate_hz)
    df.attrs["markers"] = list(names)
    return df
