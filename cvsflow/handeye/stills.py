"""Hand-eye calibration from chessboard stills, each with a pose of the camera's carrier.

Frames, the two modes (``eye_in_hand``, ``eye_to_hand``) and the problem
``T_C_B,i = inv(H) @ A_i @ G`` (``A_i G = H B_i``) are set out in :mod:`cvsflow.handeye.closed_form`.

Method
------
1. Corners per still with :func:`cvsflow.calibration.intrinsics.find_board` and ordered with
   :func:`cvsflow.board.order.order_corners` (the board's colour fixes corner 0, so every
   still shares one board frame; for boards whose ends look alike the order of each still is
   chosen so its relative rotations match the carrier's); PnP per still
   (:func:`cvsflow.optimise.se3_start.solve_pnp_frames`).
2. Closed form (:mod:`cvsflow.handeye.closed_form`): ``cv2.calibrateHandEye`` (Tsai, Park,
   Horaud, Andreff, Daniilidis) or ``cv2.calibrateRobotWorldHandEye`` (Shah, Li); G from the
   mean of ``inv(A_i) H B_i``.
3. Outlier screen: with the carrier poses taken as exact, each still's reprojection RMS under
   the fit of the other stills; the worst is rejected while it exceeds 4x the median.
4. Refinement (:mod:`cvsflow.handeye.reprojection`): H, G (and optionally fx, fy, cx, cy, distortion)
   minimising the corner reprojection error over all stills, ``scipy.optimize.least_squares``
   with the analytic Jacobian; projection and its derivatives from :mod:`cvsflow.geometry.camera`.
   By default the carrier poses are not exact: each still's pose error (a turn about the carrier
   origin and a shift) is an unknown with a zero-mean isotropic prior, the corner, rotation and
   position sigmas estimated together (Foerstner's variance components). Without it, robot or
   mocap pose errors of a few mm are absorbed into H and G: on ViSP's Franka set the plain fit
   lands 5 mm / 3.4 deg from the published eMc, the errors-in-variables fit 0.4 mm / 0.07 deg.
5. Standard errors: ``N^-1`` of the whitened problem (with one group, ``s^2 (J^T J)^-1``,
   :func:`cvsflow.optimise.se3_cov.covariances`), plus the fixed intrinsics' std when the camera
   file gives it; and a delete-one-still jackknife, which sees errors the model misses. The
   reported ``std`` is the larger of the two per parameter.

Rotation errors are local: ``R = R_hat @ expm([w]x)``, w about the axes of the child frame
(C for ``T_Cm_C`` and ``T_W_C``, B for ``T_W_B`` and ``T_Bm_B``); translations in the parent.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from cvsflow.board import board_name, board_object_points, board_record, board_type, order_corners
from cvsflow.calibration import find_board, view_corners
from cvsflow.exceptions import CalibrationError, InputError
from cvsflow.geometry import transforms as tf
from cvsflow.handeye.closed_form import (
    FRAME_NAMES,
    MIN_AXIS_SPREAD_DEG,
    MIN_STILLS,
    _check_mode,
    closed_form_hand_eye,
    motion_axis_spread_deg,
    pose_std_record,
)
from cvsflow.handeye.consistency import (
    MAX_ANGLE_DISAGREEMENT_DEG,
    check_motion_scale,
    check_pose_pairing,
    motion_scale,
)
from cvsflow.handeye.reprojection import (
    _intrinsics_vector,
    _Model,
    jackknife_std,
    leave_one_out_rms,
    refine_hand_eye,
)
from cvsflow.optimise import solve_pnp_frames

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- the session


def detect_still_corners(images, board, subpix_window_px=11):
    """Ordered corners of each still, or the reason there are none.

    Parameters
    ----------
    images : sequence of (str, ndarray)
        ``(name, gray)``: the still's name and its 8-bit grayscale image.
    board : dict
        The board block: a chessboard (``squares_x``, ``squares_y``, ``square_m``), a ChArUco
        board or an AprilGrid (``type``; corners found by :func:`cvsflow.calibration.view_corners`,
        each still with the corners it shows).

    Returns
    -------
    list of dict
        ``name``, ``uv_px`` ((P, 2) in board order, NaN rows for corners not seen, or None),
        ``order`` (how the 180-degree ambiguity was decided; ``ids`` for boards whose markers
        name every corner), ``reason``.
    """
    out = []
    kind = board_type(board)
    n_points = len(board_object_points(board))
    for name, gray in images:
        gray = np.asarray(gray)
        if gray.ndim == 3:
            gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
        if kind != "chessboard":
            seen = view_corners([(name, gray)], board, subpix_window_px)
            if seen.empty:
                out.append({"name": name, "uv_px": None, "order": None,
                            "reason": f"no {board_name(board)} found"})  # fmt: skip
                continue
            uv = np.full((n_points, 2), np.nan)
            uv[seen["corner"].to_numpy()] = seen[["u_px", "v_px"]].to_numpy(float)
            out.append({"name": name, "uv_px": uv, "order": "ids", "reason": "ok"})
            continue
        corners = find_board(gray, board, subpix_window_px)
        if corners is None:
            out.append({"name": name, "uv_px": None, "order": None,
                        "reason": f"no {board_name(board)} found"})  # fmt: skip
            continue
        uv, how = order_corners(corners, gray, board)
        out.append({"name": name, "uv_px": uv, "order": how, "reason": "ok"})
    return out


def _resolve_flips(uv, p_B, T_W_X, camera):
    """For boards whose two ends look alike: the corner order of each still (as is, reversed)
    whose relative board rotations match the carrier's in angle (conjugation keeps angles)."""
    K = np.asarray(camera["K"], float)
    dist = np.asarray(camera["dist"], float)
    T_as, _ = solve_pnp_frames(uv, p_B, K, dist)
    T_rev, _ = solve_pnp_frames(uv[:, ::-1], p_B, K, dist)
    R_X = np.asarray(T_W_X, float)[:, :3, :3]
    flip = np.zeros(len(uv), bool)
    for i in range(1, len(uv)):
        ang_X = tf.rotation_angle(R_X[0].T @ R_X[i])
        errs = [abs(tf.rotation_angle(T_as[0, :3, :3] @ T[i, :3, :3].T) - ang_X)
                for T in (T_as, T_rev)]  # fmt: skip
        flip[i] = errs[1] < errs[0]
    return np.where(flip[:, None, None], uv[:, ::-1], uv), flip


def calibrate_hand_eye(
    images: Sequence[tuple[str, np.ndarray]],
    T_W_X: np.ndarray,
    board: dict,
    camera: dict,
    mode: str = "eye_in_hand",
    method: str = "park",
    free_intrinsics: Sequence[str] = (),
    pose_noise: bool = True,
    pose_sigma_m: float | None = None,
    pose_sigma_rad: float | None = None,
    subpix_window_px: int = 11,
    reject_factor: float = 4.0,
    reject_min_px: float = 1.0,
    pose_names: Sequence[str] | None = None,
    detections: list | None = None,
) -> dict:
    """Hand-eye calibration of a session of stills with one carrier pose each.

    Parameters
    ----------
    images : sequence of (str, ndarray)
        ``(name, gray)`` per still (8-bit grayscale).
    T_W_X : ndarray, shape (N, 4, 4)
        The carrier's pose in W at each still (NaN: no valid pose), metres.
    board : dict
        ``squares_x``, ``squares_y`` (squares), ``square_m`` (m).
    camera : dict
        Known intrinsics: ``K`` (3x3, px), ``dist`` (5), ``width``, ``height`` (px).
    mode : str
        ``eye_in_hand`` (camera on the carrier) or ``eye_to_hand`` (board on the carrier).
    method : str
        Closed-form start (``CLOSED_FORM_METHODS``).
    free_intrinsics : sequence of str
        Intrinsics refined with the poses (e.g. ``fx fy cx cy``); empty: intrinsics known.
    pose_noise : bool
        Model the carrier poses' own errors (see :func:`refine_hand_eye`); False takes them
        as exact.
    pose_sigma_m, pose_sigma_rad : float, optional
        Known carrier-pose standard deviations (m, rad); estimated from the data when None.
    subpix_window_px : int
        cornerSubPix half window, px.
    reject_factor, reject_min_px : float
        With the carrier poses taken as exact, each still's RMS under the fit of the others
        (:func:`leave_one_out_rms`); the worst still is rejected and the screen redone while
        it exceeds both ``reject_factor`` times the median and ``reject_min_px``.
    pose_names : sequence of str, optional
        Where each pose came from (named in the result).
    detections : list of dict, optional
        :func:`detect_still_corners` of ``images`` when the caller has it already.

    Returns
    -------
    dict
        handeye.yaml content (see docs/tools.md): ``mode``, the two transforms as 4x4 lists
        (``T_Cm_C`` and ``T_W_B``, or ``T_W_C`` and ``T_Bm_B``), ``std`` of each (deg about the
        child axes, mm in the parent; the larger of ``std_gauss_newton`` and
        ``std_jackknife``), ``closed_form``, ``rms_px``, ``sigma_px``, ``intrinsics``,
        ``stills`` (name, pose, used, reason, ``rms_px`` under the fit, ``chain_rms_px`` the
        board's corners projected through the carrier pose as given, T_H, T_G and the
        intrinsics of the fit that takes the carrier poses as exact, ``chain_rms_loo_px`` the
        same under that fit without the still) and ``n_used``.

    Raises
    ------
    InputError
        Image and pose counts differ, or a bad mode, method or camera.
    CalibrationError
        Fewer than 3 usable stills, or carrier motions about one axis only.
    PosePairingError
        Stills and poses paired wrong (the angles of their motions disagree; worst pairs named).
    ScaleMismatchError
        The camera's translations by PnP and the carrier's disagree in scale (a wrong
        ``square_m`` or pose unit).
    """
    _check_mode(mode)
    T_W_X = np.asarray(T_W_X, float)
    if T_W_X.shape != (len(images), 4, 4):
        raise InputError(
            f"hand-eye: {len(images)} stills and carrier poses of shape {T_W_X.shape}; expected "
            f"one pose per still, ({len(images)}, 4, 4)"
        )
    pose_names = list(pose_names) if pose_names is not None else [""] * len(images)
    p_B = board_object_points(board)
    K = np.asarray(camera["K"], float)
    dist = np.asarray(camera.get("dist", np.zeros(5)), float).ravel()
    cam = {"K": K, "dist": dist, "std": camera.get("std")}
    det = detections if detections is not None else detect_still_corners(images, board, subpix_window_px)
    records = [{"name": d["name"], "pose": pn, "used": False, "reason": d["reason"],
                "rms_px": None} for d, pn in zip(det, pose_names, strict=True)]  # fmt: skip
    for rec, T in zip(records, T_W_X, strict=True):
        if rec["reason"] == "ok" and not np.isfinite(T).all():
            rec["reason"] = "no valid carrier pose"
    idx = [i for i, r in enumerate(records) if r["reason"] == "ok"]
    if len(idx) < MIN_STILLS:
        raise CalibrationError(_too_few(records))
    uv = np.stack([det[i]["uv_px"] for i in idx])
    flipped = np.zeros(len(idx), bool)
    if any(det[i]["order"] not in ("colour", "ids") for i in idx):
        uv, flipped = _resolve_flips(uv, p_B, T_W_X[idx], cam)
    T_C_B, ok = solve_pnp_frames(uv, p_B, K, dist)
    for k, i in enumerate(idx):
        if not ok[k]:
            records[i]["reason"] = "PnP failed"
    keep = ok.copy()
    _check_motions(records, idx, keep, T_W_X, T_C_B, mode, method, board)
    opts = {"pose_noise": pose_noise, "pose_sigma_m": pose_sigma_m,
            "pose_sigma_rad": pose_sigma_rad}
    while True:
        sel = np.array(idx)[keep]
        if len(sel) < MIN_STILLS:
            raise CalibrationError(_too_few(records))
        T0_H, T0_G = closed_form_hand_eye(T_W_X[sel], T_C_B[keep], mode, method)
        start = _Model(T_W_X[sel], mode, uv[keep], p_B, T0_H, T0_G, _intrinsics_vector(cam), ())
        cf_rms = start.still_rms(start.x0())
        # Screen with the carrier poses taken as exact: the pose-error model would absorb a
        # grossly wrong pose into that still's own error (and inflate the estimated sigma).
        screen = refine_hand_eye(uv[keep], p_B, T_W_X[sel], cam, T0_H, T0_G, mode,
                                 free_intrinsics, pose_noise=False)  # fmt: skip
        rms = leave_one_out_rms(uv[keep], p_B, T_W_X[sel], cam, screen, mode, free_intrinsics)
        worst = int(np.argmax(rms))
        limit = max(reject_factor * float(np.median(rms)), reject_min_px)
        if rms[worst] <= limit or len(sel) <= MIN_STILLS:
            break
        i = sel[worst]
        records[i]["reason"] = (
            f"outlier: reprojection RMS {rms[worst]:.2f} px > {limit:.2f} px when fitted "
            f"without it ({reject_factor:g} x the median {np.median(rms):.2f} px; carrier poses "
            "taken as exact)"
        )
        records[i]["rms_px"] = float(rms[worst])
        log.warning("hand-eye: still %s rejected (%s)", records[i]["name"], records[i]["reason"])
        keep[list(idx).index(i)] = False
    loo = rms
    fit = screen
    if pose_noise:
        fit = refine_hand_eye(uv[keep], p_B, T_W_X[sel], cam, T0_H, T0_G, mode,
                              free_intrinsics, **opts)  # fmt: skip
    rms = fit["still_rms_px"]
    chain_rms = screen["still_rms_px"]  # the fit with the carrier poses as given
    d_X = fit["carrier_residuals"]
    for k, i in enumerate(sel):
        records[i].update(used=True, reason="ok", rms_px=float(rms[k]), chain_rms_px=float(chain_rms[k]),
                          chain_rms_loo_px=float(loo[k]))  # fmt: skip
        if pose_noise:  # the carrier pose's estimated own error at this still
            records[i]["carrier_error_mm"] = float(1e3 * np.linalg.norm(d_X[k, 3:]))
            records[i]["carrier_error_deg"] = float(np.degrees(np.linalg.norm(d_X[k, :3])))
        if flipped[list(idx).index(i)]:
            records[i]["reason"] = "ok (corner order reversed to match the carrier's motion)"
    jk = jackknife_std(uv[keep], p_B, T_W_X[sel], cam, fit, mode, free_intrinsics, **opts)
    std_gn = np.sqrt(np.clip(np.diag(fit["cov"]), 0.0, None))
    std = std_gn if jk is None else np.maximum(std_gn, jk)
    name_H, name_G = FRAME_NAMES[mode]
    n_free = len(fit["param_names"]) - 12
    intr_free = {nm: float(v) for nm, v in zip(fit["param_names"][12:], std[12:], strict=True)}
    result = {
        "mode": mode,
        "frames": _frames_note(mode),
        name_H: fit["T_H"].tolist(),
        name_G: fit["T_G"].tolist(),
        "std": {name_H: pose_std_record(std[:6]), name_G: pose_std_record(std[6:12])},
        "std_method": ("larger of " if jk is not None else "") + (
            "the Gauss-Newton covariance with the carrier-pose errors modelled (variance "
            "components)" if pose_noise else "Gauss-Newton s^2 (J^T J)^-1 (poses as exact)")
        + (" and the delete-one-still jackknife" if jk is not None else
           " (too few stills for a jackknife)"),
        "std_gauss_newton": {name_H: pose_std_record(std_gn[:6]), name_G: pose_std_record(std_gn[6:12])},
        "std_jackknife": None if jk is None else {name_H: pose_std_record(jk[:6]),
                                                  name_G: pose_std_record(jk[6:12])},
        "rms_px": fit["rms_px"],
        "sigma_px": fit["sigma_px"],
        "closed_form": {"method": method, name_H: T0_H.tolist(), name_G: T0_G.tolist(),
                        "rms_px": float(np.sqrt(np.mean(cf_rms**2)))},
        "intrinsics": {
            "K": [[fit["intrinsics"][0], 0.0, fit["intrinsics"][2]],
                  [0.0, fit["intrinsics"][1], fit["intrinsics"][3]], [0.0, 0.0, 1.0]],
            "dist": fit["intrinsics"][4:].tolist(),
            "free": list(fit["param_names"][12:]),
            "std": intr_free if n_free else {},
            "fixed_std_propagated": fit["intrinsic_std_propagated"],
        },
        "carrier_pose_noise": {
            "modelled": bool(pose_noise),
            "sigma_pos_mm": None if fit["sigma_pos_m"] is None else 1e3 * fit["sigma_pos_m"],
            "sigma_rot_deg": None if fit["sigma_rot_rad"] is None
            else float(np.degrees(fit["sigma_rot_rad"])),
            "estimated": bool(pose_noise) and (pose_sigma_m is None or pose_sigma_rad is None),
        },
        "board": board_record(board),
        "n_stills": len(images),
        "n_used": int(len(sel)),
        "stills": records,
    }  # fmt: skip
    log.info("hand-eye (%s): %d of %d stills, RMS %.3f px", mode, len(sel), len(images),
             fit["rms_px"])  # fmt: skip
    return result


def _check_motions(records, idx, keep, T_W_X, T_C_B, mode, method, board):
    """Before any fit: views paired with their poses (outliers marked, keep updated in place),
    rotations about two axes, and the camera's translations in the carrier's scale."""
    sel = np.array(idx)[keep]
    bad = check_pose_pairing(T_W_X[sel], T_C_B[keep], [records[i]["name"] for i in sel],
                             [records[i]["pose"] or f"pose {i}" for i in sel])  # fmt: skip
    for i in sel[bad]:
        records[i]["reason"] = (f"outlier: the angles of its motions disagree with its carrier "
                                f"pose's by more than {MAX_ANGLE_DISAGREEMENT_DEG:g} deg")  # fmt: skip
        log.warning("hand-eye: still %s rejected (%s)", records[i]["name"], records[i]["reason"])
    keep[np.flatnonzero(keep)[bad]] = False
    sel = np.array(idx)[keep]
    spread = motion_axis_spread_deg(T_W_X[sel])
    if spread < MIN_AXIS_SPREAD_DEG:
        raise CalibrationError(
            f"hand-eye: the carrier's motions between the {int(keep.sum())} usable stills turn "
            f"about axes at most {spread:.1f} deg apart (expected at least "
            f"{MIN_AXIS_SPREAD_DEG:g} deg): rotate the carrier about two different axes"
        )
    if len(sel) >= MIN_STILLS:
        T_H, T_G = closed_form_hand_eye(T_W_X[sel], T_C_B[keep], mode, method)
        R_X = (T_H if mode == "eye_in_hand" else T_G)[:3, :3]
        size = (("tag size", board["tag_size_m"]) if "tag_size_m" in board
                else ("square size", board.get("square_m")))  # fmt: skip
        check_motion_scale(motion_scale(T_W_X[sel], T_C_B[keep], R_X, mode), size[1], size[0])


def _frames_note(mode):
    if mode == "eye_in_hand":
        return ("T_Cm_C: camera optical frame C in the carrier Cm (end-effector / camera "
                "markers); T_W_B: board B in the pose source's world W")  # fmt: skip
    return ("T_W_C: camera optical frame C in the pose source's world W; T_Bm_B: board B in "
            "the carrier Bm (end-effector / board markers)")  # fmt: skip


def _too_few(records):
    lines = "; ".join(f"{r['name']}: {r['reason']}" for r in records if r["reason"] != "ok")
    n_ok = sum(r["reason"] == "ok" for r in records)
    return (f"hand-eye: {n_ok} of {len(records)} stills usable; at least {MIN_STILLS} needed "
            f"({lines or 'no stills'})")  # fmt: skip


# --------------------------------------------------------------------------- pairing


def _last_int(text):
    found = re.findall(r"\d+", Path(str(text)).stem)
    return int(found[-1]) if found else None


def pair_stills_with_poses(still_names, pose_names):
    """Index of the pose of each still (-1: none), and the rule that paired them.

    Rules, in order: names equal (a CSV ``name_col`` naming the still's file or stem); the
    last integer in the names (``franka_image-3.png`` with ``franka_pose_rPe_3.yaml``) when it
    is unique on both sides; else position, which needs as many poses as stills.

    Parameters
    ----------
    still_names : sequence of str
        File names of the stills, in their order.
    pose_names : sequence of str
        The pose table's ``name`` column (empty strings when the format has no names).

    Returns
    -------
    index : list of int
        Per still, the row of its pose in ``pose_names``, -1 when it has none.
    rule : str
        ``"by name"``, ``"by the number in the file names"`` or ``"by position"``.

    Raises
    ------
    InputError
        Pairing by position with different counts.
    """
    stills = [str(s) for s in still_names]
    poses = [str(p) for p in pose_names]
    stems = [Path(s).stem for s in stills]
    if any(poses):
        lookup = {p: k for k, p in enumerate(poses)}
        by_name = [lookup.get(s, lookup.get(st, -1)) for s, st in zip(stills, stems, strict=True)]
        if all(k >= 0 for k in by_name):
            return by_name, "by name"
        s_int, p_int = [_last_int(s) for s in stills], [_last_int(p) for p in poses]
        if (None not in s_int and None not in p_int and len(set(s_int)) == len(s_int)
                and len(set(p_int)) == len(p_int)):  # fmt: skip
            where = {v: k for k, v in enumerate(p_int)}
            return [where.get(v, -1) for v in s_int], "by the number in the file names"
    if len(stills) != len(poses):
        raise InputError(
            f"hand-eye: {len(stills)} stills and {len(poses)} poses, paired by position (no "
            "names or numbers pair them); expected one pose per still, in the stills' order"
        )
    return list(range(len(stills))), "by position"
