"""The chessboard grid in the image: spacing, deviation from the neighbours, the pixel scales.

Every pixel threshold of corner detection and tracking scales with the board's squares as the
image shows them (``local_spacing``), so the same checks hold at 640x480 and 1920x1080.
``grid_deviation`` measures how far each corner lies from where its grid neighbours put it
(a local homography); ``keep_consistent_corners`` keeps the corners that agree with the grid.
Used by :mod:`cvsflow.corners.refine`, :mod:`cvsflow.corners.detect` and
:mod:`cvsflow.corners.track`.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from cvsflow.board import board_pattern

# Every pixel threshold scales with the board's squares as the image shows them (the local
# spacing of the grid, ``local_spacing``), so the same checks hold at 640x480 and 1920x1080.
# cornerSubPix half window: this share of the median spacing when that exceeds the configured
# window (squares of ~20 px and more), never reaching a neighbouring corner. A quarter square
# averages the edges over more pixels than 0.15 did: on the realistic renders' effects the
# median corner error fell 0.134-0.149 px -> 0.108-0.116 px (0.15: 1.23-1.31 times that of a
# quarter-square cornerSubPix started at the truth; defocus, H.264 and the realistic preset
# unchanged or better).
SUBPIX_WINDOW_FRAC = 0.25


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
        :func:`cvsflow.board.model.board_pattern`.
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
    # (u, v, u^2 + v^2) per corner, each times its X X': the normal equations' 27 columns
    # (the products of np.concatenate of the three (N, 9) blocks, in one broadcast).
    n = len(uv)
    coef = np.empty((n, 3))
    np.multiply(uv - centre, scale, out=coef[:, :2])
    u, v = coef[:, 0], coef[:, 1]
    np.add(u * u, v * v, out=coef[:, 2])
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
    sums = weights @ (coef[:, :, None] * mono[:, None, :]).reshape(n, 27)
    blocks = sums.reshape(n, 3, 3, 3)
    # U over V, (n, 6, 3) (a view): one 6x3 product per corner where two 3x3 ones gave the
    # same values (the same dot products).
    UV6, S = blocks[:, :2].reshape(n, 6, 3), blocks[:, 2]
    UV = UV6.reshape(n, 2, 3, 3)
    # A^-1 (and A^-1 X_k) from the grid moments' adjugate, a_inv_x = (A^-1, A^-1 X_k).
    UVA = (UV6 @ a_inv_x[:, :, :3]).reshape(n, 2, 3, 3)
    UVAUV = UVA @ UV
    M = S - (UVAUV[:, 0] + UVAUV[:, 1])  # .sum(axis=1) of two terms
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
        puv = ((UV6 @ h3[:, :, None]).reshape(n, 2, 3) * a_inv_x[:, None, :, 3]).sum(axis=2)
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


def quadratic_deviation(corners_px: np.ndarray, board: dict) -> np.ndarray:
    """Distance of each corner from where a quadratic through its grid neighbours puts it.

    ``grid_deviation``'s check as one linear map: for every corner, the pixel coordinates of
    its known neighbours within two grid steps are fitted (least squares) by a quadratic in
    the grid coordinates (6 terms per axis), evaluated at the corner. The map's weights depend
    only on which corners are known, so they are computed once per visibility mask and a
    frame costs one (N, N) @ (N, 2) product. A quadratic follows the lens's curvature as
    well as the perspective's over two squares: on the realistic 640x480 to 1080x1920 renders
    the stage's found corners deviate by a median 0.03-0.07 and at the 99th percentile
    0.17-0.24 of ``deviation_limit_px`` (the local homography of ``grid_deviation``:
    0.06-0.12 and 0.23-0.44), and a corner moved by d moves its own deviation by d, as there.

    Parameters
    ----------
    corners_px : ndarray, shape (nx * ny, 2)
        Corners in grid order, pixels (NaN where unknown).
    board : dict

    Returns
    -------
    deviation_px : ndarray, shape (nx * ny,)
        Distance between corner and prediction, pixels; inf for corners unknown or with
        neighbours too few (under 6, the quadratic's terms) or not fixing a quadratic (on two lines).
    """
    nx, ny = board_pattern(board)
    uv = np.asarray(corners_px, dtype=np.float64).reshape(-1, 2)
    finite = np.isfinite(uv)
    known = finite[:, 0] & finite[:, 1]
    weights, ok = _quadratic_predictor(nx, ny, known.tobytes())
    uv = np.where(known[:, None], uv, 0.0)
    d = uv - weights @ uv
    dx, dy = d[:, 0], d[:, 1]
    return np.where(ok, np.sqrt(dx * dx + dy * dy), np.inf)


# A quadratic prediction needs this many known neighbours within two grid steps (its terms;
# with as few, a corner's prediction interpolates them and is noisier, which costs a fast-path
# frame now and then, never a wrong corner: the corner's own displacement is its deviation).
MIN_QUADRATIC_NEIGHBOURS = 6


@functools.lru_cache(maxsize=128)
def _quadratic_predictor(nx: int, ny: int, known_bytes: bytes):
    """``quadratic_deviation``'s map for the corners ``known`` (a bool mask's bytes): the
    weights W (N, N) with prediction W @ uv, and which corners it predicts (N,) bool."""
    known = np.frombuffer(known_bytes, dtype=bool)
    index, design, outer = _quadratic_neighbourhood(nx, ny)
    used = (index >= 0) & known[np.maximum(index, 0)]  # (N, 24)
    normal = (used @ outer).reshape(-1, 6, 6)  # sum over the used neighbours of t t'
    eig = np.linalg.eigvalsh(normal)  # ascending (the normal matrices are symmetric)
    ok = (known & (used.sum(axis=1) >= MIN_QUADRATIC_NEIGHBOURS)
          & (eig[:, 0] > 1e-8 * eig[:, -1]))
    n = nx * ny
    safe = np.where(ok[:, None, None], normal, np.eye(6))
    # The prediction at the corner itself is the fit's constant: e0' (T'T)^-1 T' uv.
    e0 = np.linalg.solve(safe, np.broadcast_to(np.eye(6)[:, :1], (n, 6, 1)))[:, :, 0]
    w_local = (e0 @ design.T) * (used & ok[:, None])  # (N, 24)
    weights = np.zeros((n, n))
    rows = np.broadcast_to(np.arange(n)[:, None], index.shape)
    weights[rows[used], index[used]] = w_local[used]
    for arr in (weights, ok):
        arr.flags.writeable = False  # cached: shared by every call
    return weights, ok


@functools.lru_cache(maxsize=16)
def _quadratic_neighbourhood(nx: int, ny: int):
    """The 24 offsets within two grid steps: each corner's neighbour index there (N, 24; -1
    off the board), the quadratic's terms at each offset (24, 6) and their outer products
    flattened (24, 36)."""
    off = np.array([(a, b) for b in range(-2, 3) for a in range(-2, 3) if (a, b) != (0, 0)])
    k = np.arange(nx * ny)
    x = (k % nx)[:, None] + off[None, :, 0]
    y = (k // nx)[:, None] + off[None, :, 1]
    index = np.where((x >= 0) & (x < nx) & (y >= 0) & (y < ny), y * nx + x, -1)
    a, b = off[:, 0].astype(float), off[:, 1].astype(float)
    design = np.stack([np.ones_like(a), a, b, a * a, a * b, b * b], axis=1)
    outer = (design[:, :, None] * design[:, None, :]).reshape(-1, 36)
    for arr in (index, design, outer):
        arr.flags.writeable = False  # cached: shared by every call
    return index, design, outer


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


def _grid_points(board: dict) -> np.ndarray:
    """Grid coordinates (k % nx, k // nx) of the inner corners, shape (N, 2), float32."""
    return _grid_points_cached(*board_pattern(board))


@functools.lru_cache(maxsize=16)
def _grid_points_cached(nx: int, ny: int) -> np.ndarray:
    k = np.arange(nx * ny)
    grid = np.stack([k % nx, k // nx], axis=1).astype(np.float32)
    grid.flags.writeable = False  # cached: shared by every call
    return grid


def _inside(p: np.ndarray, w: int, h: int, margin: float) -> np.ndarray:
    """(N,) bool: points at least ``margin`` px inside a w x h image."""
    return (p[:, 0] >= margin) & (p[:, 0] <= w - 1 - margin) & (p[:, 1] >= margin) & (
        p[:, 1] <= h - 1 - margin
    )


def _median_spacing(corners_px: np.ndarray, board: dict) -> float:
    """Median distance between grid neighbours, px (0 when none is known)."""
    d = _neighbour_distances(corners_px, board)
    return _median(d) if len(d) else 0.0
