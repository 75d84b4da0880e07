"""ChArUco boards: a chessboard whose white squares carry ArUco markers, so that every corner
seen has its identity even when a hand or the image border hides the rest of the board.

Board convention (the chessboard's, docs/contracts.md)
------------------------------------------------------
Config ``board: {type: charuco, squares_x, squares_y, square_m, marker_m, dictionary}``.
OpenCV's ``cv2.aruco.CharucoBoard((squares_x, squares_y), square_m, marker_m, dictionary)``
numbers its chessboard corners row-major, corner ``id`` at ``((id % nx + 1) s, (id // nx + 1)
s, 0)`` in its own frame (origin at the outer corner of the black square (0, 0), x along the
rows, y down the printed sheet, z into it). Shifting that origin by one square onto the first
inner corner gives exactly the frame B of ``cvsflow.calibration.intrinsics.board_object_points``: ChArUco
corner ``id`` is the chessboard's corner ``k = id``, at ``((k % nx) s, (k // nx) s, 0)``, and
square (0, 0) diagonally outside it is black in both (OpenCV >= 4.6's pattern, not the
legacy one). The corners table, PnP, the joint fit and the calibration therefore take ChArUco
corners unchanged; a frame simply has the subset of ids it saw.

Detection: ``cv2.aruco.CharucoDetector`` finds the markers and puts each corner between its
two neighbouring markers; the corner is then refined with ``cv2.cornerSubPix`` in a window
scaled to the squares as the image shows them, kept short of the markers (their edges would
pull it), and checked against the markers it was placed from and for the point symmetry of
a corner (a finger over it is not). Both markers beside a corner must be found, so a finger
over a corner usually hides one of them too.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Iterable

import cv2
import numpy as np
import pandas as pd

from cvsflow.board.model import SUBPIX_CRITERIA, CornerRows, board_object_points, board_pattern, board_type
from cvsflow.exceptions import ConfigError, InputError

log = logging.getLogger(__name__)

# A frame (or still) counts as found with at least this many refined, checked corners spread
# over two rows and two columns of the grid: PnP's minimum (cvsflow.calibration.pnp.MIN_INLIERS).
MIN_CORNERS = 6
# cornerSubPix half window: the distance (px, max norm: the window is a square) between the
# corner and the nearest point of its two markers, less WINDOW_CLEARANCE_PX (blur spreads the
# markers' edges into the white margin), at least MIN_WINDOW_PX and at most the larger of the
# configured window and SUBPIX_WINDOW_FRAC of the square. A window reaching the markers'
# edges is pulled by them, a smaller one sees too few pixels of the corner: on realistic
# 640x480 frames (33 px squares, markers 0.75 of a square, a 4.1 px margin) the RMS error was
# 0.19, 0.07, 0.065, 0.10, 0.19 px for half windows of 2, 3, 4, 6, 9 px; on a still tilted by
# 40 deg (margins 5.4 to 9.9 px) windows one pixel short of the margin kept every corner
# within 0.12 px, windows reaching it were up to 0.8 px off.
WINDOW_CLEARANCE_PX = 1.0
MIN_WINDOW_PX = 2
SUBPIX_WINDOW_FRAC = 0.15
# Largest distance (px) of a refined corner from where its two markers put it (a homography
# through their eight corners), as a share of the local square size; never below 1 px. The
# markers' corners are a few tenths of a pixel off and the lens bends little over a square;
# a corner refined onto a finger's edge moves by a good part of the white margin.
MAX_MARKER_DEVIATION_FRAC = 0.06
MIN_MARKER_DEVIATION_PX = 1.0
# Largest point asymmetry (``point_asymmetry``) of the window around a kept corner, and the
# least contrast (grey levels) it must have. A finger over part of a corner whose two markers
# are both seen passes the marker check, and cornerSubPix settles on the finger's edge, up to
# ~4 px off. Measured on rendered stills and realistic frames (640x480): 210 clean corners had
# a median asymmetry of 0.015, at most 0.059; with a grey disc (3 to 7 px) over a corner at
# 147 places around it, the 88 corners placed more than 0.5 px off had 0.113 or more, and the
# 6 with 0.09 or less were within 0.24 px.
MAX_ASYMMETRY = 0.09
MIN_CORNER_CONTRAST = 20.0


def is_charuco(board: dict) -> bool:
    """True for a ``type: charuco`` board.

    Parameters
    ----------
    board : dict
        The session's ``board`` block (``type``, ``squares_x``, ``squares_y``, ``square_m``,
        ``marker_m``, ``dictionary``).

    Returns
    -------
    charuco : bool
    """
    return board_type(board) == "charuco"


def _board_key(board: dict) -> tuple:
    """Hashable, checked (squares_x, squares_y, square_m, marker_m, dictionary) of a config."""
    nx, ny = board_pattern(board)
    for key in ("marker_m", "dictionary"):
        if key not in board:
            raise ConfigError(
                f"board {board!r}: type charuco needs key '{key}' (marker_m: marker side in "
                "m; dictionary: an OpenCV ArUco dictionary such as DICT_5X5_100)"
            )
    s, m, name = float(board["square_m"]), float(board["marker_m"]), str(board["dictionary"])
    if not 0.0 < m < s:
        raise ConfigError(
            f"board: marker_m={board['marker_m']!r}; expected a length in m between 0 and "
            f"square_m={s:g} (the marker sits inside its white square)"
        )
    if not name.startswith("DICT_") or not isinstance(getattr(cv2.aruco, name, None), int):
        raise ConfigError(
            f"board: dictionary={name!r}; expected an OpenCV ArUco dictionary name such as "
            "DICT_5X5_100 (cv2.aruco.DICT_*)"
        )
    return nx + 1, ny + 1, s, m, name


@functools.lru_cache(maxsize=8)
def _charuco_cached(sx: int, sy: int, s: float, m: float, name: str) -> cv2.aruco.CharucoBoard:
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    n_markers = (sx * sy) // 2
    if dictionary.bytesList.shape[0] < n_markers:
        raise ConfigError(
            f"board: dictionary {name} has {dictionary.bytesList.shape[0]} markers; a "
            f"{sx}x{sy} ChArUco board needs {n_markers} (choose a larger dictionary)"
        )
    board = cv2.aruco.CharucoBoard((sx, sy), s, m, dictionary)
    board.setLegacyPattern(False)  # square (0, 0) black, as board frame B has it
    return board


def charuco_board(board: dict) -> cv2.aruco.CharucoBoard:
    """The OpenCV board of a ``type: charuco`` config (cached; do not modify it).

    Parameters
    ----------
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m), ``marker_m`` (m), ``dictionary``
        (OpenCV name, e.g. ``DICT_5X5_100``).

    Returns
    -------
    cv2.aruco.CharucoBoard

    Raises
    ------
    ConfigError
        A missing key, a marker not smaller than its square, an unknown dictionary or one
        with fewer markers than the board's white squares.
    """
    return _charuco_cached(*_board_key(board))


def charuco_object_points(board: dict) -> np.ndarray:
    """ChArUco corner positions in board frame B, row ``id`` for corner ``id``.

    Parameters
    ----------
    board : dict
        A ``type: charuco`` board.

    Returns
    -------
    p_B : ndarray, shape (nx * ny, 3), float64
        OpenCV's chessboard corners shifted by one square: corner ``id`` at
        ``((id % nx) s, (id // nx) s, 0)``, metres, equal to
        ``cvsflow.calibration.intrinsics.board_object_points(board)``.
    """
    s = float(board["square_m"])
    p = np.asarray(charuco_board(board).getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
    p_B = board_object_points(board)
    # OpenCV stores the board in single precision: equal to ~1e-8 m; the exact grid is returned.
    if p.shape != p_B.shape or np.abs(p - [s, s, 0.0] - p_B).max() > 1e-6 * max(s, 1.0):
        raise ConfigError(f"board {board!r}: OpenCV's ChArUco corners are not the chessboard's "
                          "grid shifted by one square (an OpenCV without the current pattern?)")
    return p_B


@functools.lru_cache(maxsize=8)
def _corner_markers_cached(key: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Per inner corner: its two markers (ids) and their corners in B, (2, 4, 2)."""
    sx, sy, s, m, name = key
    cb = _charuco_cached(*key)
    obj = np.asarray(cb.getObjPoints(), dtype=np.float64)[..., :2] - s  # (M, 4, 2) in B
    ids = np.asarray(cb.getIds()).ravel()
    centre = obj.mean(axis=1)
    nx = sx - 1
    k = np.arange(nx * (sy - 1))
    corners_B = np.stack([(k % nx) * s, (k // nx) * s], axis=1)
    # Each inner corner touches two white squares, whose centres are s / sqrt(2) away.
    d = np.linalg.norm(centre[None] - corners_B[:, None], axis=-1)  # (N, M)
    near = np.argsort(d, axis=1, kind="stable")[:, :2]
    if not np.allclose(d[np.arange(len(k))[:, None], near], s / np.sqrt(2)):
        raise ConfigError(f"board: ChArUco layout of {name} is not the expected pattern")
    marker_ids, pts = ids[near], obj[near]  # (N, 2), (N, 2, 4, 2)
    for a in (marker_ids, pts):
        a.flags.writeable = False
    return marker_ids, pts


def corner_markers(board: dict) -> tuple[np.ndarray, np.ndarray]:
    """The two markers beside each inner corner.

    Parameters
    ----------
    board : dict
        The session's ``board`` block (``type``, ``squares_x``, ``squares_y``, ``square_m``,
        ``marker_m``, ``dictionary``).

    Returns
    -------
    marker_ids : ndarray, shape (nx * ny, 2), int
        ArUco ids of the markers in the two white squares touching corner k.
    marker_corners_B : ndarray, shape (nx * ny, 2, 4, 2)
        Their corners (x, y) in board frame B, metres, in OpenCV's order.
    """
    return _corner_markers_cached(_board_key(board))


def make_detector(board: dict) -> cv2.aruco.CharucoDetector:
    """A ``cv2.aruco.CharucoDetector`` for the board (corners placed by local homographies).

    Both markers beside a corner must be found (``minMarkers`` 2): one marker alone puts a
    corner from a homography extrapolated past its own edge. Marker corners are refined
    (``CORNER_REFINE_SUBPIX``) so the corners' starting points and the marker check below
    are sub-pixel.

    Parameters
    ----------
    board : dict
        The session's ``board`` block (``type``, ``squares_x``, ``squares_y``, ``square_m``,
        ``marker_m``, ``dictionary``).

    Returns
    -------
    detector : cv2.aruco.CharucoDetector
    """
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    charuco_params = cv2.aruco.CharucoParameters()
    charuco_params.minMarkers = 2
    return cv2.aruco.CharucoDetector(charuco_board(board), charuco_params, params)


def _marker_predictions(ids, marker_ids_found, marker_corners_found, board):
    """For detected corners ``ids``: the position the homography through their two markers'
    eight corners gives (NaN where a marker is missing), the markers' distance from it in the
    max norm (px), and the square size (px)."""
    m_ids, m_B = corner_markers(board)
    lookup = {int(i): np.asarray(c, np.float64).reshape(4, 2)
              for i, c in zip(marker_ids_found, marker_corners_found, strict=True)}
    s = float(board["square_m"])
    k_B = np.stack([(ids % board_pattern(board)[0]) * s, (ids // board_pattern(board)[0]) * s],
                   axis=1)
    predicted = np.full((len(ids), 2), np.nan)
    margin_px = np.full(len(ids), np.nan)
    spacing_px = np.full(len(ids), np.nan)
    for row, k in enumerate(ids):
        pair = [lookup.get(int(j)) for j in m_ids[k]]
        if any(p is None for p in pair):
            continue
        src = m_B[k].reshape(-1, 2)
        dst = np.concatenate(pair)
        H, _ = cv2.findHomography(src, dst, 0)
        if H is None:
            continue
        predicted[row] = cv2.perspectiveTransform(k_B[row].reshape(1, 1, 2), H).reshape(2)
        # The window is a square in the image: its half side must stay below the markers'
        # distance in the max norm, which a slanted view makes smaller than along x or y.
        edge = dst.reshape(2, 4, 1, 2) + _EDGE_T * (np.roll(dst.reshape(2, 4, 2), -1, axis=1)
                                                    - dst.reshape(2, 4, 2))[:, :, None]
        margin_px[row] = np.abs(edge - predicted[row]).max(axis=-1).min()
        eps = 1e-4  # the square size from the homography's scale at the corner
        p = cv2.perspectiveTransform(
            np.array([[k_B[row], k_B[row] + [eps, 0.0], k_B[row] + [0.0, eps]]]), H
        ).reshape(3, 2)
        spacing_px[row] = s * np.linalg.norm(p[1:] - p[0], axis=1).mean() / eps
    return predicted, margin_px, spacing_px


_EDGE_T = np.linspace(0.0, 1.0, 16, endpoint=False)[:, None]  # samples along a marker's edge


def detect_charuco_corners(
    gray: np.ndarray,
    board: dict,
    subpix_window_px: int = 5,
    detector: cv2.aruco.CharucoDetector | None = None,
    max_marker_deviation: float = MAX_MARKER_DEVIATION_FRAC,
    max_asymmetry: float = MAX_ASYMMETRY,
) -> tuple[np.ndarray | None, str]:
    """ChArUco corners of one frame, refined, in board order (the chessboard's record).

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    board : dict
        A ``type: charuco`` board.
    subpix_window_px : int
        Bound of the cornerSubPix half window, pixels. The window is the white margin between
        the corner and its markers (rounded, at least ``MIN_WINDOW_PX``), at most the larger of
        this and ``SUBPIX_WINDOW_FRAC`` of the square.
    detector : cv2.aruco.CharucoDetector, optional
        ``make_detector(board)`` made once per video.
    max_marker_deviation : float
        Largest distance of a refined corner from where its two markers put it, share of the
        local square size (``MAX_MARKER_DEVIATION_FRAC``).
    max_asymmetry : float
        Largest ``point_asymmetry`` of the window around a kept corner (``MAX_ASYMMETRY``).

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        Corner k at board point (k % nx, k // nx) * square_m, NaN where not seen; None when
        fewer than ``MIN_CORNERS`` corners spanning two rows and columns are kept.
    method : str
        ``"charuco"`` (every corner), ``"partial"`` (a subset, the others inside the image:
        a hand over them), ``"out_of_view"`` (a subset, others outside the image or at its
        border) or ``"not_found"``.

    Notes
    -----
    ``cv2.aruco.CharucoDetector.detectBoard`` (markers, then each corner between its two
    markers and OpenCV's own refinement), then ``cv2.cornerSubPix`` (criteria EPS + MAX_ITER,
    30, 0.001 as the chessboard) from there with the window above, per corner. A corner is
    kept when it stays near where its markers put it, its window is point-symmetric (a
    corner, not a finger's edge: ``point_asymmetry``) and inside the image.
    """
    if detector is None:
        detector = make_detector(board)
    nx, ny = board_pattern(board)
    out = np.full((nx * ny, 2), np.nan)
    ch_corners, ch_ids, m_corners, m_ids = detector.detectBoard(gray)
    if ch_ids is None or len(ch_ids) < MIN_CORNERS:
        return None, "not_found"
    ids = np.asarray(ch_ids, dtype=np.int64).ravel()
    uv = np.asarray(ch_corners, dtype=np.float64).reshape(-1, 2)
    predicted, margin_px, spacing_px = _marker_predictions(
        ids, np.asarray(m_ids).ravel(), m_corners, board
    )
    keep = np.isfinite(predicted).all(axis=1)
    largest = np.maximum(int(subpix_window_px), np.floor(SUBPIX_WINDOW_FRAC * spacing_px))
    windows = np.clip(np.floor(margin_px - WINDOW_CLEARANCE_PX), MIN_WINDOW_PX,
                      np.maximum(largest, MIN_WINDOW_PX))
    windows = np.where(keep, windows, MIN_WINDOW_PX).astype(int)  # NaN: no markers, not kept
    h, w = gray.shape
    refined = uv.copy()
    for win in np.unique(windows[keep]):
        sel = keep & (windows == win)
        start = np.ascontiguousarray(uv[sel], dtype=np.float32).reshape(-1, 1, 2)
        refined[sel] = cv2.cornerSubPix(gray, start, (win, win), (-1, -1),
                                        SUBPIX_CRITERIA).reshape(-1, 2)
    with np.errstate(invalid="ignore"):
        keep &= point_asymmetry(gray, refined, windows) <= max_asymmetry
    limit = np.maximum(MIN_MARKER_DEVIATION_PX, max_marker_deviation * spacing_px)
    with np.errstate(invalid="ignore"):
        dev = np.linalg.norm(refined - predicted, axis=1)
        keep &= dev <= limit
        # cornerSubPix's window must lie inside the image.
        keep &= ((refined[:, 0] >= windows + 1) & (refined[:, 0] <= w - 2 - windows)
                 & (refined[:, 1] >= windows + 1) & (refined[:, 1] <= h - 2 - windows))
    if not _spread_ok(ids[keep], board):
        return None, "not_found"
    out[ids[keep]] = refined[keep]
    if keep.sum() == nx * ny:
        return out, "charuco"
    return out, _missing_reason(out, gray.shape, board)


def point_asymmetry(gray: np.ndarray, corners_px: np.ndarray, windows_px) -> np.ndarray:
    """How far the image around each corner is from point symmetry, share of its contrast.

    A chessboard corner (two dark and two light quadrants meeting at the corner) looks the
    same turned by 180 degrees about it, and stays so under any affine view and blur; a
    finger or an edge over part of the window does not.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    corners_px : ndarray, shape (M, 2)
        Corners, pixels (NaN rows give NaN).
    windows_px : array_like of int, shape (M,)
        Half side of the square patch around each corner, pixels.

    Returns
    -------
    asymmetry : ndarray, shape (M,)
        Mean absolute difference between the patch (bilinear, ``cv2.getRectSubPix`` centred
        on the corner) and the patch turned by 180 degrees, over its contrast (90th minus
        10th percentile grey level); NaN for an unknown corner or a patch without contrast.
    """
    out = np.full(len(corners_px), np.nan)
    for i, (q, w) in enumerate(zip(np.asarray(corners_px, np.float64),
                                   np.broadcast_to(windows_px, len(corners_px)), strict=True)):
        if not np.isfinite(q).all():
            continue
        w = int(w)
        patch = cv2.getRectSubPix(gray, (2 * w + 1, 2 * w + 1), (float(q[0]), float(q[1])))
        patch = patch.astype(np.float64)
        lo, hi = np.percentile(patch, [10.0, 90.0])
        if hi - lo >= MIN_CORNER_CONTRAST:
            out[i] = np.mean(np.abs(patch - patch[::-1, ::-1])) / (hi - lo)
    return out


def _spread_ok(ids: np.ndarray, board: dict) -> bool:
    """At least MIN_CORNERS corners, not all on one line of the grid."""
    if len(ids) < MIN_CORNERS:
        return False
    nx, _ = board_pattern(board)
    g = np.stack([ids % nx, ids // nx], axis=1).astype(np.float64)
    g -= g.mean(axis=0)
    return bool(np.linalg.svd(g, compute_uv=False)[-1] > 1e-6)


def _missing_reason(corners_px: np.ndarray, shape, board: dict) -> str:
    """``"out_of_view"`` when a missing corner lies outside the image (the homography of the
    kept corners), else ``"partial"``."""
    nx, ny = board_pattern(board)
    known = np.isfinite(corners_px).all(axis=1)
    k = np.arange(nx * ny)
    grid = np.stack([k % nx, k // nx], axis=1).astype(np.float32)
    H, _ = cv2.findHomography(grid[known], corners_px[known].astype(np.float32), 0)
    if H is None:
        return "partial"
    p = cv2.perspectiveTransform(grid[~known].reshape(-1, 1, 2), H).reshape(-1, 2)
    h, w = shape
    margin = 2.0
    outside = (p[:, 0] < margin) | (p[:, 0] > w - 1 - margin) | (p[:, 1] < margin) | (
        p[:, 1] > h - 1 - margin)
    return "out_of_view" if outside.any() else "partial"


def extract_charuco_corners(
    frames: Iterable[tuple[int, float, np.ndarray]],
    board: dict,
    subpix_window_px: int = 5,
    n_frames: int | None = None,
    log_every: int = 300,
    keep_partial: bool = True,
    max_marker_deviation: float = MAX_MARKER_DEVIATION_FRAC,
) -> pd.DataFrame:
    """ChArUco corners of every video frame: the corners table of ``cvsflow.corners.extract.extract_corners``.

    Every frame is detected on its own (the markers name the corners, so nothing is tracked
    and a video cut into chunks gives the table of one pass).

    Parameters
    ----------
    frames : iterable of (int, float, ndarray)
        ``(frame, t_s, gray)``: frame index, video time (s), 8-bit grayscale image (H, W).
    board : dict
        A ``type: charuco`` board.
    subpix_window_px : int
        As in ``detect_charuco_corners``.
    n_frames : int, optional
        Frames expected, for progress messages only.
    log_every : int
        Log progress every this many frames.
    keep_partial : bool
        False counts frames with a subset of the corners (``partial``, ``out_of_view``) as
        not found.
    max_marker_deviation : float
        As in ``detect_charuco_corners``.

    Returns
    -------
    corners : DataFrame
        ``frame, t_s, found, corner, u_px, v_px`` (docs/contracts.md corners.parquet): a found
        frame has one row per corner kept, corner k at board point (k % nx, k // nx) *
        square_m; a frame without a board one row with ``corner = -1`` and NaN pixels.
        ``attrs``: ``n_frames``, ``n_found``, ``order_methods`` (method -> frames:
        ``charuco``, ``partial``, ``out_of_view``, ``not_found``, ``cv_error``),
        ``n_cv_errors``.

    Raises
    ------
    InputError
        A frame that is not a 2-D uint8 image, or no frames at all.
    """
    detector = make_detector(board)
    nx, ny = board_pattern(board)
    rows = CornerRows(nx * ny)
    methods: dict[str, int] = {}
    n_done = n_found = n_cv_errors = 0
    t_start = time.perf_counter()
    for frame, t_s, gray in frames:
        if gray is None:  # the decoder refused it (iter_video_gray's ``undecodable``)
            methods["undecodable"] = methods.get("undecodable", 0) + 1
            rows.add(frame, t_s, None)
            n_done += 1
            continue
        gray = np.asarray(gray)
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise InputError(
                f"video frame {frame}: expected an 8-bit grayscale image, got dtype "
                f"{gray.dtype}, shape {gray.shape}"
            )
        try:
            corners_px, method = detect_charuco_corners(gray, board, subpix_window_px,
                                                        detector, max_marker_deviation)
        except cv2.error as exc:
            n_cv_errors += 1
            log.warning("corners: frame %d: OpenCV failed in the ChArUco detector (%s); "
                        "counted as not found", frame, str(exc).strip().splitlines()[-1])
            corners_px, method = None, "cv_error"
        if corners_px is not None and method != "charuco" and not keep_partial:
            corners_px, method = None, "not_found"
        methods[method] = methods.get(method, 0) + 1
        n_found += corners_px is not None
        rows.add(frame, t_s, corners_px)
        n_done += 1
        if log_every and n_done % log_every == 0:
            of_total = f" of {n_frames}" if n_frames else ""
            log.info("corners (ChArUco): %d%s frames done, board found in %d", n_done,
                     of_total, n_found)
    if n_done == 0:
        raise InputError("video: no frames to extract corners from (expected at least one)")
    corners = rows.table()
    corners.attrs = {"n_frames": n_done, "n_found": n_found, "order_methods": methods,
                     "n_cv_errors": n_cv_errors}
    log.info("corners (ChArUco): board found in %d of %d frames (%.1f %%), %.1f frames/s; %s",
             n_found, n_done, 100.0 * n_found / n_done,
             n_done / max(time.perf_counter() - t_start, 1e-9), methods)
    if n_done - n_found:
        log.warning("corners: %d frames without a board kept as found=False", n_done - n_found)
    return corners


def find_charuco(gray: np.ndarray, board: dict, subpix_window_px: int = 11,
                 detector: cv2.aruco.CharucoDetector | None = None):
    """ChArUco corners of a calibration still, or None (``cvsflow.calibration.intrinsics``).

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    board : dict
        A ``type: charuco`` board.
    subpix_window_px : int
        As in ``detect_charuco_corners``.
    detector : cv2.aruco.CharucoDetector, optional

    Returns
    -------
    (ids, corners_px) or None
        ``ids`` (M,) int64 ascending, ``corners_px`` (M, 2) float64 pixels; None with fewer
        than ``MIN_CORNERS`` corners spread over two rows and columns.
    """
    corners_px, _ = detect_charuco_corners(gray, board, subpix_window_px, detector)
    if corners_px is None:
        return None
    known = np.flatnonzero(np.isfinite(corners_px).all(axis=1))
    return known.astype(np.int64), corners_px[known]
