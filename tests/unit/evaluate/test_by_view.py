"""The held-out error against the board's distance and tilt: geometry from the reference pose, RMS per bin."""

import math

import matplotlib
import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.evaluate import errors_by_view, view_geometry
from cvsflow.metrics import ERROR_DIMS, error_columns

matplotlib.use("Agg")


def _frames(n=600, seed=3):
    rng = np.random.default_rng(seed)
    distance = rng.uniform(1.0, 4.0, n)
    tilt = rng.uniform(0.0, math.radians(60), n)
    # board rotated about its own x axis by the tilt, then turned about the optical axis
    R = Rotation.from_euler("zx", np.column_stack([rng.uniform(-np.pi, np.pi, n), tilt]))
    q = R.as_quat()  # scalar last
    t = np.column_stack([np.zeros(n), np.zeros(n), distance])
    df = pd.DataFrame({"ref_x_m": t[:, 0], "ref_y_m": t[:, 1], "ref_z_m": t[:, 2],
                       "ref_qx": q[:, 0], "ref_qy": q[:, 1], "ref_qz": q[:, 2], "ref_qw": q[:, 3]})
    err = rng.normal(size=(n, 6)) * 1e-4
    err[:, 2] *= distance**2  # depth error as distance squared
    df[error_columns()] = err
    return df, distance, tilt


def test_view_geometry_recovers_distance_and_tilt():
    """Distance is the translation's norm, tilt the normal's angle from the optical axis."""
    df, distance, tilt = _frames()
    view = view_geometry(df)
    assert np.allclose(view["distance_m"], distance)
    assert np.allclose(view["tilt_rad"], tilt, atol=1e-9)


def test_errors_by_view_bins_show_depth_error_growing_with_distance():
    """Equal-count bins; z RMS rises bin to bin with distance, as the errors were drawn."""
    df, _, _ = _frames()
    binned = errors_by_view(df, n_bins=6)
    dist = binned[binned["by"] == "distance_m"]
    assert list(binned.columns[5:]) == list(ERROR_DIMS)
    assert len(dist) == 6 and dist["n"].sum() == 600 and dist["n"].min() >= 99
    assert np.all(np.diff(dist["z_m"].to_numpy()) > 0)
    x = dist["x_m"].to_numpy()
    assert x.max() / x.min() < 1.5  # x was drawn independent of distance
    assert len(binned[binned["by"] == "tilt_rad"]) == 6


def test_errors_by_view_leaves_out_small_bins_and_draws():
    """Too few frames: no rows (no error); the figure draws whatever bins there are."""
    from cvsflow.plots.se3 import plot_errors_by_view

    df, _, _ = _frames(n=8)
    assert errors_by_view(df, min_count=10).empty
    fig = plot_errors_by_view(errors_by_view(_frames()[0]))
    assert len(fig.axes) == 4 and "deg" in fig.axes[3].get_xlabel()
