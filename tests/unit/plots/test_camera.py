"""Camera figures: the image coverage of the video's corners and the stills'; the raw poses."""

import matplotlib
import numpy as np
import pandas as pd

from cvsflow.plots.camera import plot_image_coverage, plot_pose_timeseries

matplotlib.use("Agg")


def test_image_coverage_counts_found_corners_over_the_image():
    """Found frames' corners become the density (not-found rows and NaN left out), the stills' corners dots."""
    rng = np.random.default_rng(5)
    n = 400
    corners = pd.DataFrame({"found": np.r_[np.ones(n, bool), False], "u_px": np.r_[rng.uniform(0, 640, n), np.nan],
                            "v_px": np.r_[rng.uniform(0, 480, n), np.nan]})
    stills = pd.DataFrame({"u_px": rng.uniform(0, 640, 50), "v_px": rng.uniform(0, 480, 50)})
    fig = plot_image_coverage(corners, stills, {"width": 640, "height": 480})
    ax = fig.axes[0]
    assert f"({n})" in ax.get_title() and "(50)" in ax.get_title()
    assert ax.get_xlim() == (0.0, 640.0) and ax.get_ylim() == (480.0, 0.0)
    assert np.nansum(ax.collections[0].get_array()) == n


def test_pose_timeseries_draws_a_long_session_as_its_envelope():
    """18,000 frames (10 min at 30 fps) are drawn from at most 4000 points per panel, keeping
    each panel's extremes and a gap of 10 s; a short session's points are drawn as they are."""
    rng = np.random.default_rng(3)
    for n, most in ((600, 600), (18_000, 4000)):
        t = np.arange(n) / 30.0
        poses = pd.DataFrame({"t_s": t, "valid": (t < 100) | (t > 110)})
        for col in ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad"):
            poses[col] = rng.normal(size=n)
        fig = plot_pose_timeseries(poses)
        for ax, col in zip(fig.axes, ("x_m", "y_m", "z_m"), strict=False):
            x, y = ax.lines[0].get_data()
            assert len(x) <= most
            v = poses[col].to_numpy()[poses["valid"].to_numpy()] * 1e3
            assert np.nanmax(y) == v.max() and np.nanmin(y) == v.min()
            assert n == 600 or np.isnan(y).any()
