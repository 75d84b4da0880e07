"""The camera reference of a rendered flight, measured as a CVS measures it (no images).

One camera (:func:`measure_reference`: the board's corners projected with the true lens,
corner noise added, the CVS's PnP with a calibration one draw of its stated std off the
lens, model (T)'s covariance) or a rig of cameras exposed together
(:func:`measure_reference_rig`: the rig calibrated on shared views with the drawn lenses, the
board pose fused from every camera, its covariance with the calibration's share). Used by
:func:`cvsflow.synth.flight_demo.render_flight` (``reference="pnp"`` / ``"stereo"``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.board import board_object_points, board_pattern
from cvsflow.calibration import estimate_poses
from cvsflow.evaluate import heldout as ev
from cvsflow.exceptions import ConfigError
from cvsflow.flight import reference_covariance_transfer
from cvsflow.geometry import INTRINSIC_NAMES, R_from_euler, invert_T, make_T, project_points
from cvsflow.optimise import K_from_intrinsics, se3, simulate_session
from cvsflow.rig import (
    board_pose_starts,
    fused_board_pose_best,
    rig_calibration_covariance,
    stereo_extrinsics,
)
from cvsflow.synth.imaging import Board as SynthBoard
from cvsflow.synth.stereo import shared_view_poses

#: The demo's camera (its lens, bench/uncertainty_sessions.yaml u_demo), 640 x 480 px.
CAMERA_DEMO = {"fx_px": 702.0, "fy_px": 698.0, "cx_px": 331.5, "cy_px": 247.0,
               "dist": [-0.12, 0.09, 0.0009, -0.0007, -0.02], "width_px": 640, "height_px": 480}
#: The board on the body: 6 x 5 squares of 12.5 cm, 20 inner corners over 0.5 x 0.375 m (the
#: distance model's 0.5 m and 20 corners).
BOARD_DEFAULT = {"squares_x": 6, "squares_y": 5, "square_m": 0.125}
#: 1-sigma of the flight camera's calibration (a camera.yaml ``std``: fx fy cx cy px, k1..k3);
#: the reference's PnP uses a calibration off the true lens by one draw of it per flight.
CALIB_STD_DEFAULT = {"fx": 0.5, "fy": 0.5, "cx": 0.5, "cy": 0.5, "k1": 0.002, "k2": 0.01,
                     "p1": 1e-4, "p2": 1e-4, "k3": 0.02}  # fmt: skip
#: Corners nearer the image border than this are not detected (px).
BORDER_PX = 2.0


def _K_dist(camera):
    K = np.array([[camera["fx_px"], 0.0, camera["cx_px"]], [0.0, camera["fy_px"], camera["cy_px"]],
                  [0.0, 0.0, 1.0]])  # fmt: skip
    return K, np.asarray(camera["dist"], float).ravel()


def corner_noise(rng, n_frames, board, sigma_px, shared_px=0.0, shared_squares=1.0):
    """Detection error of every corner of ``n_frames`` frames, px, shape (n_frames, P, 2).

    Per image axis: iid N(0, sigma_px^2) plus a field shared by neighbouring corners, with
    covariance ``shared_px^2 exp(-g^2 / (2 shared_squares^2))`` between corners ``g`` squares
    apart on the board (a detector's error is partly common to nearby corners: the same blur,
    the same pixel grid phase, overlapping refinement windows).

    Parameters
    ----------
    rng : numpy.random.Generator
        The seeded generator.
    n_frames : int
        Number of frames.
    board : dict
        Board config; P = nx * ny inner corners, corner k at square (k % nx, k // nx).
    sigma_px : float
        Standard deviation of the independent part per axis, px.
    shared_px : float, default 0.0
        Standard deviation of the shared field per axis, px; 0 for none.
    shared_squares : float, default 1.0
        Correlation length of the shared field, board squares.

    Returns
    -------
    ndarray, shape (n_frames, P, 2)
        The error (du, dv) of every corner, px.
    """

    nx, ny = board_pattern(board)
    k = np.arange(nx * ny)
    g = np.column_stack([k % nx, k // nx]).astype(float)
    out = sigma_px * rng.standard_normal((n_frames, len(k), 2))
    if shared_px > 0:
        d2 = np.sum((g[:, None] - g[None]) ** 2, axis=-1)
        C = shared_px**2 * np.exp(-d2 / (2.0 * shared_squares**2))
        L = np.linalg.cholesky(C + 1e-12 * np.eye(len(k)))
        out += np.einsum("pq,nqa->npa", L, rng.standard_normal((n_frames, len(k), 2)))
    return out


def measure_reference(T_C_B, t_s, seen, rng, camera=None, board=None, sigma_px=0.3,
                      shared_px=0.0, shared_squares=1.0, calib_std=None, model=None,
                      calibration=None, return_terms=False):
    """The camera reference of a flight as the CVS measures it, at corner level.

    The board's corners are projected with the true camera (``camera``), those inside the
    image (``BORDER_PX``) on frames ``seen`` are detected with :func:`corner_noise`, and the
    CVS's PnP (:func:`cvsflow.calibration.pnp.estimate_poses`, RANSAC + LM) solves them with a
    calibration drawn once about the true lens from ``calib_std``. The covariance stated is
    :func:`cvsflow.flight.reference_covariance_transfer` with that calibration and its std.

    Parameters
    ----------
    T_C_B : ndarray, shape (N, 4, 4)
        True board poses in the camera, m.
    t_s : ndarray, shape (N,)
        Frame times, s.
    seen : ndarray of bool, shape (N,)
        Frames on which the detector finds the board (if enough corners are in the image).
    rng : numpy.random.Generator
    camera : dict, optional
        ``fx_px, fy_px, cx_px, cy_px, dist, width_px, height_px``; default ``CAMERA_DEMO``.
    board : dict, optional
        ``squares_x, squares_y, square_m``; default ``BOARD_DEFAULT``.
    sigma_px, shared_px, shared_squares : float
        Corner noise (:func:`corner_noise`).
    calib_std : dict, optional
        1-sigma of fx, fy, cx, cy, k1, k2, p1, p2, k3; default ``CALIB_STD_DEFAULT``.
    model : dict, optional
        The model (T) the reference states its covariance with (a validation session's,
        :func:`cvsflow.flight.session_error_model`); default the rendered sessions'.
    calibration : dict, optional
        The calibration the CVS uses, as a validation session's se3 result (``K``, ``dist``,
        ``std_errors``, ``fixed_intrinsics``), instead of the true lens off by a draw of
        ``calib_std`` (still drawn, so the noise stays the same).
    return_terms : bool
        Also return the flip term's parts and the calibration's factor (``flip``,
        ``cal_factor``, :func:`reference_covariance_transfer`).

    Returns
    -------
    T_meas : ndarray, shape (N, 4, 4)
        Measured T_C_B, NaN where not valid.
    valid : ndarray of bool, shape (N,)
    Sigma_ref : ndarray, shape (N, 6, 6)
        Stated covariance ([dt m, dtheta rad] in C), NaN where not valid.
    poses, corners : DataFrame
        The poses_raw and corners tables of the measurement.
    flip, cal_factor : ndarray, shape (N, 7) and (N, 6, 9)
        With ``return_terms``.
    """

    camera = CAMERA_DEMO if camera is None else camera
    board = BOARD_DEFAULT if board is None else board
    calib_std = CALIB_STD_DEFAULT if calib_std is None else calib_std
    K, dist = _K_dist(camera)
    p_B = board_object_points(board)
    p_C = np.einsum("nij,pj->npi", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
    uv = project_points(p_C, K, dist) + corner_noise(rng, len(T_C_B), board, sigma_px,
                                                     shared_px, shared_squares)
    w, h = float(camera.get("width_px", 640)), float(camera.get("height_px", 480))
    inside = ((p_C[..., 2] > 0) & (uv[..., 0] >= BORDER_PX) & (uv[..., 0] <= w - 1 - BORDER_PX)
              & (uv[..., 1] >= BORDER_PX) & (uv[..., 1] <= h - 1 - BORDER_PX))  # fmt: skip
    found = np.asarray(seen, bool) & (inside.sum(axis=1) >= 6)
    # the calibration the CVS uses: the true lens plus one draw of its stated error
    true_intr = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist]
    sd = np.array([float(calib_std.get(n, 0.0)) for n in INTRINSIC_NAMES])
    intr = true_intr + sd * rng.standard_normal(len(sd))
    K_cal, dist_cal = K_from_intrinsics(*intr[:4]), intr[4:]
    if calibration is not None:
        K_cal, dist_cal = np.asarray(calibration["K"], float), np.asarray(calibration["dist"], float)
    fr, ci = np.nonzero(found[:, None] & inside)
    rows = [pd.DataFrame({"frame": fr, "t_s": np.asarray(t_s, float)[fr], "found": True,
                          "corner": ci, "u_px": uv[fr, ci, 0], "v_px": uv[fr, ci, 1]})]
    lost = np.flatnonzero(~found)
    rows.append(pd.DataFrame({"frame": lost, "t_s": np.asarray(t_s, float)[lost], "found": False,
                              "corner": -1, "u_px": np.nan, "v_px": np.nan}))
    corners = pd.concat(rows).sort_values(["frame", "corner"], kind="stable").reset_index(drop=True)
    corners = corners.astype({"frame": np.int64, "corner": np.int64, "found": bool})
    poses = estimate_poses(corners, K_cal, dist_cal, board)
    valid = poses["valid"].to_numpy(bool)
    T_meas = np.full_like(np.asarray(T_C_B, float), np.nan)
    rv = poses[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)
    T_meas[valid] = make_T(Rotation.from_rotvec(rv[valid]).as_matrix(),
                           poses.loc[valid, ["x_m", "y_m", "z_m"]].to_numpy(float))
    calib = {"K": K_cal.tolist(), "dist": dist_cal.tolist(),
             "std": {n: float(v) for n, v in zip(INTRINSIC_NAMES, sd, strict=True)}}
    if calibration is not None:
        calib = calibration
    Sigma, flip, cal_factor = reference_covariance_transfer(poses, corners, p_B, calib, model=model,
                                                            return_terms=True)  # fmt: skip
    if return_terms:
        return T_meas, valid, Sigma, poses, corners, flip, cal_factor
    return T_meas, valid, Sigma, poses, corners


def stereo_rig(baseline_m: float, cross_m: float = 10.0) -> list:
    """``T_Ci_C0`` of a two-camera rig: camera 1 ``baseline_m`` to the right of camera 0,
    turned in so that the optical axes cross ``cross_m`` ahead.

    Parameters
    ----------
    baseline_m : float
        Distance between the camera centres along camera 0's x axis, m (> 0).
    cross_m : float
        Distance ahead of camera 0 where the axes cross, m (> 0).

    Returns
    -------
    list of ndarray, shape (4, 4)
        ``[I, T_C1_C0]``: a point in C0 maps to Ci.
    """
    if not (baseline_m > 0 and cross_m > 0):
        raise ConfigError(f"flight demo: rig baseline_m={baseline_m}, cross_m={cross_m}; both must be > 0")
    T_C0_C1 = make_T(R_from_euler([0.0, -np.arctan2(baseline_m, cross_m), 0.0]), [baseline_m, 0.0, 0.0])
    return [np.eye(4), invert_T(T_C0_C1)]


def observe_rig(T_C0_B, T_Ci_C0, p_B, cameras, noise_px=None):
    """Each rig camera's image of the board's corners, and which of them it detects.

    Parameters
    ----------
    T_C0_B : ndarray, shape (F, 4, 4)
        Board poses in camera 0, m.
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        Each camera's pose from camera 0.
    p_B : ndarray, shape (N, 3)
        The corners in B, m.
    cameras : sequence of dict
        Each camera as ``CAMERA_DEMO`` (``fx_px .. dist, width_px, height_px``).
    noise_px : ndarray, shape (F, C, N, 2), optional
        Detection error added to the projections, px.

    Returns
    -------
    uv : ndarray, shape (F, C, N, 2)
        Corner k in camera c on frame f, px.
    seen : ndarray of bool, shape (F, C, N)
        Corners in front of the camera and at least ``BORDER_PX`` inside its image, on frames
        where the camera has at least 6 of them (fewer: it does not find the board).
    """
    uv = np.zeros((len(T_C0_B), len(T_Ci_C0), len(p_B), 2))
    seen = np.zeros(uv.shape[:3], bool)
    for c, (T, camera) in enumerate(zip(T_Ci_C0, cameras, strict=True)):
        K, dist = _K_dist(camera)
        w, h = float(camera.get("width_px", 640)), float(camera.get("height_px", 480))
        T_C_B = np.asarray(T, float) @ T_C0_B
        p_C = np.einsum("fij,nj->fni", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
        uv[:, c] = project_points(p_C, K, dist)
        if noise_px is not None:
            uv[:, c] += noise_px[:, c]
        inside = ((p_C[..., 2] > 0) & (uv[:, c, :, 0] >= BORDER_PX) & (uv[:, c, :, 0] <= w - 1 - BORDER_PX)
                  & (uv[:, c, :, 1] >= BORDER_PX) & (uv[:, c, :, 1] <= h - 1 - BORDER_PX))  # fmt: skip
        seen[:, c] = inside & (inside.sum(axis=1) >= 6)[:, None]
    return uv, seen


def calibrate_rig_views(rng, T_Ci_C0, cameras, cameras_cal, calib_std, board, n_views=20, sigma_px=0.1):
    """The rig's relative poses as a user finds them: from shared views, with the drawn lens.

    ``n_views`` board poses that every camera sees whole (:func:`cvsflow.synth.stereo.
    shared_view_poses`, at 1.5-4 m or 1.5-4 baselines), their corners projected with the
    true cameras plus ``sigma_px`` of noise, solved by :func:`cvsflow.rig.extrinsics.stereo_extrinsics`
    with the calibration the CVS uses (``cameras_cal``, stated ``calib_std``). The fitted
    poses take up part of the intrinsics' error, as a real rig calibration does.

    Parameters
    ----------
    rng : numpy.random.Generator
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        The true rig.
    cameras : sequence of dict
        The true cameras (``CAMERA_DEMO`` form).
    cameras_cal : sequence of (K, dist)
        The calibration used.
    calib_std : dict
        Its stated 1-sigma, the same for every camera.
    board : dict
        The board of the views.
    n_views : int
        Shared views.
    sigma_px : float
        Corner noise of the views (sharp stills), px.

    Returns
    -------
    dict
        :func:`cvsflow.rig.extrinsics.stereo_extrinsics`' result.
    """
    b_m = max(float(np.linalg.norm(invert_T(np.asarray(T, float))[:3, 3])) for T in T_Ci_C0)
    sboard = SynthBoard(int(board["squares_x"]), int(board["squares_y"]), float(board["square_m"]))
    true = [(*_K_dist(c), (int(c.get("width_px", 640)), int(c.get("height_px", 480)))) for c in cameras]
    depth_m = (max(1.5, 1.5 * b_m), max(4.0, 4.0 * b_m))
    T_C0_V = shared_view_poses(rng, n_views, true, T_Ci_C0, sboard, depth_m=depth_m, min_square_px=10.0)
    p_B = board_object_points(board)
    noise = sigma_px * rng.standard_normal((n_views, len(T_Ci_C0), len(p_B), 2))
    uv, seen = observe_rig(T_C0_V, T_Ci_C0, p_B, cameras, noise)
    tables = []
    for c in range(len(T_Ci_C0)):
        v, k = np.nonzero(seen[:, c])
        tables.append(pd.DataFrame({"image": [f"shared_{x:03d}" for x in v], "corner": k,
                                    "u_px": uv[v, c, k, 0], "v_px": uv[v, c, k, 1],
                                    "X_m": p_B[k, 0], "Y_m": p_B[k, 1]}))  # fmt: skip
    cal = [{"K": np.asarray(K).tolist(), "dist": np.asarray(d).tolist(), "std": dict(calib_std),
            "width": w, "height": h}
           for (K, d), (_, _, (w, h)) in zip(cameras_cal, true, strict=True)]  # fmt: skip
    return stereo_extrinsics(tables, cal)


def measure_reference_rig(T_C0_B, seen, rng, T_Ci_C0, cameras=None, board=None, sigma_px=0.3,
                          shared_px=0.0, shared_squares=1.0, calib_std=None, n_views=20, view_sigma_px=0.1,
                          return_factor=False):
    """The camera reference of a flight measured by a rig of cameras exposed together.

    Every camera detects the board's corners (:func:`observe_rig`, :func:`corner_noise`). The
    rig's calibration is what a user gets: each camera's intrinsics the truth off by one draw
    of ``calib_std``, the relative poses fitted with them on shared views
    (:func:`calibrate_rig_views`). The board pose is fused from all corners
    (:func:`cvsflow.rig.fusion.fused_board_pose_best`, started from both IPPE solutions of every
    camera's own view, with the mirrored solution's flip term). Its stated covariance is the
    corner noise's plus the calibration's, with the intrinsics' cross-covariance with the
    fitted poses (:func:`cvsflow.rig.fusion.rig_calibration_covariance`).

    Parameters
    ----------
    T_C0_B : ndarray, shape (N, 4, 4)
        True board poses in camera 0, m.
    seen : ndarray of bool, shape (N,) or (N, C)
        Frames on which each camera's detector works (if enough corners are in its image).
    rng : numpy.random.Generator
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        The true rig (:func:`stereo_rig`), identity first.
    cameras : sequence of dict, optional
        Each camera as ``CAMERA_DEMO`` (the default for all).
    board : dict, optional
        ``BOARD_DEFAULT`` by default (also the rig calibration's board).
    sigma_px, shared_px, shared_squares : float
        Corner noise (:func:`corner_noise`), the same for every camera.
    calib_std : dict, optional
        Each camera's calibration 1-sigma; default ``CALIB_STD_DEFAULT``.
    n_views, view_sigma_px : int, float
        The rig calibration's shared views and their corner noise (:func:`calibrate_rig_views`).
    return_factor : bool
        Also return the calibration's share of ``Sigma_ref`` as its factor ``G`` (N, 6, k),
        one draw common to every frame (:func:`rig_calibration_covariance`).

    Returns
    -------
    T_meas : ndarray, shape (N, 4, 4)
        Measured T_C0_B, NaN where not valid.
    valid : ndarray of bool, shape (N,)
    Sigma_ref : ndarray, shape (N, 6, 6)
        Stated covariance ([dt m, dtheta rad] in C0, rotation perturbed on the left), NaN
        where not valid.
    rig : dict
        The rig calibration (:func:`cvsflow.rig.extrinsics.stereo_extrinsics`).
    G : ndarray, shape (N, 6, k)
        With ``return_factor``; NaN where not valid.

    Notes
    -----
    The stated corner noise is ``sqrt(sigma_px^2 + shared_px^2)`` per corner, treated as
    independent: a shared part makes that optimistic.
    """
    n_cam = len(T_Ci_C0)
    cameras = [CAMERA_DEMO] * n_cam if cameras is None else list(cameras)
    board = BOARD_DEFAULT if board is None else board
    calib_std = CALIB_STD_DEFAULT if calib_std is None else calib_std
    if len(cameras) != n_cam or n_cam < 2:
        raise ConfigError(f"flight demo: {len(cameras)} cameras for a rig of {n_cam} (2 or more)")
    T_C0_B = np.asarray(T_C0_B, float)
    p_B = board_object_points(board)
    noise = np.stack([corner_noise(rng, len(T_C0_B), board, sigma_px, shared_px, shared_squares)
                      for _ in range(n_cam)], axis=1)  # fmt: skip
    uv, det = observe_rig(T_C0_B, T_Ci_C0, p_B, cameras, noise)
    det &= np.broadcast_to(np.asarray(seen, bool).reshape(len(T_C0_B), -1), det.shape[:2])[..., None]
    # the calibration the CVS uses: the truth plus one draw of its stated error, then the rig
    sd = np.array([float(calib_std.get(n, 0.0)) for n in INTRINSIC_NAMES])
    cams_cal = []
    for camera in cameras:
        K, dist = _K_dist(camera)
        intr = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist] + sd * rng.standard_normal(len(sd))
        cams_cal.append((K_from_intrinsics(*intr[:4]), intr[4:]))
    rig = calibrate_rig_views(rng, T_Ci_C0, cameras, cams_cal, calib_std, board, n_views, view_sigma_px)
    T_cal = [np.eye(4)] + [np.asarray(c["T_Ci_C0"], float) for c in rig["cameras"]]
    n_det = det.sum(axis=2)
    starts = board_pose_starts(uv, det, p_B, cams_cal, T_cal)
    sigma_eff = float(np.hypot(sigma_px, shared_px))
    T_meas, Sigma, _ = fused_board_pose_best(uv, det, p_B, cams_cal, T_cal, starts, sigma_px=sigma_eff,
                                             flip_term=True)  # fmt: skip
    valid = np.isfinite(T_meas[:, 0, 0]) & (n_det.max(axis=1) >= 6)
    ext_cov = [c["covariance"] for c in rig["cameras"]]
    ext_sens = [c["intrinsics_sensitivity"] for c in rig["cameras"]]
    S_cal, G_cal = rig_calibration_covariance(uv[valid], det[valid], p_B, cams_cal, T_cal,
                                              T_meas[valid], sigma_eff, [calib_std] * n_cam, ext_cov,
                                              ext_sens, return_factor=True)  # fmt: skip
    Sigma[valid] += S_cal
    T_meas[~valid], Sigma[~valid] = np.nan, np.nan
    if return_factor:
        G = np.full((len(T_meas), 6, G_cal.shape[2]), np.nan)
        G[valid] = G_cal
        return T_meas, valid, Sigma, rig, G
    return T_meas, valid, Sigma, rig


#: The se3 intrinsics the workflow frees by default (config/config.yaml optimise.se3.free).
SE3_FREE_DEFAULT = ("fx", "fy", "k1", "k2", "p1", "p2")


def validate_simulated_session(seed, focal_px=700.0, duration_s=20.0, calib_std=None, n_folds=5,
                               block_s=2.0):
    """Validate as the workflow does, on a simulated session: what a flight then uses.

    A corner-level session (:func:`cvsflow.optimise.se3_sim.simulate_session`: iid 0.3 px
    corners, a Vicon reference, 1-3 m) starts from a calibration off the true lens by one draw
    of ``calib_std`` (which se3 is told), runs se3's held-out folds and full fit
    (:data:`SE3_FREE_DEFAULT` free) and the compare stage (:func:`cvsflow.evaluate.heldout.compare_heldout`).

    Parameters
    ----------
    seed : int
        The session's seed; the calibration draw's is ``1000 + seed``.
    focal_px : float
        Nominal focal length of the 640 x 480 camera.
    duration_s : float
        Session length.
    calib_std : dict, optional
        1-sigma of the starting calibration; default ``CALIB_STD_DEFAULT``; ``{}`` starts from
        the true lens.
    n_folds, block_s : int, float
        se3's held-out folds.

    Returns
    -------
    se3_result : dict
        The full se3 fit (``K``, ``dist``, ``std_errors``, ``fixed_intrinsics``, ...).
    comparison : dict
        The compare stage's output (``error_model_fit``: the session's model (T)).
    camera : dict
        The true lens, as :func:`measure_reference`'s ``camera`` (640 x 480).
    """
    calib_std = CALIB_STD_DEFAULT if calib_std is None else calib_std
    v = simulate_session(seed, duration_s=duration_s, focal_px=focal_px)
    K, dist = np.asarray(v["camera"]["K"], float), np.asarray(v["camera"]["dist"], float)
    sd = np.array([float(calib_std.get(n, 0.0)) for n in INTRINSIC_NAMES])
    intr = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist]
    intr = intr + sd * np.random.default_rng(1000 + seed).standard_normal(len(sd))
    start = {"K": K_from_intrinsics(*intr[:4]).tolist(), "dist": intr[4:].tolist(),
             "std": dict(calib_std)}  # fmt: skip
    dt = v["truth"]["dt_offset_s"]
    free = list(SE3_FREE_DEFAULT)
    held, fits = ev.cross_validate_se3(v["corners"], v["bodies"], start, v["board"], dt,
                                       n_folds=n_folds, block_s=block_s, seed=0, free=free)  # fmt: skip
    full = se3.optimise_se3(v["corners"], v["bodies"], start, v["board"], dt, free=free).result
    comparison, *_ = ev.compare_heldout(None, held, full, fits, v["board"], n_boot=20,
                                        corners=v["corners"])  # fmt: skip
    camera = {"fx_px": K[0, 0], "fy_px": K[1, 1], "cx_px": K[0, 2], "cy_px": K[1, 2],
              "dist": dist.tolist(), "width_px": 640, "height_px": 480}  # fmt: skip
    return full, comparison, camera
