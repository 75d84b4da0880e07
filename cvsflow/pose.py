"""Chessboard corners in every video frame, and the board's pose in the camera (PnP) per frame.

Seed: "OpenCV's solvePnPRansac() function can be employed to extract the pose matrix P of the
camera relative to the calibration board ... It was found that a 5x6 chessboard does not have
enough features to guarantee accurate results from the ePnP method".

Tables are those of docs/contracts.md: ``corners.parquet`` (``extract_corners``) and
``poses_raw.parquet`` (``estimate_poses``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable

import cv2
import numpy as np
import pandas as pd

from cvsflow import transforms as tf
from cvsflow.calibration import (
    SUBPIX_CRITERIA,
    board_object_points,
    board_pattern,
    order_corners,
)
from cvsflow.errors import InputError

log = logging.getLogger(__name__)

# ADAPTIVE_THRESH and NORMALIZE_IMAGE cope with the uneven light and auto-exposure of a
# hand-held board. FAST_CHECK pays only where the board is absent: measured on a rendered
# 640x480 session it halves the time of a frame without a board (15 vs 30-50 ms) but adds
# ~1.5 ms to a frame with one (5.2 vs 3.6 ms), at equal recall (844 of 900 frames). So
# extract_corners uses it only when no board was found in the last few frames.
VIDEO_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
VIDEO_SEARCH_FLAGS = VIDEO_FIND_FLAGS | cv2.CALIB_CB_FAST_CHECK

CORNER_COLUMNS = ["frame", "t_s", "found", "corner", "u_px", "v_px"]
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
]

# IPPE (Collins & Bartoli 2014) is the closed-form solution for a planar target: it returns
# both solutions of the planar ambiguity and keeps the one with the lower reprojection error.
# The 5x4 grid is planar, so the general EPnP (which the seed found not accurate enough on
# this board) and the iterative DLT start (unstable with few coplanar points) are the weaker
# choices. The LM refinement that follows is the seed's "Levenberg-Marquardt optimisation".
PNP_FLAG = cv2.SOLVEPNP_IPPE

# Fewer points than this leaves too little redundancy to trust a 6-dof pose.
MIN_INLIERS = 6


def _subpix_window(corners_px: np.ndarray, board: dict, max_window_px: int) -> int:
    """cornerSubPix half window: at most ``max_window_px`` and under half the corner spacing.

    A search window reaching a neighbouring corner pulls the estimate towards it, which
    matters for far boards whose squares are only a few pixels wide.
    """
    nx, ny = board_pattern(board)
    grid = corners_px.reshape(ny, nx, 2)
    spacing = min(
        np.linalg.norm(np.diff(grid, axis=1), axis=-1).min(),
        np.linalg.norm(np.diff(grid, axis=0), axis=-1).min(),
    )
    return int(max(2, min(max_window_px, np.floor((spacing - 1.0) / 2.0))))


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
    weights = _neighbour_weights(nx, ny)  # (N, N): 1 where corner j helps predict corner k
    # Conditioning as in Hartley's normalised DLT: centre and scale the pixels.
    centre = uv.mean(axis=0)
    scale = np.sqrt(2.0) / max(np.linalg.norm(uv - centre, axis=1).mean(), 1e-9)
    u, v = ((uv - centre) * scale).T
    k = np.arange(nx * ny)
    x, y = (k % nx).astype(np.float64), (k // nx).astype(np.float64)
    zero, one = np.zeros_like(x), np.ones_like(x)
    rows_u = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], axis=1)
    rows_v = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v], axis=1)
    A = np.concatenate([rows_u, rows_v], axis=0)  # (2N, 9)
    w2 = np.concatenate([weights, weights], axis=1)  # (N, 2N)
    A_k = w2[:, :, None] * A[None]  # rows of non-neighbours zeroed: (N, 2N, 9)
    h = np.linalg.svd(A_k)[2][:, -1, :]  # (N, 9): each corner's homography, null vector
    p = np.einsum("kij,kj->ki", h.reshape(-1, 3, 3), np.stack([x, y, one], axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        predicted = p[:, :2] / p[:, 2:3] / scale + centre
    deviation = np.linalg.norm(predicted - uv, axis=1)
    return predicted, np.where(np.isfinite(deviation), deviation, np.inf)


def _neighbour_weights(nx: int, ny: int) -> np.ndarray:
    """(N, N) mask: corner j within two grid steps of corner k, j != k."""
    k = np.arange(nx * ny)
    di = np.abs(k[:, None] % nx - k[None, :] % nx)
    dj = np.abs(k[:, None] // nx - k[None, :] // nx)
    near = (di <= 2) & (dj <= 2)
    np.fill_diagonal(near, False)
    return near.astype(np.float64)


def detect_corners(
    gray: np.ndarray,
    board: dict,
    subpix_window_px: int = 5,
    previous_px: np.ndarray | None = None,
    flags: int = VIDEO_FIND_FLAGS,
    max_grid_deviation_px: float = 2.0,
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
    max_grid_deviation_px : float
        Largest distance (px) of a refined corner from the position its neighbours predict
        (``grid_deviation``). A corner beyond it is refined once more from the prediction; if
        it still deviates, the frame counts as not found (``"inconsistent"``).

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        Corner k at board point (k % nx, k // nx) * square_m (see
        ``cvsflow.calibration.order_corners``).
    method : str
        How the 180-degree ambiguity was decided (``"colour"``, ``"continuity"``,
        ``"unresolved"``), or ``"not_found"`` / ``"inconsistent"``.

    Notes
    -----
    Under motion blur, findChessboardCorners' estimate of an outer corner can be more than a
    search window away from the true corner; cornerSubPix then leaves it where it was
    (it refuses moves larger than its window). Near the image border the window is cut off.
    The neighbour check catches both.
    """
    pattern = board_pattern(board)
    found, corners = cv2.findChessboardCorners(gray, pattern, None, flags)
    if not found:
        return None, "not_found"
    w = _subpix_window(corners.reshape(-1, 2), board, subpix_window_px)
    corners = cv2.cornerSubPix(gray, corners, (w, w), (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2)
    predicted, deviation = grid_deviation(corners, board)
    bad = deviation > max_grid_deviation_px
    if bad.any():
        retry = cv2.cornerSubPix(
            gray, predicted[bad].astype(np.float32).reshape(-1, 1, 2), (w, w), (-1, -1),
            SUBPIX_CRITERIA,
        )
        corners[bad] = retry.reshape(-1, 2)
        _, deviation = grid_deviation(corners, board)
        if (deviation > max_grid_deviation_px).any():
            return None, "inconsistent"
    return order_corners(corners, gray, board, previous_px)


def extract_corners(
    frames: Iterable[tuple[int, float, np.ndarray]],
    board: dict,
    subpix_window_px: int = 5,
    n_frames: int | None = None,
    log_every: int = 300,
    flags: int | None = None,
    max_continuity_gap: int = 3,
    max_grid_deviation_px: float = 2.0,
) -> pd.DataFrame:
    """Chessboard corners of every video frame, the same physical corner under the same index.

    Parameters
    ----------
    frames : iterable of (int, float, ndarray)
        ``(frame, t_s, gray)``: frame index, video time (s) and 8-bit grayscale image (H, W),
        e.g. ``cvsflow.io.media.iter_video_gray``.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m).
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
    max_grid_deviation_px : float
        A frame with a corner farther than this (px) from where its grid neighbours put it,
        even after a second refinement, counts as not found (see ``detect_corners``).

    Returns
    -------
    corners : DataFrame
        ``frame`` (int64), ``t_s`` (float64, s), ``found`` (bool), ``corner`` (int64),
        ``u_px``, ``v_px`` (float64, distorted pixels). A found frame has one row per inner
        corner, corner k at board point (k % nx, k // nx) * square_m; a frame without a board
        has one row with ``corner = -1`` and NaN pixels. ``attrs`` holds counts:
        ``n_frames``, ``n_found``, ``order_methods`` (dict method -> frames).

    Raises
    ------
    InputError
        A frame that is not a 2-D uint8 image.
    """
    n_corners = int(np.prod(board_pattern(board)))
    corner_ids = np.arange(n_corners, dtype=np.int64)
    frame_ids, times, founds, corner_col, uv_blocks = [], [], [], [], []
    methods: dict[str, int] = {}
    previous_px, previous_frame = None, None
    t_start = time.perf_counter()
    n_done = n_found = 0
    for frame, t_s, gray in frames:
        gray = np.asarray(gray)
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise InputError(
                f"video frame {frame}: expected an 8-bit grayscale image, got dtype "
                f"{gray.dtype}, shape {gray.shape}"
            )
        prev = (
            previous_px
            if previous_frame is not None and frame - previous_frame <= max_continuity_gap
            else None
        )
        if flags is not None:
            frame_flags = flags
        else:
            frame_flags = VIDEO_FIND_FLAGS if prev is not None else VIDEO_SEARCH_FLAGS
        corners_px, method = detect_corners(
            gray, board, subpix_window_px, prev, frame_flags, max_grid_deviation_px
        )
        methods[method] = methods.get(method, 0) + 1
        if corners_px is None:
            frame_ids.append(np.array([frame], dtype=np.int64))
            times.append(np.array([t_s], dtype=np.float64))
            founds.append(np.array([False]))
            corner_col.append(np.array([-1], dtype=np.int64))
            uv_blocks.append(np.full((1, 2), np.nan))
        else:
            n_found += 1
            previous_px, previous_frame = corners_px, frame
            frame_ids.append(np.full(n_corners, frame, dtype=np.int64))
            times.append(np.full(n_corners, t_s, dtype=np.float64))
            founds.append(np.ones(n_corners, dtype=bool))
            corner_col.append(corner_ids)
            uv_blocks.append(corners_px)
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
    elapsed = time.perf_counter() - t_start
    if n_done == 0:
        raise InputError("video: no frames to extract corners from (expected at least one)")
    uv = np.concatenate(uv_blocks).astype(np.float64)
    corners = pd.DataFrame(
        {
            "frame": np.concatenate(frame_ids),
            "t_s": np.concatenate(times),
            "found": np.concatenate(founds),
            "corner": np.concatenate(corner_col),
            "u_px": uv[:, 0],
            "v_px": uv[:, 1],
        }
    )[CORNER_COLUMNS]
    corners.attrs = {"n_frames": n_done, "n_found": n_found, "order_methods": methods}
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
            "corners: %d frames had a corner off its grid neighbours by more than %.1f px "
            "after refinement; counted as not found",
            methods["inconsistent"],
            max_grid_deviation_px,
        )
    if methods.get("unresolved"):
        log.warning(
            "corners: %d frames had an undecidable 180-degree corner order (board ends alike, "
            "no recent previous frame); OpenCV's order kept",
            methods["unresolved"],
        )
    return corners


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
        the inliers' reprojection errors after refinement, px), ``n_inliers``. Frames without
        a board, or whose PnP fails or keeps fewer than 6 inliers, have ``valid = False`` and
        NaN pose.

    Raises
    ------
    InputError
        Missing columns, or a found frame whose corner indices are not exactly 0..N-1 or
        whose pixels are not finite.

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
        row = {"frame": frame, "t_s": t_s, "valid": False, "n_inliers": 0}
        found = bool(block["found"].iloc[0])
        if found:
            if not block["found"].all() or not np.array_equal(
                block["corner"].to_numpy(), np.arange(n_corners)
            ):
                raise InputError(
                    f"corners table, frame {frame}: found frame with corners "
                    f"{block['corner'].tolist()} / found {block['found'].unique().tolist()}; "
                    f"expected corners 0..{n_corners - 1} all found"
                )
            uv = block[["u_px", "v_px"]].to_numpy(dtype=np.float64)
            if not np.isfinite(uv).all():
                raise InputError(
                    f"corners table, frame {frame}: non-finite u_px/v_px on a found frame; "
                    "expected pixel coordinates"
                )
            row.update(
                _solve_frame(
                    p_B, uv, K, dist, ransac_reproj_px, ransac_iterations, ransac_confidence, seed
                )
            )
        rows.append(row)
    poses = pd.DataFrame(rows)
    for col in POSE_COLUMNS:
        if col not in poses.columns:
            poses[col] = np.nan
    poses = poses[POSE_COLUMNS].astype(
        {"frame": np.int64, "t_s": np.float64, "valid": bool, "n_inliers": np.int64}
    )
    n_valid = int(poses["valid"].sum())
    log.info("poses: %d of %d frames valid", n_valid, len(poses))
    return poses


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
