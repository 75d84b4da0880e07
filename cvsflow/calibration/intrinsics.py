"""Camera intrinsics from chessboard stills, and the chessboard geometry shared with ``pose``.

Board convention (docs/contracts.md)
------------------------------------
The board has ``squares_x`` by ``squares_y`` squares of side ``square_m``. Its inner corners
form a grid of ``nx = squares_x - 1`` by ``ny = squares_y - 1`` points; inner corner ``k`` lies
at board point ``((k % nx) * square_m, (k // nx) * square_m, 0)`` in frame B (origin at corner
0, z into the board). Square ``(i, j)`` (column ``i`` along board x, row ``j`` along board y,
square ``(0, 0)`` diagonally outside corner 0) is black when ``i + j`` is even. OpenCV's
pattern size is ``(nx, ny)``: rows of ``nx`` corners.

Seed: "the OpenCV functions findChessboardCorners() and cornerSubPix() are used to detect and
extract two-dimensional coordinate data of the corners ... fed to the calibrateCamera()
function to produce the camera matrix".
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import cv2
import numpy as np
import pandas as pd

from cvsflow.board import (
    SUBPIX_CRITERIA,
    board_name,
    board_object_points,
    board_pattern,
    board_record,
    board_type,
    default_passes,
    find_aprilgrid,
    find_charuco,
    make_detector,
    order_corners,
    passes_name,
)
from cvsflow.calibration.still_corners import refine_still_corners
from cvsflow.exceptions import CalibrationError, InputError

log = logging.getLogger(__name__)

# Stills are few and carefully taken, so the detector may take its time: adaptive threshold
# and normalisation help in uneven light; FAST_CHECK is left out because it only saves time on
# images without a board, which a calibration set should not have.
CALIB_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE

CALIB_CORNER_COLUMNS = ["image", "corner", "u_px", "v_px", "X_m", "Y_m"]

# camera.yaml's reason for a still without a board, by board type.
NOT_FOUND = {"chessboard": "no chessboard found", "charuco": "no ChArUco corners found",
             "aprilgrid": "no AprilGrid found"}

#: Keys of camera.yaml's ``std`` (the intrinsics' standard deviations; px, then unitless).
INTRINSIC_STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def find_board(
    gray: np.ndarray,
    board: dict,
    subpix_window_px: int,
    flags: int = CALIB_FIND_FLAGS,
) -> np.ndarray | None:
    """Detect the chessboard and refine its corners (OpenCV order), or None when not found.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    board : dict
    subpix_window_px : int
        Half side of cornerSubPix's search window (OpenCV ``winSize``); the window is
        ``2 * w + 1`` pixels wide.
    flags : int
        ``findChessboardCorners`` flags.

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float32, or None
    """
    pattern = board_pattern(board)
    found, corners = cv2.findChessboardCorners(gray, pattern, None, flags)
    if not found:
        return None
    w = int(subpix_window_px)
    corners = cv2.cornerSubPix(gray, corners, (w, w), (-1, -1), SUBPIX_CRITERIA)
    return corners.reshape(-1, 2)


def _check_gray(name: str, img) -> np.ndarray:
    """An image as a 2-D uint8 array, or an InputError naming it."""
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim != 2 or img.dtype != np.uint8 or img.size == 0:
        raise InputError(
            f"{name}: expected an 8-bit grayscale image, got dtype {img.dtype}, shape {img.shape}"
        )
    return img


def _duplicate_of(uv: np.ndarray, kept: list[tuple[str, np.ndarray]], duplicate_px: float,
                  ids: np.ndarray | None = None):
    """(name, corner RMS difference px) of the first kept view within duplicate_px, or None.

    With ``ids`` (a ChArUco view's corners; ``kept`` then holds ``(name, (ids, uv))``) the RMS
    is over the corners both views have, at least 4 of them."""
    for name, other in kept:
        if ids is not None:
            other_ids, other = other
            _, mine, theirs = np.intersect1d(ids, other_ids, return_indices=True)
            if len(mine) < 4:
                continue
            d = float(np.sqrt(np.mean(np.sum((uv[mine] - other[theirs]) ** 2, axis=1))))
        else:
            d = float(np.sqrt(np.mean(np.sum((uv - other) ** 2, axis=1))))
        if d < duplicate_px:
            return name, d
    return None


#: cornerSubPix half window of a ChArUco still when none is given (its detector's own
#: square-scaled window, ``detect_charuco_corners``, bounded by this).
CHARUCO_WINDOW_PX = 11


def _detect_view(gray: np.ndarray, board: dict, subpix_window_px: int | None, detector):
    """(corner ids, corners px in board order, refinement notes) of a still, or None.

    The chessboard's whole grid (``findChessboardCorners``, then the per-corner windows of
    :func:`cvsflow.calibration.still_corners.refine_still_corners`, or one fixed window of
    ``subpix_window_px``; ``order_corners``), or the ChArUco corners seen (``detector`` not
    None) or the AprilGrid's (its own window, from each tag's size). The notes name corners
    whose refinement is suspect (a fixed window reaching beyond the corner's four squares, a
    corner off its grid neighbours after a second refinement).
    """
    if board.get("type") == "aprilgrid":
        view = find_aprilgrid(gray, board)
        return None if view is None else (*view, {"notes": []})
    if detector is not None:
        view = find_charuco(gray, board, subpix_window_px or CHARUCO_WINDOW_PX, detector)
        return None if view is None else (*view, {"notes": []})
    found, corners = cv2.findChessboardCorners(gray, board_pattern(board), None, CALIB_FIND_FLAGS)
    if not found:
        return None
    refined = refine_still_corners(gray, corners, board, window_px=subpix_window_px)
    ordered, _ = order_corners(refined.uv_px, gray, board)
    over = int(np.sum(refined.window_px > np.floor(refined.limit_px)))
    notes = [f"corner {k} (OpenCV order): {why}" for k, why in refined.suspect.items()]
    if over:
        notes.append(f"{over} corners' fixed {int(subpix_window_px)} px window reaches beyond "
                     "their four squares (a neighbouring corner or the board's outline)")
    info = {"window_px": [int(refined.window_px.min()), int(refined.window_px.max())],
            "notes": notes}
    return None, ordered, info


def calibration_quality(
    rvecs: Sequence[np.ndarray],
    img_points: Sequence[np.ndarray],
    size_wh: tuple[int, int],
    K: np.ndarray,
    std: dict,
) -> dict:
    """How well a set of views constrains the intrinsics: coverage, tilt, focal uncertainty.

    Parameters
    ----------
    rvecs : sequence of ndarray, shape (3,)
        ``rvec_C_B`` of each used view (calibrateCamera).
    img_points : sequence of ndarray, shape (N, 2) or (N, 1, 2)
        Each view's corners, pixels.
    size_wh : (int, int)
        Image width and height, pixels.
    K : ndarray, shape (3, 3)
        Calibrated camera matrix, pixels.
    std : dict
        ``fx``, ``fy``, ... standard deviations (px for fx, fy).

    Returns
    -------
    dict
        ``coverage_share`` (share of the image inside the union of the views' corner hulls),
        ``tilt_min_deg``, ``tilt_max_deg`` (angle between the board normal and the optical
        axis), ``normal_spread_deg`` (largest angle between two views' board normals),
        ``rel_std_fx``, ``rel_std_fy`` (std of fx, fy over fx, fy).

    Notes
    -----
    Zhang's method needs views of the plane in different orientations: with parallel board
    normals the focal length trades off against distance, which ``normal_spread_deg`` and the
    relative std of fx reveal. Corners over a small part of the image leave the distortion
    unconstrained elsewhere (``coverage_share``).
    """
    w, h = size_wh
    scale = 4  # the coverage mask at a quarter of the resolution is plenty for a share
    mask = np.zeros((max(h // scale, 1), max(w // scale, 1)), np.uint8)
    for uv in img_points:
        hull = cv2.convexHull(np.asarray(uv, np.float32).reshape(-1, 2) / scale)
        cv2.fillConvexPoly(mask, np.rint(hull).astype(np.int32), 1)
    normals = np.array([cv2.Rodrigues(np.asarray(r, float))[0][:, 2] for r in rvecs])
    tilt = np.degrees(np.arccos(np.clip(np.abs(normals[:, 2]), 0.0, 1.0)))
    cosines = np.clip(np.abs(normals @ normals.T), 0.0, 1.0)
    return {
        "coverage_share": float(mask.mean()),
        "tilt_min_deg": float(tilt.min()),
        "tilt_max_deg": float(tilt.max()),
        "normal_spread_deg": float(np.degrees(np.arccos(cosines.min()))),
        "rel_std_fx": float(std["fx"] / K[0, 0]),
        "rel_std_fy": float(std["fy"] / K[1, 1]),
    }


def quality_warnings(
    quality: dict,
    used_names: Sequence[str],
    min_coverage: float = 0.3,
    min_normal_spread_deg: float = 10.0,
    max_rel_std_f: float = 0.01,
) -> list[str]:
    """Plain-language warnings for a calibration that ran but may not be trusted.

    Parameters
    ----------
    quality : dict
        `calibration_quality` of the used views.
    used_names : sequence of str
        The stills used, named in the warnings.
    min_coverage, min_normal_spread_deg, max_rel_std_f : float
        Thresholds: share of the image, degrees, std of fx or fy over its value.

    Returns
    -------
    list of str
    """
    names = ", ".join(used_names)
    out = []
    if quality["coverage_share"] < min_coverage:
        out.append(
            f"the board covers {100 * quality['coverage_share']:.0f} % of the image over all "
            f"stills (expected at least {100 * min_coverage:.0f} %): distortion is "
            f"extrapolated elsewhere; add stills with the board near the edges and corners"
        )
    if quality["normal_spread_deg"] < min_normal_spread_deg:
        out.append(
            f"the board normals of the stills ({names}) differ by at most "
            f"{quality['normal_spread_deg']:.1f} deg (tilt {quality['tilt_min_deg']:.1f} to "
            f"{quality['tilt_max_deg']:.1f} deg; expected a spread of at least "
            f"{min_normal_spread_deg:g} deg): the focal length trades off against distance; "
            f"add stills with the board tilted 20 to 45 deg in different directions"
        )
    worst = max(quality["rel_std_fx"], quality["rel_std_fy"])
    if worst > max_rel_std_f:
        out.append(
            f"the focal length is uncertain: std of fx {100 * quality['rel_std_fx']:.2f} %, "
            f"fy {100 * quality['rel_std_fy']:.2f} % (expected at most "
            f"{100 * max_rel_std_f:.2f} %)"
        )
    return out


def calibrate_camera(
    images: Sequence[tuple[str, np.ndarray]],
    board: dict,
    subpix_window_px: int | None = None,
    min_images: int = 5,
    duplicate_px: float = 0.5,
    min_coverage: float = 0.3,
    min_normal_spread_deg: float = 10.0,
    max_rel_std_f: float = 0.01,
    unreadable: Sequence[tuple[str, str]] = (),
) -> tuple[dict, pd.DataFrame]:
    """Intrinsics and distortion of a camera from chessboard (or ChArUco) stills.

    Parameters
    ----------
    images : sequence of (str, ndarray)
        ``(name, gray)`` pairs: the still's file name (used in messages and tables) and its
        8-bit grayscale image, shape (H, W). All stills must have the same size.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m). With ``type: charuco`` (``marker_m``,
        ``dictionary``) or ``type: aprilgrid`` the corners come from ``find_charuco`` or
        ``find_aprilgrid`` and a still may show part of the board (each view enters with the
        corners it has; camera.yaml's ``detector`` names an AprilGrid's tag detector).
    subpix_window_px : int, optional
        One cornerSubPix half window (OpenCV ``winSize``, pixels) for every corner; 11 is
        OpenCV's calibration sample (and reproduces its result). None (default): each corner
        its own window, sized to its squares and the edges' blur
        (:mod:`cvsflow.calibration.still_corners`).
    min_images : int
        Fewest *distinct* views (stills with a detected board, near-duplicates removed)
        needed to calibrate.
    duplicate_px : float
        A still whose ordered corners are within this RMS distance (px) of an earlier used
        still's is a near-duplicate: listed unused with the still it repeats. It would add
        no information and shrink the reported standard deviations.
    min_coverage, min_normal_spread_deg, max_rel_std_f : float
        Thresholds of the warnings (`quality_warnings`): share of the image covered by the
        board, spread of the board normals (deg), std of fx or fy over its value.
    unreadable : sequence of (str, str)
        ``(name, reason)`` of the stills that could not be decoded (an empty or truncated
        file: ``cvsflow.io.media.read_stills``): listed unused with their reason after the
        others, counted among the stills, and named in ``warnings``.

    Returns
    -------
    camera : dict
        camera.yaml content: ``K`` (3x3 list, px), ``dist`` ([k1, k2, p1, p2, k3]),
        ``std`` (1-sigma of each intrinsic: ``fx, fy, cx, cy`` in px, ``k1, k2, p1, p2, k3``
        unitless, OpenCV's ``stdDeviationsIntrinsics``),
        ``width``, ``height`` (px), ``rms_px`` (overall reprojection RMS), ``images`` (list of
        ``{name, used, reason, rms_px}``; ``rms_px`` is None for unused stills), ``n_used``,
        ``board``, ``quality`` (`calibration_quality`) and ``warnings`` (list of str, empty
        when the views constrain the intrinsics well).
    calib_corners : DataFrame
        ``image, corner, u_px, v_px, X_m, Y_m``: refined corners in board order (see
        ``order_corners``; a ChArUco still only the corners it shows) with their board-frame
        positions (m, Z = 0).

    Raises
    ------
    InputError
        A still that is not an 8-bit grayscale image, or whose size differs from the first.
    CalibrationError
        Fewer than ``min_images`` distinct stills with a board (the near-duplicates named),
        or calibrateCamera failing.

    Notes
    -----
    OpenCV ``findChessboardCorners``, ``cornerSubPix`` (criteria EPS + MAX_ITER, 30, 0.001)
    and ``calibrateCamera`` with default flags (k1, k2, p1, p2, k3), as the seed describes.
    The overall RMS is ``sqrt(sum of squared point errors / number of points)``, as OpenCV
    reports it; per-image RMS values use the same definition over that still's corners.
    ``std`` comes from ``calibrateCameraExtended``: the Gauss-Newton covariance
    ``s^2 (J^T J)^-1`` of the calibration (``s^2`` the residual variance per coordinate), i.e.
    the data-only uncertainty of the stills; downstream fits that hold some intrinsics fixed
    (``optimise_se3``) propagate it into their own standard errors.
    """
    if len(images) == 0:
        bad = "".join(f"; {n}: {r}" for n, r in unreadable)
        raise CalibrationError(f"calibration: no stills given; expected at least one image{bad}")
    p_B = board_object_points(board).astype(np.float32)
    kind = board_type(board)
    detector = make_detector(board) if kind == "charuco" else None
    what = board_name(board)
    size_wh = None
    first_name = None
    records = []
    obj_points, img_points, used_names, view_ids = [], [], [], []
    kept, duplicates = [], []
    for name, img in images:
        gray = _check_gray(name, img)
        h, w = gray.shape
        if size_wh is None:
            size_wh, first_name = (w, h), name
        elif (w, h) != size_wh:
            raise InputError(
                f"{name}: image is {w}x{h} px; expected {size_wh[0]}x{size_wh[1]} px like "
                f"{first_name} (all calibration stills must have the same size)"
            )
        view = _detect_view(gray, board, subpix_window_px, detector)
        if view is None:
            log.warning("%s: no %s found; skipped", name, what)
            records.append(
                {"name": name, "used": False, "reason": NOT_FOUND[kind], "rms_px": None}
            )
            continue
        ids, ordered, info = view
        dup = _duplicate_of(ordered, kept, duplicate_px, ids)
        if dup is not None:
            log.warning("%s: near-duplicate of %s (corners within %.3f px RMS); skipped",
                        name, *dup)
            records.append(
                {
                    "name": name,
                    "used": False,
                    "reason": f"near-duplicate of {dup[0]} (corners within {dup[1]:.3f} px RMS)",
                    "rms_px": None,
                }
            )
            duplicates.append(f"{name} (of {dup[0]})")
            continue
        kept.append((name, ordered if ids is None else (ids, ordered)))
        # A ChArUco view has the corners it saw; calibrateCamera takes each view's own subset.
        obj_points.append(p_B if ids is None else p_B[ids])
        img_points.append(ordered.astype(np.float32).reshape(-1, 1, 2))
        view_ids.append(np.arange(len(p_B)) if ids is None else ids)
        used_names.append(name)
        records.append({"name": name, "used": True, "reason": "ok", "rms_px": None, **info})
        for note in info["notes"]:
            log.warning("%s: %s", name, note)

    records += [{"name": n, "used": False, "reason": r, "rms_px": None} for n, r in unreadable]
    bad_text = f"; {len(unreadable)} cannot be decoded: {', '.join(n for n, _ in unreadable)}" \
        if unreadable else ""
    if len(used_names) < min_images:
        skipped = [r["name"] for r in records if r["reason"] == NOT_FOUND[kind]]
        dup_text = (
            f"; near-duplicates removed: {', '.join(duplicates)}, within {duplicate_px:g} px"
            if duplicates
            else ""
        )
        raise CalibrationError(
            f"calibration: {len(used_names)} of {len(images) + len(unreadable)} stills have a "
            f"usable and distinct {what} view; "
            f"at least {min_images} needed (used: {used_names}; no board found in: "
            f"{skipped}{dup_text}{bad_text})"
        )

    try:
        # calibrateCameraExtended is calibrateCamera plus the standard deviations (the same
        # solver and flags: K, dist and the RMS are identical); std_intr holds fx, fy, cx, cy,
        # k1, k2, p1, p2, k3, then the terms of richer models (zero here).
        rms_px, K, dist, rvecs, tvecs, std_intr, _, _ = cv2.calibrateCameraExtended(
            obj_points, img_points, size_wh, None, None
        )
    except cv2.error as exc:
        raise CalibrationError(
            f"calibration: calibrateCamera failed on {len(used_names)} stills ({exc})"
        ) from exc

    rms_by_name = {}
    rows = []
    for name, p_obj, p_img, ids, rvec, tvec in zip(used_names, obj_points, img_points, view_ids,
                                                   rvecs, tvecs, strict=True):
        proj, _ = cv2.projectPoints(p_obj, rvec, tvec, K, dist)
        err = proj.reshape(-1, 2) - p_img.reshape(-1, 2)
        rms_by_name[name] = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
        uv = p_img.reshape(-1, 2).astype(np.float64)
        rows.append(
            pd.DataFrame(
                {
                    "image": name,
                    "corner": np.asarray(ids, dtype=np.int64),
                    "u_px": uv[:, 0],
                    "v_px": uv[:, 1],
                    "X_m": p_obj[:, 0].astype(np.float64),
                    "Y_m": p_obj[:, 1].astype(np.float64),
                }
            )
        )
    for rec in records:
        if rec["used"]:
            rec["rms_px"] = rms_by_name[rec["name"]]

    std_intr = np.asarray(std_intr, dtype=float).ravel()
    std = {n: float(v) for n, v in zip(INTRINSIC_STD_NAMES, std_intr[:9], strict=True)}
    quality = calibration_quality(rvecs, img_points, size_wh, K, std)
    warnings = quality_warnings(
        quality, used_names, min_coverage, min_normal_spread_deg, max_rel_std_f
    )
    for text in warnings:
        log.warning("calibration: %s", text)
    warnings += [f"{n}: {r}; left out" for n, r in unreadable]  # logged when read
    camera = {
        "K": np.asarray(K, dtype=float).tolist(),
        "dist": np.asarray(dist, dtype=float).ravel()[:5].tolist(),
        "std": std,
        "width": int(size_wh[0]),
        "height": int(size_wh[1]),
        "rms_px": float(rms_px),
        "images": records,
        "n_used": len(used_names),
        "board": board_record(board),
        "quality": quality,
        "warnings": warnings,
    }
    if kind == "aprilgrid":  # which tag detector found the corners (pupil-apriltags may be missing)
        camera["detector"] = passes_name(default_passes())
    log.info(
        "calibrated on %d of %d stills: rms %.3f px, fx %.2f, fy %.2f px",
        len(used_names),
        len(images) + len(unreadable),
        rms_px,
        K[0, 0],
        K[1, 1],
    )
    calib_corners = pd.concat(rows, ignore_index=True)[CALIB_CORNER_COLUMNS]
    return camera, calib_corners


def view_corners(images: Sequence[tuple[str, np.ndarray]], board: dict,
                 subpix_window_px: int | None = None) -> pd.DataFrame:
    """The board's refined corners in each still, as a ``calib_corners`` table, no calibration.

    For stills whose camera is calibrated already, e.g. the shared views of a rig
    (:func:`cvsflow.rig.extrinsics.stereo_extrinsics`): the same detection and ordering as
    :func:`calibrate_camera` (chessboard grid or ChArUco corners); a still without a board is
    left out (logged).

    Parameters
    ----------
    images : sequence of (str, ndarray)
        ``(name, gray)`` pairs, 8-bit grayscale (H, W).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m); ChArUco keys with ``type: charuco``.
    subpix_window_px : int, optional
        One cornerSubPix half window for every corner, px; None: per-corner windows (as
        :func:`calibrate_camera`).

    Returns
    -------
    corners : DataFrame
        ``image, corner, u_px, v_px, X_m, Y_m`` (``CALIB_CORNER_COLUMNS``), px and m; empty
        when no still shows the board.

    Raises
    ------
    InputError
        A still that is not an 8-bit grayscale image (named).
    """
    p_B = board_object_points(board)
    detector = make_detector(board) if board.get("type", "chessboard") == "charuco" else None
    rows = []
    for name, img in images:
        view = _detect_view(_check_gray(name, img), board, subpix_window_px, detector)
        if view is None:
            log.warning("%s: no board found; left out", name)
            continue
        ids, uv, _ = view
        ids = np.arange(len(p_B)) if ids is None else np.asarray(ids, dtype=np.int64)
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        rows.append(pd.DataFrame({"image": name, "corner": ids.astype(np.int64), "u_px": uv[:, 0],
                                  "v_px": uv[:, 1], "X_m": p_B[ids, 0], "Y_m": p_B[ids, 1]}))
    if not rows:
        return pd.DataFrame({c: [] for c in CALIB_CORNER_COLUMNS})
    return pd.concat(rows, ignore_index=True)[CALIB_CORNER_COLUMNS]
