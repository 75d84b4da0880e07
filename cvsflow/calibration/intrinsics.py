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
from cvsflow.calibration.assess import assess_fit
from cvsflow.calibration.bundle import MIN_CORNERS_PER_STILL, StillView
from cvsflow.calibration.lens import K_dist, lens_model
from cvsflow.calibration.outliers import K_SIGMA, fit_with_outliers
from cvsflow.calibration.still_corners import refine_still_corners
from cvsflow.exceptions import CalibrationError, InputError

log = logging.getLogger(__name__)

# Stills are few and carefully taken, so the detector may take its time: adaptive threshold
# and normalisation help in uneven light; FAST_CHECK is left out because it only saves time on
# images without a board, which a calibration set should not have.
CALIB_FIND_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE

CALIB_CORNER_COLUMNS = ["image", "corner", "u_px", "v_px", "X_m", "Y_m", "used"]

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


def _check_sizes(grays: list[tuple[str, np.ndarray]]) -> tuple[int, int]:
    """The stills' common (width, height), px, or an InputError naming each size's files."""
    by_size: dict = {}
    for name, gray in grays:
        by_size.setdefault((gray.shape[1], gray.shape[0]), []).append(name)
    if len(by_size) > 1:
        sizes = sorted(by_size.items(), key=lambda kv: -len(kv[1]))
        listed = "; ".join(
            f"{w}x{h} px: {', '.join(names[:5])}" + (f" and {len(names) - 5} more"
                                                      if len(names) > 5 else "")
            for (w, h), names in sizes)
        raise InputError(f"calibration stills of {len(by_size)} sizes ({listed}); expected one "
                         "size (all stills from the same camera mode)")
    return next(iter(by_size))


def _detect_stills(grays, board: dict, subpix_window_px: int | None, duplicate_px: float):
    """Each still's refined corners in board order, near-duplicates left out.

    Returns
    -------
    views : list of StillView
    records : list of dict
        camera.yaml's ``images``: ``name``, ``used``, ``reason``, ``rms_px`` (None here), and
        for a used still its refinement's ``window_px`` (min, max) and ``notes``.
    duplicates : list of str
    """
    p_B = board_object_points(board)
    kind = board_type(board)
    detector = make_detector(board) if kind == "charuco" else None
    what = board_name(board)
    views, records, kept, duplicates = [], [], [], []
    for name, gray in grays:
        view = _detect_view(gray, board, subpix_window_px, detector)
        if view is None:
            log.warning("%s: no %s found; skipped", name, what)
            records.append({"name": name, "used": False, "reason": NOT_FOUND[kind],
                            "rms_px": None})
            continue
        ids, ordered, info = view
        dup = _duplicate_of(ordered, kept, duplicate_px, ids)
        if dup is not None:
            log.warning("%s: near-duplicate of %s (corners within %.3f px RMS); skipped",
                        name, *dup)
            records.append({"name": name, "used": False, "rms_px": None, "reason":
                            f"near-duplicate of {dup[0]} (corners within {dup[1]:.3f} px RMS)"})
            duplicates.append(f"{name} (of {dup[0]})")
            continue
        kept.append((name, ordered if ids is None else (ids, ordered)))
        ids = np.arange(len(p_B)) if ids is None else np.asarray(ids, dtype=np.int64)
        views.append(StillView(name, ids, p_B[ids], np.asarray(ordered, np.float64)))
        records.append({"name": name, "used": True, "reason": "ok", "rms_px": None, **info})
        for note in info["notes"]:
            log.warning("%s: %s", name, note)
    return views, records, duplicates


def _too_few_error(records, views, n_images, min_images, duplicates, duplicate_px, board,
                   unreadable=()):
    """The CalibrationError of too few usable, distinct stills (each kind of still named)."""
    what = board_name(board)
    skipped = [r["name"] for r in records if r["reason"] == NOT_FOUND[board_type(board)]]
    dup_text = (f"; near-duplicates removed: {', '.join(duplicates)}, within {duplicate_px:g} px"
                if duplicates else "")
    if unreadable:
        dup_text += (f"; {len(unreadable)} cannot be decoded: "
                     f"{', '.join(n for n, _ in unreadable)}")
    return CalibrationError(
        f"calibration: {len(views)} of {n_images} stills have a usable and distinct {what} "
        f"view; at least {min_images} needed (used: {[v.name for v in views]}; no board found "
        f"in: {skipped}{dup_text})")


def _fit_stills(views, size_wh, model, reject, k_sigma, min_images):
    """The fit with its outliers, or a CalibrationError when rejection leaves too little."""
    try:
        fit, rejected = fit_with_outliers(views, size_wh, model, k_sigma=k_sigma, reject=reject)
    except (cv2.error, np.linalg.LinAlgError) as exc:
        raise CalibrationError(f"calibration: the {model.name} fit failed on {len(views)} stills "
                               f"({exc})") from exc
    lost = [f"{v.name} ({int(m.sum())} of {len(v.ids)} corners kept)"
            for v, m in zip(views, fit.inlier, strict=True) if m.sum() < MIN_CORNERS_PER_STILL]
    if len(views) - len(lost) < min_images:
        raise CalibrationError(
            f"calibration: after outlier rejection {len(views) - len(lost)} stills keep a pose; "
            f"at least {min_images} needed (lost: {', '.join(lost[:4])}"
            + (f" and {len(lost) - 4} more" if len(lost) > 4 else "") + ")")
    if lost:
        log.warning("calibration: stills without a pose after outlier rejection: %s",
                    ", ".join(lost))
    return fit, rejected


def calibrate_camera(
    images: Sequence[tuple[str, np.ndarray]],
    board: dict,
    subpix_window_px: int | None = None,
    min_images: int = 5,
    duplicate_px: float = 0.5,
    min_coverage: float = 0.3,
    min_normal_spread_deg: float = 10.0,
    max_rel_std_f: float = 0.01,
    model: str = "opencv5",
    reject_outliers: bool = True,
    k_sigma: float = K_SIGMA,
    cross_validation: bool = True,
    unreadable: Sequence[tuple[str, str]] = (),
) -> tuple[dict, pd.DataFrame]:
    """Intrinsics and distortion of a camera from chessboard (or ChArUco) stills, judged.

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
        needed to calibrate, and fewest stills keeping a pose after outlier rejection.
    duplicate_px : float
        A still whose ordered corners are within this RMS distance (px) of an earlier used
        still's is a near-duplicate: listed unused with the still it repeats. It would add
        no information and shrink the reported standard deviations.
    min_coverage, min_normal_spread_deg, max_rel_std_f : float
        Warn boundaries of the quality verdicts (:mod:`cvsflow.calibration.quality`): share
        of the image covered by the board, spread of the board normals (deg), std of fx or fy
        over its value.
    model : {"opencv5", "opencv8", "fisheye4"}
        Lens model (:mod:`cvsflow.calibration.lens`): OpenCV's 5 terms, the 8-term rational
        model, the 4-term fisheye (Kannala-Brandt).
    reject_outliers : bool
        Leave out corners beyond ``k_sigma`` fitted corner sigmas (:mod:`.outliers`); they are
        named in ``outliers`` either way.
    k_sigma : float
        The rejection threshold, in sigmas of the fitted corner noise.
    cross_validation : bool
        Fit two interleaved halves of the stills and compare (:mod:`.cross_validation`).
    unreadable : sequence of (str, str)
        ``(name, reason)`` of the stills that could not be decoded (an empty or truncated
        file: ``cvsflow.io.media.read_stills``): listed unused with their reason after the
        others, counted among the stills, and named in ``warnings``.

    Returns
    -------
    camera : dict
        camera.yaml content: ``model``; ``K`` (3x3 list, px), ``dist`` (the model's terms in
        OpenCV's order: k1 k2 p1 p2 k3 [k4 k5 k6], or the fisheye's k1..k4); ``std`` (1-sigma
        of each intrinsic, ``fx, fy, cx, cy`` px, the terms unitless: ``s^2 (J^T J)^-1``, which
        is OpenCV's ``stdDeviationsIntrinsics``), ``std_jackknife`` (leave-one-still-out);
        ``width``, ``height`` (px); ``rms_px`` (reprojection RMS of the kept corners, OpenCV's
        definition), ``sigma_px`` (fitted corner noise per coordinate); ``subpix_window_px``;
        ``images`` (per still ``name, used, reason, rms_px`` and for a used still
        ``window_px``, ``notes``, ``n_rejected``, ``chi2_ratio``, ``influence_sigma``,
        ``named``, ``reasons``); ``n_used``; ``board``; ``outliers``;
        ``projection_uncertainty``; ``cross_validation``; ``quality`` (the stills' geometry,
        ``verdicts`` and their ``summary`` line) and ``warnings`` (list of str).
    calib_corners : DataFrame
        ``image, corner, u_px, v_px, X_m, Y_m, used``: refined corners in board order (see
        ``order_corners``; a ChArUco still only the corners it shows) with their board-frame
        positions (m, Z = 0), ``used`` False for a corner left out of the fit.

    Raises
    ------
    InputError
        A still that is not an 8-bit grayscale image, or stills of different sizes (each size
        and its files named).
    CalibrationError
        Fewer than ``min_images`` distinct stills with a board (the near-duplicates named),
        every still losing its corners to the outlier rejection, fewer than ``min_images``
        stills keeping a pose after it (each named with its corners kept), or the fit failing.
    ConfigError
        An unknown ``model``.

    Notes
    -----
    Corners: OpenCV ``findChessboardCorners``, then cornerSubPix per corner
    (:mod:`.still_corners`). The fit (:mod:`.bundle`) is OpenCV's problem solved by
    Levenberg-Marquardt from ``calibrateCamera``'s answer, so that corners can be left out by
    name and the covariance of every parameter kept; on the same corners it is OpenCV's
    minimum. The overall RMS is ``sqrt(sum of squared point errors / number of points)``, as
    OpenCV reports it; per-still RMS values use the same definition over that still's kept
    corners. The intrinsics' ``std`` is the data-only uncertainty of the stills; downstream
    fits that hold some intrinsics fixed (``optimise_se3``) propagate it into their own
    standard errors.
    """
    if len(images) == 0:
        bad = "".join(f"; {n}: {r}" for n, r in unreadable)
        raise CalibrationError(f"calibration: no stills given; expected at least one image{bad}")
    lm = lens_model(model)
    grays = [(name, _check_gray(name, img)) for name, img in images]
    size_wh = _check_sizes(grays)
    views, records, duplicates = _detect_stills(grays, board, subpix_window_px, duplicate_px)
    records += [{"name": n, "used": False, "reason": r, "rms_px": None} for n, r in unreadable]
    if len(views) < min_images:
        raise _too_few_error(records, views, len(images) + len(unreadable), min_images,
                             duplicates, duplicate_px, board, unreadable)
    fit, rejected = _fit_stills(views, size_wh, lm, reject_outliers, k_sigma, min_images)
    judged = assess_fit(views, fit, rejected, k_sigma=k_sigma, reject=reject_outliers,
                        cross_validation=cross_validation, min_coverage=min_coverage,
                        min_normal_spread_deg=min_normal_spread_deg, max_rel_std_f=max_rel_std_f)
    by_name = {s["name"]: s for s in judged["stills"]}
    for rec in records:
        if rec["used"]:
            s = by_name[rec["name"]]
            rec.update({"rms_px": s["rms_px"], "n_rejected": s["n_rejected"],
                        "chi2_ratio": s["chi2_ratio"], "influence_sigma": s["influence_sigma"],
                        "named": s["named"], "reasons": s["reasons"]})
    for text in judged["warnings"]:
        log.warning("calibration: %s", text)
    judged["warnings"] += [f"{n}: {r}; left out" for n, r in unreadable]  # logged when read
    K, dist = K_dist(fit.theta, lm)
    names = lm.param_names
    camera = {
        "model": lm.name, "K": K.tolist(), "dist": dist.tolist(),
        "std": dict(zip(names, map(float, fit.theta_std), strict=True)),
        "std_jackknife": dict(zip(names, map(float, judged["std_jackknife"]), strict=True)),
        "width": int(size_wh[0]), "height": int(size_wh[1]),
        "rms_px": fit.rms_px, "sigma_px": fit.sigma_px,
        "subpix_window_px": None if subpix_window_px is None else int(subpix_window_px),
        "images": records, "n_used": len(views), "board": board_record(board),
        "outliers": judged["outliers"],
        "projection_uncertainty": judged["projection_uncertainty"],
        "cross_validation": judged["cross_validation"],
        "quality": judged["quality"], "warnings": judged["warnings"],
    }
    if board_type(board) == "aprilgrid":  # the tag detector that ran (pupil-apriltags or not)
        camera["detector"] = passes_name(default_passes())
    log.info("calibrated on %d of %d stills (%s): rms %.3f px, fx %.2f, fy %.2f px; %s",
             len(views), len(images) + len(unreadable), lm.name, fit.rms_px, K[0, 0], K[1, 1],
             judged["quality"]["summary"])
    return camera, _corner_table(views, fit)


def _corner_table(views, fit) -> pd.DataFrame:
    """calib_corners: every still's corners with their board points and whether the fit used them."""
    rows = [pd.DataFrame({"image": v.name, "corner": v.ids.astype(np.int64),
                          "u_px": v.uv_px[:, 0], "v_px": v.uv_px[:, 1],
                          "X_m": v.p_B[:, 0].astype(np.float64),
                          "Y_m": v.p_B[:, 1].astype(np.float64), "used": m.copy()})
            for v, m in zip(views, fit.inlier, strict=True)]
    return pd.concat(rows, ignore_index=True)[CALIB_CORNER_COLUMNS]

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
        ``image, corner, u_px, v_px, X_m, Y_m, used`` (``CALIB_CORNER_COLUMNS``; ``used`` True),
        px and m; empty when no still shows the board.

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
                                  "v_px": uv[:, 1], "X_m": p_B[ids, 0], "Y_m": p_B[ids, 1],
                                  "used": True}))
    if not rows:
        return pd.DataFrame({c: [] for c in CALIB_CORNER_COLUMNS})
    return pd.concat(rows, ignore_index=True)[CALIB_CORNER_COLUMNS]
