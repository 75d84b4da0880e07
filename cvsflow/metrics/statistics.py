"""Error statistics: one registry of named statistics, one key set, the axes named by ERROR_DIMS.

Every summary of errors the package writes (a run's ``stats.json``, the held-out comparison
``comparison.yaml``, a flight's ``stats.yaml``, the seed method's iterations) takes its numbers
from :func:`error_statistics` (one series) or :func:`axis_statistics` (one series per axis,
keyed by :data:`cvsflow.metrics.errors.ERROR_DIMS`), so a statistic means the same everywhere
and a new one is one entry of :data:`STATISTICS` (as evo's ``StatisticsType``).

:func:`bootstrap_error_stats` gives the moving-block bootstrap intervals of the mean, the
standard deviation and the covariance of autocorrelated per-frame errors.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from cvsflow.exceptions import OptimiseError
from cvsflow.metrics.errors import ERROR_DIMS


@dataclass(frozen=True)
class Statistic:
    """A named statistic of a series of errors.

    Attributes
    ----------
    name : str
        Its key in every output.
    compute : callable
        ``compute(e) -> float`` of ``e``, an ndarray of shape (N,), N >= 1, all finite.
    squared : bool
        True when the value is in the square of the errors' unit (``sse``).
    """

    name: str
    compute: Callable[[np.ndarray], float]
    squared: bool = False


def _rmse(e):
    """sqrt(mean(e^2)): the error about zero, not about the mean."""
    return float(np.sqrt(np.mean(e * e)))


def _std(e):
    """Sample standard deviation (ddof 1), the square root of Sigma's diagonal; NaN for one value."""
    return float(e.std(ddof=1)) if e.size > 1 else float("nan")


#: The statistics of every error summary, in output order (evo's ``StatisticsType`` order).
#: ``std`` is the sample one (ddof 1), as the covariance Sigma and the bootstrap's; evo states
#: the population one (ddof 0), a factor sqrt((n - 1) / n) below it.
STATISTICS: dict[str, Statistic] = {s.name: s for s in (
    Statistic("rmse", _rmse),
    Statistic("mean", lambda e: float(e.mean())),
    Statistic("median", lambda e: float(np.median(e))),
    Statistic("std", _std),
    Statistic("min", lambda e: float(e.min())),
    Statistic("max", lambda e: float(e.max())),
    Statistic("sse", lambda e: float(np.sum(e * e)), squared=True),
)}  # fmt: skip


def error_statistics(e, names=None) -> dict:
    """The statistics of one error series, its non-finite values left out.

    Parameters
    ----------
    e : array_like, shape (N,)
        Errors in one unit (m, rad, px, ...).
    names : sequence of str, optional
        Keys of :data:`STATISTICS` to compute; default all of them.

    Returns
    -------
    dict
        ``n`` (the finite count) and one float per statistic, in the unit of ``e`` (``sse`` in
        its square); NaN when no value is finite.

    Raises
    ------
    KeyError
        A name that is not in :data:`STATISTICS`.
    """
    e = np.asarray(e, dtype=float).ravel()
    e = e[np.isfinite(e)]
    out: dict = {"n": int(e.size)}
    for name in STATISTICS if names is None else names:
        out[name] = STATISTICS[name].compute(e) if e.size else float("nan")
    return out


def axis_statistics(E, axes=ERROR_DIMS, names=None) -> dict:
    """:func:`error_statistics` of each column of a per-axis error table.

    Parameters
    ----------
    E : array_like, shape (N, len(axes))
        Errors, one column per axis (SI: m for x, y, z; rad for roll, pitch, yaw).
    axes : sequence of str
        The columns' names; default :data:`~cvsflow.metrics.errors.ERROR_DIMS`.
    names : sequence of str, optional
        As :func:`error_statistics`.

    Returns
    -------
    dict
        Axis name -> its statistics; each column's non-finite values are left out on their own.
    """
    E = np.asarray(E, dtype=float).reshape(len(E), -1)
    if E.shape[1] != len(axes):
        raise OptimiseError(f"axis_statistics: {E.shape[1]} columns for {len(axes)} axes {list(axes)}")
    return {a: error_statistics(E[:, j], names) for j, a in enumerate(axes)}


#: Memory of one chunk of bootstrap resamples (the resampled errors and their deviations).
BOOTSTRAP_CHUNK_BYTES = 32 * 2**20


def bootstrap_error_stats(errors, block_len, n_boot=1000, seed=0, level=0.95):
    """Moving-block bootstrap confidence intervals of the mean, std and Sigma of errors.

    Parameters
    ----------
    errors : ndarray, shape (N, d), or DataFrame
        Per-frame errors in time order (SI units).
    block_len : int
        Block length in frames (longer than the errors' autocorrelation; e.g. 1-2 s of
        frames). 1 gives the ordinary iid bootstrap.
    n_boot : int
        Bootstrap resamples.
    seed : int
        Seed of the resampling.
    level : float
        Confidence level of the percentile intervals, in (0, 1).

    Returns
    -------
    stats : dict
        For each of ``mean``, ``std`` (shape (d,), ddof 1 as :data:`STATISTICS`) and ``Sigma``
        (shape (d, d)): the estimate and its interval ``{name}_lo``, ``{name}_hi`` (ndarrays),
        plus ``block_len``, ``n_boot``, ``level``.

    Raises
    ------
    OptimiseError
        Fewer than 2 rows, block_len out of [1, N], or level not in (0, 1).

    Notes
    -----
    Künsch (1989), "The jackknife and the bootstrap for general stationary observations":
    ceil(N / L) blocks of L consecutive frames drawn with replacement from the N - L + 1
    overlapping blocks, concatenated and cut to N. Percentile intervals.
    """
    E = np.asarray(errors.to_numpy(float) if isinstance(errors, pd.DataFrame) else errors, float)
    if E.ndim == 1:
        E = E[:, None]
    n, d = E.shape
    L = int(block_len)
    if n < 2 or not 1 <= L <= n:
        raise OptimiseError(
            f"bootstrap: {n} rows and block_len {block_len}; need N >= 2 and 1 <= block_len <= N"
        )
    if not 0 < level < 1:
        raise OptimiseError(f"bootstrap: level {level}; expected in (0, 1)")
    rng = np.random.default_rng(seed)
    n_blocks = -(-n // L)
    starts = rng.integers(0, n - L + 1, size=(n_boot, n_blocks))
    means = np.empty((n_boot, d))
    sigmas = np.empty((n_boot, d, d))
    # Resamples a chunk at a time: all at once held n_boot x N x d values twice (0.9 GB for
    # a 5-minute session, 1000 resamples); each resample's arithmetic is its own, so the
    # chunking changes no bit of the result.
    chunk = max(1, BOOTSTRAP_CHUNK_BYTES // (16 * n * d))
    for b0 in range(0, n_boot, chunk):
        b1 = min(n_boot, b0 + chunk)
        idx = (starts[b0:b1, :, None] + np.arange(L)[None, None, :]).reshape(b1 - b0, -1)[:, :n]
        S = E[idx]  # (chunk, n, d)
        means[b0:b1] = S.mean(axis=1)
        C = S - means[b0:b1, None, :]
        sigmas[b0:b1] = np.einsum("bni,bnj->bij", C, C, optimize=False) / (n - 1)
    stds = np.sqrt(np.einsum("bii->bi", sigmas))
    a = (1.0 - level) / 2.0
    out = {"block_len": L, "n_boot": int(n_boot), "level": float(level)}
    est = {"mean": E.mean(axis=0), "std": E.std(axis=0, ddof=1), "Sigma": np.cov(E, rowvar=False)}
    for name, boot in (("mean", means), ("std", stds), ("Sigma", sigmas)):
        out[name] = np.atleast_1d(est[name]) if name != "Sigma" else np.atleast_2d(est[name])
        out[f"{name}_lo"] = np.quantile(boot, a, axis=0)
        out[f"{name}_hi"] = np.quantile(boot, 1.0 - a, axis=0)
    return out
