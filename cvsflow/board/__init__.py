"""Calibration targets: the board model (chessboard), ChArUco boards, Kalibr AprilGrids and target
files, and what stills show of one."""

from cvsflow.board.aprilgrid import AprilGrid, aprilgrid_from_board
from cvsflow.board.aprilgrid_detect import (
    detect_aprilgrid,
    extract_aprilgrid_corners,
    find_aprilgrid,
)
from cvsflow.board.aprilgrid_tags import default_passes, passes_name
from cvsflow.board.charuco import (
    charuco_board,
    extract_charuco_corners,
    find_charuco,
    is_charuco,
    make_detector,
)
from cvsflow.board.charuco_guess import guess_charuco_board
from cvsflow.board.kalibr import R_B_KALIBR_CHECKERBOARD, KalibrCheckerboard, kalibr_board, kalibr_target
from cvsflow.board.model import (
    BOARD_TYPES,
    CORNER_COLUMNS,
    SUBPIX_CRITERIA,
    CornerRows,
    board_name,
    board_object_points,
    board_pattern,
    board_record,
    board_type,
    ends_distinguishable,
)
from cvsflow.board.order import order_corners

__all__ = [
    "AprilGrid", "aprilgrid_from_board", "board_name", "board_object_points", "board_pattern",
    "board_record", "board_type",
    "BOARD_TYPES", "charuco_board", "CORNER_COLUMNS", "CornerRows", "default_passes",
    "detect_aprilgrid", "ends_distinguishable", "extract_aprilgrid_corners", "extract_charuco_corners",
    "find_aprilgrid", "find_charuco", "guess_charuco_board", "is_charuco", "kalibr_board",
    "kalibr_target", "KalibrCheckerboard", "make_detector", "order_corners", "passes_name",
    "R_B_KALIBR_CHECKERBOARD",
    "SUBPIX_CRITERIA"
]
