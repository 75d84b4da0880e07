"""Checks at the stage boundaries (units, overlap, fit quality) and of the optimisers' results."""
