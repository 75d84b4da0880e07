"""Long time series thinned for drawing: a figure shows a few thousand columns of pixels, and
matplotlib draws every point it is given (a 20-minute 300 Hz track is 360,000 per line)."""

from __future__ import annotations

import numpy as np


def min_max_envelope(t, y, n_bins=2000):
    """The samples a line plot of (t, y) needs at ``n_bins`` columns: each bin's lowest and
    highest sample, in time order.

    Parameters
    ----------
    t, y : array_like, shape (N,)
        Sample times (increasing) and values; NaN values are gaps.
    n_bins : int
        Bins of consecutive samples (about the figure's width in pixels or more).

    Returns
    -------
    t_out, y_out : ndarray, shape (M,)
        ``t, y`` themselves when N <= 2 n_bins; else, per bin, the samples holding its
        minimum and its maximum (one when they are the same), in time order, M <= 2 n_bins. A
        bin with no finite value gives one NaN sample, so a gap still breaks the line.
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    n = len(y)
    if n <= 2 * int(n_bins):
        return t, y
    k = -(-n // int(n_bins))
    rows = -(-n // k)
    pad = rows * k - n
    Y = np.concatenate([y, np.full(pad, np.nan)]).reshape(rows, k)
    finite = np.isfinite(Y)
    lo = np.argmin(np.where(finite, Y, np.inf), axis=1)
    hi = np.argmax(np.where(finite, Y, -np.inf), axis=1)
    empty = ~finite.any(axis=1)
    base = np.arange(rows) * k
    first = base + np.minimum(lo, hi)
    second = base + np.maximum(lo, hi)
    pos = np.stack([first, second], axis=1)
    keep = np.ones_like(pos, bool)
    keep[:, 1] = (second != first) & ~empty
    pos = pos[keep]  # every index < n: padding is never a bin's extreme, an empty bin is its start
    t_out = t[pos]
    y_out = y[pos]
    y_out[np.repeat(empty, keep.sum(axis=1))] = np.nan
    return t_out, y_out
