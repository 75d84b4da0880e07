"""Calibration targets: the board model (chessboard), ChArUco boards and what stills show of one."""

from cvsflow.board.charuco import (
    board_type,
    charuco_board,
    extract_charuco_corners,
    find_charuco,
    is_charuco,
    make_detector,
)
from cvsflow.board.charuco_guess import guess_charuco_board
from cvsflow.board.model import (
    CORNER_COLUMNS,
    SUBPIX_CRITERIA,
    CornerRows,
    board_object_points,
    board_pattern,
    ends_distinguishable,
)

__all__ = [
    "board_object_points", "board_pattern", "board_type", "charuco_board", "CORNER_COLUMNS",
    "CornerRows", "ends_distinguishable", "extract_charuco_corners", "find_charuco",
    "guess_charuco_board", "is_charuco", "make_detector", "SUBPIX_CRITERIA"
]
