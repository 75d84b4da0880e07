"""The tracker's fast path: corners predicted from the last two frames, refined, checked.

A board held by hand moves smoothly: at 30 fps the corners of the realistic renders move up to
30 px a frame, but their motion changes by a few pixels (the median second difference is 1.0
to 1.7 px, the 95th percentile 2.3 to 4.6 px, against cornerSubPix half windows of 6 to 18
px). So where the board was followed in the last two frames, each corner seen there is
predicted at constant velocity (scaled by the frame times: a dropped frame doubles the step)
and refined by cornerSubPix from there, without optical flow or a RANSAC homography.

``predict_corners`` accepts the result only where nothing changed: every corner seen in the
last frame refined within half its window of the prediction (a corner that lands farther
means the prediction missed, and the flow decides), agrees with its grid neighbours
(``grid_deviation`` within ``deviation_limit_px``) and shows its own chessboard saddle
(``_saddle_ok``), no corner seen before is lost, and none of those not seen (under a hand,
out of the image) shows a saddle where the board's homography puts it now (it came back).
Otherwise the caller runs the full tracker (:func:`cvsflow.corners.track.track_corners`),
which handles the change. Corner identity cannot slip: a corner is accepted only within half a
window (at most 0.15 of a square) of where its own track predicts it.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from cvsflow.board import board_pattern
from cvsflow.corners.grid import (
    MAX_GRID_DEVIATION_FRAC,
    MIN_GRID_DEVIATION_PX,
    MIN_TRACKED_CORNERS,
    SUBPIX_WINDOW_FRAC,
    TRACK_BORDER_FRAC,
    TRACK_BORDER_PX,
    _grid_points,
    _grid_points_cached,
    _inside,
    _median,
    _pair_distances,
    _spacing_from_pairs,
    grid_deviation,
    quadratic_deviation,
)
from cvsflow.corners.refine import (
    MAX_SADDLES_BEYOND,
    MIN_PATTERN_CONTRAST,
    _refine_for_blur,
    _ring_grid,
    _saddle_ok,
    _saddles_beyond,
    _subpix,
    board_squares_pattern_ok,
)

# A refined corner farther than this share of the cornerSubPix half window from its prediction
# means the prediction missed (the board jerked): the full tracker decides.
MAX_PREDICTION_MISS_FRAC = 0.5
# Frame-time ratios beyond this (a long gap after a short one) are not extrapolated.
MAX_STEP_RATIO = 3.0


def predict_corners(
    gray: np.ndarray,
    prev_px: np.ndarray,
    prev2_px: np.ndarray,
    step_ratio: float,
    board: dict,
    subpix_window_px: int = 5,
    max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC,
) -> tuple[np.ndarray | None, str]:
    """Corners of a frame predicted at constant velocity from the last two, if nothing changed.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
        This frame.
    prev_px, prev2_px : ndarray, shape (nx * ny, 2)
        The corners kept in the last frame and in the one before, board order, pixels (NaN
        where not seen: a hand, the image border).
    step_ratio : float
        (t - t_prev) / (t_prev - t_prev2): this frame's time step over the last one.
    board : dict
    subpix_window_px : int
        Largest cornerSubPix half window, pixels (``_subpix_window``).
    max_grid_deviation : float
        As in ``detect_corners``.

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        The refined corners, NaN where ``prev_px`` is NaN; None where anything changed (see
        the module's docstring) and the full tracker must decide.
    method : str
        As ``track_corners`` names it: ``"tracked"`` (every corner seen), ``"out_of_view"``
        (some of those not seen are outside the image now), ``"partial"`` (the others: a
        hand); ``"changed"`` with None.
    """
    if not 0.0 < step_ratio <= MAX_STEP_RATIO:
        return None, "changed"
    prev = np.asarray(prev_px, dtype=np.float64)
    finite = np.isfinite(prev)
    seen = finite[:, 0] & finite[:, 1]
    before = np.asarray(prev2_px, dtype=np.float64)
    predicted = prev + step_ratio * (prev - before)
    pairs = _pair_distances(prev, board)
    d = pairs[np.isfinite(pairs)]
    if not len(d):
        return None, "changed"
    spacing = _median(d)
    h, w = gray.shape
    border = max(TRACK_BORDER_PX, TRACK_BORDER_FRAC * spacing)
    # A corner seen last frame that the prediction puts within the border margin is dropped,
    # as the full tracker drops it (its cornerSubPix window would be cut off).
    inner = _inside(predicted, w, h, border)
    if not inner[seen].any():
        return None, "changed"
    new = seen & ~np.isfinite(predicted[:, 0])
    if new.any():
        # Seen last frame but not the frame before (it came back): the mean velocity of the
        # others.
        old = seen & ~new
        if not old.any():
            return None, "changed"
        predicted[new] = prev[new] + step_ratio * (
            np.add.reduce(prev[old] - before[old], axis=0) / np.count_nonzero(old))
        inner = _inside(predicted, w, h, border)
    keep = seen & inner
    n_keep = int(np.count_nonzero(keep))
    if n_keep < MIN_TRACKED_CORNERS:
        return None, "changed"
    grid = _grid_points(board)
    H = _four_point_homography(grid, predicted, keep)
    if H is None:
        return None, "changed"
    # cornerSubPix's half window, as _subpix_window gives it for these corners.
    win = int(max(2, min(max(subpix_window_px, int(round(SUBPIX_WINDOW_FRAC * spacing))),
                         np.floor((d.min() - 1.0) / 2.0))))
    # Corners not kept, where the board's homography puts them now (inside the margin):
    # refined with the others, one that shows its saddle again came back.
    whole = n_keep == len(keep)
    if whole:
        start = predicted
        back = guess = None
    else:
        missing = np.flatnonzero(~keep)
        guess = cv2.perspectiveTransform(grid[missing].reshape(-1, 1, 2), H).reshape(-1, 2)
        try_back = _inside(guess, w, h, border) & ~seen[missing]
        back = missing[try_back]
        start = np.concatenate([predicted[keep], guess[try_back]])
    refined = _subpix(gray, start, win)
    if refined is None:
        return None, "changed"
    miss = refined[:n_keep] - (predicted if whole else predicted[keep])
    mx, my = miss[:, 0], miss[:, 1]
    if np.maximum.reduce(mx * mx + my * my) > (MAX_PREDICTION_MISS_FRAC * win) ** 2:
        return None, "changed"  # the prediction missed: the flow decides
    out = np.full(prev.shape, np.nan)
    out[keep] = refined[:n_keep]
    checked = keep
    # One saddle check for the corners kept, those that may be back and, for a board not
    # seen whole, the grid points one square beyond its inner corners (``_saddles_beyond``:
    # saddles there mean the labels are a square off, a board that jumped a whole square
    # diagonally from its track; a whole board's square-colour check below catches that).
    probe = out
    if back is not None and len(back):
        probe = out.copy()
        probe[back] = refined[n_keep:]
    n = len(out)
    if whole:
        saddle = _saddle_ok(gray, H, probe, grid, border_ok=True)
        beyond = 0
    else:
        points, ring, inner_rows = _grid_and_ring(*board_pattern(board))
        ring_px = cv2.perspectiveTransform(ring.reshape(-1, 1, 2), H).reshape(-1, 2)
        reference = np.concatenate([keep, np.zeros(len(ring), bool)])
        # Samples outside the image: a corner passes (as the full tracker's), a ring point
        # shows no saddle.
        all_saddle = _saddle_ok(gray, H, np.concatenate([probe, ring_px]), points,
                                border_ok=inner_rows, reference=reference)
        saddle, beyond = all_saddle[:n], int(np.count_nonzero(all_saddle[n:]))
    if beyond >= MAX_SADDLES_BEYOND:
        return None, "changed"
    if back is not None and len(back):
        back = back[saddle[back]]
        if len(back):  # they came back: checked against their neighbours below
            out[back] = probe[back]
            checked = keep.copy()
            checked[back] = True
    gone = keep & ~saddle
    if gone.any():
        # A corner kept last frame shows no saddle now: a hand arrives over it. It goes, as the
        # full tracker drops it; the others must still be enough and agree with the grid.
        if whole and _saddles_beyond(gray, H, out, keep & ~gone, grid, board) >= (
                MAX_SADDLES_BEYOND):
            return None, "changed"
        out[gone] = np.nan
        keep = keep & ~gone
        checked = checked & ~gone
        if np.count_nonzero(keep) < MIN_TRACKED_CORNERS:
            return None, "changed"
    deviation = _deviation(out, board, checked)
    limit = None
    # Each corner's limit (deviation_limit_px) is at least that of the shortest grid step.
    if np.maximum.reduce(deviation) > max(MIN_GRID_DEVIATION_PX, max_grid_deviation * d.min()):
        limit = np.maximum(MIN_GRID_DEVIATION_PX,
                           max_grid_deviation * _spacing_from_pairs(pairs, board))
        off = np.zeros(len(out), bool)
        off[checked] = deviation > limit[checked]
        if (off & keep).any():
            return None, "changed"
        if off.any():
            # Only corners that came back are off their grid (a window cut by the border, a
            # hand's edge): they stay unseen, and the kept ones are checked without them.
            out[off] = np.nan
            checked = checked & ~off
            if (_deviation(out, board, checked) > limit[checked]).any():
                return None, "changed"
    if checked.all():
        if limit is None:
            limit = np.maximum(MIN_GRID_DEVIATION_PX,
                               max_grid_deviation * _spacing_from_pairs(pairs, board))
        if not board_squares_pattern_ok(gray, H, board, MIN_PATTERN_CONTRAST):
            return None, "changed"
        return _refine_for_blur(gray, out, board, win, limit), "tracked"
    # A corner dropped at the margin, or one not seen whose place is beyond it: out of view;
    # else the corners not seen are under a hand.
    at_border = (seen & ~inner).any() or (guess is not None and not _inside(guess, w, h, border).all())
    return out, "out_of_view" if at_border else "partial"


def _deviation(corners_px: np.ndarray, board: dict, rows: np.ndarray) -> np.ndarray:
    """``quadratic_deviation`` of the corners ``rows``, or ``grid_deviation``'s where one of
    them has too few known neighbours for the quadratic (next to a hand or the border)."""
    deviation = quadratic_deviation(corners_px, board)[rows]
    if np.isfinite(deviation).all():
        return deviation
    return grid_deviation(corners_px, board)[1][rows]


def _four_point_homography(grid: np.ndarray, points_px: np.ndarray, keep: np.ndarray):
    """The homography through the four outermost kept corners (extremes of x + y and x - y
    in the grid), or None when they do not span a quadrilateral.

    The fast path needs a homography only for the saddle samples' directions at a fifth and
    two fifths of a square from each corner, for the square-colour check and for where the
    corners not seen would be; through four corners it costs 2 microseconds, where the least
    squares fit of all corners costs 50 to 100, and its extrapolation to the corners not seen
    is about as good (on the realistic renders' partly hidden frames, median 0.7 / 3.6 / 0.5
    px against 1.6 / 3.6 / 0.7 px at 640x480 / 720p / portrait 1080p).
    """
    pick = _four_corners(grid.tobytes(), len(grid), np.asarray(keep, bool).tobytes())
    if pick is None:
        return None
    return cv2.getPerspectiveTransform(grid[pick], np.asarray(points_px[pick], dtype=np.float32))


@functools.lru_cache(maxsize=128)
def _four_corners(grid_bytes: bytes, n: int, keep_bytes: bytes):
    """``_four_point_homography``'s corners for a visibility mask (a board keeps its mask for
    many frames): their indices around the quadrilateral, or None when it is degenerate."""
    grid = np.frombuffer(grid_bytes, dtype=np.float32).reshape(n, 2)
    idx = np.flatnonzero(np.frombuffer(keep_bytes, dtype=bool))
    g = grid[idx]
    s, d = g[:, 0] + g[:, 1], g[:, 0] - g[:, 1]
    pick = idx[[s.argmin(), d.argmax(), s.argmax(), d.argmin()]]  # around the quadrilateral
    # Every turn around it the same way (twice each triangle's area over half a square).
    q = grid[pick].tolist()
    for k in range(4):
        (ax, ay), (bx, by), (cx, cy) = q[k], q[(k + 1) % 4], q[(k + 2) % 4]
        if (bx - ax) * (cy - ay) - (by - ay) * (cx - ax) <= 0.5:
            return None
    pick.flags.writeable = False  # cached: shared by every call
    return pick


@functools.lru_cache(maxsize=16)
def _grid_and_ring(nx: int, ny: int):
    """The inner corners' grid points followed by the ring one square beyond them (N + M, 2),
    the ring alone (M, 2), both float32, and (N + M,) bool, True on the inner corners' rows."""
    grid = _grid_points_cached(nx, ny)
    ring = _ring_grid(nx, ny)
    points = np.concatenate([grid, ring])
    inner_rows = np.arange(len(points)) < len(grid)
    for arr in (points, inner_rows):
        arr.flags.writeable = False  # cached: shared by every call
    return points, ring, inner_rows
