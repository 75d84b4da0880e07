"""The board's pose in the camera (PnP) per video frame, from the corners table.

Seed: "OpenCV's solvePnPRansac() function can be employed to extract the pose matrix P of the
camera relative to the calibration board ... It was found that a 5x6 chessboard does not have
enough features to guarantee accurate results from the ePnP method".

Reads ``corners.parquet`` (:func:`cvsflow.corners.extract.extract_corners`) and gives the
``poses_raw.parquet`` table of docs/contracts.md (``estimate_poses``).
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pandas as pd

from cvsflow.board import CORNER_COLUMNS, board_object_points
from cvsflow.exceptions import InputError
from cvsflow.geometry import transforms as tf

log = logging.getLogger(__name__)


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
        ``squares_x``, ``squares_y``, ``square_m`` (m); any board type (corner ids are rows of
        ``cvsflow.board.board_object_points``).
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
        (corners the frame has: a found frame may have a subset, e.g. a hand over the board);
        ``t_ns`` (int64, exact) after ``t_s`` when the corners table has it (a frame folder).
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
            if _spread_ok(p_B[ids]):
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
    if "t_ns" in corners.columns:  # a timestamped source: its exact times carried along
        poses.insert(2, "t_ns", ordered.groupby("frame", sort=True)["t_ns"].first().to_numpy(np.int64))
    n_valid = int(poses["valid"].sum())
    log.info("poses: %d of %d frames valid", n_valid, len(poses))
    return poses


def _spread_ok(p_B: np.ndarray) -> bool:
    """At least MIN_INLIERS corners spanning two rows and two columns of the board (two distinct
    x and two distinct y in B: not all on one grid line, a pose needs a planar spread)."""
    return bool(len(p_B) >= MIN_INLIERS and len(np.unique(p_B[:, 0])) >= 2
                and len(np.unique(p_B[:, 1])) >= 2)


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
