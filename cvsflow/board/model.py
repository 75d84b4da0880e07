"""The calibration board: its corner ids and their points in its own frame B, for every board type.

A chessboard and a ChArUco board (:mod:`cvsflow.board.charuco`) have the same squares and corners:
corner ``k`` is at ``((k % nx) * s, (k // nx) * s, 0)`` in B, square (0, 0) black, z into the board.
An AprilGrid (:mod:`cvsflow.board.aprilgrid`) has corner ``4 t + k`` (corner k of tag t) in
Kalibr's target frame, z out of the printed face. Everything downstream of the detectors (the
corners table, PnP, the calibration, the fits) takes a corner id as a row of
:func:`board_object_points`.
"""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd

from cvsflow.board.aprilgrid import aprilgrid_from_board
from cvsflow.exceptions import ConfigError

#: The ``board.type`` values: a chessboard (the default), a ChArUco board, a Kalibr AprilGrid.
BOARD_TYPES = ("chessboard", "charuco", "aprilgrid")

# The termination criteria of OpenCV's calibration tutorial (and of the published reference
# calibration in shared/data/real/SOURCES.md): 30 iterations or a 0.001 px step.
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)


def board_type(board: dict) -> str:
    """``board["type"]``, ``"chessboard"`` when absent.

    Parameters
    ----------
    board : dict
        The session's ``board`` block.

    Returns
    -------
    kind : str
        One of ``BOARD_TYPES``.

    Raises
    ------
    ConfigError
        An unknown type.
    """
    kind = board.get("type", "chessboard")
    if kind not in BOARD_TYPES:
        raise ConfigError(f"board.type={kind!r}; expected one of {list(BOARD_TYPES)}")
    return kind


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
        If ``squares_x``/``squares_y`` are not integers >= 3 or ``square_m`` is not positive, or
        the board is an AprilGrid (a grid of tags, no chessboard pattern).
    """
    if board.get("type") == "aprilgrid":
        raise ConfigError("board: type aprilgrid has no chessboard pattern (squares_x, squares_y); "
                          "this step takes a chessboard or ChArUco board")
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
    """Corner positions of the board in its own frame B, row ``k`` for corner id ``k``.

    Parameters
    ----------
    board : dict
        ``squares_x``, ``squares_y`` (int, squares along board x and y), ``square_m`` (m); a
        ``type: aprilgrid`` board has ``tag_cols``, ``tag_rows``, ``tag_size_m``,
        ``tag_spacing`` instead.

    Returns
    -------
    p_B : ndarray, shape (N, 3), float64
        Metres, frame B. Chessboard and ChArUco: N = nx * ny inner corners, corner ``k`` at
        ``((k % nx) * s, (k // nx) * s, 0)``; AprilGrid: N = 4 tags, Kalibr's points
        (:meth:`cvsflow.board.aprilgrid.AprilGrid.object_points`).
    """
    if board_type(board) == "aprilgrid":
        return aprilgrid_from_board(board).object_points()
    nx, ny = board_pattern(board)
    s = float(board["square_m"])
    k = np.arange(nx * ny)
    return np.stack([(k % nx) * s, (k // nx) * s, np.zeros(nx * ny)], axis=1).astype(np.float64)


def board_name(board: dict) -> str:
    """How messages name a board.

    Parameters
    ----------
    board : dict
        The session's ``board`` block.

    Returns
    -------
    name : str
        ``"9x6 chessboard"`` (inner corners), ``"ChArUco board"`` or ``"6x6 AprilGrid"`` (tags).
    """
    kind = board_type(board)
    if kind == "aprilgrid":
        return f"{board['tag_cols']}x{board['tag_rows']} AprilGrid"
    return "ChArUco board" if kind == "charuco" else "{}x{} chessboard".format(*board_pattern(board))


def board_record(board: dict) -> dict:
    """The board block as a result file records it (camera.yaml's ``board``), plain numbers.

    Parameters
    ----------
    board : dict
        The session's ``board`` block.

    Returns
    -------
    record : dict
        Chessboard: ``squares_x``, ``squares_y``, ``square_m``; ChArUco: also ``type``,
        ``marker_m``, ``dictionary``; AprilGrid: :meth:`cvsflow.board.aprilgrid.AprilGrid.config`.
    """
    kind = board_type(board)
    if kind == "aprilgrid":
        return aprilgrid_from_board(board).config()
    out = {"squares_x": int(board["squares_x"]), "squares_y": int(board["squares_y"]),
           "square_m": float(board["square_m"])}
    if kind == "charuco":
        out.update(type="charuco", marker_m=float(board["marker_m"]), dictionary=str(board["dictionary"]))
    return out


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


#: Columns of the corners table (corners.parquet) every board detector writes.
CORNER_COLUMNS = ["frame", "t_s", "found", "corner", "u_px", "v_px"]


class CornerRows:
    """The corners table, built frame by frame (any board type).

    A found frame gives one row per corner it knows (finite pixels), with corner k's index;
    a frame without a board gives one row with ``corner = -1``, NaN pixels, ``found`` False.

    Parameters
    ----------
    n_corners : int
        Inner corners of the board (corner k is row k of the per-frame pixel arrays).
    """

    def __init__(self, n_corners: int):
        self._ids = np.arange(int(n_corners), dtype=np.int64)
        self._frame, self._t, self._found, self._corner, self._uv = [], [], [], [], []

    def add(self, frame: int, t_s: float, corners_px: np.ndarray | None) -> None:
        """Append one frame's rows.

        Parameters
        ----------
        frame : int
        t_s : float
            Video time, s.
        corners_px : ndarray, shape (n_corners, 2), or None
            Distorted pixels in corner order, NaN for corners not kept; None: no board.

        Returns
        -------
        None
        """
        if corners_px is None:
            self._frame.append(np.array([frame], dtype=np.int64))
            self._t.append(np.array([t_s], dtype=np.float64))
            self._found.append(np.array([False]))
            self._corner.append(np.array([-1], dtype=np.int64))
            self._uv.append(np.full((1, 2), np.nan))
            return
        known = np.isfinite(corners_px).all(axis=1)
        n = int(known.sum())
        self._frame.append(np.full(n, frame, dtype=np.int64))
        self._t.append(np.full(n, t_s, dtype=np.float64))
        self._found.append(np.ones(n, dtype=bool))
        self._corner.append(self._ids[known])
        self._uv.append(corners_px[known])

    def table(self) -> pd.DataFrame:
        """The rows so far as a corners table.

        Returns
        -------
        corners : DataFrame
            :data:`CORNER_COLUMNS`: ``frame`` int64, ``t_s`` float64 s, ``found`` bool,
            ``corner`` int64, ``u_px``, ``v_px`` float64 distorted pixels.
        """
        uv = np.concatenate(self._uv).astype(np.float64)
        return pd.DataFrame(
            {
                "frame": np.concatenate(self._frame),
                "t_s": np.concatenate(self._t),
                "found": np.concatenate(self._found),
                "corner": np.concatenate(self._corner),
                "u_px": uv[:, 0],
                "v_px": uv[:, 1],
            }
        )[CORNER_COLUMNS]
