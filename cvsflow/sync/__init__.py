"""The two clocks: angular-speed streams, the time offset (correlation, gesture, refinement) and the
frame pairs.
"""
