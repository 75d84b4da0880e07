"""Board order of a chessboard's detected corners: corner k at board point (k % nx, k // nx).

``findChessboardCorners`` may start the grid at either end; the board's printed side
(handedness) and its colours (square (0, 0) black) decide which (:func:`order_corners`). Used by
the stills' calibration, the video's corner detection and the hand-eye stills alike.
"""

from __future__ import annotations

import numpy as np

from cvsflow.board.model import board_pattern, ends_distinguishable


def _cell_contrast(gray: np.ndarray, grid_px: np.ndarray) -> float:
    """Mean grey level of the inner squares expected white minus those expected black.

    ``grid_px`` has shape (ny, nx, 2). Inner square between corners (i, j) and (i+1, j+1) is
    board square (i+1, j+1), black when i + j is even. Each square is sampled at 9 points of its
    bilinear interior (25 % to 75 % across), which the detected corners map exactly up to the
    lens's curvature over one square.
    """
    h, w = gray.shape[:2]
    p00 = grid_px[:-1, :-1]
    p10 = grid_px[:-1, 1:]
    p01 = grid_px[1:, :-1]
    p11 = grid_px[1:, 1:]
    a = np.array([0.25, 0.5, 0.75])
    aa, bb = np.meshgrid(a, a, indexing="ij")
    aa = aa.ravel()[:, None, None, None]
    bb = bb.ravel()[:, None, None, None]
    pts = (1 - aa) * (1 - bb) * p00 + aa * (1 - bb) * p10 + (1 - aa) * bb * p01 + aa * bb * p11
    u = np.clip(np.rint(pts[..., 0]).astype(int), 0, w - 1)
    v = np.clip(np.rint(pts[..., 1]).astype(int), 0, h - 1)
    level = gray[v, u].astype(np.float64).mean(axis=0)  # (ny-1, nx-1)
    jj, ii = np.indices(level.shape)
    black = (ii + jj) % 2 == 0
    return float(level[~black].mean() - level[black].mean())


def _handedness(grid_px: np.ndarray) -> float:
    """Sign of the image cross product of the grid's x and y directions (positive: front view).

    With B's z axis into the board, a board seen from its printed side has board x and y
    mapped to image directions whose cross product (u right, v down) is positive.
    """
    d_x = grid_px[:, -1].mean(axis=0) - grid_px[:, 0].mean(axis=0)
    d_y = grid_px[-1, :].mean(axis=0) - grid_px[0, :].mean(axis=0)
    return float(d_x[0] * d_y[1] - d_x[1] * d_y[0])


def order_corners(
    corners_px: np.ndarray,
    gray: np.ndarray,
    board: dict,
    previous_px: np.ndarray | None = None,
    min_contrast: float = 8.0,
) -> tuple[np.ndarray, str]:
    """Put detected corners in board order: corner k at board point (k % nx, k // nx).

    ``findChessboardCorners`` returns rows of ``nx`` corners, but may start the grid at either
    end (a 180-degree ambiguity), and its row order may run either way. Two checks fix both:

    1. Handedness: the printed side faces the camera, so board x cross board y is positive in
       the image; if not, the row order is reversed.
    2. Colour: square (0, 0), diagonally outside corner 0, is black. When the two ends of the
       grid differ in colour (``squares_x + squares_y`` odd, e.g. the demo 6x5 board), a 180-degree
       turn swaps the colour of *every* square, so the inner squares, which are always in view
       when the corners are, decide it: expected-black squares must be darker than
       expected-white ones. This is the same rule as sampling the squares just outside corner 0
       (black) and outside the last corner (white), but never needs pixels beyond the grid.

    For boards whose two ends look alike (``squares_x + squares_y`` even), or when the colour
    contrast is below ``min_contrast`` grey levels, the order closest to ``previous_px`` (the
    ordered corners of the previous found frame) is kept: temporal continuity. Without a
    previous frame the handedness-corrected OpenCV order is kept and the method says so.
    Square patterns (nx == ny) also have a 90-degree ambiguity, which is not resolved here.

    Parameters
    ----------
    corners_px : ndarray, shape (nx * ny, 2) or (nx * ny, 1, 2)
        Detected corners as OpenCV returns them, pixels.
    gray : ndarray, shape (H, W), uint8
        The image they were found in.
    board : dict
        Board geometry (``squares_x``, ``squares_y``, ``square_m``).
    previous_px : ndarray, shape (nx * ny, 2), optional
        Ordered corners of the previous frame, pixels.
    min_contrast : float
        Smallest white-minus-black grey-level difference trusted for the colour check.

    Returns
    -------
    ordered_px : ndarray, shape (nx * ny, 2), float64
        Corners in board order, pixels.
    method : str
        ``"colour"``, ``"continuity"`` or ``"unresolved"``: how the 180-degree ambiguity was
        decided.
    """
    nx, ny = board_pattern(board)
    grid = np.asarray(corners_px, dtype=np.float64).reshape(ny, nx, 2)
    if _handedness(grid) < 0:
        grid = grid[::-1]
    if ends_distinguishable(board):
        contrast = _cell_contrast(gray, grid)
        if abs(contrast) >= min_contrast:
            if contrast < 0:
                grid = grid[::-1, ::-1]
            return grid.reshape(-1, 2).copy(), "colour"
    if previous_px is not None:
        flat = grid.reshape(-1, 2)
        prev = np.asarray(previous_px, dtype=np.float64).reshape(-1, 2)
        d_same = np.sum((flat - prev) ** 2)
        d_flip = np.sum((flat[::-1] - prev) ** 2)
        return (flat[::-1] if d_flip < d_same else flat).copy(), "continuity"
    return grid.reshape(-1, 2).copy(), "unresolved"
