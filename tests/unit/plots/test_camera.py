"""Camera figures: the image coverage of the video's corners and the stills'."""

import matplotlib
import numpy as np
import pandas as pd

from cvsflow.plots.camera import plot_image_coverage

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
