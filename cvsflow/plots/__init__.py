"""Figures: matplotlib only here. Each function takes DataFrames/arrays and returns a Figure;
conversion to millimetres and degrees happens only in this package, with units in axis labels.

A module of this package is loaded on first use as an attribute (``from cvsflow import plots``,
then ``plots.mocap.plot_sync(...)``), so that a workflow job run with ``figures: false`` never
imports matplotlib (about 0.3 s of CPU per job); ``from cvsflow.plots import mocap`` loads it at
once, as any module.
"""

import importlib

_MODULES = ("camera", "decimate", "flight", "mocap", "results", "se3", "summary", "timing", "uncertainty")


def __getattr__(name):
    """Import the module ``name`` of this package when first asked for."""
    if name in _MODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
