"""Board poses of a rig fit: one fused board pose per rig frame from every camera that saw it
(:func:`fused_rig_poses`), with its covariance from the corner noise and from the calibration
the fit found (:func:`calibration_covariance`, :func:`rig_geometry`,
:func:`fused_pose_calibration_covariance`). The fit itself is
:func:`cvsflow.rig.fit.optimise_se3_rig`; frames are as its module docstring says.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow.board import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import INTRINSIC_NAMES, project_points, sample_period
from cvsflow.geometry import transforms as tf
from cvsflow.optimise import (
    K_from_intrinsics,
    corner_arrays,
    pose_columns,
    solve_pnp_frames,
    tracks_from_params,
)
from cvsflow.rig.fusion import fused_board_pose, fused_pose_jacobian
from cvsflow.rig.instants import corners_at_instants, interpolation_error_ms

log = logging.getLogger(__name__)


def _worst_residual_px(T_C_B, uv, p_B, K, dist):
    """Per frame the largest corner distance (px) from its PnP pose's projection (NaN-safe)."""
    p_C = np.einsum("fij,pj->fpi", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
    with np.errstate(invalid="ignore"):
        d = np.linalg.norm(project_points(p_C, K, dist) - uv, axis=-1)
    return np.nanmax(np.where(np.isfinite(d), d, -1.0), axis=1)


def _group_frames(t_vicon, tol):
    """Rig frames: per camera the index of each frame's group; groups of at most one frame per
    camera whose times lie within ``tol`` of the group's first."""
    cam = np.concatenate([np.full(len(t), i) for i, t in enumerate(t_vicon)])
    idx = np.concatenate([np.arange(len(t)) for t in t_vicon])
    t = np.concatenate(t_vicon)
    order = np.lexsort((cam, t))
    group = np.empty(len(t), int)
    g, t_start, members = -1, -np.inf, set()
    for k in order:
        if t[k] - t_start > tol or cam[k] in members:
            g, t_start, members = g + 1, t[k], set()
        members.add(cam[k])
        group[k] = g
    out, pos = [], 0
    for tv in t_vicon:
        out.append(group[pos : pos + len(tv)])
        pos += len(tv)
    return out, g + 1, cam, idx


def _group_instants(t_vicon, group, n_groups):
    """Each rig frame's instant: the time of its member with the lowest camera index."""
    t_g = np.full(n_groups, np.nan)
    for t, g in reversed(list(zip(t_vicon, group, strict=True))):
        t_g[g] = t
    return t_g


def fused_rig_poses(
    params, corners, bodies, board, frames=None, match_tol_s=None, sigma_px=None, calibration_cov=True,
    instant="interpolate", max_residual_px=None, interpolation_cov=True,
):
    """Per rig frame: the board pose fused from every camera that saw it, and the reference.

    Parameters
    ----------
    params : dict
        :func:`optimise_se3_rig`'s ``result`` (``cameras`` with ``K, dist, T_Cm_C,
        dt_offset_s``; ``T_Bm_B``; ``sigma_px``; the smoothing options).
    corners : list of DataFrame
        Each camera's corners table.
    bodies : DataFrame
        bodies.parquet.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    frames : list of array_like of int, optional
        Per camera, the frames to use (None: all found frames).
    match_tol_s : float, optional
        Frames of several cameras within this of each other on the Vicon clock form one rig
        frame; default a quarter of the shortest median frame interval of any camera.
    sigma_px : float, optional
        Corner noise per axis for the covariance, px; default ``params["sigma_px"]``.
    calibration_cov : bool
        Add the calibration's uncertainty (every camera's intrinsics and mounting, with
        their cross-covariances: :func:`fused_pose_calibration_covariance`) to the corner
        noise's; False: the corner noise's only.
    instant : {"interpolate", "nearest"}
        ``"interpolate"``: a rig frame is fused at the time of its member with the lowest
        camera index, every other member's corners interpolated in time between its frame and
        the neighbouring one on the other side of that instant (through a third, the frame's
        other neighbour, where that has the corner:
        :func:`cvsflow.rig.instants.corners_at_instants`), or extrapolated by at
        most half an interval from the one before (their noise scaled accordingly; a
        member with neither within 1.5 of its frame intervals is left out of that rig
        frame). ``"nearest"``: every member's frame as it is, at the mean of their times
        (cameras not triggered together are then fused as if simultaneous).
    max_residual_px : float, optional
        Leave a camera's view of a rig frame out of the fusion when a corner of it lies
        farther than this from that camera's own PnP pose of the frame (px): a corner the
        tracker put on the wrong crossing. None (default): every view is used.
    interpolation_cov : bool
        With ``instant="interpolate"``: add each moved view's interpolation error to its
        corner noise (:func:`cvsflow.rig.instants.interpolation_error_ms`, the
        track's third difference), as an error common to the view's corners; False: the
        corner noise's propagation only.

    Returns
    -------
    poses : DataFrame
        One row per rig frame with a pose and valid Vicon poses, in time order: ``frame``
        (rig frame number), ``t_vicon_s`` (mean of its cameras' times), ``n_cameras``,
        ``frame_cam{i}`` (camera i's frame, -1 if it did not see the board then),
        ``n_corners_cam{i}``; ``cvs_`` (fused T_C0_B) and ``ref_`` (Vicon, eq. 1 with camera
        0's mounting) pose columns as :func:`~cvsflow.optimise.se3_apply.apply_se3`'s, in camera
        0's frame C0; ``S00 .. S55`` the fused pose's covariance of ``[dt (m), dtheta (rad)]``
        in C0, rotation perturbed on the left (the flight reference's convention); and
        ``reproj_rms_px`` over all its corners.

    Notes
    -----
    The covariance is the corner noise's (:func:`cvsflow.rig.fusion.fused_board_pose`) plus, by
    default, the calibration's: every camera's intrinsics and mounting T_Cm_Ci, with the
    fit's cross-covariances, carried through the fused solve to first order
    (:func:`fused_pose_calibration_covariance`). The cross-covariances matter: the common
    motion of all mountings cancels in T_Ci_C0, and leaving them out overstates the
    calibration term 3-7 times in standard deviation. Without the calibration term a frame
    seen by two cameras is overconfident, its fused depth sigma (1.4 mm against 4.0 mm for
    one camera) being comparable to the error of the fitted relative mounting: on the
    simulated 6 s two-camera rig of tests/unit/test_se3_rig.py (seed 3), against the true
    pose, NEES 6.2 on one-camera and 10.4 on two-camera frames without it, 5.9 and 7.3 with
    it (6 expected); over seeds 0-7 of that session the two-camera mean is 5.6-7.3 with it
    and 5.9-10.4 without. The fit's own frames are scored in sample, so the calibration
    error and a frame's corner noise are slightly correlated; held-out frames
    (:func:`cross_validate_se3_rig`) are not. Rolling-shutter line delays are ignored here.
    Cameras not triggered together see the board at different instants. With
    ``instant="nearest"`` they are fused as if simultaneous and the board's motion in between
    is in no covariance: in bench/bench_se3_rig.py (seed 3, 6 s) the rig frames the 25 fps
    camera 2 shares with the genlocked 30 fps pair then have NEES 24 (31 without the
    calibration term); moved to one instant (the default) they have 5.7 (7.6; 5.9 and 8.1
    interpolating linearly), and the tests' seeds 0-3 give 5.8-7.6 against 21-60. Linear
    interpolation misses a corner by up to an eighth of its image acceleration times the
    frame interval squared, comparable to the corner noise for a hand-held board: on the 10 s
    render of config/stereo.yaml (seed 19) with the default tolerance, two-camera NEES 10.9
    in sample and 13.1 held out linearly, 7.4 and 9.4 through three frames
    (bench/bench_rig_instants.py). What remains was measured there against the renderer's
    true corners: the three-frame interpolation misses the moved corners by 0.042 px RMS
    per axis (corner noise 0.054 px), 0.040 px of it common to the view's corners (hand
    tremor at 5-11 Hz, near the 25 fps camera's Nyquist frequency); the time offsets' error
    moves them by 0.003 px; the renderer has no rolling shutter. With the true calibration
    and no calibration term the two-camera NEES is 6.3 at a 2 ms tolerance and 21.5 at the
    default. ``interpolation_cov`` adds the error to each moved view's corner variance
    (:func:`cvsflow.rig.instants.interpolation_error_ms`: the track's third
    difference scaled for its dominant frequency, taken as an error shared by the view's
    corners): 6.6 in sample and 7.2 held
    out with the true calibration, and with the fit's (and its calibration term) 3.6 and 4.2
    (3 folds) on that render (4.0 and 4.6 from stills refined with OpenCV's 11 px window),
    5.5 and 5.2 on seed 7 (without the term 5.8 in sample on that render, 7.6 and 6.7 on
    seed 7). The calibration's
    error is one draw shared by all of a session's frames and moves the poses along about
    three directions, so one session's mean NEES with the fit's calibration lies anywhere in
    3.3-15 on that render (0.5 and 99.5 %): tests/workflow/test_rig.py judges the corners'
    part (true calibration) and the calibration's (its error whitened, a chi-square) apart.
    One-camera frames, the 2 ms tolerance (5.9 and 7.9 over 36 frames; seed 7 5.5
    and 4.5) and the poses' errors (0.92 mm RMS on two-camera frames) unchanged. An error
    the view's n corners share, of variance s^2, is weighed as n independent errors of
    variance n s^2: right in the direction of the view's image translation, more than right
    in the others; propagating only a shared shift (the pose's response to the view's cx,
    cy) covered less of it (with the true calibration and the true interpolation variance
    7.2 and 7.6 that way, 5.5 and 6.0 this way). On the 20 s render the two-camera NEES is
    3.9 in sample and 4.3 held out over 257 frames (6.5 and 6.8 without the term; 4.5 and
    4.8 over 86 at 2 ms; one-camera frames 3.8, the calibration term being generous there:
    with the true calibration 6.1 and 6.7, 15.1 and 15.2 without the term). A view
    extrapolated (no neighbour across the instant, as at the held-out folds' block edges),
    interpolated linearly, or through three frames with no fourth beyond gets the next
    Newton term of its own interpolant (without the frequency factor): held out, seed 7's
    two-camera NEES 5.21 -> 4.69 (its largest 48, 24 -> 13, 12), seed 19's 6.19 -> 6.03
    (bench/bench_rig_instants.py). In bench/bench_se3_rig.py (seed 3, 6 s, smooth motion) the term
    changes the NEES by 0.04 at most.
    """
    if instant not in ("interpolate", "nearest"):
        raise OptimiseError(f"se3 rig: instant must be 'interpolate' or 'nearest', not {instant!r}")
    p_B = board_object_points(board)
    cams = params["cameras"]
    n_cam = len(cams)
    if len(corners) != n_cam:
        raise OptimiseError(f"se3 rig: {len(corners)} corner tables for {n_cam} cameras")
    K = [np.asarray(c["K"], float) for c in cams]
    dist = [np.asarray(c["dist"], float) for c in cams]
    T_Cm_C = [np.asarray(c["T_Cm_C"], float) for c in cams]
    T_Bm_B = np.asarray(params["T_Bm_B"], float)
    arrays, t_vicon = [], []
    for i in range(n_cam):
        try:
            fr, tv, uv = corner_arrays(corners[i], len(p_B))
        except OptimiseError as exc:
            raise OptimiseError(f"se3 rig: camera {i}: {exc}") from exc
        if frames is not None and frames[i] is not None:
            sel = np.isin(fr, np.asarray(frames[i]))
            fr, tv, uv = fr[sel], tv[sel], uv[sel]
        arrays.append((fr, uv))
        t_vicon.append(tv + float(cams[i]["dt_offset_s"]))
    if match_tol_s is None:
        steps = [sample_period(t) for t in t_vicon if len(t) > 1]
        match_tol_s = 0.25 * min(steps) if steps else 1e-3
    group, n_groups, _, _ = _group_frames(t_vicon, float(match_tol_s))
    uv_g = np.full((n_groups, n_cam, len(p_B), 2), np.nan)
    frame_g = -np.ones((n_groups, n_cam), int)
    noise_g = np.ones((n_groups, n_cam))
    interp_g = np.zeros((n_groups, n_cam))  # interpolation variance per corner, px^2
    sigma = float(params["sigma_px"]) if sigma_px is None else float(sigma_px)
    t_sum, t_n = np.zeros(n_groups), np.zeros(n_groups)
    start = np.full((n_groups, 4, 4), np.nan)
    T_Ci_C0 = [tf.invert_T(T) @ T_Cm_C[0] for T in T_Cm_C]
    t_instant = _group_instants(t_vicon, group, n_groups) if instant == "interpolate" else None
    for i, ((fr, uv), g) in enumerate(zip(arrays, group, strict=True)):
        if t_instant is not None and len(fr):
            max_gap_s = 1.5 * sample_period(t_vicon[i], default=0.0)
            uv_at, noise, moved, usable = corners_at_instants(uv, t_vicon[i], t_instant[g], max_gap_s)
            if np.any(moved & ~usable):
                log.info("se3 rig: camera %d: %d of %d frames off their rig frame's instant have no "
                         "neighbour to interpolate from; left out of those rig frames", i,
                         int(np.sum(moved & ~usable)), int(np.sum(moved)))  # fmt: skip
            uv_g[g, i], noise_g[g, i] = uv_at, noise
            if interpolation_cov:
                # the error is common to the view's corners (a shift of the whole view: 0.040
                # of 0.042 px RMS on the stereo render); on the pose, n corners sharing one
                # error of variance s^2 weigh as n independent ones of variance n s^2 each
                n_seen = np.isfinite(uv_at).all(axis=-1).sum(axis=1)
                ms = interpolation_error_ms(uv, t_vicon[i], t_instant[g], max_gap_s, sigma)
                interp_g[g, i] = n_seen * ms
        else:
            uv_g[g, i] = uv
        frame_g[g, i] = fr
        np.add.at(t_sum, g, t_vicon[i])
        np.add.at(t_n, g, 1)
        T_C_B, ok = solve_pnp_frames(uv, p_B, K[i], dist[i])
        if max_residual_px is not None:
            bad = ok & (_worst_residual_px(T_C_B, uv, p_B, K[i], dist[i]) > float(max_residual_px))
            if bad.any():
                log.info("se3 rig: camera %d: %d views left out of the fusion (a corner > %g px "
                         "from the view's PnP pose)", i, int(bad.sum()), max_residual_px)
                uv_g[g[bad], i] = np.nan
                frame_g[g[bad], i] = -1
                ok = ok & ~bad
        fill = ok & ~np.isfinite(start[g, 0, 0])
        start[g[fill]] = tf.invert_T(T_Ci_C0[i]) @ T_C_B[fill]
    t_g = t_sum / np.maximum(t_n, 1) if t_instant is None else t_instant
    seen = np.isfinite(uv_g).all(axis=-1)
    frame_g = np.where(seen.any(axis=2), frame_g, -1)
    has = np.isfinite(start[:, 0, 0])
    cam, brd = tracks_from_params(params, bodies)
    has &= cam.ok(t_g) & brd.ok(t_g)
    uv_g, seen, start, frame_g, t_g = uv_g[has], seen[has], start[has], frame_g[has], t_g[has]
    if t_instant is not None:
        sigma = np.sqrt((sigma * noise_g[has]) ** 2 + interp_g[has])
    T_fused, Sigma, n_seen = fused_board_pose(uv_g, seen, p_B, list(zip(K, dist, strict=True)), T_Ci_C0,
                                              start, sigma_px=sigma)  # fmt: skip
    if calibration_cov:
        Sigma = Sigma + fused_pose_calibration_covariance(params, uv_g, seen, p_B, T_fused, sigma)
    T_ref = tf.invert_T(cam(t_g) @ T_Cm_C[0]) @ brd(t_g) @ T_Bm_B  # eq. (1) in C0
    keep = np.isfinite(T_fused[:, 0, 0])
    # reprojection RMS of the fused pose over every camera's corners
    err2 = np.zeros(len(t_g))
    for i in range(n_cam):
        p_C = (
            np.einsum("fij,pj->fpi", (T_Ci_C0[i] @ T_fused)[:, :3, :3], p_B)
            + (T_Ci_C0[i] @ T_fused)[:, None, :3, 3]
        )
        d = project_points(p_C, K[i], dist[i]) - uv_g[:, i]
        err2 += np.where(seen[:, i], np.sum(np.nan_to_num(d) ** 2, axis=-1), 0.0).sum(axis=1)
    rms = np.sqrt(err2 / np.maximum(n_seen.sum(axis=1), 1))
    out = {"frame": np.arange(int(keep.sum())), "t_vicon_s": t_g[keep],
           "n_cameras": (frame_g[keep] >= 0).sum(axis=1)}  # fmt: skip
    for i in range(n_cam):
        out[f"frame_cam{i}"] = frame_g[keep, i]
        out[f"n_corners_cam{i}"] = n_seen[keep, i]
    out.update(pose_columns("cvs_", T_fused[keep]))
    out.update(pose_columns("ref_", T_ref[keep]))
    S = Sigma[keep].reshape(-1, 36)
    for a in range(6):
        for b in range(6):
            out[f"S{a}{b}"] = S[:, 6 * a + b]
    out["reproj_rms_px"] = rms[keep]
    return pd.DataFrame(out)


def calibration_covariance(params):
    """Joint covariance of every camera's intrinsics and T_Cm_C parameters, fitted and fixed.

    The fitted ones' block is the fit's ``covariance_total``; a fixed intrinsic theta_k
    (``std`` s_k) enters the fitted ones through the sensitivity S (``fixed_sensitivity``),
    so its cross-covariance with them is ``S_k s_k^2`` and its own variance ``s_k^2``.

    Parameters
    ----------
    params : dict
        :func:`optimise_se3_rig`'s ``result``.

    Returns
    -------
    names : list of str
        ``cam{i}_{intrinsic}`` (fitted or fixed, std > 0) and ``cam{i}_T_Cm_C_*``.
    values : ndarray, shape (p,)
        Their values (rotations: the fit's perturbation of the start, rad).
    cov : ndarray, shape (p, p)
    """
    missing = [k for k in ("covariance_total", "fixed_sensitivity", "estimates") if k not in params]
    if missing:
        raise OptimiseError(f"se3 rig: the calibration covariance needs the fit's {missing}")
    names_x = list(params["estimates"])
    fixed_names, fixed_values, sd = [], [], []
    for i, c in enumerate(params["cameras"]):
        fx = c["fixed_intrinsics"]
        fixed_names += [f"cam{i}_{n}" for n in fx["names"]]
        fixed_values += list(fx["values"])
        sd += list(fx["std"])
    sd = np.asarray(sd, float)
    C_x = np.asarray(params["covariance_total"], float)
    S = np.asarray(params["fixed_sensitivity"], float).reshape(len(names_x), len(sd))
    cov = np.block([[C_x, S * sd**2], [(S * sd**2).T, np.diag(sd**2)]])
    all_names = names_x + fixed_names
    all_values = np.concatenate([[params["estimates"][n] for n in names_x], fixed_values])
    keep = [k for k, n in enumerate(all_names)
            if (n.split("_", 1)[1] in INTRINSIC_NAMES or "_T_Cm_C_" in n) and cov[k, k] > 0.0]  # fmt: skip
    return [all_names[k] for k in keep], all_values[keep], cov[np.ix_(keep, keep)]


def rig_geometry(params, names=(), values=()):
    """Each camera's (K, dist) and T_Ci_C0, with the parameters ``names`` set to ``values``.

    Parameters
    ----------
    params : dict
        :func:`optimise_se3_rig`'s ``result``.
    names : sequence of str
        Rig parameter names (``cam{i}_{intrinsic}``, ``cam{i}_T_Cm_C_*``) to override.
    values : sequence of float
        Their values, in the fit's parametrisation (rotations perturb the start on the right).

    Returns
    -------
    cameras : list of (ndarray, ndarray)
        Each camera's K (3, 3) px and dist (5,).
    T_Ci_C0 : list of ndarray, shape (4, 4)
        Each camera's pose from camera 0, m.
    """
    cams = params["cameras"]
    intr = [np.array([*np.asarray(c["K"], float)[[0, 1, 0, 1], [0, 1, 2, 2]], *c["dist"]], float)
            for c in cams]  # fmt: skip
    T_Cm_C = [np.asarray(c["T_Cm_C"], float).copy() for c in cams]
    w = {}
    for n, v in zip(names, values, strict=True):
        i, s = int(n[3 : n.index("_")]), n[n.index("_") + 1 :]
        if s in INTRINSIC_NAMES:
            intr[i][INTRINSIC_NAMES.index(s)] = v
        elif s.startswith("T_Cm_C_r"):
            w.setdefault(i, {})["xyz".index(s[8])] = v
        else:
            T_Cm_C[i][:3, 3]["xyz".index(s[7])] = v
    for i, wi in w.items():
        # the fit's rotation parameters perturb its start on the right (Se3Model.unpack)
        r = np.array([wi.get(k, params["estimates"][f"cam{i}_T_Cm_C_r{a}_rad"]) for k, a in enumerate("xyz")])
        T_Cm_C[i][:3, :3] = np.asarray(cams[i]["init"]["T_Cm_C"], float)[:3, :3] @ tf.R_from_rvec(r)
    K = [(K_from_intrinsics(*a[:4]), a[4:]) for a in intr]
    return K, [tf.invert_T(T) @ T_Cm_C[0] for T in T_Cm_C]


def fused_pose_calibration_covariance(params, uv_px, seen, p_B, T_C0_B, sigma_px, rel_step=0.01):
    """Covariance of fused board poses from the calibration's uncertainty, first order.

    ``D Sigma_theta D^T`` per frame, Sigma_theta the joint covariance of every camera's
    intrinsics and mounting (:func:`calibration_covariance`), D = d T_C0_B / d theta by
    :func:`cvsflow.rig.fusion.fused_pose_jacobian` (central differences of three Gauss-Newton
    steps from the solution), steps of ``rel_step`` standard errors.
    tests/unit/test_se3_rig.py checks it against full re-solves at sampled calibrations.
    Cost: two three-step solves (eight residual and Jacobian evaluations of every frame)
    per parameter, p = 10 per camera with four free intrinsics: in bench/bench_se3_rig.py
    (seed 3, 6 s, CPU) :func:`fused_rig_poses` takes 1.2 s instead of 0.17 s for two
    cameras (191 rig frames; the fit 1.0 s) and 3.0 s instead of 0.26 s for three (250
    frames; the fit 2.1 s).

    Parameters
    ----------
    params : dict
        :func:`optimise_se3_rig`'s ``result``.
    uv_px, seen, p_B
        As :func:`~cvsflow.rig.fusion.fused_board_pose`.
    T_C0_B : ndarray, shape (F, 4, 4)
        The fused poses (the solution).
    sigma_px : float or ndarray of shape (F, C)
        Corner noise, px: a float only passes through; an array weights the cameras of
        each frame as in the fused solve.
    rel_step : float
        Difference step, in standard errors of each parameter.

    Returns
    -------
    Sigma : ndarray, shape (F, 6, 6)
        ``[dt (m), dtheta (rad)]`` in C0, rotation perturbed on the left.
    """
    names, values, cov = calibration_covariance(params)

    def geometry_at(j, h):
        v = values.copy()
        v[j] += h
        return rig_geometry(params, names, v)

    D = fused_pose_jacobian(uv_px, seen, p_B, T_C0_B, sigma_px, geometry_at, rel_step * np.sqrt(np.diag(cov)))
    return np.einsum("fip,pq,fjq->fij", D, cov, D)
