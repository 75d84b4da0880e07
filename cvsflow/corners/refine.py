"""Refining and checking a candidate chessboard grid: sub-pixel corners and the board's looks.

cornerSubPix with a window adapted to the squares and to the edges' blur
(``refine_corners``, ``edge_blur_px``), the square-colour check (``board_squares_pattern_ok``),
the saddle check of each corner, and keeping the consistent part of a partly seen board
(``_follow_partial``). Shared by the detector (:mod:`cvsflow.corners.detect`) and the tracker
(:mod:`cvsflow.corners.track`).
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
    _keep_consistent,
    _median,
    _neighbour_pairs,
    _pair_distances,
    _spacing_from_pairs,
    _subpix_window,
    grid_deviation,
    keep_consistent_corners,
)

# A blurred corner spreads its saddle over a few blur sigmas; a window smaller than that sees
# only the flat middle and lands up to twice as far off (defocus of a fixed-focus webcam at
# 0.5 m: 0.49 px against 0.24 px). A refined board whose edges show a blur sigma with
# BLUR_WINDOW_SIGMAS * sigma above its window is refined once more with that window, capped
# at BLUR_WINDOW_MAX_FRAC of the spacing and short of the neighbouring corners; a sharp board
# (every frame of the demo) keeps its first window.
BLUR_WINDOW_SIGMAS = 3.5
BLUR_WINDOW_MAX_FRAC = 0.3
# Edge profiles count towards the blur estimate only with this light-dark step (grey levels).
BLUR_MIN_EDGE_CONTRAST = 20.0


# cornerSubPix in video frames: two iterations. Each iteration solves for the point where the
# window's gradients are orthogonal to their offsets, which for a corner inside the window is
# the corner up to the image's noise; the second only re-centres the window. Started 1 to 3.5
# px from the true corner on the realistic 640x480 and 1280x720 renders (H.264, blur, noise),
# two iterations are as close to the truth as 30 at 0.001 px (median 0.119 / 0.117 px, p95
# 0.266 / 0.291 px, against 0.120 / 0.118 and 0.268 / 0.289) at half the cost
# (0.13 against 0.25 ms for a 640x480 frame's 44 corners, 0.40 against 0.80 ms at 720p).
# Calibration stills keep ``cvsflow.board.model.SUBPIX_CRITERIA``.
VIDEO_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 2, 0.001)


def _clip_into(points_px: np.ndarray, gray: np.ndarray) -> np.ndarray | None:
    """Points (N, 2) clipped into the image for cornerSubPix (float32, (N, 1, 2)); None if NaN."""
    pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
    if not np.isfinite(pts).all():
        return None
    h, w = gray.shape[:2]
    # np.clip's bounds per column (finite points: the same values), straight into float32.
    out = np.empty((len(pts), 1, 2), np.float32)
    np.minimum(np.maximum(pts, 0.0), (w - 1.001, h - 1.001), out=out[:, 0, :], casting="same_kind")
    return out


def _subpix(gray: np.ndarray, points_px: np.ndarray, w: int) -> np.ndarray | None:
    """cornerSubPix from points clipped into the image; (N, 2) float32, or None."""
    pts = _clip_into(points_px, gray)
    if pts is None or not len(pts):
        return None
    return cv2.cornerSubPix(gray, pts, (w, w), (-1, -1), VIDEO_SUBPIX_CRITERIA).reshape(-1, 2)


def refine_corners(
    gray: np.ndarray,
    corners_px: np.ndarray,
    board: dict,
    subpix_window_px: int = 5,
    max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC,
) -> np.ndarray | None:
    """cornerSubPix from initial corners, then the grid-neighbour check (``detect_corners``).

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    corners_px : ndarray, shape (nx * ny, 2) or (nx * ny, 1, 2)
        Initial corners in grid order, pixels.
    board : dict
    subpix_window_px : int
        Largest cornerSubPix half window, pixels (see ``_subpix_window``).
    max_grid_deviation : float
        Largest distance of a refined corner from where its neighbours put it, as a share of
        its local grid spacing (``deviation_limit_px``); a corner beyond it is refined once
        more from that prediction.

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        Refined corners in the order given; None when a corner still deviates.
    """
    return _refine_corners(gray, corners_px, board, subpix_window_px, max_grid_deviation)[0]


def _refine_corners(gray, corners_px, board, subpix_window_px, max_grid_deviation,
                    no_retry=None):
    """``refine_corners``, and the corners of its first cornerSubPix (None where it failed)
    with their ``(deviation_limit_px, grid_deviation)``, which a caller that falls back to
    ``_follow_partial`` reuses. ``no_retry``: (N,) bool, corners whose deviation after the
    first cornerSubPix fails the refinement at once (no second cornerSubPix)."""
    corners = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
    w = _subpix_window(corners, board, subpix_window_px)
    first = _subpix(gray, corners, w)
    if first is None:
        return None, None
    corners = first.copy()
    predicted, deviation = grid_deviation(corners, board)
    # deviation_limit_px, with the neighbour distances kept for _refine_for_blur.
    pairs = _pair_distances(corners, board)
    limit = np.maximum(MIN_GRID_DEVIATION_PX,
                       max_grid_deviation * _spacing_from_pairs(pairs, board))
    first = (first, limit, deviation)
    bad = deviation > limit
    if bad.any():
        pairs = None  # the corners change
        if no_retry is not None and (bad & no_retry).any():
            return None, first
        retry = _subpix(gray, predicted[bad], w)
        if retry is None:
            return None, first
        corners[bad] = retry
        _, deviation = grid_deviation(corners, board)
        if (deviation > limit).any():
            return None, first
    return _refine_for_blur(gray, corners, board, w, limit, pairs), first


def edge_blur_px(gray: np.ndarray, corners_px: np.ndarray, board: dict) -> float:
    """Blur sigma of the board's square edges, px, from their profiles (0 when none is usable).

    Across a step edge of contrast C blurred by a Gaussian of sigma s, the steepest slope is
    C / (sqrt(2 pi) s). The edges are sampled across their midpoints between grid neighbours
    (away from the corners' saddles), every half pixel over 0.3 squares either side.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    corners_px : ndarray, shape (nx * ny, 2)
        Corners in grid order, pixels (NaN where unknown).
    board : dict

    Returns
    -------
    sigma_px : float
        Median over the edges with at least ``BLUR_MIN_EDGE_CONTRAST`` grey levels of step.
    """
    return _edge_blur(gray, corners_px, board)


def _edge_blur(gray, corners_px, board, length=None):
    """``edge_blur_px``; ``length``: the corners' ``_pair_distances`` where the caller has
    them (the same edges, in the same order)."""
    a, b = _neighbour_pairs(*board_pattern(board))[:2]
    uv = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
    p0, p1 = uv[a], uv[b]  # each edge's ends: along the rows, then the columns
    d = p1 - p0
    if length is None:
        dx, dy = d[:, 0], d[:, 1]
        length = np.sqrt(dx * dx + dy * dy)
    ok = np.isfinite(length) & (length > 4.0)
    if not ok.any():
        return 0.0
    mid, d, length = 0.5 * (p0[ok] + p1[ok]), d[ok], length[ok]
    half = 0.3 * _median(length)
    s = np.arange(-half, half + 1e-9, 0.5)
    # The samples' x and y maps, each contiguous for remap: mid + s * normal, the normal
    # (-dy, dx) / length.
    map_x = (mid[:, 0, None] + s * (-d[:, 1] / length)[:, None]).astype(np.float32)
    map_y = (mid[:, 1, None] + s * (d[:, 0] / length)[:, None]).astype(np.float32)
    prof = cv2.remap(gray, map_x, map_y, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    # (np.mean and ndarray.max as their reductions, without the wrappers: the same values.)
    step = np.abs(np.add.reduce(prof[:, -3:], axis=1) / 3 - np.add.reduce(prof[:, :3], axis=1) / 3)
    slope = np.maximum.reduce(np.abs(prof[:, 1:] - prof[:, :-1]), axis=1) / 0.5
    use = (step >= BLUR_MIN_EDGE_CONTRAST) & (slope > 0)
    if not use.any():
        return 0.0
    return _median(step[use] / (np.sqrt(2.0 * np.pi) * slope[use]))


def _refine_for_blur(gray, corners, board, w, limit, pairs=None):
    """Corners refined again with a window that covers the blur (``BLUR_WINDOW_SIGMAS``), when
    the first window was smaller and the result still agrees with its neighbours; else as given.
    ``pairs``: the corners' ``_pair_distances`` where the caller has them."""
    if pairs is None:
        pairs = _pair_distances(corners, board)
    d = pairs[np.isfinite(pairs)]
    if not len(d):
        return corners.astype(np.float64)
    cap = int(min(BLUR_WINDOW_MAX_FRAC * _median(d), np.floor((d.min() - 1.0) / 2.0)))
    if cap <= w:
        return corners.astype(np.float64)
    w_blur = min(cap, int(np.ceil(BLUR_WINDOW_SIGMAS * _edge_blur(gray, corners, board, pairs))))
    if w_blur <= w:
        return corners.astype(np.float64)
    again = _subpix(gray, corners, w_blur)
    if again is None or (grid_deviation(again, board)[1] > limit).any():
        return corners.astype(np.float64)
    return again.astype(np.float64)


# The checkerboard seen through the tracked corners must have this much contrast (grey levels)
# between its white and black squares, and every square on the right side of the midpoint.
MIN_PATTERN_CONTRAST = 20.0


@functools.lru_cache(maxsize=16)
def _square_samples(sx: int, sy: int) -> tuple[np.ndarray, np.ndarray]:
    """``board_squares_pattern_ok``'s sample points in grid coordinates, (3, sx * sy, 9)
    homogeneous, and which squares are black, (sx * sy,)."""
    jj, ii = np.mgrid[0:sy, 0:sx]
    a = np.array([-0.25, 0.0, 0.25])
    da, db = (g.ravel() for g in np.meshgrid(a, a))
    # Square (i, j) spans grid x in [i - 1, i], y in [j - 1, j] (corner 0 at (0, 0)).
    gx = (ii.ravel() - 0.5)[:, None] + da[None]
    gy = (jj.ravel() - 0.5)[:, None] + db[None]
    samples = np.stack([gx, gy, np.ones_like(gx)])
    black = (ii.ravel() + jj.ravel()) % 2 == 0
    for arr in (samples, black):
        arr.flags.writeable = False  # cached: shared by every call
    return samples, black


def board_squares_pattern_ok(
    gray: np.ndarray, H_img_grid: np.ndarray, board: dict, min_contrast: float = 20.0,
    corner_known: np.ndarray | None = None,
) -> bool:
    """Whether the board's squares seen through a homography have the chessboard's colours.

    Every square of the board (``squares_x`` by ``squares_y``, the outer ring included) whose
    centre region is inside the image is sampled at 9 points (25 % to 75 % across); square
    (i, j) must be darker than the midpoint of the black and white means when black
    (``i + j`` even), lighter when white, with white minus black at least ``min_contrast``.
    A grid shifted by one square fails on colour, one shifted by two on the outer ring (the
    white border of the sheet where black squares belong).

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    H_img_grid : ndarray, shape (3, 3)
        Homography from grid coordinates (corner k at (k % nx, k // nx)) to pixels.
    board : dict
    min_contrast : float
        Smallest mean white-minus-black difference, grey levels.
    corner_known : ndarray of bool, shape (nx * ny,), optional
        Corners seen; only squares all of whose inner corners are seen are sampled (a hand
        over the others).

    Returns
    -------
    ok : bool
    """
    sx, sy = int(board["squares_x"]), int(board["squares_y"])
    samples, black_all = _square_samples(sx, sy)
    p = np.einsum("ij,jsk->isk", H_img_grid, samples)
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = p[0] / p[2], p[1] / p[2]
    h, w = gray.shape
    inside = np.logical_and.reduce(
        (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1) & (p[2] > 0), axis=1)
    if corner_known is not None:
        # Square (i, j) has corners (i-1..i, j-1..j) where they exist (the index nx * ny,
        # always known, stands for those that do not).
        known = np.concatenate([np.asarray(corner_known, bool), _TRUE])
        inside &= np.logical_and.reduce(known[_square_corners(sx, sy)], axis=1)
    if not inside.any():
        return False
    # (The means are np.mean's: float64 sums divided by the count, without its wrapper.)
    if gray.flags.c_contiguous:  # one flat gather (the rounded pixels are exact in float64)
        flat = np.rint(v[inside])
        flat *= w
        flat += np.rint(u[inside])
        samples_in = gray.reshape(-1)[flat.astype(int)]
    else:
        samples_in = gray[np.rint(v[inside]).astype(int), np.rint(u[inside]).astype(int)]
    level = np.add.reduce(samples_in, axis=1, dtype=np.float64) / samples_in.shape[1]
    black = black_all[inside]
    n_black = int(np.count_nonzero(black))
    if n_black == len(black) or not n_black:
        return False
    lo, hi = level[black], level[~black]
    lo_mean, hi_mean = np.add.reduce(lo) / len(lo), np.add.reduce(hi) / len(hi)
    if hi_mean - lo_mean < min_contrast:
        return False
    mid = 0.5 * (hi_mean + lo_mean)
    return bool(np.maximum.reduce(lo) < mid < np.minimum.reduce(hi))


_TRUE = np.ones(1, bool)
_TRUE.flags.writeable = False


@functools.lru_cache(maxsize=16)
def _square_corners(sx: int, sy: int) -> np.ndarray:
    """(sx * sy, 4): the inner corners of each square (``_square_samples``' order), nx * ny
    where a square of the outer ring has none."""
    nx, ny = sx - 1, sy - 1
    jj, ii = np.mgrid[0:sy, 0:sx]
    out = []
    for di in (0, 1):
        for dj in (0, 1):
            ci, cj = ii.ravel() - 1 + di, jj.ravel() - 1 + dj
            ok = (ci >= 0) & (ci < nx) & (cj >= 0) & (cj < ny)
            out.append(np.where(ok, cj * nx + ci, nx * ny))
    idx = np.stack(out, axis=1)
    idx.flags.writeable = False  # cached: shared by every call
    return idx


# Smallest grey-level step between the light and the dark quadrants around a kept corner:
# this share of the board's contrast (median light minus median dark over all kept corners),
# and never below MIN_SADDLE_CONTRAST grey levels. A finger over part of a corner's squares
# puts skin (between the two) into a quadrant and fails it.
MIN_SADDLE_CONTRAST = 10.0
SADDLE_CONTRAST_FRAC = 0.5
# Sample points along the diagonals, as a share of a square from the corner.
SADDLE_RADII = (0.2, 0.4)


def _saddle_ok(gray, H_img_grid, corners_px, grid, border_ok=False, reference=None) -> np.ndarray:
    """(N,) bool: corner k shows dark squares on one diagonal, light on the other (its own
    colours: square (x+1, y+1) black when x + y is even), sampled along the diagonals at
    ``SADDLE_RADII`` squares from the corner, every sample of a quadrant on its side.
    ``border_ok``: a corner with a sample outside the image passes (a whole board's corner
    near the border, which the other checks passed: its saddle cannot be seen whole; on the
    realistic 1920x1080 render 4 of 8549 visible corners failed only for that); an (N,) bool
    array says it per row.
    ``reference``: (N,) bool, the rows whose levels set the board's contrast (default: every
    row with a finite corner)."""
    h, w = gray.shape
    points, n = _saddle_points(grid.tobytes(), grid.shape)
    n_off = len(points) // n - 1
    # The grid points and the samples around them in one call (each point on its own).
    t = cv2.perspectiveTransform(points, H_img_grid).reshape(-1, 2)
    q = t[n:].reshape(n, n_off, 2) - t[:n].reshape(n, 1, 2) + np.asarray(corners_px)[:, None, :]
    finite = np.isfinite(q)
    ok = np.logical_and.reduce(finite.reshape(n, -1), axis=1)
    # (Rows with a non-finite sample fail whatever their levels.)
    qi = np.rint(np.where(finite, q, 0.0)).astype(int)
    # 0 <= qi < (w, h) as one comparison: a negative int64 is above any size as uint64.
    in_image = np.logical_and.reduce((qi.view(np.uint64) < _as_uint64(w, h)).reshape(n, -1),
                                     axis=1)
    ok &= in_image
    np.minimum(np.maximum(qi, 0, out=qi), (w - 1, h - 1), out=qi)  # np.clip per column
    if gray.flags.c_contiguous:  # one flat gather where the rows are contiguous
        flat = qi[..., 1] * w
        flat += qi[..., 0]
        level = gray.reshape(-1)[flat].astype(np.float64)  # (N, M)
    else:
        level = gray[qi[..., 1], qi[..., 0]].astype(np.float64)
    half = n_off // 2  # each row's dark samples first (``_saddle_points``), then its light
    dark, light = level[:, :half], level[:, half:]
    corners_finite = np.isfinite(np.asarray(corners_px))
    known = ok & corners_finite[:, 0] & corners_finite[:, 1]
    if reference is not None:
        known &= np.asarray(reference, bool)
    contrast = 0.0
    if known.any():
        # The medians of the known rows' light and dark samples (``_median``'s), from one sort.
        seen = level[known]
        both = np.sort(seen.reshape(len(seen), 2, half).transpose(1, 0, 2).reshape(2, -1),
                       axis=1)
        m = both.shape[1]
        mid = 0.5 * (both[:, (m - 1) // 2] + both[:, m // 2])
        contrast = float(mid[1]) - float(mid[0])  # light minus dark
    need = max(MIN_SADDLE_CONTRAST, SADDLE_CONTRAST_FRAC * contrast)
    saddle = ok & (np.minimum.reduce(light, axis=1) - np.maximum.reduce(dark, axis=1) >= need)
    if border_ok is True or border_ok is False:
        return saddle | ~in_image if border_ok else saddle
    return saddle | (~in_image & np.asarray(border_ok, bool))


@functools.lru_cache(maxsize=16)
def _as_uint64(w: int, h: int) -> np.ndarray:
    """(w, h) as uint64, for ``_saddle_ok``'s bounds check."""
    out = np.array([w, h], np.uint64)
    out.flags.writeable = False  # cached: shared by every call
    return out


@functools.lru_cache(maxsize=16)
def _saddle_points(grid_bytes: bytes, shape: tuple) -> tuple[np.ndarray, int]:
    """``_saddle_ok``'s points, (N + N * M, 1, 2) float64: the N grid points, then the M
    samples around each along the diagonals, its dark ones first (the (1, 1) and (-1, -1)
    diagonal where square (x+1, y+1) is black, i.e. x + y even, else the other), then its
    light ones; and N."""
    grid = np.frombuffer(grid_bytes, dtype=np.float32).reshape(shape)
    off = np.array([[r * a, r * b] for a, b in ((1, 1), (-1, -1), (1, -1), (-1, 1))
                    for r in SADDLE_RADII])  # dark-or-light pairs: first 2 radii x 2 = 4
    half = len(off) // 2
    swapped = np.concatenate([off[half:], off[:half]])
    black_first = (grid[:, 0] + grid[:, 1]).astype(int) % 2 == 0
    pts = grid[:, None, :] + np.where(black_first[:, None, None], off[None], swapped[None])
    out = np.concatenate([grid.reshape(-1, 1, 2).astype(np.float64),
                          pts.reshape(-1, 1, 2).astype(np.float64)])
    out.flags.writeable = False  # cached: shared by every call
    return out, len(grid)


def _follow_partial(gray, p, inner, grid, board, subpix_window_px, sc, max_grid_deviation,
                    method="out_of_view", refined=None):
    """Refine the corners ``inner`` of a board partly hidden (image border, a hand), keep those
    consistent with their neighbours, check the squares they bound; NaN for the others.
    ``refined``: ``_refine_corners``' first cornerSubPix of ``p`` (every corner ``inner``),
    with its limits and deviations."""
    if inner.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    limit = deviation = None
    if refined is None:
        w = _subpix_window(p, board, subpix_window_px)
        refined = _subpix(gray, p[inner], w)
    else:
        refined, limit, deviation = refined
    if refined is None:
        return None, "lost"
    out = np.full((len(grid), 2), np.nan)
    out[inner] = refined
    out = _keep_consistent(out, board, max_grid_deviation, limit, deviation)
    known = np.isfinite(out).all(axis=1)
    if known.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    # A corner under a hand (a flat region) stays where it was put and agrees with its
    # neighbours: it must also show the chessboard's saddle (dark-light-dark-light around it).
    H, _ = cv2.findHomography(grid[known], out[known].astype(np.float32), 0)
    if H is None:
        return None, "lost"
    saddle = _saddle_ok(gray, H, out, grid)
    if not saddle[known].all():
        return _partial_without(gray, out, saddle, grid, board, sc, max_grid_deviation, method)
    # (else the corners are those H was fitted to)
    return _partial_checked(gray, out, known, H, grid, board, sc, method)


def _partial_without(gray, corners_px, keep, grid, board, sc, max_grid_deviation,
                     method="partial", consistent=False):
    """``_follow_partial``'s end for refined corners of which only ``keep`` may stay: those
    consistent with their kept neighbours (``consistent``: they are already, with the others
    among them), if the squares they bound have the right colours (``_partial_checked``)."""
    out = np.array(corners_px, dtype=np.float64)
    out[~keep] = np.nan
    if not consistent:
        out = keep_consistent_corners(out, board, max_grid_deviation)
    known = np.isfinite(out).all(axis=1)
    if known.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    H, _ = cv2.findHomography(grid[known], out[known].astype(np.float32), 0)
    if H is None:
        return None, "lost"
    return _partial_checked(gray, out, known, H, grid, board, sc, method)


@functools.lru_cache(maxsize=16)
def _ring_grid(nx: int, ny: int) -> np.ndarray:
    """Grid points one step outside the inner corners, (M, 2) float32: where a board's labels
    shifted by a square would have corners that a true board does not."""
    pts = [(i, j) for j in range(-1, ny + 1) for i in range(-1, nx + 1)
           if not (0 <= i < nx and 0 <= j < ny)]  # fmt: skip
    ring = np.array(pts, np.float32)
    ring.flags.writeable = False  # cached: shared by every call
    return ring


#: A partial board whose homography puts this many chessboard saddles just outside its inner
#: corners is labelled a square off (see ``_saddles_beyond``).
MAX_SADDLES_BEYOND = 2


def _saddles_beyond(gray, H, out, known, grid, board) -> int:
    """Chessboard saddles at the grid points just outside the board's inner corners.

    A true board has none there: one square beyond its last inner corner is the edge of its
    outer squares against the margin. A partial board whose corners were given labels one
    square off diagonally (a (1, 1) shift keeps every square's colour) has the true corners of
    its far rows there, while the near rows' labels fall on the margin, fail the saddle check
    and pass for hidden. Saddles are judged against the contrast of the kept corners."""
    ring = _ring_grid(*board_pattern(board))
    ring_px = cv2.perspectiveTransform(ring.reshape(-1, 1, 2), H).reshape(-1, 2)
    pts = np.concatenate([np.asarray(out, np.float64)[known], ring_px])
    grid_all = np.concatenate([grid[known], ring]).astype(np.float32, copy=False)
    reference = np.zeros(len(grid_all), bool)
    reference[:len(grid_all) - len(ring)] = True
    saddle = _saddle_ok(gray, H, pts, grid_all, reference=reference)
    return int(saddle[~reference].sum())


def _partial_checked(gray, out, known, H, grid, board, sc, method):
    """The corners ``known`` of ``out`` with ``method`` if they fit the homography ``H`` (fitted
    to them) within the tracker's RMS, bound squares of the right colours and show no board
    beyond them (``_saddles_beyond``: labels a square off), else lost."""
    fit = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H).reshape(-1, 2)
    e = fit[known] - out[known]
    ex, ey = e[:, 0], e[:, 1]
    # (np.mean of the rows' np.sum: the same two-term sums and pairwise total.)
    rms = np.sqrt(np.add.reduce(ex * ex + ey * ey) / len(e))
    if rms > sc["homography_rms"] or not board_squares_pattern_ok(
        gray, H, board, MIN_PATTERN_CONTRAST, corner_known=known
    ):
        return None, "lost"
    if _saddles_beyond(gray, H, out, known, grid, board) >= MAX_SADDLES_BEYOND:
        return None, "lost"
    return out, method
