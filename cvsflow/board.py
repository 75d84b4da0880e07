"""The calibration board: its corner grid in its own frame B, shared by every board type.

A chessboard and a ChArUco board (:mod:`cvsflow.charuco`) have the same squares and corners:
corner ``k`` is at ``((k % nx) * s, (k // nx) * s, 0)`` in B, square (0, 0) black.
"""

from __future__ import annotations

import cv2
import numpy as np

from cvsflow.errors import ConfigError

# The termination criteria of OpenCV's calibration tutorial (and of the published reference
# calibration in shared/data/real/SOURCES.md): 30 iterations or a 0.001 px step.
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


def board_pattern(board: dict) -> tuple[int, int]:
    """OpenCV pattern size ``(nx, ny)`` (inner corners per row, rows) of a board dict.

    Parameters
    ----------
    board : dict
        ``squares_x``, ``squares_y`` (int, squares along board x and y), ``square_m`` (m).

    Returns
    -------
    pattern : (int, int)
        ``(squares_x - 1, squares_y - 1)``: inner corners along x, along y.

    Raises
    ------
    ConfigError
        If ``squares_x``/``squares_y`` are not integers >= 3 or ``square_m`` is not positive.
    """
    try:
        squares_x = int(board["squares_x"])
        squares_y = int(board["squares_y"])
        square_m = float(board["square_m"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(
            f"board {board!r}: expected keys squares_x, squares_y (integers) and square_m "
            f"(metres) ({exc})"
        ) from exc
    if squares_x < 3 or squares_y < 3 or squares_x != board["squares_x"] or squares_y != board[
        "squares_y"
    ]:
        raise ConfigError(
            f"board: squares_x={board['squares_x']!r}, squares_y={board['squares_y']!r}; "
            "expected integers >= 3 (at least 2x2 inner corners)"
        )
    if not square_m > 0.0:
        raise ConfigError(f"board: square_m={board['square_m']!r}; expected a positive length in m")
    return squares_x - 1, squares_y - 1


def board_object_points(board: dict) -> np.ndarray:
    """Inner-corner positions of the board in its own frame B.

    Parameters
    ----------
    board : dict
        ``squares_x``, ``squares_y`` (int, squares along board x and y), ``square_m`` (m).

    Returns
    -------
    p_B : ndarray, shape (nx * ny, 3), float64
        Corner ``k`` at ``((k % nx) * s, (k // nx) * s, 0)``, metres, frame B.
    """
    nx, ny = board_pattern(board)
    s = float(board["square_m"])
    k = np.arange(nx * ny)
    return np.stack([(k % nx) * s, (k // nx) * s, np.zeros(nx * ny)], axis=1).astype(np.float64)


def ends_distinguishable(board: dict) -> bool:
    """True when the two ends of the corner grid differ in colour (squares_x + squares_y odd).

    Parameters
    ----------
    board : dict
        ``squares_x``, ``squares_y``.

    Returns
    -------
    distinguishable : bool

    A 180-degree turn of the board maps square (i, j) to (sx-1-i, sy-1-j), which changes the
    parity of i + j by sx + sy; only when that is odd does every square change colour.
    """
    return (int(board["squares_x"]) + int(board["squares_y"])) % 2 == 1
