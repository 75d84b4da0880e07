"""Long series thinned for drawing keep every bin's extremes."""

import numpy as np

from cvsflow.plots.decimate import min_max_envelope


def test_the_envelope_keeps_each_bins_extremes_in_time_order():
    """100,000 samples into 500 bins: at most 1000 points, times increasing, every kept point
    a real sample, each bin's minimum and maximum kept (a lone spike too), and a bin of only
    NaN becomes one NaN so the line still breaks; a short series comes back as it is."""
    rng = np.random.default_rng(3)
    t = np.arange(100_000) / 300.0
    y = np.sin(t) + 0.01 * rng.normal(size=t.size)
    y[77_777] = 9.0
    y[40_000:40_400] = np.nan  # two whole bins of 200 samples
    t_out, y_out = min_max_envelope(t, y, n_bins=500)
    assert len(t_out) <= 1000
    assert np.all(np.diff(t_out) > 0)
    idx = np.round(t_out * 300.0).astype(int)
    finite = np.isfinite(y_out)
    assert np.array_equal(y_out[finite], y[idx[finite]])
    for b in range(500):
        seg = y[b * 200:(b + 1) * 200]
        inside = (idx >= b * 200) & (idx < (b + 1) * 200)
        if np.isfinite(seg).any():
            assert np.nanmax(y_out[inside]) == np.nanmax(seg)
            assert np.nanmin(y_out[inside]) == np.nanmin(seg)
        else:
            assert inside.sum() == 1 and np.isnan(y_out[inside]).all()
    assert 9.0 in y_out
    short_t, short_y = np.arange(10.0), np.arange(10.0) ** 2
    same_t, same_y = min_max_envelope(short_t, short_y, n_bins=5)
    assert np.array_equal(same_t, short_t) and np.array_equal(same_y, short_y)
