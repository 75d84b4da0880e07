"""What an optimiser returns: the per-iteration table, the per-frame errors and result.yaml.

Each optimiser returns an :class:`OptimiseResult`: the per-iteration table
(``iterations.parquet``), the per-frame error table (``errors.parquet`` input of the
analysis) and the ``result.yaml`` mapping (plain Python values, SI units).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd


@dataclass
class OptimiseResult:
    """What an optimiser hands to the writer and to the analysis.

    Attributes
    ----------
    iterations : pandas.DataFrame
        One row per iteration (``iterations.parquet``), SI units.
    errors : pandas.DataFrame
        One row per pair frame: poses and errors at the initial and final focal lengths.
    result : dict
        ``result.yaml`` content: plain floats, ints, lists and strings.
    """

    iterations: pd.DataFrame
    errors: pd.DataFrame
    result: dict = field(default_factory=dict)
