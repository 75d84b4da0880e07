"""Held-out evaluation, method comparison, seed scoring, per-run analysis, the summary and the headline
table.
"""
