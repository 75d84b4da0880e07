"""Calibration targets: the board model (chessboard), ChArUco boards and what stills show of one."""
