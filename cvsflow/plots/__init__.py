"""Figures: matplotlib only here. Each function takes DataFrames/arrays and returns a Figure;
conversion to millimetres and degrees happens only in this package, with units in axis labels.
"""
