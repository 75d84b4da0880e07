"""The corners stage: a board's corners in every video frame (extract, track, predict, detect, refine,
grid).
"""
