"""Relative poses of two or more calibrated cameras from views of the board they share.

Each camera is calibrated on its own stills first (``cvsflow.calibration.intrinsics``); this module then
finds every camera's pose relative to camera 0, ``T_Ci_C0`` (a point in C0 maps to Ci), from
stills taken at the same instant by several cameras ("shared views"). ``cv2.stereoCalibrate``
with the intrinsics held fixed gives the start for each pair (0, i); one joint least-squares
fit over all cameras and views then refines the relative poses and each view's board pose
``T_C0_B`` from every corner any camera saw, so views that a third camera shares improve all
of them, and a view where a camera sees only part of the board (ChArUco) still counts.

Standard errors add two parts: the Gauss-Newton covariance ``s^2 (J^T J)^-1`` of the joint
fit (``s^2`` the residual variance per coordinate), the uncertainty from the shared views'
noise, and the intrinsics' own uncertainty (their calibration ``std``) propagated through the
fit's sensitivity to them. On sharp stills the second dominates: rendered 640x480 pairs with
0.04-0.08 px corner noise and a 0.6 m baseline gave errors of 10-80 data-only sigmas and
0.01-1.3 total sigmas.
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np
import pandas as pd

from cvsflow.calibration import calibrate_camera
from cvsflow.exceptions import CalibrationError, InputError
from cvsflow.geometry import (
    INTRINSIC_NAMES,
    R_from_rvec,
    invert_T,
    make_T,
    project_points_jac,
    rvec_from_R,
    skew,
)
from cvsflow.rig.fusion import _board_pose_jacobian

#: Columns of the per-camera corner tables (calibration's ``calib_corners``; ``image`` names the
#: shared view: stills taken at the same instant carry the same name in every camera's table).
VIEW_CORNER_COLUMNS = ["image", "corner", "u_px", "v_px", "X_m", "Y_m"]

#: Keys of a relative pose's ``std``: the left rotation increment (rad), then t (m).
POSE_STD_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")


def _camera_arrays(camera: dict, i: int) -> tuple[np.ndarray, np.ndarray]:
    try:
        K = np.asarray(camera["K"], float).reshape(3, 3)
        dist = np.asarray(camera["dist"], float).ravel()[:5]
    except (KeyError, ValueError) as exc:
        raise InputError(f"camera {i}: camera.yaml needs K (3x3) and dist (5 terms): {exc}") from exc
    if dist.size != 5:
        raise InputError(f"camera {i}: dist has {dist.size} terms; expected 5 [k1, k2, p1, p2, k3]")
    return K, dist


def _check_corners(table: pd.DataFrame, i: int) -> pd.DataFrame:
    missing = [c for c in VIEW_CORNER_COLUMNS if c not in table.columns]
    if missing:
        raise InputError(f"camera {i}: corner table lacks columns {missing}")
    bad = ~np.isfinite(table[["u_px", "v_px", "X_m", "Y_m"]].to_numpy(float)).all(axis=1)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"camera {i}: corner table row {row} (image {table['image'].iloc[row]}) is not finite")
    return table[VIEW_CORNER_COLUMNS].sort_values(["image", "corner"], kind="stable")


class _View(NamedTuple):
    """One camera's corners in one view: ids (N,), pixels (N, 2), board points (N, 3), m."""

    corner: np.ndarray
    uv: np.ndarray
    p_B: np.ndarray


def _split_views(table: pd.DataFrame, i: int) -> dict[str, _View]:
    table = _check_corners(table, i)
    names = table["image"].astype(str).to_numpy()
    corner = table["corner"].to_numpy(int)
    uv = table[["u_px", "v_px"]].to_numpy(float)
    XY = table[["X_m", "Y_m"]].to_numpy(float)
    p_B = np.column_stack([XY, np.zeros(len(XY))])
    cut = np.flatnonzero(names[1:] != names[:-1]) + 1
    starts, ends = np.r_[0, cut], np.r_[cut, len(names)]
    views = {}
    for a, b in zip(starts, ends, strict=True):
        if len(np.unique(corner[a:b])) != b - a:
            raise InputError(f"camera {i}: image {names[a]} lists a corner id twice")
        views[names[a]] = _View(corner[a:b], uv[a:b], p_B[a:b])
    return views


def _pnp(p_B: np.ndarray, uv: np.ndarray, K, dist) -> np.ndarray:
    ok, rvec, tvec = cv2.solvePnP(p_B, uv, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("stereo: solvePnP failed on a shared view")
    return make_T(R_from_rvec(rvec.ravel()), tvec.ravel())


def _start_pair(views: list[str], tables, K, dist, i: int, size_wh) -> np.ndarray:
    """T_Ci_C0 from cv2.stereoCalibrate on the corners both cameras saw in each shared view."""
    obj, img0, imgi = [], [], []
    for v in views:
        a, b = tables[0][v], tables[i][v]
        common, ia, ib = np.intersect1d(a.corner, b.corner, assume_unique=True, return_indices=True)
        if len(common) < 6:
            continue
        obj.append(a.p_B[ia].astype(np.float32))
        img0.append(a.uv[ia].astype(np.float32))
        imgi.append(b.uv[ib].astype(np.float32))
    if not obj:
        raise CalibrationError(
            f"stereo: cameras 0 and {i} share no view with 6 or more common corners; "
            f"shared view names: {views[:5]}{' ...' if len(views) > 5 else ''}")
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-9)
    out = cv2.stereoCalibrate(
        obj, img0, imgi, K[0].copy(), dist[0].copy(), K[i].copy(), dist[i].copy(), size_wh,
        flags=cv2.CALIB_FIX_INTRINSIC, criteria=criteria)
    R, T = out[5], out[6]
    return make_T(R, np.asarray(T, float).ravel())


def _observations(views, seen_by, tables) -> dict:
    cam, view, p_B, uv = [], [], [], []
    for vi, v in enumerate(views):
        for c in seen_by[v]:
            g = tables[c][v]
            cam.append(np.full(len(g.corner), c))
            view.append(np.full(len(g.corner), vi))
            p_B.append(g.p_B)
            uv.append(g.uv)
    return {"cam": np.concatenate(cam), "view": np.concatenate(view), "p_B": np.concatenate(p_B),
            "uv": np.concatenate(uv), "n_views": len(views)}


def _linearise(T_Ci_C0, T_C0_B, obs, K, dist):
    """Residuals (px, shape (2M,)) and their Jacobians w.r.t. the pose increments and intrinsics.

    Poses are perturbed on the left, R <- exp([w]x) R, t <- t + dt, per camera i >= 1 (columns
    6(i-1) ..) and per view (after them). The intrinsics' Jacobian has 9 columns per camera.
    """
    n_cam, n_views = len(T_Ci_C0), len(T_C0_B)
    n_params = 6 * (n_cam - 1) + 6 * n_views
    M = len(obs["cam"])
    r = np.empty((M, 2))
    J = np.zeros((M, 2, n_params))
    J_k = np.zeros((M, 2, 9 * n_cam))
    T_v = np.stack(T_C0_B)
    Rp_B = np.einsum("nij,nj->ni", T_v[obs["view"], :3, :3], obs["p_B"])
    p_C0 = Rp_B + T_v[obs["view"], :3, 3]
    off = 6 * (n_cam - 1)
    cols_v = off + 6 * obs["view"]
    for c in range(n_cam):
        sel = np.flatnonzero(obs["cam"] == c)
        R, t = T_Ci_C0[c][:3, :3], T_Ci_C0[c][:3, 3]
        Rp = p_C0[sel] @ R.T
        uv, d_uv_d_p, d_uv_d_k = project_points_jac(Rp + t, K[c], dist[c])
        r[sel] = uv - obs["uv"][sel]
        J_k[sel, :, 9 * c: 9 * c + 9] = d_uv_d_k
        if c > 0:
            J[sel, :, 6 * (c - 1): 6 * (c - 1) + 3] = -d_uv_d_p @ skew(Rp)
            J[sel, :, 6 * (c - 1) + 3: 6 * c] = d_uv_d_p
        J_rot, d_uv_d_pc0 = _board_pose_jacobian(d_uv_d_p, R, Rp_B[sel])
        for k in range(3):
            J[sel, :, cols_v[sel] + k] = J_rot[:, :, k]
            J[sel, :, cols_v[sel] + 3 + k] = d_uv_d_pc0[:, :, k]
    return r.ravel(), J.reshape(2 * M, n_params), J_k.reshape(2 * M, 9 * n_cam)


def _retract(T, delta):
    return make_T(R_from_rvec(delta[:3]) @ T[:3, :3], T[:3, 3] + delta[3:])


def _gauss_newton(T_Ci_C0, T_C0_B, obs, K, dist, max_iterations=30, tol=1e-12):
    n_cam = len(T_Ci_C0)
    for _ in range(max_iterations):
        r, J, _ = _linearise(T_Ci_C0, T_C0_B, obs, K, dist)
        step = np.linalg.solve(J.T @ J, -(J.T @ r))
        T_Ci_C0 = [T_Ci_C0[0]] + [_retract(T, step[6 * (c - 1): 6 * c]) for c, T in enumerate(T_Ci_C0[1:], 1)]
        off = 6 * (n_cam - 1)
        T_C0_B = [_retract(T, step[off + 6 * v: off + 6 * v + 6]) for v, T in enumerate(T_C0_B)]
        if np.max(np.abs(step)) < tol ** 0.5 * 1e-2:
            break
    else:
        raise CalibrationError(f"stereo: the joint fit did not converge in {max_iterations} iterations")
    return T_Ci_C0, T_C0_B


def stereo_extrinsics(
    corners: list[pd.DataFrame],
    cameras: list[dict],
    min_shared_views: int = 3,
) -> dict:
    """Every camera's pose relative to camera 0 from shared board views, with standard errors.

    Parameters
    ----------
    corners : list of DataFrame, one per camera
        ``image, corner, u_px, v_px, X_m, Y_m`` (:data:`VIEW_CORNER_COLUMNS`; a calibration's
        ``calib_corners`` table): each camera's refined corners, px, with their board-frame
        points, m. ``image`` names the view: the same name in two tables means the stills
        were taken at the same instant with the board still (a shared view).
    cameras : list of dict, one per camera
        camera.yaml content of each camera: ``K`` (3x3, px), ``dist`` ([k1, k2, p1, p2, k3]),
        optionally ``std`` (1-sigma per intrinsic, keys ``fx, fy, cx, cy, k1 .. k3``) and
        ``width``, ``height`` (px).
    min_shared_views : int
        Fewest views each camera i >= 1 must share with camera 0.

    Returns
    -------
    dict
        ``cameras``: list, entry i for camera i >= 1 with ``T_Ci_C0`` (4x4 list: a point in
        C0 maps to Ci, metres), ``rvec_rad`` and ``t_m`` of it, ``baseline_m`` (camera i's
        centre from camera 0's), ``std`` (1-sigma of ``rx ry rz`` (rad) and ``tx ty tz`` (m):
        the rotation as a small rotation of Ci on the left, R_Ci_C0 <- exp([r]x) R_Ci_C0, the
        translation as t_m's own error; the shared views' noise and the intrinsics' ``std``
        propagated), ``std_data_only`` (the views' noise alone: too small whenever the
        intrinsics are less certain than the views, as with sharp stills),
        ``baseline_std_m``, ``covariance`` (6x6 list, [r, t] order as ``std``, the same
        total as ``std``), ``intrinsics_sensitivity`` (6 x 9C list: d[r, t] / d(every
        camera's ``fx fy cx cy k1 k2 p1 p2 k3``, camera by camera); with the intrinsics'
        std it gives their cross-covariance with the pose, which
        :func:`rig_calibration_covariance` needs: a cx error is largely taken up by the
        rotation fitted with it), ``n_shared_views``,
        ``start_T_Ci_C0`` (stereoCalibrate's, before the joint refinement); ``rms_px`` (per
        camera, the joint fit's reprojection RMS), ``n_views`` (views seen by two or more
        cameras), ``views`` (their names), ``T_C0_B`` (dict view -> 4x4 list, m),
        ``sigma_px`` (the residual's estimated std per coordinate).

    Raises
    ------
    InputError
        Fewer than two cameras, a corner table or camera without the needed fields or with a
        non-finite row (named).
    CalibrationError
        A camera sharing fewer than ``min_shared_views`` views with camera 0, or no view with
        six common corners (named).

    Notes
    -----
    A view seen by one camera only says nothing about relative poses and is left out. The
    intrinsics are held fixed in the fit (each camera's own calibration is the better place
    to estimate them); their uncertainty enters ``std`` as
    ``A J_k Sigma_k J_k^T A^T`` with ``A = (J^T J)^-1 J^T``, which treats the nine
    intrinsics of a camera as uncorrelated because camera.yaml stores standard deviations
    only: a conservative or optimistic approximation depending on the sign of their
    correlation (fx with fy is typically positive).
    """
    n_cam = len(corners)
    if n_cam < 2 or len(cameras) != n_cam:
        raise InputError(f"stereo: need corner tables and cameras for two or more cameras; got "
                         f"{n_cam} tables and {len(cameras)} cameras")
    arrays = [_camera_arrays(c, i) for i, c in enumerate(cameras)]
    K, dist = [a[0] for a in arrays], [a[1] for a in arrays]
    tables = [_split_views(t, i) for i, t in enumerate(corners)]
    seen_by = {}
    for i, t in enumerate(tables):
        for v in t:
            seen_by.setdefault(v, []).append(i)
    views = sorted(v for v, cams in seen_by.items() if len(cams) >= 2)
    size_wh = (int(cameras[0].get("width", 2 * K[0][0, 2])), int(cameras[0].get("height", 2 * K[0][1, 2])))

    starts = [np.eye(4)]
    for i in range(1, n_cam):
        shared = [v for v in views if 0 in seen_by[v] and i in seen_by[v]]
        if len(shared) < min_shared_views:
            raise CalibrationError(
                f"stereo: camera {i} shares {len(shared)} views with camera 0 "
                f"(need {min_shared_views}); name the stills taken together the same in both folders")
        starts.append(_start_pair(shared, tables, K, dist, i, size_wh))

    # Each view's board pose in C0: PnP in camera 0 if it saw the view, else through a camera
    # that did and its start pose.
    T_C0_B = []
    for v in views:
        c = seen_by[v][0]
        g = tables[c][v]
        T_c_B = _pnp(g.p_B, g.uv, K[c], dist[c])
        T_C0_B.append(invert_T(starts[c]) @ T_c_B)

    obs = _observations(views, seen_by, tables)
    T_Ci_C0, T_C0_B = _gauss_newton(starts, T_C0_B, obs, K, dist)
    r, J, J_k = _linearise(T_Ci_C0, T_C0_B, obs, K, dist)
    n_params = J.shape[1]
    dof = r.size - n_params
    if dof <= 0:
        raise CalibrationError(f"stereo: {r.size} residuals for {n_params} parameters; too few corners")
    sigma2 = float(r @ r) / dof
    JtJ_inv = np.linalg.inv(J.T @ J)
    cov = sigma2 * JtJ_inv
    G = -JtJ_inv @ (J.T @ J_k)  # d(parameters)/d(intrinsics) at the solution
    var_k = np.zeros(J_k.shape[1])
    for c in range(n_cam):
        std = cameras[c].get("std") or {}
        var_k[9 * c: 9 * c + 9] = [float(std.get(name, 0.0)) ** 2 for name in INTRINSIC_NAMES]
    cov_k = (G * var_k) @ G.T

    rms = []
    res = r.reshape(-1, 2)
    for c in range(n_cam):
        sel = obs["cam"] == c
        rms.append(float(np.sqrt(np.mean(np.sum(res[sel] ** 2, axis=1)))))
    out_cams = []
    for i in range(1, n_cam):
        s = slice(6 * (i - 1), 6 * i)
        T = T_Ci_C0[i]
        C, C_k = cov[s, s], cov_k[s, s]
        # camera i's centre in C0 is -R^T t, as long as t is; under the left increments a
        # rotation leaves |t| unchanged, so only dt moves the baseline: d|t|/dt = t^T / |t|.
        centre = -T[:3, :3].T @ T[:3, 3]
        g_t = T[:3, 3] / np.linalg.norm(T[:3, 3])
        out_cams.append({
            "camera": i,
            "T_Ci_C0": T.tolist(),
            "rvec_rad": rvec_from_R(T[:3, :3]).tolist(),
            "t_m": T[:3, 3].tolist(),
            "baseline_m": float(np.linalg.norm(centre)),
            "baseline_std_m": float(np.sqrt(g_t @ (C + C_k)[3:, 3:] @ g_t)),
            "std": dict(zip(POSE_STD_NAMES, np.sqrt(np.diag(C + C_k)).tolist(), strict=True)),
            "std_data_only": dict(zip(POSE_STD_NAMES, np.sqrt(np.diag(C)).tolist(), strict=True)),
            "covariance": (C + C_k).tolist(),
            "intrinsics_sensitivity": G[s].tolist(),
            "n_shared_views": int(sum(1 for v in views if 0 in seen_by[v] and i in seen_by[v])),
            "start_T_Ci_C0": starts[i].tolist(),
        })
    return {
        "cameras": out_cams,
        "rms_px": rms,
        "sigma_px": float(np.sqrt(sigma2)),
        "n_views": len(views),
        "views": views,
        "T_C0_B": {v: T.tolist() for v, T in zip(views, T_C0_B, strict=True)},
    }


def calibrate_rig(stills: list, board: dict, min_shared_views: int = 3, **calibrate_kwargs):
    """Calibrate every camera of a rig from its stills, then the rig from the shared ones.

    Parameters
    ----------
    stills : list (per camera) of sequence of (str, ndarray)
        Each camera's ``(name, gray)`` stills (``calibration.calibrate_camera``'s input). Stills
        taken at the same instant by several cameras carry the same name: those are the shared
        views; a camera's other stills help its own intrinsics only.
    board : dict
        The board (``squares_x``, ``squares_y``, ``square_m``; ChArUco keys for ``type:
        charuco``).
    min_shared_views : int
        Fewest shared views each camera needs with camera 0.
    **calibrate_kwargs
        Passed to ``calibration.calibrate_camera`` (``subpix_window_px``, ``min_images``, ...).

    Returns
    -------
    cameras : list of dict
        Each camera's camera.yaml content.
    rig : dict
        :func:`stereo_extrinsics`' result.
    corners : list of DataFrame
        Each camera's ``calib_corners`` table.

    Raises
    ------
    CalibrationError
        A camera that cannot be calibrated (named, with its index), or too few shared views.
    """
    cameras, corners = [], []
    for i, camera_stills in enumerate(stills):
        try:
            camera, table = calibrate_camera(camera_stills, board, **calibrate_kwargs)
        except CalibrationError as exc:
            raise CalibrationError(f"camera {i}: {exc}") from exc
        cameras.append(camera)
        corners.append(table)
    return cameras, stereo_extrinsics(corners, cameras, min_shared_views=min_shared_views), corners
