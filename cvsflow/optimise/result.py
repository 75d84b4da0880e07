"""What every optimiser shares: its result and the way its options are given.

Each optimiser returns an :class:`OptimiseResult`: the per-iteration table
(``iterations.parquet``), the per-frame error table (``errors.parquet`` input of the
analysis) and the ``result.yaml`` mapping (plain Python values, SI units). Its options are a
frozen dataclass built by :func:`build_options` from the config's block and keyword overrides.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import pandas as pd

from cvsflow.exceptions import OptimiseError


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


def build_options(cls, options, overrides, label):
    """An options dataclass from a config block or an instance, with fields overridden.

    Parameters
    ----------
    cls : type
        The options dataclass (:class:`~cvsflow.optimise.seed_search.SeedOptions`,
        :class:`~cvsflow.optimise.se3_fit.Se3Options`).
    options : cls or dict or None
        The starting options (a dict: the config block); None: the class defaults.
    overrides : dict
        Fields to change.
    label : str
        Prefix of the error message.

    Returns
    -------
    cls
        Not checked: the class checks its values.

    Raises
    ------
    OptimiseError
        A name that is no field of ``cls``.
    """
    names = {f.name for f in fields(cls)}
    given = dict(options) if isinstance(options, dict) else {}
    unknown = sorted((set(given) | set(overrides)) - names)
    if unknown:
        raise OptimiseError(f"{label}: unknown options {unknown}; expected some of {sorted(names)}")
    return replace(options if isinstance(options, cls) else cls(**given), **overrides)
