"""One board pose per frame from every camera of a rig that saw it, with its covariance.

The rig's calibration (each camera's intrinsics, every camera's pose from camera 0) comes
from :mod:`cvsflow.rig.extrinsics`; this module fuses the corners that several cameras saw at one
instant into one board pose ``T_C0_B`` in camera 0 (:func:`fused_board_pose`, Gauss-Newton on
the stacked reprojection residuals), starts it from every camera's own IPPE poses and keeps
the least cost with the mirrored solution's flip term (:func:`board_pose_starts`,
:func:`fused_board_pose_best`), and states the calibration's share of its covariance
(:func:`fused_pose_jacobian`, :func:`rig_calibration_covariance`). Poses are perturbed on the
left, ``[dt (m), dtheta (rad)]`` in C0 (``geometry.pose_error_left``).
"""

from __future__ import annotations

import cv2
import numpy as np

from cvsflow.exceptions import InputError
from cvsflow.geometry import (
    INTRINSIC_NAMES,
    R_from_rvec,
    invert_T,
    make_T,
    pose_error_left,
    project_points_jac,
    rvec_from_R,
    skew,
)


def _board_pose_jacobian(d_uv_d_p, R_Ci_C0, Rp_B):
    """Jacobians of a camera's pixels w.r.t. the board pose T_C0_B perturbed on the left.

    With R_C0_B <- exp([w]x) R_C0_B and t_C0_B <- t_C0_B + dt, a corner's point in Ci moves by
    R_Ci_C0 (w x R_C0_B p_B + dt). ``d_uv_d_p`` (..., 2, 3) is the projection's Jacobian at the
    point in Ci, ``Rp_B`` (..., 3) the corner rotated into C0 (R_C0_B p_B). Returns d uv / d w
    and d uv / d dt, each (..., 2, 3).
    """
    d_uv_d_pc0 = d_uv_d_p @ R_Ci_C0
    return -d_uv_d_pc0 @ skew(Rp_B), d_uv_d_pc0




def _board_pose_residuals(T_C0_B, uv, seen, p_B, K, dist, T_Ci_C0):
    """Residuals (F, C, N, 2) px, zero where unseen, and d/d[dt, dtheta] of T_C0_B (F, C, N, 2, 6)."""
    n_frames, n_cam, n_pts = seen.shape
    r = np.zeros((n_frames, n_cam, n_pts, 2))
    J = np.zeros((n_frames, n_cam, n_pts, 2, 6))
    Rp_B = np.matmul(T_C0_B[:, None, :3, :3], p_B[None, :, :, None])[..., 0]
    p_C0 = Rp_B + T_C0_B[:, None, :3, 3]
    for c in range(n_cam):
        R, t = T_Ci_C0[c][:3, :3], T_Ci_C0[c][:3, 3]
        p_C = p_C0 @ R.T + t
        front = p_C[..., 2] > 1e-6
        p_C = np.where(front[..., None], p_C, [0.0, 0.0, 1.0])
        uv_hat, d_uv_d_p, _ = project_points_jac(p_C, K[c], dist[c])
        m = seen[:, c] & front
        r[:, c] = np.where(m[..., None], uv_hat - np.nan_to_num(uv[:, c]), 0.0)
        J_rot, J_t = _board_pose_jacobian(d_uv_d_p, R, Rp_B)
        J[:, c, :, :, :3] = J_t
        J[:, c, :, :, 3:] = J_rot
        J[:, c] *= m[..., None, None]
    return r, J


def fused_board_pose(uv_px, seen, p_B, cameras, T_Ci_C0, T_C0_B_start, sigma_px=None,
                     n_iterations=10):
    """One board pose per frame from the corners every camera saw, with its covariance.

    Parameters
    ----------
    uv_px : ndarray, shape (F, C, N, 2)
        Detected corner k of the board in camera c on frame f, px (anything where not seen).
    seen : ndarray of bool, shape (F, C, N)
        Which corners each camera saw on each frame.
    p_B : ndarray, shape (N, 3)
        The corners in the board frame B, m.
    cameras : sequence of (K, dist)
        Each camera's matrix (3, 3) px and distortion (5,).
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        Each camera's pose from camera 0 (identity first), m.
    T_C0_B_start : ndarray, shape (F, 4, 4)
        Start of each frame's solve (e.g. one camera's PnP mapped to C0), m.
    sigma_px : float or ndarray of shape (F, C), optional
        Corner noise per image axis, px; an array gives each camera on each frame its own
        (corners interpolated between two frames are less noisy than one frame's) and weights
        the solve by it; None: each frame's residual RMS (dof-corrected).
    n_iterations : int
        Gauss-Newton steps (it converges in 3-5 from a PnP start).

    Returns
    -------
    T_C0_B : ndarray, shape (F, 4, 4)
        The fused board pose in camera 0, m; NaN on frames with fewer than 4 corners in all.
    Sigma : ndarray, shape (F, 6, 6)
        Its covariance, ``[dt (m), dtheta (rad)]`` in C0 with the rotation perturbed on the left
        (R <- exp([dtheta]x) R: the flight reference's convention), NaN where not solved.
    n_seen : ndarray of int, shape (F, C)
        Corners used per camera.

    Notes
    -----
    The covariance is ``sigma^2 (J^T J)^-1`` of the stacked reprojection residuals of every
    camera: the corner noise only. A second camera ``b`` metres away measures depth by
    triangulation, with an error that grows as d^2 / (f b) instead of the single camera's
    d^2 / (f L) for a board of size L (``bench/bench_stereo_flight.py`` shows both).
    """
    uv = np.asarray(uv_px, float)
    seen = np.asarray(seen, bool)
    K = [np.asarray(c[0], float) for c in cameras]
    dist = [np.asarray(c[1], float).ravel()[:5] for c in cameras]
    T = np.array(T_C0_B_start, float, copy=True)
    n_seen = seen.sum(axis=2)
    ok = n_seen.sum(axis=1) >= 4
    T[~ok] = np.eye(4)
    n_frames = len(T)
    weighted = sigma_px is not None and np.ndim(sigma_px) > 0
    if weighted:
        sigma_fc = np.broadcast_to(np.asarray(sigma_px, float), seen.shape[:2])
        if not np.all(sigma_fc[n_seen > 0] > 0):
            raise ValueError("fused_board_pose: sigma_px must be positive wherever a camera saw corners")
        # 1/sigma per residual row: (F, C) -> (F, C, N, 2), flattened like J's rows
        scale = np.broadcast_to((1.0 / np.where(sigma_fc > 0, sigma_fc, 1.0))[:, :, None, None],
                                seen.shape + (2,)).reshape(n_frames, -1)  # fmt: skip
    for _ in range(n_iterations):
        r, J = _board_pose_residuals(T, uv, seen, p_B, K, dist, T_Ci_C0)
        Jf = J.reshape(n_frames, -1, 6)
        r_f = r.reshape(n_frames, -1)
        if weighted:
            Jf, r_f = Jf * scale[..., None], r_f * scale
        JfT = np.swapaxes(Jf, 1, 2)
        H = JfT @ Jf + 1e-12 * np.eye(6)
        g = (JfT @ r_f[..., None])[..., 0]
        step = -np.linalg.solve(H, g[..., None])[..., 0]
        step[~ok] = 0.0
        T[:, :3, 3] += step[:, :3]
        T[:, :3, :3] = R_from_rvec(step[:, 3:]) @ T[:, :3, :3]
    r, J = _board_pose_residuals(T, uv, seen, p_B, K, dist, T_Ci_C0)
    Jf = J.reshape(n_frames, -1, 6)
    if weighted:
        Jf = Jf * scale[..., None]
    H = np.swapaxes(Jf, 1, 2) @ Jf + 1e-12 * np.eye(6)
    if weighted:
        s2 = np.ones(n_frames)
    elif sigma_px is None:
        r_f = r.reshape(n_frames, -1)
        s2 = np.einsum("fm,fm->f", r_f, r_f) / np.maximum(2 * n_seen.sum(axis=1) - 6, 1)
    else:
        s2 = np.full(n_frames, float(sigma_px) ** 2)
    Sigma = s2[:, None, None] * np.linalg.inv(H)
    T[~ok] = np.nan
    Sigma[~ok] = np.nan
    return T, Sigma, n_seen


def fused_pose_jacobian(uv_px, seen, p_B, T_C0_B, sigma_px, geometry_at, steps, n_iterations=3):
    """Derivative of fused board poses with respect to calibration parameters, first order.

    Central differences of ``n_iterations`` Gauss-Newton steps of :func:`fused_board_pose`
    from the solution. One step's derivative, ``-(J^T J)^-1 J^T dr/dtheta``, leaves out the
    residuals' curvature, which matters along a nearly ambiguous direction of a lone
    camera's view (tilt against sideways shift): on a 2 m view of a 0.3 m board seen by one
    camera, one step gave 4 times the tilt's true response to fx; each further step shrinks
    that error by the same factor (two steps: within 1 %).

    Parameters
    ----------
    uv_px, seen, p_B
        As :func:`fused_board_pose`.
    T_C0_B : ndarray, shape (F, 4, 4)
        The fused poses (the solution), m.
    sigma_px : float or ndarray of shape (F, C)
        As :func:`fused_board_pose` (only an array's relative weights matter).
    geometry_at : callable
        ``geometry_at(j, h)`` -> ``(cameras, T_Ci_C0)`` of the rig with parameter j moved by h.
    steps : sequence of float
        The difference step of each parameter (its units).
    n_iterations : int
        Gauss-Newton steps per difference.

    Returns
    -------
    D : ndarray, shape (F, 6, p)
        d[dt (m), dtheta (rad)] / d theta_j in C0, rotation perturbed on the left.
    """
    D = np.zeros((len(T_C0_B), 6, len(steps)))
    for j, h in enumerate(steps):
        T = []
        for sign in (1.0, -1.0):
            cameras, T_Ci_C0 = geometry_at(j, sign * h)
            T.append(fused_board_pose(uv_px, seen, p_B, cameras, T_Ci_C0, T_C0_B, sigma_px=sigma_px,
                                      n_iterations=n_iterations)[0])  # fmt: skip
        D[:, :3, j] = (T[0][:, :3, 3] - T[1][:, :3, 3]) / (2.0 * h)
        R_diff = np.einsum("fij,fkj->fik", T[0][:, :3, :3], T[1][:, :3, :3])
        D[:, 3:, j] = rvec_from_R(R_diff).reshape(-1, 3) / (2.0 * h)
    return D


def rig_calibration_covariance(uv_px, seen, p_B, cameras, T_Ci_C0, T_C0_B, sigma_px, intrinsics_std,
                               extrinsics_cov, extrinsics_sensitivity=None, rel_step=0.01,
                               return_factor=False):
    """Covariance of fused board poses from a rig calibration's uncertainty, first order.

    ``D Sigma_theta D^T`` (:func:`fused_pose_jacobian`) over every camera's intrinsics (their
    calibration ``std``, independent) and every camera's pose from camera 0 (its 6x6
    covariance, as :func:`stereo_extrinsics` states it: ``[r, t]``, the rotation a small
    rotation of Ci on the left), with their cross-covariance ``S_i V`` (S_i the pose's
    sensitivity to the intrinsics, V their variances) when the sensitivities are given.

    The cross-covariance is what makes a stereo rig's depth hold: the relative pose is
    fitted with the intrinsics as they are, so a principal point off by 0.5 px is mostly
    absorbed by a turn of the camera, and the disparity of a far point moves far less than
    0.5 px. Left out (``extrinsics_sensitivity=None``), the two are treated as independent,
    which overstates the depth term of a far board several times.

    Parameters
    ----------
    uv_px, seen, p_B
        As :func:`fused_board_pose`.
    cameras : sequence of (K, dist)
        The calibration used, per camera.
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        Each camera's pose from camera 0 (identity first), m.
    T_C0_B : ndarray, shape (F, 4, 4)
        The fused poses, m.
    sigma_px : float or ndarray of shape (F, C)
        As :func:`fused_board_pose`.
    intrinsics_std : sequence of dict
        Per camera, 1-sigma of ``fx fy cx cy k1 k2 p1 p2 k3`` (missing names: 0).
    extrinsics_cov : sequence of array_like, shape (6, 6)
        Per camera i >= 1 (camera 0's pose is the identity by definition): the total, the
        intrinsics' part included (:func:`stereo_extrinsics` ``covariance``).
    extrinsics_sensitivity : sequence of array_like, shape (6, 9 C), optional
        Per camera i >= 1, d[r, t] / d(intrinsics) (:func:`stereo_extrinsics`
        ``intrinsics_sensitivity``).
    rel_step : float
        Difference step, in standard deviations of each parameter.
    return_factor : bool
        Also return a factor ``G`` with ``Sigma = G G^T`` frame by frame: the pose error is
        ``G xi`` with one ``xi ~ N(0, I)`` for every frame (one calibration, shared), which a
        flight's alignment partly absorbs (:func:`cvsflow.flight.evaluate_flight`).

    Returns
    -------
    Sigma : ndarray, shape (F, 6, 6)
        ``[dt (m), dtheta (rad)]`` in C0, rotation perturbed on the left.
    G : ndarray, shape (F, 6, k)
        With ``return_factor``.
    """
    n_cam = len(cameras)
    n_sens = n_cam - 1 if extrinsics_sensitivity is None else len(extrinsics_sensitivity)
    if (len(T_Ci_C0) != n_cam or len(intrinsics_std) != n_cam or len(extrinsics_cov) != n_cam - 1
            or n_sens != n_cam - 1):
        raise InputError(f"rig calibration covariance: {n_cam} cameras, {len(T_Ci_C0)} poses, "
                         f"{len(intrinsics_std)} intrinsics std, {len(extrinsics_cov)} extrinsics "
                         f"covariances and {n_sens} sensitivities (one per camera after the "
                         "first)")  # fmt: skip
    intr = [np.r_[np.asarray(K, float)[[0, 1, 0, 1], [0, 1, 2, 2]], np.asarray(d, float).ravel()[:5]]
            for K, d in cameras]  # fmt: skip
    params = [("intr", c, k) for c in range(n_cam) for k in range(9)]
    params += [("extr", i, k) for i in range(1, n_cam) for k in range(6)]
    var = np.array([float(std.get(n, 0.0)) ** 2 for std in intrinsics_std for n in INTRINSIC_NAMES])
    n_int = 9 * n_cam
    cov = np.zeros((len(params), len(params)))
    cov[:n_int, :n_int] = np.diag(var)
    S = [None if extrinsics_sensitivity is None else np.asarray(a, float).reshape(6, n_int)
         for a in (extrinsics_sensitivity or [None] * (n_cam - 1))]  # fmt: skip
    for i in range(n_cam - 1):
        a = slice(n_int + 6 * i, n_int + 6 * i + 6)
        cov[a, a] = np.asarray(extrinsics_cov[i], float).reshape(6, 6)
        if S[i] is not None:
            cov[a, :n_int] = S[i] * var
            cov[:n_int, a] = cov[a, :n_int].T
            for j in range(i):
                b = slice(n_int + 6 * j, n_int + 6 * j + 6)
                cov[a, b] = (S[i] * var) @ S[j].T
                cov[b, a] = cov[a, b].T
    keep = np.flatnonzero(np.diag(cov) > 0)  # an exactly known parameter moves nothing
    params, cov = [params[k] for k in keep], cov[np.ix_(keep, keep)]

    def geometry_at(j, h):
        kind, c, k = params[j]
        x = [a.copy() for a in intr]
        T = [np.array(t, float, copy=True) for t in T_Ci_C0]
        if kind == "intr":
            x[c][k] += h
        elif k < 3:
            T[c][:3, :3] = R_from_rvec(h * np.eye(3)[k]) @ T[c][:3, :3]
        else:
            T[c][k - 3, 3] += h
        return [(np.array([[a[0], 0.0, a[2]], [0.0, a[1], a[3]], [0.0, 0.0, 1.0]]), a[4:]) for a in x], T

    D = fused_pose_jacobian(uv_px, seen, p_B, T_C0_B, sigma_px, geometry_at,
                            rel_step * np.sqrt(np.diag(cov)))  # fmt: skip
    Sigma = np.einsum("fip,pq,fjq->fij", D, cov, D)
    if not return_factor:
        return Sigma
    lam, V = np.linalg.eigh(cov)
    return Sigma, D @ (V * np.sqrt(np.clip(lam, 0.0, None)))


def board_pose_starts(uv_px, seen, p_B, cameras, T_Ci_C0):
    """Starts for the fused solve: both IPPE solutions of every camera's own view, in C0.

    A far board's view is nearly ambiguous: its tilt mirrored about the line of sight fits a
    single camera almost as well, and a second camera too close to it (a baseline that is
    small against the distance) does not pull a solve started on the wrong side across. So
    the fused solve is started from each candidate (:func:`fused_board_pose_best`).

    Parameters
    ----------
    uv_px, seen, p_B, cameras, T_Ci_C0
        As :func:`fused_board_pose`.

    Returns
    -------
    starts : ndarray, shape (2 C, F, 4, 4)
        Candidate T_C0_B (camera c's two solutions at 2c, 2c + 1), m; NaN where camera c saw
        fewer than 4 corners or IPPE gave one solution only.
    """
    uv = np.asarray(uv_px, float)
    seen = np.asarray(seen, bool)
    n_frames, n_cam = seen.shape[:2]
    starts = np.full((2 * n_cam, n_frames, 4, 4), np.nan)
    obj = np.asarray(p_B, np.float64)
    for c, ((K, dist), T) in enumerate(zip(cameras, T_Ci_C0, strict=True)):
        K, dist = np.asarray(K, np.float64), np.asarray(dist, np.float64).ravel()
        T_C0_Ci = invert_T(np.asarray(T, float))
        for f in np.flatnonzero(seen[:, c].sum(axis=1) >= 4):
            m = seen[f, c]
            n, rvs, tvs, _ = cv2.solvePnPGeneric(np.ascontiguousarray(obj[m]),
                                                 np.ascontiguousarray(uv[f, c, m]), K, dist,
                                                 flags=cv2.SOLVEPNP_IPPE)  # fmt: skip
            for k in range(min(int(n), 2)):
                starts[2 * c + k, f] = T_C0_Ci @ make_T(R_from_rvec(np.ravel(rvs[k])), np.ravel(tvs[k]))
    return starts


def fused_board_pose_best(uv_px, seen, p_B, cameras, T_Ci_C0, starts, sigma_px=None, n_iterations=10,
                          flip_term=False):
    """:func:`fused_board_pose` from several starts per frame, keeping the lowest cost.

    Parameters
    ----------
    uv_px, seen, p_B, cameras, T_Ci_C0, sigma_px, n_iterations
        As :func:`fused_board_pose`.
    starts : ndarray, shape (S, F, 4, 4)
        Candidate starts (:func:`board_pose_starts`); NaN candidates are skipped.
    flip_term : bool
        Add the ambiguity of a nearly mirrored solution to the covariance: ``w d d^T``, d the
        kept pose minus the best solution whose rotation differs from it by more than
        1 mrad, and ``w = 1 / (1 + exp(dc / 2))`` the chance that it is the true one given
        its cost excess dc in units of the corner variance (the mixture's covariance about
        the kept pose, as :func:`cvsflow.flight.reference.reference_covariance_transfer`'s
        flip term for one camera).

    Returns
    -------
    T_C0_B, Sigma, n_seen
        As :func:`fused_board_pose`, from the start whose solution has the least (weighted)
        sum of squared reprojection residuals.
    """
    seen = np.asarray(seen, bool)
    uv = np.asarray(uv_px, float)
    starts = np.asarray(starts, float)
    n_frames = seen.shape[0]
    K = [np.asarray(c[0], float) for c in cameras]
    dist = [np.asarray(c[1], float).ravel()[:5] for c in cameras]
    per_camera = sigma_px is not None and np.ndim(sigma_px) > 0
    sigma_fc = np.broadcast_to(np.asarray(sigma_px if per_camera else 1.0, float), seen.shape[:2])
    cost = np.full((len(starts), n_frames), np.inf)
    T_all = np.full((len(starts), n_frames, 4, 4), np.nan)
    Sigma_all = np.full((len(starts), n_frames, 6, 6), np.nan)
    for k, start in enumerate(starts):
        rows = np.flatnonzero(np.isfinite(start[:, 0, 0]))
        if not len(rows):
            continue
        sig = sigma_fc[rows] if per_camera else sigma_px
        T, Sigma, _ = fused_board_pose(uv[rows], seen[rows], p_B, cameras, T_Ci_C0, start[rows],
                                       sigma_px=sig, n_iterations=n_iterations)  # fmt: skip
        ok = np.isfinite(T[:, 0, 0])
        if ok.any():
            r, _ = _board_pose_residuals(T[ok], uv[rows[ok]], seen[rows[ok]], p_B, K, dist, T_Ci_C0)
            cost[k, rows[ok]] = np.einsum("fcnk,fc->f", r**2, 1.0 / sigma_fc[rows[ok]] ** 2)
        T_all[k, rows], Sigma_all[k, rows] = T, Sigma
    best = np.argmin(cost, axis=0)
    f = np.arange(n_frames)
    T_best, Sigma_best = T_all[best, f], Sigma_all[best, f]
    found = np.isfinite(cost[best, f])
    T_best[~found], Sigma_best[~found] = np.nan, np.nan
    if flip_term and found.any():
        # cost in units of the corner variance: sigma_px's, or each frame's own residual's
        if sigma_px is None:
            dof = np.maximum(2 * seen.sum(axis=(1, 2)) - 6, 1)
            var = np.where(found, cost[best, f] / dof, 1.0)
        elif per_camera:
            var = np.ones(n_frames)
        else:
            var = np.full(n_frames, float(sigma_px) ** 2)
        def rotations(T):  # identity where unsolved (their cost is inf anyway)
            return np.where(np.isfinite(T[:, :3, :3]), T[:, :3, :3], np.eye(3))

        R_best = rotations(T_best)
        ang = np.stack([np.linalg.norm(rvec_from_R(np.einsum("fij,fkj->fik", rotations(T_all[k]), R_best))
                                       .reshape(-1, 3), axis=1) for k in range(len(starts))])  # fmt: skip
        alt_cost = np.where(ang > 1e-3, cost, np.inf)
        alt = np.argmin(alt_cost, axis=0)
        has = found & np.isfinite(alt_cost[alt, f])
        if has.any():
            T_alt = T_all[alt[has], f[has]]
            d = pose_error_left(T_best[has], T_alt)
            dc = (alt_cost[alt[has], f[has]] - cost[best[has], f[has]]) / var[has]
            w = 1.0 / (1.0 + np.exp(np.clip(dc / 2.0, -50.0, 50.0)))
            Sigma_best[has] += w[:, None, None] * d[:, :, None] * d[:, None, :]
    return T_best, Sigma_best, seen.sum(axis=2)
