"""plot_stream_bodies: the bodies of a pose-stream session drawn without a fit residual."""

import warnings

import matplotlib.pyplot as plt
import numpy as np

from cvsflow.geometry import make_T
from cvsflow.mocap import bodies_from_streams
from cvsflow.plots.mocap import plot_stream_bodies


def _legend(fig):
    return [x.get_text() for ax in fig.axes for x in ax.get_legend().get_texts()]


def test_stream_bodies_figure_shows_path_and_unknown_samples():
    """A moving camera body and a still board whose stream stops halfway: one line each, the
    board's unknown samples counted, no warning (a stream's residual is all NaN)."""
    t = np.arange(40, dtype=np.int64) * 50_000_000
    T_cam = np.stack([make_T(np.eye(3), [0.01 * k, 0.0, 1.0]) for k in range(40)])
    T_brd = np.stack([make_T(np.eye(3), [1.0, 0.0, 0.0])] * 20)
    bodies = bodies_from_streams(t, T_cam, t[:20], T_brd)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fig = plot_stream_bodies(bodies)
    legend = _legend(fig)
    assert "camera (median 100.0 mm)" in legend and "board: 20 of 40 samples unknown" in legend
    plt.close(fig)
    held = bodies_from_streams(t, T_cam, t[:1], T_brd[:1])  # one board sample: held, all known
    fig = plot_stream_bodies(held)
    assert "board: 0 of 40 samples unknown" in _legend(fig)
    plt.close(fig)
