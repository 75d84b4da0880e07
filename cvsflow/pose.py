"""Chessboard corners in every video frame, and the board's pose in the camera (PnP) per frame.

Seed: "OpenCV's solvePnPRansac() function can be employed to extract the pose matrix P of the
camera relative to the calibration board ... It was found that a 5x6 chessboard does not have
enough features to guarantee accurate results from the ePnP method".

Tables are those of docs/contracts.md: ``corners.parquet`` (``extract_corners``) and
``poses_raw.parquet`` (``estimate_poses``).

Speed: the full detector (``detect_corners``) costs ~3 ms on a frame with a whole board and
~30 ms on one without (a board partly out of view is the worst case). ``extract_corners``
therefore follows the board from frame to frame (``track_corners``: optical flow on a shrunk
image, then refinement at full size and the grid, saddle and square-colour checks), keeps
following it while it is partly out of view or under a hand, looks for a lost board with a
quick detector on a shrunk image, backing off while it stays lost (the frames in between wait,
within a memory bound, and are tracked backwards from where it is found), and runs the full
detector (on the shrunk image) only right after the tracker loses the board and every
``DEEP_SEARCH_EVERY`` frames while lost. ``cvsflow.corners_fast`` runs it in chunks on several cores.
bench/bench_corners.py measures it per resolution against the renderer's truth.
"""

from __future__ import annotations

import collections
import functools
import logging
import math
import time
from collections.abc import Iterable

import cv2
import numpy as np
import pandas as pd

from cvsflow import transforms as tf
from cvsflow.board import CORNER_COLUMNS, CornerRows
from cvsflow.calibration import (
    SUBPIX_CRITERIA,
    board_object_points,
    board_pattern,
    order_corners,
)
from cvsflow.charuco import extract_charuco_corners, is_charuco
from cvsflow.errors import InputError

log = logging.getLogger(__name__)

# ADAPTIVE_THRESH and NORMALIZE_IMAGE cope with the uneven light and auto-exposure of a
# hand-held board. FAST_CHECK pays only where the board is absent: measured on a rendered
# 640x480 session it halves the time of a frame without a board (15 vs 30-50 ms) but adds
# ~1.5 ms to a frame with one (5.2 vs 3.6 ms), at equal recall (844 of 900 frames). So
# extract_corners uses it only when no board was found in the last few frames.
VIDEO_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
VIDEO_SEARCH_FLAGS = VIDEO_FIND_FLAGS | cv2.CALIB_CB_FAST_CHECK

POSE_COLUMNS = [
    "frame",
    "t_s",
    "valid",
    "rvec_0",
    "rvec_1",
    "rvec_2",
    "x_m",
    "y_m",
    "z_m",
    "roll_rad",
    "pitch_rad",
    "yaw_rad",
    "reproj_rms_px",
    "n_inliers",
    "n_corners",
]

# IPPE (Collins & Bartoli 2014) is the closed-form solution for a planar target: it returns
# both solutions of the planar ambiguity and keeps the one with the lower reprojection error.
# The 5x4 grid is planar, so the general EPnP (which the seed found not accurate enough on
# this board) and the iterative DLT start (unstable with few coplanar points) are the weaker
# choices. The LM refinement that follows is the seed's "Levenberg-Marquardt optimisation".
PNP_FLAG = cv2.SOLVEPNP_IPPE

# Fewer points than this leaves too little redundancy to trust a 6-dof pose.
MIN_INLIERS = 6

# extract_corners starts afresh (full detection, no state) at frame indices that are multiples
# of this: 5 s at 30 fps. Costs one full detection per 150 frames; lets a video be cut into
# chunks (one per core) whose tables join into exactly the single-pass table.
RESTART_EVERY_FRAMES = 150


# Every pixel threshold scales with the board's squares as the image shows them (the local
# spacing of the grid, ``local_spacing``), so the same checks hold at 640x480 and 1920x1080.
# cornerSubPix half window: this share of the median spacing when that exceeds the configured
# window (squares of ~33 px and more), never reaching a neighbouring corner.
SUBPIX_WINDOW_FRAC = 0.15
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
# Largest distance of a refined corner from where its grid neighbours put it, as a share of
# its local spacing (never below MIN_GRID_DEVIATION_PX). The neighbours' homography misses
# the lens's curvature by an amount that grows with the square size in pixels (k1 ~ -0.3 at
# the image edge: up to 0.04 of the spacing, measured at 640x480 to 1080x1920 with blur), and
# blur spreads a corner; a corner the
# detector put on the wrong feature is off by a good part of a square.
MAX_GRID_DEVIATION_FRAC = 0.08
MIN_GRID_DEVIATION_PX = 1.0


def _median(values: np.ndarray) -> float:
    """np.median of an array (same value), without its overhead (~10x on ~100 values)."""
    s = np.asarray(values).flatten()  # np.sort(values, axis=None) without its wrapper
    s.sort()
    n = len(s)
    return float(0.5 * (s[(n - 1) // 2] + s[n // 2]))


@functools.lru_cache(maxsize=16)
def _neighbour_pairs(nx: int, ny: int) -> tuple:
    """Grid neighbour pairs (corner a, corner b = its right, then lower neighbour), in the
    order of ``np.diff`` along rows, then columns; the number of row pairs; ``local_spacing``'s
    scatter indices (every pair's a and b for the rows, then for the columns) and its
    neighbour counts."""
    k = np.arange(nx * ny).reshape(ny, nx)
    ax, bx = k[:, :-1].ravel(), k[:, 1:].ravel()
    ay, by = k[:-1, :].ravel(), k[1:, :].ravel()
    a, b = np.concatenate([ax, ay]), np.concatenate([bx, by])
    nr = len(ax)
    # For corner k the sums run right, left, down, up neighbour, as local_spacing's did.
    scatter = np.concatenate([ax, bx, ay, by])
    count = np.bincount(scatter, minlength=nx * ny).astype(np.float64)
    for arr in (a, b, scatter, count):
        arr.flags.writeable = False  # cached: shared by every call
    return a, b, nr, scatter, count


def _pair_distances(corners_px: np.ndarray, board: dict) -> np.ndarray:
    """Distances between grid neighbours (rows, then columns), px; NaN where unknown."""
    a, b = _neighbour_pairs(*board_pattern(board))[:2]
    uv = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
    e = uv[b] - uv[a]
    ex, ey = e[:, 0], e[:, 1]
    return np.sqrt(ex * ex + ey * ey)  # (e * e).sum(axis=-1): the same two-term sums


def _neighbour_distances(corners_px: np.ndarray, board: dict) -> np.ndarray:
    """Finite distances between grid neighbours (rows, then columns), px."""
    d = _pair_distances(corners_px, board)
    return d[np.isfinite(d)]


def local_spacing(corners_px: np.ndarray, board: dict) -> np.ndarray:
    """Local grid spacing at each corner: the mean distance to its grid neighbours (px).

    Parameters
    ----------
    corners_px : ndarray, shape (nx * ny, 2)
        Corners in grid order, pixels (NaN where unknown).
    board : dict

    Returns
    -------
    spacing_px : ndarray, shape (nx * ny,)
        Mean distance to the up to four neighbours one grid step away, pixels; the median
        over the grid where a corner has no known neighbour.
    """
    return _spacing_from_pairs(_pair_distances(corners_px, board), board)


def _spacing_from_pairs(d: np.ndarray, board: dict) -> np.ndarray:
    """``local_spacing`` from the corners' ``_pair_distances``."""
    nx, ny = board_pattern(board)
    _, _, nr, scatter, count = _neighbour_pairs(nx, ny)
    both = np.concatenate([d[:nr], d[:nr], d[nr:], d[nr:]])
    ok = np.isfinite(both)
    if ok.all():
        return np.bincount(scatter, both, nx * ny) / count
    total = np.bincount(scatter, np.where(ok, both, 0.0), nx * ny)
    count = np.bincount(scatter, ok, nx * ny)
    with np.errstate(divide="ignore", invalid="ignore"):
        spacing = total / count
    finite = np.isfinite(spacing)
    fill = _median(spacing[finite]) if finite.any() else 1.0
    return np.where(finite, spacing, fill)


def _subpix_window(corners_px: np.ndarray, board: dict, max_window_px: int) -> int:
    """cornerSubPix half window: ``max_window_px`` (more for big squares), under half a square.

    A search window reaching a neighbouring corner pulls the estimate towards it, which
    matters for far boards whose squares are only a few pixels wide; squares much bigger than
    the window (large images, near boards) get ``SUBPIX_WINDOW_FRAC`` of their spacing, so
    blur that spreads a corner over more pixels still fits inside the window.
    """
    d = _neighbour_distances(corners_px, board)
    if not len(d):
        return int(max(2, max_window_px))
    wanted = max(max_window_px, int(round(SUBPIX_WINDOW_FRAC * _median(d))))
    return int(max(2, min(wanted, np.floor((d.min() - 1.0) / 2.0))))


def deviation_limit_px(corners_px: np.ndarray, board: dict,
                       max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC) -> np.ndarray:
    """Per-corner limit of ``grid_deviation``: a share of the local spacing, pixels, shape (N,).

    Parameters
    ----------
    corners_px : ndarray, shape (nx * ny, 2)
        Corners in grid order, pixels (NaN where unknown).
    board : dict
        Board description: ``squares_x``, ``squares_y`` (int) and ``square_m`` (m), see
        :func:`cvsflow.board.board_pattern`.
    max_grid_deviation : float
        Limit as a share of the local grid spacing (:func:`local_spacing`), dimensionless.

    Returns
    -------
    limit_px : ndarray, shape (nx * ny,)
        ``max(MIN_GRID_DEVIATION_PX, max_grid_deviation * local_spacing)``, pixels. A corner
        without known neighbours gets the share of the median spacing over the grid.
    """
    return np.maximum(MIN_GRID_DEVIATION_PX,
                      max_grid_deviation * local_spacing(corners_px, board))


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
    return cv2.cornerSubPix(gray, pts, (w, w), (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2)


def grid_deviation(corners_px: np.ndarray, board: dict) -> tuple[np.ndarray, np.ndarray]:
    """Distance of each corner from where its grid neighbours put it.

    For every corner, a homography is fitted (least squares) from board grid coordinates to
    the pixels of its neighbours within two grid steps (itself left out) and evaluated at the
    corner. Over two squares the lens's curvature is small (below 0.45 px for the demo lens
    at the image edge), so a larger deviation marks a corner that the detector misplaced.

    Parameters
    ----------
    corners_px : ndarray, shape (nx * ny, 2)
        Corners in grid order (OpenCV's or board order), pixels.
    board : dict

    Returns
    -------
    predicted_px : ndarray, shape (nx * ny, 2)
        Position predicted by the neighbours, pixels.
    deviation_px : ndarray, shape (nx * ny,)
        Distance between corner and prediction, pixels.
    """
    nx, ny = board_pattern(board)
    uv = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
    # NaN corners (dropped, hidden) predict nothing.
    finite = np.isfinite(uv)
    known = finite[:, 0] & finite[:, 1]
    n_known = int(np.count_nonzero(known))
    all_known = n_known == len(known)
    if all_known:
        weights, xy1, mono, a_inv_x, enough = _deviation_constants(nx, ny)
    else:
        weights, xy1, mono, a_inv_x, enough = _deviation_constants_known(nx, ny,
                                                                          known.tobytes())
        uv = np.where(known[:, None], uv, 0.0)
    # Conditioning as in Hartley's normalised DLT: centre and scale the pixels. (The means
    # are np.mean's: its sums divided by the count, without its wrapper.)
    if n_known:
        seen = uv if all_known else uv[known]
        centre = np.add.reduce(seen, axis=0) / n_known
        d = seen - centre
        dx, dy = d[:, 0], d[:, 1]
        scale = _SQRT2 / max(np.add.reduce(np.sqrt(dx * dx + dy * dy)) / n_known, 1e-9)
    else:
        centre, scale = np.zeros(2), 1.0
    u, v = ((uv - centre) * scale).T
    # Corner k's DLT system keeps only its neighbours' rows: the sum of their outer products
    # (normal equations). With X = (x, y, 1) a neighbour's two rows are (X, 0, -u X) and
    # (0, X, -v X), so the sum has the blocks [[A, 0, -U], [0, A, -V], [-U, -V, S]] of
    # A = sum X X', U = sum u X X', V = sum v X X', S = sum (u^2 + v^2) X X': one
    # (N, N) @ (N, 27) product. Its homography (h1, h2, h3) is taken with h33 = 1 (the
    # board's origin is in front of the camera, so h33, its projective depth, is not 0).
    # The first two block rows give h1 = A^-1 U h3, h2 = A^-1 V h3; the third, the 3x3 Schur
    # complement M = S - U A^-1 U - V A^-1 V with M h3 = 0, of which the first two rows fix
    # (h31, h32): the same solution as the 8x8 solve, at a fraction of its cost. A holds
    # grid coordinates only (the same for every frame with the same corners known), and is
    # singular exactly (integer entries) when the neighbours lie on a line: no prediction.
    n = len(u)
    sums = weights @ np.concatenate(
        [u[:, None] * mono, v[:, None] * mono, (u * u + v * v)[:, None] * mono], axis=1
    )
    blocks = sums.reshape(n, 3, 3, 3)
    UV, S = blocks[:, :2], blocks[:, 2]  # (n, 2, 3, 3): U and V; (n, 3, 3)
    # A^-1 (and A^-1 X_k) from the grid moments' adjugate, a_inv_x = (A^-1, A^-1 X_k).
    UVA = UV @ a_inv_x[:, None, :, :3]
    M = S - (UVA @ UV).sum(axis=1)
    m = M[:, :2].reshape(n, 6)
    m00, m01, m02, m10, m11, m12 = m.T
    m00m11, m01m10 = m00 * m11, m01 * m10
    det_m = m00m11 - m01m10
    # No prediction with fewer than four neighbours, or neighbours on a line (A singular), or
    # three of four on a line (M's 2x2 singular up to rounding: the homography is not fixed).
    well_posed = np.abs(det_m) > 1e-9 * (np.abs(m00m11) + np.abs(m01m10))
    with np.errstate(divide="ignore", invalid="ignore"):
        h3 = np.empty((n, 3))  # np.stack of the three columns
        np.subtract(m01 * m12, m11 * m02, out=h3[:, 0])
        np.subtract(m10 * m02, m00 * m12, out=h3[:, 1])
        h3[:, 2] = det_m
        # The prediction at X_k: (X_k' A^-1 U h3, X_k' A^-1 V h3) / (X_k' h3), h3 scaled by
        # det M (it cancels).
        puv = ((UV @ h3[:, None, :, None])[..., 0] * a_inv_x[:, None, :, 3]).sum(axis=2)
        predicted = puv / (xy1 * h3).sum(axis=1)[:, None] / scale + centre
    d = predicted - uv
    dx, dy = d[:, 0], d[:, 1]
    deviation = np.sqrt(dx * dx + dy * dy)
    # Fewer than four known neighbours leave the homography undetermined.
    ok = np.isfinite(deviation) & known & enough & well_posed
    return predicted, np.where(ok, deviation, np.inf)


_SQRT2 = np.sqrt(2.0)


def _grid_moment_inverse(a_flat: np.ndarray, xy1: np.ndarray):
    """Per corner, A^-1 and A^-1 X_k side by side, (N, 3, 4), and det A, (N,), from the grid
    moments A = sum X X' flattened, (N, 9). A is symmetric with integer entries, so its
    adjugate and determinant are exact; singular rows (det 0) hold zeros."""
    a, b, c, _, d, e, _, _, f = a_flat.T
    adj = np.stack([d * f - e * e, c * e - b * f, b * e - c * d,
                    c * e - b * f, a * f - c * c, b * c - a * e,
                    b * e - c * d, b * c - a * e, a * d - b * b], axis=1)
    det = a * adj[:, 0] + b * adj[:, 1] + c * adj[:, 2]
    singular = det == 0
    inv = adj / np.where(singular, 1.0, det)[:, None]
    inv[singular] = 0.0
    inv = inv.reshape(-1, 3, 3)
    return np.concatenate([inv, inv @ xy1[:, :, None]], axis=2), det


@functools.lru_cache(maxsize=16)
def _deviation_constants(nx: int, ny: int):
    """``grid_deviation``'s constants: neighbour weights (N, N), grid points (N, 3), their
    X X' (N, 9), and for every corner known the grid moments' inverse with A^-1 X_k (N, 3, 4)
    and whether the grid alone allows a prediction (N,) bool: at least four neighbours, not
    on a line (det A != 0)."""
    xy1, mono = _grid_monomials(nx, ny)
    weights = _neighbour_weights(nx, ny)
    a_inv_x, det = _grid_moment_inverse(weights @ mono, xy1)
    enough = (weights.sum(axis=1) >= 4) & (det != 0)
    for arr in (a_inv_x, enough):
        arr.flags.writeable = False  # cached: shared by every call
    return weights, xy1, mono, a_inv_x, enough


@functools.lru_cache(maxsize=64)
def _deviation_constants_known(nx: int, ny: int, known_bytes: bytes):
    """``_deviation_constants`` with only the corners ``known`` (a bool mask's bytes) as
    neighbours: a board partly out of view or under a hand keeps the same mask for a few
    frames, and ``keep_consistent_corners`` revisits masks."""
    weights, xy1, mono, _, _ = _deviation_constants(nx, ny)
    known = np.frombuffer(known_bytes, dtype=bool)
    weights = weights * known[None, :]
    a_inv_x, det = _grid_moment_inverse(weights @ mono, xy1)
    enough = (weights.sum(axis=1) >= 4) & (det != 0)
    for arr in (weights, a_inv_x, enough):
        arr.flags.writeable = False  # cached: shared by every call
    return weights, xy1, mono, a_inv_x, enough


def keep_consistent_corners(corners_px: np.ndarray, board: dict,
                            max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC) -> np.ndarray:
    """Drop, worst first, the corners off their grid neighbours until the rest agree.

    Parameters
    ----------
    corners_px : ndarray, shape (nx * ny, 2)
        Refined corners in board order, pixels; NaN where unknown.
    board : dict
    max_grid_deviation : float
        As in ``detect_corners`` (share of the local spacing).

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2)
        The input with dropped corners set to NaN (a hand over them, a border cutting their
        window); every kept corner within its limit of its kept neighbours' prediction.
    """
    return _keep_consistent(corners_px, board, max_grid_deviation)


def _keep_consistent(corners_px, board, max_grid_deviation, limit=None, deviation=None):
    """``keep_consistent_corners``; ``limit`` and ``deviation``: ``deviation_limit_px`` and
    ``grid_deviation`` of ``corners_px`` where the caller has them already."""
    out = np.array(corners_px, dtype=np.float64).reshape(-1, 2)
    # The limits from all the corners given: dropping one changes the local spacing little.
    if limit is None:
        limit = deviation_limit_px(out, board, max_grid_deviation)
    for _ in range(len(out)):
        finite = np.isfinite(out)
        known = finite[:, 0] & finite[:, 1]
        if not known.any():
            break
        if deviation is None:
            _, dev = grid_deviation(out, board)
        else:
            dev, deviation = deviation, None
        excess = np.where(known, dev / limit, 0.0)
        if np.maximum.reduce(excess) <= 1.0:
            break
        # Drop each corner that is the worst among its grid neighbours (a misplaced corner
        # pulls its neighbours' predictions too, so only the local worst is dropped; corners
        # far apart go in the same pass).
        near = _neighbour_mask(*board_pattern(board))
        neighbour_max = np.maximum.reduce(np.where(near, excess[None, :], 0.0), axis=1)
        worst = (excess > 1.0) & (excess >= neighbour_max)
        out[worst] = np.nan
    return out


@functools.lru_cache(maxsize=16)
def _grid_monomials(nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    """Grid points (x, y, 1) of the inner corners, (N, 3), and their X X' flattened, (N, 9)."""
    k = np.arange(nx * ny)
    xy1 = np.stack([k % nx, k // nx, np.ones_like(k)], axis=1).astype(np.float64)
    mono = (xy1[:, :, None] * xy1[:, None, :]).reshape(-1, 9)
    for a in (xy1, mono):
        a.flags.writeable = False  # cached: shared by every call
    return xy1, mono


@functools.lru_cache(maxsize=16)
def _neighbour_mask(nx: int, ny: int) -> np.ndarray:
    """``_neighbour_weights > 0``, (N, N) bool."""
    near = _neighbour_weights(nx, ny) > 0
    near.flags.writeable = False  # cached: shared by every call
    return near


@functools.lru_cache(maxsize=16)
def _neighbour_weights(nx: int, ny: int) -> np.ndarray:
    """(N, N) mask: corner j within two grid steps of corner k, j != k."""
    k = np.arange(nx * ny)
    di = np.abs(k[:, None] % nx - k[None, :] % nx)
    dj = np.abs(k[:, None] // nx - k[None, :] // nx)
    near = (di <= 2) & (dj <= 2)
    np.fill_diagonal(near, False)
    weights = near.astype(np.float64)
    weights.flags.writeable = False  # cached: shared by every call
    return weights


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
        Where OpenCV finds the grid but some corners fail the neighbour check (a hand over
        them), keep the others (``"partial"``) instead of counting the frame as not found.

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        Corner k at board point (k % nx, k // nx) * square_m (see
        ``cvsflow.calibration.order_corners``); with ``"partial"``, NaN for the corners
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
    The neighbour check catches both.
    """
    pattern = board_pattern(board)
    found, corners = _find_on_pyramid(gray, pattern, flags, full_size)
    if not found:
        return None, "not_found"
    refined, first = _refine_corners(gray, corners, board, subpix_window_px, max_grid_deviation)
    if refined is not None:
        return order_corners(refined, gray, board, previous_px)
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
    nx, ny = board_pattern(board)
    g = np.asarray(corners_px, dtype=np.float64).reshape(ny, nx, 2)
    p0 = np.concatenate([g[:, :-1].reshape(-1, 2), g[:-1].reshape(-1, 2)])
    p1 = np.concatenate([g[:, 1:].reshape(-1, 2), g[1:].reshape(-1, 2)])
    d = p1 - p0
    dx, dy = d[:, 0], d[:, 1]
    length = np.sqrt(dx * dx + dy * dy)
    ok = np.isfinite(length) & (length > 4.0)
    if not ok.any():
        return 0.0
    mid, d, length = 0.5 * (p0[ok] + p1[ok]), d[ok], length[ok]
    normal = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    half = 0.3 * _median(length)
    s = np.arange(-half, half + 1e-9, 0.5)
    pts = (mid[:, None, :] + s[None, :, None] * normal[:, None, :]).astype(np.float32)
    prof = cv2.remap(gray, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR,
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
    d = _pair_distances(corners, board) if pairs is None else pairs
    d = d[np.isfinite(d)]
    if not len(d):
        return corners.astype(np.float64)
    cap = int(min(BLUR_WINDOW_MAX_FRAC * _median(d), np.floor((d.min() - 1.0) / 2.0)))
    if cap <= w:
        return corners.astype(np.float64)
    w_blur = min(cap, int(np.ceil(BLUR_WINDOW_SIGMAS * edge_blur_px(gray, corners, board))))
    if w_blur <= w:
        return corners.astype(np.float64)
    again = _subpix(gray, corners, w_blur)
    if again is None or (grid_deviation(again, board)[1] > limit).any():
        return corners.astype(np.float64)
    return again.astype(np.float64)


# Tracking (extract_corners' fast path). Pyramidal Lucas-Kanade (Bouguet 2000) moves the
# previous frame's corners into the current frame; cornerSubPix and the checks of
# detect_corners then decide, as for a detected board. 21 px windows over 3 pyramid levels
# follow a corner moving up to ~80 px between frames.
LK_WINDOW_PX = 21
LK_LEVELS = 3
LK_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 20, 0.03)
# A board is tracked while at least this many of its corners are seen. A tracked frame counts
# as found only with every refined corner this far inside the image. The full detector needs
# the squares around each corner: on the demo render it found 2 of the 12 frames whose nearest
# corner is 3 to 5 px from the border, and none nearer.
MIN_TRACKED_CORNERS = 8
TRACK_BORDER_PX = 4.0
# Largest RMS (px) of the tracked corners about the board homography through them. The lens's
# departure from a homography over the demo board is below ~1.5 px; a corner tracked onto the
# wrong feature is off by a good part of a square.
MAX_TRACK_HOMOGRAPHY_RMS_PX = 2.5
# ... and these shares of the median square size in pixels where that is larger: the border
# margin (a cornerSubPix window cut by the border), the homography RMS (the lens's departure
# from a homography grows with the board's size in pixels), the LK window. LK's pyramid gets
# one level more per doubling of the image size over 640 px (motion in px grows with it).
TRACK_BORDER_FRAC = SUBPIX_WINDOW_FRAC
TRACK_HOMOGRAPHY_FRAC = 0.25
LK_WINDOW_FRAC = 0.5
LK_WINDOW_MAX_PX = 61
LK_MIN_SQUARE_PX = 12.0
LK_MAX_SHRINK = 3
LK_WINDOW_SHRUNK_PX = 11


def _track_scales(corners_px: np.ndarray, board: dict, shape: tuple[int, int]) -> dict:
    """Pixel thresholds of the tracker for a board of this size in an image of this shape."""
    d = _neighbour_distances(corners_px, board)
    spacing = _median(d) if len(d) else 0.0
    # Optical flow runs on the image shrunk by 2 ** lk_shrink, so that squares keep at least
    # LK_MIN_SQUARE_PX: its cost grows with the window's area, and the flow only has to land
    # within cornerSubPix's window (refined at full size afterwards).
    # (np.clip and np.floor as Python's min, max and math.floor: the same integer.)
    shrink = min(max(math.floor(float(np.log2(max(spacing, 1.0) / LK_MIN_SQUARE_PX))), 0),
                 LK_MAX_SHRINK)
    lk = int(min(LK_WINDOW_MAX_PX, max(LK_WINDOW_PX if not shrink else LK_WINDOW_SHRUNK_PX,
                                       round(LK_WINDOW_FRAC * spacing / 2 ** shrink))))
    lk += 1 - lk % 2  # odd
    extra = _extra_lk_levels(max(shape))
    return {
        "border": max(TRACK_BORDER_PX, TRACK_BORDER_FRAC * spacing),
        "homography_rms": max(MAX_TRACK_HOMOGRAPHY_RMS_PX, TRACK_HOMOGRAPHY_FRAC * spacing),
        "lk_window": lk,
        "lk_levels": max(2, LK_LEVELS + extra - shrink),
        "lk_shrink": shrink,
    }


@functools.lru_cache(maxsize=16)
def _extra_lk_levels(long_side_px: int) -> int:
    """LK pyramid levels added for an image of this long side (one per doubling over 640)."""
    return max(0, int(round(np.log2(long_side_px / 640.0)))) if long_side_px > 640 else 0
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
        known = np.append(np.asarray(corner_known, bool), True)
        inside &= known[_square_corners(sx, sy)].all(axis=1)
    if not inside.any():
        return False
    # (The means are np.mean's: float64 sums divided by the count, without its wrapper.)
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
    return bool(lo.max() < mid < hi.min())


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


def _grid_points(board: dict) -> np.ndarray:
    """Grid coordinates (k % nx, k // nx) of the inner corners, shape (N, 2), float32."""
    return _grid_points_cached(*board_pattern(board))


@functools.lru_cache(maxsize=16)
def _grid_points_cached(nx: int, ny: int) -> np.ndarray:
    k = np.arange(nx * ny)
    grid = np.stack([k % nx, k // nx], axis=1).astype(np.float32)
    grid.flags.writeable = False  # cached: shared by every call
    return grid


def track_corners(
    prev_gray: np.ndarray,
    gray: np.ndarray,
    prev_px: np.ndarray,
    board: dict,
    subpix_window_px: int = 5,
    max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC,
    hidden: np.ndarray | None = None,
) -> tuple[np.ndarray | None, str]:
    """Board corners of a frame from those of an earlier frame (optical flow, then checks).

    Parameters
    ----------
    prev_gray : ndarray, shape (H, W), uint8
        The earlier frame.
    gray : ndarray, shape (H, W), uint8
        This frame.
    prev_px : ndarray, shape (nx * ny, 2)
        Corners of the earlier frame in board order, pixels; corners outside the image (a
        board partly out of view) are predictions.
    board : dict
    subpix_window_px : int
        Largest cornerSubPix half window, pixels.
    max_grid_deviation : float
        As in ``detect_corners``.
    hidden : ndarray of bool, shape (nx * ny,), optional
        Corners a hand hid in the earlier frame. Where one of them is still off its grid
        neighbours after the first cornerSubPix, the hand is taken to be there still: the
        frame goes straight to the partial check, without the second cornerSubPix that
        rescues a corner the flow put a little off (it cannot rescue one under a hand).

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        With ``"tracked"``: the refined corners in board order. With ``"out_of_view"``: where
        the corners are (refined where inside the image, predicted elsewhere), to track from.
        None with ``"lost"``.
    method : str
        ``"tracked"``: every corner inside the image, refined, consistent with its grid
        neighbours, in the order the colours of the squares confirm (``order_corners``), and
        every square of the board of the right colour (``board_squares_pattern_ok``).
        ``"out_of_view"``: the board is followed but a corner is within the border margin
        (``TRACK_BORDER_PX`` or ``TRACK_BORDER_FRAC`` of the square size) of the border or
        outside (the frame has no whole board). ``"lost"``: any check failed; the caller
        falls back to ``detect_corners``.

    Notes
    -----
    ``cv2.calcOpticalFlowPyrLK`` (pyramidal Lucas-Kanade) on the corners inside the earlier
    image, a RANSAC homography (``cv2.findHomography``) from grid to image through them to
    place the others and to reject corners the flow lost, then ``refine_corners``. A one-square
    slip of the whole grid keeps its geometry; the colour checks catch it.
    """
    h, w = gray.shape
    grid = _grid_points(board)
    prev = np.asarray(prev_px, dtype=np.float32).reshape(-1, 2)
    seen = np.isfinite(prev).all(axis=1) & (
        (prev[:, 0] >= 0) & (prev[:, 0] <= w - 1) & (prev[:, 1] >= 0) & (prev[:, 1] <= h - 1)
    )
    if seen.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    sc = _track_scales(prev, board, gray.shape)
    f = 2 ** sc["lk_shrink"]
    start = prev[seen].reshape(-1, 1, 2)
    if f > 1:
        # Area-averaged pixel i of the shrunk image covers full pixels [f i, f (i + 1)).
        small_prev, small = _shrunk(prev_gray, f), _shrunk(gray, f)
        start = ((start + 0.5) / f - 0.5).astype(np.float32)
    else:
        small_prev, small = prev_gray, gray
    moved, status, _ = cv2.calcOpticalFlowPyrLK(
        small_prev, small, start, None,
        winSize=(sc["lk_window"], sc["lk_window"]), maxLevel=sc["lk_levels"],
        criteria=LK_CRITERIA,
    )
    if f > 1:
        moved = (moved + 0.5) * f - 0.5
    ok = status.ravel() == 1
    if ok.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    H, inliers = cv2.findHomography(
        grid[seen][ok], moved.reshape(-1, 2)[ok], cv2.RANSAC, sc["homography_rms"]
    )
    if H is None or inliers.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    p = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H).reshape(-1, 2)
    inlier = inliers.ravel() == 1
    p[np.flatnonzero(seen)[ok][inlier]] = moved.reshape(-1, 2)[ok][inlier]
    if not _inside(p, w, h, 0.0).all():
        return _follow_partial(gray, p, _inside(p, w, h, sc["border"]), grid, board,
                               subpix_window_px, sc, max_grid_deviation)
    corners, first = _refine_corners(gray, p, board, subpix_window_px, max_grid_deviation,
                                     hidden)
    if corners is None:  # a corner off its neighbours: hidden (a hand) or misplaced
        return _follow_partial(gray, p, np.ones(len(p), bool), grid, board, subpix_window_px,
                               sc, max_grid_deviation, "partial", first)
    inner = _inside(corners, w, h, sc["border"])
    if not inner.all():
        return _follow_partial(gray, corners, inner, grid, board, subpix_window_px, sc,
                               max_grid_deviation)
    # No order_corners here: the flow cannot mirror the grid, and a grid turned by 180 degrees
    # on a board whose ends differ puts every square on the wrong colour, which the square
    # check below refuses (on a board whose ends look alike nothing can tell, as in detection).
    H_fit, _ = cv2.findHomography(grid, corners.astype(np.float32), 0)
    if H_fit is None:
        return None, "lost"
    if not board_squares_pattern_ok(gray, H_fit, board, MIN_PATTERN_CONTRAST):
        # A hand over squares (and the corners it hides, which stay where they were put and
        # agree with their neighbours): keep the corners that show the chessboard's saddle.
        return _follow_partial(gray, corners, np.ones(len(corners), bool), grid, board,
                               subpix_window_px, sc, max_grid_deviation, "partial")
    return corners, "tracked"


# Shrunk copies of the last few images: a frame shrunk for the flow into it serves again for
# the flow out of it. Keyed by the image object itself (held here, so its id is not reused).
_SHRUNK: list = []


def _shrunk(gray: np.ndarray, f: int) -> np.ndarray:
    """``gray`` shrunk by the integer factor ``f`` (area average), from a small cache.

    A power of two is halved repeatedly: OpenCV's area resize by 1/2 is ~8x faster than by
    1/4 (0.12 against 0.95 ms for a 1080x1920 frame), and two 2x2 averages are the 4x4
    average (up to the rounding of the half-size image to 8 bits).
    """
    for image, k, small in _SHRUNK:
        if image is gray and k == f:
            return small
    if f > 2 and f % 2 == 0:
        small = cv2.resize(_shrunk(gray, f // 2), None, fx=0.5, fy=0.5,
                           interpolation=cv2.INTER_AREA)
    else:
        small = cv2.resize(gray, None, fx=1.0 / f, fy=1.0 / f, interpolation=cv2.INTER_AREA)
    _SHRUNK.append((gray, f, small))
    del _SHRUNK[:-6]  # the last three images, at up to two factors each
    return small


def _inside(p: np.ndarray, w: int, h: int, margin: float) -> np.ndarray:
    """(N,) bool: points at least ``margin`` px inside a w x h image."""
    return (p[:, 0] >= margin) & (p[:, 0] <= w - 1 - margin) & (p[:, 1] >= margin) & (
        p[:, 1] <= h - 1 - margin
    )


# Smallest grey-level step between the light and the dark quadrants around a kept corner:
# this share of the board's contrast (median light minus median dark over all kept corners),
# and never below MIN_SADDLE_CONTRAST grey levels. A finger over part of a corner's squares
# puts skin (between the two) into a quadrant and fails it.
MIN_SADDLE_CONTRAST = 10.0
SADDLE_CONTRAST_FRAC = 0.5
# Sample points along the diagonals, as a share of a square from the corner.
SADDLE_RADII = (0.2, 0.4)


def _saddle_ok(gray, H_img_grid, corners_px, grid) -> np.ndarray:
    """(N,) bool: corner k shows dark squares on one diagonal, light on the other (its own
    colours: square (x+1, y+1) black when x + y is even), sampled along the diagonals at
    ``SADDLE_RADII`` squares from the corner, every sample of a quadrant on its side."""
    h, w = gray.shape
    grid_pts, pts = _saddle_points(grid.tobytes(), grid.shape)
    n_off = pts.shape[0] // grid_pts.shape[0]
    ref = cv2.perspectiveTransform(grid_pts, H_img_grid)
    q = cv2.perspectiveTransform(pts, H_img_grid)
    q = q.reshape(-1, n_off, 2) - ref.reshape(-1, 1, 2) + np.asarray(corners_px)[:, None, :]
    finite = np.isfinite(q)
    n = len(q)
    ok = np.logical_and.reduce(finite.reshape(n, -1), axis=1)
    # (Rows with a non-finite sample fail whatever their levels.)
    qi = np.rint(np.where(finite, q, 0.0)).astype(int)
    ok &= np.logical_and.reduce(((qi >= 0) & (qi < (w, h))).reshape(n, -1), axis=1)
    np.minimum(np.maximum(qi, 0, out=qi), (w - 1, h - 1), out=qi)  # np.clip per column
    level = gray[qi[..., 1], qi[..., 0]].astype(np.float64)  # (N, M)
    half = n_off // 2  # the (1, 1) and (-1, -1) diagonal first, then the other
    black_first = ((grid[:, 0] + grid[:, 1]).astype(int) % 2 == 0)
    dark = np.where(black_first[:, None], level[:, :half], level[:, half:])
    light = np.where(black_first[:, None], level[:, half:], level[:, :half])
    corners_finite = np.isfinite(np.asarray(corners_px))
    known = ok & corners_finite[:, 0] & corners_finite[:, 1]
    contrast = _median(light[known]) - _median(dark[known]) if known.any() else 0.0
    need = max(MIN_SADDLE_CONTRAST, SADDLE_CONTRAST_FRAC * contrast)
    return ok & (np.minimum.reduce(light, axis=1) - np.maximum.reduce(dark, axis=1) >= need)


@functools.lru_cache(maxsize=16)
def _saddle_points(grid_bytes: bytes, shape: tuple) -> tuple[np.ndarray, np.ndarray]:
    """``_saddle_ok``'s grid points, (N, 1, 2), and its sample points around each, (N * M, 1,
    2): dark-or-light pairs along the diagonals, the (1, 1) and (-1, -1) ones first."""
    grid = np.frombuffer(grid_bytes, dtype=np.float32).reshape(shape)
    off = np.array([[r * a, r * b] for a, b in ((1, 1), (-1, -1), (1, -1), (-1, 1))
                    for r in SADDLE_RADII])  # dark-or-light pairs: first 2 radii x 2 = 4
    pts = grid[:, None, :] + off[None]  # (N, M, 2)
    out = (grid.reshape(-1, 1, 2).astype(np.float64), pts.reshape(-1, 1, 2).astype(np.float64))
    for arr in out:
        arr.flags.writeable = False  # cached: shared by every call
    return out


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
        out[~saddle] = np.nan
        out = keep_consistent_corners(out, board, max_grid_deviation)
        known = np.isfinite(out).all(axis=1)
        if known.sum() < MIN_TRACKED_CORNERS:
            return None, "lost"
        H, _ = cv2.findHomography(grid[known], out[known].astype(np.float32), 0)
        if H is None:
            return None, "lost"
    # (else the corners are those H was fitted to)
    fit = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H).reshape(-1, 2)
    rms = np.sqrt(np.mean(np.sum((fit[known] - out[known]) ** 2, axis=1)))
    if rms > sc["homography_rms"] or not board_squares_pattern_ok(
        gray, H, board, MIN_PATTERN_CONTRAST, corner_known=known
    ):
        return None, "lost"
    return out, method


# Tracked frames with some corners hidden (a hand; the image border) that keep the rest.
PARTIAL_METHODS = ("partial", "out_of_view")


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
# The search backs off while the board stays lost: it runs on the 1st, 2nd, 4th and 8th frame
# after the loss, then every SEARCH_EVERY_MAX frames (a board that comes back is found within
# that many frames and the frames before it are tracked backwards).
SEARCH_EVERY_MAX = 8
# ... and the full detector (on the image shrunk to DETECT_LONG_SIDE_PX) every
# DEEP_SEARCH_EVERY frames while no board is followed (and on the frames right after the
# tracker lost one, ``_relocate``). Not on the first frame of a session or restart: there the
# quick search misses mostly boards that are not there (a hand, the border; ~220 ms per
# 1280x720 frame for nothing on the realistic renders), and a whole board it misses is found
# DEEP_SEARCH_EVERY frames later and tracked back.
DEEP_SEARCH_EVERY = 32
# Most grey-image bytes kept waiting for a board (memory does not grow with the session:
# 48 frames at 1920x1080, 340 at 640x480); older waiting frames are decided without it.
MAX_PENDING_BYTES = 100 * 2**20


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
        if H is not None and board_squares_pattern_ok(gray, H, board, MIN_PATTERN_CONTRAST):
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


def _median_spacing(corners_px: np.ndarray, board: dict) -> float:
    """Median distance between grid neighbours, px (0 when none is known)."""
    d = _neighbour_distances(corners_px, board)
    return _median(d) if len(d) else 0.0


def _hand_hidden(corners_px, method):
    """The corners a hand hid in a frame followed as ``"partial"`` (for ``track_corners``'
    ``hidden``), else None."""
    if method != "partial" or corners_px is None:
        return None
    return ~np.isfinite(corners_px).all(axis=1)


class _CornerFollower:
    """extract_corners' per-frame decisions: track, search quickly (backing off), or detect.

    ``push`` takes frames in order and returns the ``(frame, t_s, corners_px or None,
    method)`` results that are decided, in frame order; ``finish`` returns the rest.
    Frames without a board are ``"not_found"`` when a detector looked at them and
    ``"not_searched"`` when the search's back-off skipped them (and no board could be
    tracked into them from a later frame).
    """

    def __init__(self, board, subpix_window_px, max_grid_deviation, max_gap, flags, track,
                 restart_every, keep_partial=True):
        self.keep_partial = keep_partial
        self.board = board
        self.subpix = subpix_window_px
        self.max_dev = max_grid_deviation
        self.max_gap = max_gap
        self.flags = flags
        self.track = track
        self.restart_every = restart_every
        self.pending = collections.deque()  # (frame, t_s, gray, searched) waiting for a board
        self.pending_bytes = 0
        self.cv_errors = 0  # OpenCV calls that raised (the frame went on without them)
        self._reset()

    def _guard(self, fn, fail_method, frame, *args):
        """``fn(*args)``; a cv2.error becomes ``(None, fail_method)``, logged and counted."""
        try:
            return fn(*args)
        except cv2.error as exc:
            self.cv_errors += 1
            log.warning("corners: frame %d: OpenCV failed in %s (%s); the frame goes on "
                        "without it", frame, fn.__name__, str(exc).strip().splitlines()[-1])
            return None, fail_method

    def _reset(self):
        # (gray, corners_px, frame, hidden) of the last frame the board was followed; hidden:
        # the corners a hand hid there (``track_corners``), None unless it was partial.
        self.state = None
        self.last_found = None  # (corners_px, frame): continuity for detect_corners
        self.lost_for = 0  # frames since the board was last followed (the search's back-off)
        self.spacing = 0.0  # median square size (px) of the board when last followed

    def _search_now(self) -> bool:
        n = self.lost_for
        return n <= 2 or (n <= SEARCH_EVERY_MAX and n & (n - 1) == 0) or n % SEARCH_EVERY_MAX == 0

    def _quick_scale(self):
        """Shrink factor of the quick search: squares of the last board >= QUICK_MIN_SQUARE_PX."""
        if self.spacing <= 0:
            return None
        return float(np.clip(QUICK_MIN_SQUARE_PX / self.spacing, 0.25, QUICK_SCALE))

    def push(self, frame, t_s, gray):
        out = []
        if self.restart_every and frame % self.restart_every == 0:
            out += self.finish()
            self._reset()
        if not self.track:
            out.append(self._detect(frame, t_s, gray))
            return out
        if self.state is not None and frame - self.state[2] <= self.max_gap:
            out.append(self._track(frame, t_s, gray, self.state))
            return out
        self.lost_for += 1
        if not self._search_now():
            self._wait(frame, t_s, gray, False, out)
            return out
        corners_px, method = self._guard(quick_detect_corners, "not_found", frame, gray,
                                         self.board, self.subpix, self.max_dev,
                                         self._quick_scale())
        if corners_px is None and self.lost_for % DEEP_SEARCH_EVERY == 0:
            # Now and then the full detector (on the shrunk image), for the whole boards the
            # quick one misses (low contrast, small squares).
            prev = self.flags if self.flags is not None else VIDEO_SEARCH_FLAGS
            corners_px, method = self._guard(detect_corners, "cv_error", frame, gray,
                                             self.board, self.subpix, None, prev,
                                             self.max_dev, False, self.keep_partial)
        if corners_px is None:
            self._wait(frame, t_s, gray, True, out)
            return out
        out += self._track_back(gray, corners_px, frame, method)
        self._keep(gray, corners_px, frame, found=True, method=method)
        out.append((frame, t_s, corners_px, method))
        return out

    def _wait(self, frame, t_s, gray, searched, out):
        """Keep a frame for tracking backwards; decide the oldest beyond the memory bound."""
        self.pending.append((frame, t_s, gray, searched))
        self.pending_bytes += gray.nbytes
        while self.pending_bytes > MAX_PENDING_BYTES and len(self.pending) > 1:
            out.append(self._undecided(*self.pending.popleft()))

    def _undecided(self, frame, t_s, gray, searched):
        self.pending_bytes -= gray.nbytes
        return frame, t_s, None, "not_found" if searched else "not_searched"

    def finish(self):
        """Decide the frames still waiting: the last one is searched (if the back-off skipped
        it; then, if the quick search fails, with the full detector) and the others tracked
        back from it; else no board was found to track from."""
        if self.pending and not self.pending[-1][3]:
            frame, t_s, gray, _ = self.pending.pop()
            self.pending_bytes -= gray.nbytes
            corners_px, method = self._guard(quick_detect_corners, "not_found", frame, gray,
                                             self.board, self.subpix, self.max_dev,
                                             self._quick_scale())
            if corners_px is None:
                # A board the quick search misses (a hand over it from the start, low
                # contrast) in a take, or a piece before a restart, shorter than
                # DEEP_SEARCH_EVERY frames: the full detector once, on the shrunk image.
                corners_px, method = self._guard(detect_corners, "cv_error", frame, gray,
                                                 self.board, self.subpix, None,
                                                 self.flags or VIDEO_SEARCH_FLAGS,
                                                 self.max_dev, False, self.keep_partial)
            if corners_px is not None:
                return self._track_back(gray, corners_px, frame, method) + [
                    (frame, t_s, corners_px, method)]
            self.pending.append((frame, t_s, gray, True))
            self.pending_bytes += gray.nbytes
        out = [self._undecided(*p) for p in self.pending]
        self.pending.clear()
        self.pending_bytes = 0
        return out

    def _keep(self, gray, corners_px, frame, found, method=None):
        self.state = (gray, corners_px, frame, _hand_hidden(corners_px, method))
        self.lost_for = 0
        self.spacing = _median_spacing(corners_px, self.board) or self.spacing
        if found:
            self.last_found = (corners_px, frame)

    def _track(self, frame, t_s, gray, ref):
        corners_px, method = self._guard(
            track_corners, "lost", frame, ref[0], gray, ref[1], self.board, self.subpix,
            self.max_dev, ref[3]
        )
        if method == "lost":
            return self._relocate(frame, t_s, gray)
        self._keep(gray, corners_px, frame, found=method == "tracked", method=method)
        return frame, t_s, self._published(corners_px, method), method

    def _relocate(self, frame, t_s, gray):
        """A frame the tracker lost the board in (at most ``max_gap`` frames after it was
        followed): the quick search, then the detector on the image shrunk to
        DETECT_LONG_SIDE_PX (the board is likely still there)."""
        self.lost_for += 1
        corners_px, method = self._guard(quick_detect_corners, "not_found", frame, gray,
                                         self.board, self.subpix, self.max_dev,
                                         self._quick_scale())
        if corners_px is None:
            return self._detect(frame, t_s, gray, full_size=False)
        self._keep(gray, corners_px, frame, found=True)
        return frame, t_s, corners_px, method

    def _published(self, corners_px, method):
        """The corners a tracked frame puts in the table (None: not found)."""
        if method == "tracked" or (self.keep_partial and method in PARTIAL_METHODS):
            return corners_px
        return None

    def _detect(self, frame, t_s, gray, full_size=True):
        prev = None
        if self.last_found is not None and frame - self.last_found[1] <= self.max_gap:
            prev = self.last_found[0]
        flags = self.flags
        if flags is None:
            flags = VIDEO_FIND_FLAGS if prev is not None else VIDEO_SEARCH_FLAGS
        corners_px, method = self._guard(detect_corners, "cv_error", frame, gray, self.board,
                                         self.subpix, prev, flags, self.max_dev, full_size,
                                         self.keep_partial)
        if corners_px is not None:
            self._keep(gray, corners_px, frame, found=True, method=method)
        return frame, t_s, corners_px, method

    def _track_back(self, gray, corners_px, frame, found_by=None):
        """Results of the waiting frames, tracked backwards from a frame with the board (found
        by the method ``found_by``); where that fails, the detector once (the board may have been whole
        there), then nothing."""
        pending, self.pending = list(self.pending), collections.deque()
        self.pending_bytes = 0
        ref = (gray, corners_px, frame, _hand_hidden(corners_px, found_by))
        out = []
        tried_detect = False
        for f, t_s, g, searched in reversed(pending):
            result = None
            if ref[2] - f <= self.max_gap:
                px, method = self._guard(track_corners, "lost", f, ref[0], g, ref[1],
                                         self.board, self.subpix, self.max_dev, ref[3])
                if method != "lost":
                    ref = (g, px, f, _hand_hidden(px, method))
                    result = (f, t_s, self._published(px, method), method + "_back")
                elif not tried_detect:
                    tried_detect = True
                    px, method = self._guard(detect_corners, "cv_error", f, g, self.board,
                                             self.subpix, None,
                                             self.flags or VIDEO_SEARCH_FLAGS, self.max_dev,
                                             False, self.keep_partial)
                    if px is not None:
                        ref = (g, px, f, _hand_hidden(px, method))
                    result = (f, t_s, px, method)
            if result is None:
                result = (f, t_s, None, "not_found" if searched else "not_searched")
            out.append(result)
        return out[::-1]


def extract_corners(
    frames: Iterable[tuple[int, float, np.ndarray]],
    board: dict,
    subpix_window_px: int = 5,
    n_frames: int | None = None,
    log_every: int = 300,
    flags: int | None = None,
    max_continuity_gap: int = 3,
    max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC,
    track: bool = True,
    restart_every: int | None = RESTART_EVERY_FRAMES,
    keep_partial: bool = True,
) -> pd.DataFrame:
    """Chessboard corners of every video frame, the same physical corner under the same index.

    Parameters
    ----------
    frames : iterable of (int, float, ndarray)
        ``(frame, t_s, gray)``: frame index, video time (s) and 8-bit grayscale image (H, W),
        e.g. ``cvsflow.io.media.iter_video_gray``.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m); with ``type: charuco`` (and
        ``marker_m``, ``dictionary``) ``cvsflow.charuco.extract_charuco_corners`` makes the
        table instead (the tracking arguments do not apply).
    subpix_window_px : int
        Largest cornerSubPix half window, pixels (shrunk for far boards, see ``_subpix_window``).
    n_frames : int, optional
        Number of frames expected, for progress messages only.
    log_every : int
        Log progress every this many frames.
    flags : int, optional
        ``findChessboardCorners`` flags for every frame. By default adaptive threshold and
        normalisation, plus FAST_CHECK when no board was found in the last
        ``max_continuity_gap`` frames.
    max_continuity_gap : int
        For boards whose ends look alike: the previous found frame is used for temporal
        continuity only if at most this many frames back.
    max_grid_deviation : float
        A frame with a corner farther than this share of its local grid spacing from where
        its grid neighbours put it, even after a second refinement, counts as not found (see
        ``detect_corners``).
    track : bool
        Follow the board from the last frame where it was seen (``track_corners``) and run the
        full detector only where that fails; False runs ``detect_corners`` on every frame.
    restart_every : int or None
        Frames whose index is a multiple of this start afresh: no tracking state, no
        continuity, full detection. A frame's result then depends only on the frames since the
        last such index, so a video cut into chunks at multiples of it
        (``cvsflow.corners_fast``) gives exactly the table of one pass. None: never.
    keep_partial : bool
        Frames where the tracked board is partly hidden (a hand over it: ``partial``; the
        image border: ``out_of_view``) keep the corners that pass their local checks, with
        their indices, as do frames where the detector finds the grid but some corners fail
        the neighbour check (``partial``: a hand over the board with no full view before);
        False counts them as not found (the former table).

    Returns
    -------
    corners : DataFrame
        ``frame`` (int64), ``t_s`` (float64, s), ``found`` (bool), ``corner`` (int64),
        ``u_px``, ``v_px`` (float64, distorted pixels). A found frame has one row per inner
        corner it keeps (all of them, or with ``keep_partial`` those of a partly hidden board),
        corner k at board point (k % nx, k // nx) * square_m; a frame without a board
        has one row with ``corner = -1`` and NaN pixels. ``attrs`` holds counts:
        ``n_frames``, ``n_found``, ``order_methods`` (dict method -> frames: ``tracked``,
        ``out_of_view`` (followed partly out of the image), ``partial`` (a hand over it),
        ``quick`` (the quick search), ``*_back`` (tracked backwards from a later frame),
        ``detect_corners``' methods for frames where the full detector ran; without a board:
        ``not_found`` (a detector looked), ``not_searched`` (the search's back-off skipped
        the frame and no board could be tracked into it), ``inconsistent``, ``cv_error``).

    Raises
    ------
    InputError
        A frame that is not a 2-D uint8 image.
    """
    if is_charuco(board):  # the markers name each corner: every frame detected on its own
        return extract_charuco_corners(frames, board, subpix_window_px, n_frames, log_every,
                                       keep_partial)
    rows = CornerRows(int(np.prod(board_pattern(board))))
    methods: dict[str, int] = {}
    follower = _CornerFollower(board, subpix_window_px, max_grid_deviation,
                               max_continuity_gap, flags, track, restart_every, keep_partial)
    t_start = time.perf_counter()
    n_done = n_found = 0

    def record(results):
        nonlocal n_found
        for frame, t_s, corners_px, method in results:
            methods[method] = methods.get(method, 0) + 1
            n_found += corners_px is not None
            rows.add(frame, t_s, corners_px)

    for frame, t_s, gray in frames:
        gray = np.asarray(gray)
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise InputError(
                f"video frame {frame}: expected an 8-bit grayscale image, got dtype "
                f"{gray.dtype}, shape {gray.shape}"
            )
        record(follower.push(int(frame), float(t_s), gray))
        n_done += 1
        if log_every and n_done % log_every == 0:
            rate = n_done / max(time.perf_counter() - t_start, 1e-9)
            of_total = f" of {n_frames}" if n_frames else ""
            log.info(
                "corners: %d%s frames done, board found in %d (%.1f frames/s)",
                n_done,
                of_total,
                n_found,
                rate,
            )
    record(follower.finish())
    elapsed = time.perf_counter() - t_start
    if n_done == 0:
        raise InputError("video: no frames to extract corners from (expected at least one)")
    corners = rows.table()
    corners.attrs = {"n_frames": n_done, "n_found": n_found, "order_methods": methods,
                     "n_cv_errors": follower.cv_errors}
    if follower.cv_errors:
        log.warning("corners: %d OpenCV calls failed (frames went on without them)",
                    follower.cv_errors)
    log.info(
        "corners: board found in %d of %d frames (%.1f %%), %.1f frames/s; order decided by %s",
        n_found,
        n_done,
        100.0 * n_found / n_done,
        n_done / max(elapsed, 1e-9),
        methods,
    )
    if n_done - n_found:
        log.warning("corners: %d frames without a board kept as found=False", n_done - n_found)
    if methods.get("inconsistent"):
        log.warning(
            "corners: %d frames had a corner off its grid neighbours by more than %.2f of "
            "its local square size after refinement; counted as not found",
            methods["inconsistent"],
            max_grid_deviation,
        )
    if methods.get("unresolved"):
        log.warning(
            "corners: %d frames had an undecidable 180-degree corner order (board ends alike, "
            "no recent previous frame); OpenCV's order kept",
            methods["unresolved"],
        )
    return corners


def summarise_corners(corners: pd.DataFrame, timing: dict | None = None) -> dict:
    """The corners stage's summary (corners_summary.yaml): counts, no wall times.

    Parameters
    ----------
    corners : DataFrame
        corners.parquet table with ``extract_corners``' ``attrs``.
    timing : dict, optional
        ``cvsflow.io.media.video_timing`` of the video.

    Returns
    -------
    summary : dict
        ``n_frames_decoded``, ``n_found``, ``found_share``, ``frames_by_method`` (method ->
        frames: how each frame was decided; ``not_found``, ``not_searched``,
        ``inconsistent``, ``cv_error`` are the reasons a frame has no board),
        ``n_cv_errors``, ``corners_per_found_frame``
        (min, median, max); with ``timing``: ``n_frames_header``, ``n_frames_demuxed``,
        ``n_dropped``, ``dropped_gaps`` (``[after_frame, missing]``), ``period_s`` (median),
        ``period_min_s``, ``period_max_s``.
    """
    per_frame = corners.groupby("frame")["found"].first()
    n_per = corners[corners["found"]].groupby("frame").size()
    attrs = corners.attrs
    out = {
        "n_frames_decoded": int(len(per_frame)),
        "n_found": int(per_frame.sum()),
        "found_share": float(per_frame.mean()) if len(per_frame) else 0.0,
        "frames_by_method": {str(k): int(v) for k, v in
                             sorted(attrs.get("order_methods", {}).items())},
        "n_cv_errors": int(attrs.get("n_cv_errors", 0)),
        "corners_per_found_frame": [int(n_per.min()), float(n_per.median()), int(n_per.max())]
        if len(n_per) else [0, 0.0, 0],
    }
    if timing is not None:
        dt = np.diff(np.asarray(timing["t_s"], dtype=np.float64))
        out.update({
            "n_frames_header": int(timing["n_frames_header"]),
            "n_frames_demuxed": int(timing["n_frames"]),
            "n_dropped": int(timing["n_dropped"]),
            "dropped_gaps": [[int(a), int(b)] for a, b in timing["gaps"]],
            "period_s": float(timing["period_s"]),
            "period_min_s": float(dt.min()) if len(dt) else 0.0,
            "period_max_s": float(dt.max()) if len(dt) else 0.0,
        })
    return out


def _check_corners_table(corners: pd.DataFrame) -> None:
    """InputError unless the table has the corners.parquet columns."""
    missing = [c for c in CORNER_COLUMNS if c not in corners.columns]
    if missing:
        raise InputError(
            f"corners table: missing columns {missing}; expected {CORNER_COLUMNS} "
            "(docs/contracts.md corners.parquet)"
        )


def estimate_poses(
    corners: pd.DataFrame,
    K: np.ndarray,
    dist: np.ndarray,
    board: dict,
    ransac_reproj_px: float = 3.0,
    ransac_iterations: int = 200,
    ransac_confidence: float = 0.999,
    seed: int = 0,
) -> pd.DataFrame:
    """Pose T_C_B of the board in the camera for every frame of a corners table.

    Parameters
    ----------
    corners : DataFrame
        corners.parquet table (see ``extract_corners``): ``frame, t_s, found, corner, u_px,
        v_px``.
    K : ndarray, shape (3, 3)
        Camera matrix, pixels.
    dist : ndarray, shape (5,)
        Distortion [k1, k2, p1, p2, k3] (OpenCV).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m).
    ransac_reproj_px : float
        RANSAC inlier threshold, pixels.
    ransac_iterations : int
        RANSAC iterations.
    ransac_confidence : float
        RANSAC confidence, in (0, 1).
    seed : int
        Seed of OpenCV's RNG, set before each frame so that a frame's result depends only on
        its own corners and the seed.

    Returns
    -------
    poses : DataFrame
        poses_raw.parquet: one row per frame, ``frame, t_s, valid, rvec_0..2`` (rvec_C_B, rad),
        ``x_m, y_m, z_m`` (tvec_C_B, m: board origin in the camera frame C),
        ``roll_rad, pitch_rad, yaw_rad`` (of R_C_B, R = Rz Ry Rx), ``reproj_rms_px`` (RMS of
        the inliers' reprojection errors after refinement, px), ``n_inliers``, ``n_corners``
        (corners the frame has: a found frame may have a subset, e.g. a hand over the board).
        Frames without a board, with fewer than ``MIN_INLIERS`` corners or all of them on one
        grid line, or whose PnP fails or keeps fewer than ``MIN_INLIERS`` inliers, have
        ``valid = False`` and NaN pose.

    Raises
    ------
    InputError
        Missing columns, or a found frame whose corner indices are not distinct in 0..N-1
        or whose pixels are not finite.

    Notes
    -----
    ``cv2.solvePnPRansac`` (minimal sets solved by EPnP inside OpenCV, the fit on their
    consensus with ``SOLVEPNP_IPPE``), then ``cv2.solvePnPRefineLM`` on the inliers, with the
    inliers re-taken from the refined pose (reprojection error below ``ransac_reproj_px``)
    until they no longer change. Should RANSAC find no consensus, IPPE on all corners starts
    the same loop. The inliers are those of the returned pose.
    """
    p_B = board_object_points(board)
    n_corners = len(p_B)
    _check_corners_table(corners)
    K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    ordered = corners.sort_values(["frame", "corner"], kind="stable")
    rows = []
    for frame, block in ordered.groupby("frame", sort=True):
        frame = int(frame)
        t_s = float(block["t_s"].iloc[0])
        row = {"frame": frame, "t_s": t_s, "valid": False, "n_inliers": 0, "n_corners": 0}
        found = bool(block["found"].iloc[0])
        if found:
            ids = block["corner"].to_numpy()
            if (
                not block["found"].all()
                or len(np.unique(ids)) != len(ids)
                or ids.min() < 0
                or ids.max() >= n_corners
            ):
                raise InputError(
                    f"corners table, frame {frame}: found frame with corners "
                    f"{block['corner'].tolist()} / found {block['found'].unique().tolist()}; "
                    f"expected distinct corners in 0..{n_corners - 1}, all found"
                )
            uv = block[["u_px", "v_px"]].to_numpy(dtype=np.float64)
            row["n_corners"] = len(ids)
            if not np.isfinite(uv).all():
                raise InputError(
                    f"corners table, frame {frame}: non-finite u_px/v_px on a found frame; "
                    "expected pixel coordinates"
                )
            if _spread_ok(ids, board):
                row.update(
                    _solve_frame(p_B[ids], uv, K, dist, ransac_reproj_px, ransac_iterations,
                                 ransac_confidence, seed)
                )
        rows.append(row)
    poses = pd.DataFrame(rows)
    for col in POSE_COLUMNS:
        if col not in poses.columns:
            poses[col] = np.nan
    poses = poses[POSE_COLUMNS].astype(
        {"frame": np.int64, "t_s": np.float64, "valid": bool, "n_inliers": np.int64,
         "n_corners": np.int64}
    )
    n_valid = int(poses["valid"].sum())
    log.info("poses: %d of %d frames valid", n_valid, len(poses))
    return poses


def _spread_ok(ids: np.ndarray, board: dict) -> bool:
    """At least MIN_INLIERS corners spanning two rows and two columns of the grid (not all
    on one line: a pose needs a non-degenerate planar spread)."""
    nx, _ = board_pattern(board)
    return bool(len(ids) >= MIN_INLIERS and len(np.unique(ids % nx)) >= 2
                and len(np.unique(ids // nx)) >= 2)


def _solve_frame(p_B, uv, K, dist, reproj_px, iterations, confidence, seed) -> dict:
    """RANSAC PnP, LM refinement on the inliers; the pose columns of one frame (or invalid)."""
    obj = p_B.reshape(-1, 1, 3)
    img = uv.reshape(-1, 1, 2)
    cv2.setRNGSeed(int(seed))
    try:
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            obj,
            img,
            K,
            dist,
            iterationsCount=int(iterations),
            reprojectionError=float(reproj_px),
            confidence=float(confidence),
            flags=PNP_FLAG,
        )
    except cv2.error as exc:
        log.debug("solvePnPRansac failed: %s", exc)
        return {"valid": False}
    if not ok or inliers is None or len(inliers) < 4:
        # A RANSAC without consensus on few noisy points: the closed form on all points,
        # then the consensus below, decides instead.
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=PNP_FLAG)
        if not ok:
            return {"valid": False}
        inliers = np.arange(len(obj))
    idx = np.asarray(inliers).ravel()
    # OpenCV's RANSAC scores EPnP fits of 5-point samples, which on a small planar grid with
    # sub-pixel noise leave good corners outside the threshold. The consensus set is therefore
    # re-taken from the refined pose until it no longer changes (as in LO-RANSAC).
    for _ in range(5):
        rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], K, dist, rvec, tvec)
        proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
        err_px = np.linalg.norm(proj.reshape(-1, 2) - uv, axis=1)
        new_idx = np.flatnonzero(err_px < reproj_px)
        if len(new_idx) < MIN_INLIERS or np.array_equal(new_idx, idx):
            break
        idx = new_idx
    else:
        rvec, tvec = cv2.solvePnPRefineLM(obj[idx], img[idx], K, dist, rvec, tvec)
    if len(idx) < MIN_INLIERS:
        return {"valid": False, "n_inliers": len(idx)}
    rvec, tvec = rvec.ravel(), tvec.ravel()
    if not (np.isfinite(rvec).all() and np.isfinite(tvec).all()) or tvec[2] <= 0:
        return {"valid": False, "n_inliers": len(idx)}
    proj, _ = cv2.projectPoints(obj[idx], rvec, tvec, K, dist)
    err = proj.reshape(-1, 2) - uv[idx]
    rpy = tf.euler_from_R(tf.R_from_rvec(rvec))
    return {
        "valid": True,
        "rvec_0": rvec[0],
        "rvec_1": rvec[1],
        "rvec_2": rvec[2],
        "x_m": tvec[0],
        "y_m": tvec[1],
        "z_m": tvec[2],
        "roll_rad": rpy[0],
        "pitch_rad": rpy[1],
        "yaw_rad": rpy[2],
        "reproj_rms_px": float(np.sqrt(np.mean(np.sum(err**2, axis=1)))),
        "n_inliers": len(idx),
    }
