"""Finding a chessboard in a frame without a previous one: the full and the quick detector.

The full detector (``detect_corners``) costs ~3 ms on a frame with a whole board and ~30 ms on
one without (a board partly out of view is the worst case); the quick one
(``quick_detect_corners``) looks for a lost board on a shrunk image. Both refine and check what
OpenCV finds with :mod:`cvsflow.corners.refine`.
"""

from __future__ import annotations

import cv2
import numpy as np

from cvsflow.board import board_pattern, order_corners
from cvsflow.corners.grid import MAX_GRID_DEVIATION_FRAC, _grid_points, _inside, _track_scales
from cvsflow.corners.refine import (
    MIN_PATTERN_CONTRAST,
    _follow_partial,
    _partial_without,
    _refine_corners,
    _saddle_ok,
    board_squares_pattern_ok,
    refine_corners,
)

# ADAPTIVE_THRESH and NORMALIZE_IMAGE cope with the uneven light and auto-exposure of a
# hand-held board. FAST_CHECK pays only where the board is absent: measured on a rendered
# 640x480 session it halves the time of a frame without a board (15 vs 30-50 ms) but adds
# ~1.5 ms to a frame with one (5.2 vs 3.6 ms), at equal recall (844 of 900 frames). So
# extract_corners uses it only when no board was found in the last few frames.
VIDEO_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
VIDEO_SEARCH_FLAGS = VIDEO_FIND_FLAGS | cv2.CALIB_CB_FAST_CHECK


def detect_corners(
    gray: np.ndarray,
    board: dict,
    subpix_window_px: int = 5,
    previous_px: np.ndarray | None = None,
    flags: int = VIDEO_FIND_FLAGS,
    max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC,
    full_size: bool = True,
    keep_partial: bool = False,
) -> tuple[np.ndarray | None, str]:
    """Chessboard corners of one frame, refined and in board order.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m).
    subpix_window_px : int
        Largest cornerSubPix half window (OpenCV ``winSize``), pixels.
    previous_px : ndarray, shape (N, 2), optional
        Ordered corners of the previous found frame (pixels), for boards whose ends look alike.
    flags : int
        ``findChessboardCorners`` flags.
    max_grid_deviation : float
        Largest distance of a refined corner from the position its neighbours predict
        (``grid_deviation``), as a share of its local grid spacing (``local_spacing``; never
        below ``MIN_GRID_DEVIATION_PX``). A corner beyond it is refined once more from the
        prediction; if it still deviates, the frame counts as not found (``"inconsistent"``).
    full_size : bool
        Where the search on the shrunk image (``DETECT_LONG_SIDE_PX``) fails, search the
        full-size image too (slow: ~0.3 s at 1280x720 on a frame with a partly hidden board).
    keep_partial : bool
        Where OpenCV finds the grid but some corners fail the neighbour check or show no
        chessboard saddle (a hand over them), keep the others (``"partial"``) instead of
        counting the frame as not found.

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        Corner k at board point (k % nx, k // nx) * square_m (see
        ``cvsflow.board.order.order_corners``); with ``"partial"``, NaN for the corners
        dropped.
    method : str
        How the 180-degree ambiguity was decided (``"colour"``, ``"continuity"``,
        ``"unresolved"``), ``"partial"`` (``keep_partial``: the corners that agree with their
        grid neighbours, show the chessboard's saddle in their own colours and bound squares
        of the right colours, as for a tracked board partly hidden, ``_follow_partial``), or
        ``"not_found"`` / ``"inconsistent"``.

    Notes
    -----
    Under motion blur, findChessboardCorners' estimate of an outer corner can be more than a
    search window away from the true corner; cornerSubPix then leaves it where it was
    (it refuses moves larger than its window). Near the image border the window is cut off.
    The neighbour check catches both. A corner under a fingertip can pass it (cornerSubPix
    leaves it where it was put, or puts it on the finger's edge, within the limit); every
    corner of a whole board must also show the chessboard's saddle (``_saddle_ok``, where its
    samples are inside the image), else the frame is ``"partial"`` or not found.
    """
    pattern = board_pattern(board)
    found, corners = _find_on_pyramid(gray, pattern, flags, full_size)
    if not found:
        return None, "not_found"
    refined, first = _refine_corners(gray, corners, board, subpix_window_px, max_grid_deviation)
    if refined is not None:
        ordered, method = order_corners(refined, gray, board, previous_px)
        grid = _grid_points(board)
        H, _ = cv2.findHomography(grid, ordered.astype(np.float32), 0)
        if H is None:
            return None, "inconsistent"
        saddle = _saddle_ok(gray, H, ordered, grid, border_ok=True)
        if saddle.all():
            return ordered, method
        # A corner under a fingertip that agrees with its neighbours (cornerSubPix left it
        # where it was, or put it on the finger's edge): the others, checked as partial.
        if not keep_partial:
            return None, "inconsistent"
        partial, _ = _partial_without(gray, ordered, saddle, grid, board,
                                      _track_scales(ordered, board, gray.shape),
                                      max_grid_deviation)
        return (None, "inconsistent") if partial is None else (partial, "partial")
    if not keep_partial:
        return None, "inconsistent"
    return _detected_partial(gray, corners, first, board, subpix_window_px, max_grid_deviation,
                             previous_px)


def _detected_partial(gray, corners_px, first, board, subpix_window_px, max_grid_deviation,
                      previous_px):
    """``detect_corners``' fallback for a grid OpenCV found whose corners fail the neighbour
    check: those of ``first`` (``_refine_corners``' first cornerSubPix) that pass the partial
    checks of a tracked board. A grid in the wrong 180-degree order puts every corner's saddle
    and every square on the wrong colour (boards whose ends differ), so it keeps none."""
    h, w = gray.shape
    start = np.asarray(corners_px, np.float64).reshape(-1, 2) if first is None else first[0]
    ordered, _ = order_corners(start, gray, board, previous_px)
    sc = _track_scales(ordered, board, gray.shape)
    inner = _inside(ordered, w, h, sc["border"])
    # The first cornerSubPix serves where every corner is inside (its limits are recomputed
    # in board order); near the border the inner ones are refined afresh, as when tracking.
    refined = (ordered, None, None) if first is not None and inner.all() else None
    partial, _ = _follow_partial(gray, ordered, inner, _grid_points(board), board,
                                 subpix_window_px, sc, max_grid_deviation, "partial", refined)
    if partial is None:
        return None, "inconsistent"
    return partial, "partial"


# findChessboardCorners runs first on the image shrunk to this long side (its cost grows with
# the pixels; 640x480 is left as it is), then at full size with FAST_CHECK where that fails;
# the corners are refined at full size either way.
DETECT_LONG_SIDE_PX = 960


def _find_on_pyramid(gray: np.ndarray, pattern, flags: int, full_size: bool = True):
    """findChessboardCorners on a shrunk image (corners in full-size pixels), else full size
    (unless ``full_size`` is False)."""
    scale = DETECT_LONG_SIDE_PX / max(gray.shape)
    if scale < 1.0:
        small = cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        found, corners = cv2.findChessboardCorners(small, pattern, None, flags)
        if found:
            f = np.array([gray.shape[1] / small.shape[1], gray.shape[0] / small.shape[0]])
            return True, (corners.reshape(-1, 2) + 0.5) * f - 0.5
        if not full_size:
            return False, None
        flags |= cv2.CALIB_CB_FAST_CHECK
    return cv2.findChessboardCorners(gray, pattern, None, flags)


# While no board is followed, a quick detector looks for it: findChessboardCorners with the
# fast check, without adaptive threshold, on the image shrunk to at most half size and
# QUICK_LONG_SIDE_PX. On the realistic 1080x1920 render (exposure and white-balance drift,
# blur, a hand) it found 16 of the 18 boards plain OpenCV finds at half size (17 with adaptive
# threshold, at 4x the cost on frames with a partly hidden board: ~50 ms against ~190 ms at
# 640x360 on the loaded test machine). Frames it misses wait; once a board is found they are
# tracked backwards from it; the full detector runs now and then (DEEP_SEARCH_EVERY).
QUICK_FIND_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
QUICK_SCALE = 0.5
QUICK_LONG_SIDE_PX = 960
# Squares at least this size (px) in the shrunk image when the board's size is known.
QUICK_MIN_SQUARE_PX = 16.0


def quick_detect_corners(
    gray: np.ndarray,
    board: dict,
    subpix_window_px: int = 5,
    max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC,
    scale: float | None = None,
) -> tuple[np.ndarray | None, str]:
    """Corners of a whole board found on a shrunk image, refined at full size.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    board : dict
    subpix_window_px, max_grid_deviation
        As in ``detect_corners``.
    scale : float, optional
        Shrink factor (<= 1); by default ``QUICK_SCALE``, less for images whose long side
        exceeds twice ``QUICK_LONG_SIDE_PX``.

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        In board order (``order_corners`` without a previous frame).
    method : str
        ``"quick"``, or ``"not_found"`` (also when a check fails).

    Notes
    -----
    ``cv2.findChessboardCorners`` with ``QUICK_FIND_FLAGS`` on ``cv2.resize`` (area) of the
    frame, then ``refine_corners`` from the corners scaled up, ``order_corners`` and
    ``board_squares_pattern_ok``. A miss costs little; it never decides that a frame has
    no board (see ``extract_corners``).
    """
    h, w = gray.shape
    if scale is None:
        scale = min(QUICK_SCALE, QUICK_LONG_SIDE_PX / max(h, w))
    scale = float(min(1.0, scale))
    small = gray if scale >= 1.0 else cv2.resize(gray, None, fx=scale, fy=scale,
                                                 interpolation=cv2.INTER_AREA)
    found, corners = cv2.findChessboardCorners(small, board_pattern(board), None, QUICK_FIND_FLAGS)
    if not found:
        return None, "not_found"
    f = np.array([w / small.shape[1], h / small.shape[0]])
    # Pixel centres: small pixel i covers full pixels [s i, s (i + 1)), centre s (i + 0.5) - 0.5.
    corners = (corners.reshape(-1, 2) + 0.5) * f - 0.5
    grid = _grid_points(board)
    sc = _track_scales(corners, board, gray.shape)
    refined = refine_corners(gray, corners, board, subpix_window_px, max_grid_deviation)
    if refined is not None and _inside(refined, w, h, sc["border"]).all():
        ordered, _ = order_corners(refined, gray, board)
        H, _ = cv2.findHomography(grid, ordered.astype(np.float32), 0)
        if (H is not None and board_squares_pattern_ok(gray, H, board, MIN_PATTERN_CONTRAST)
                and _saddle_ok(gray, H, ordered, grid, border_ok=True).all()):
            return ordered, "quick"
    # A hand over some corners or squares, or corners at the border (OpenCV still found the
    # grid): keep the corners that agree with their neighbours and show the chessboard's
    # saddle, checked as a tracked board partly hidden.
    ordered, _ = order_corners(corners if refined is None else refined, gray, board)
    partial, _ = _follow_partial(gray, ordered, _inside(ordered, w, h, sc["border"]), grid,
                                 board, subpix_window_px, sc, max_grid_deviation, "partial")
    if partial is None:
        return None, "not_found"
    return partial, "quick"
