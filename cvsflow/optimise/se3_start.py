"""The closed-form start of the ``se3`` method: the found corners as arrays, PnP per frame,
and the robot-world/hand-eye solution A_i X = Z B_i for the two marker mountings.

A_i = T_Cm_Bm,i (Vicon), B_i = T_C_B,i (PnP at the calibrated intrinsics), X = T_Bm_B,
Z = T_Cm_C (:func:`solve_hand_eye`, Shah 2013). :func:`corner_arrays` and
:func:`solve_pnp_frames` also feed the solver, the held-out evaluation and the uncertainty
stage.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import project_SO3
from cvsflow.geometry import transforms as tf

log = logging.getLogger(__name__)

# Fewest corners of a frame that enter the fit (a planar pose has 6 dof; PnP needs 4).
MIN_FRAME_CORNERS = 6


def corner_arrays(corners, n_corners, min_corners=MIN_FRAME_CORNERS):
    """Found frames of a corners table as arrays, missing corners as NaN.

    A frame may hold a subset of the corners (a hand or the image border hides the others,
    docs/contracts.md corners.parquet); it is kept with at least ``min_corners`` of them.

    Parameters
    ----------
    corners : DataFrame
        corners.parquet: ``frame, t_s, found, corner, u_px, v_px``.
    n_corners : int
        Inner corners per board (P).
    min_corners : int
        Fewest finite corners a frame needs to be kept.

    Returns
    -------
    frame : ndarray of int, shape (F,)
    t_s : ndarray, shape (F,)
        Video times, s.
    uv_px : ndarray, shape (F, P, 2)
        Observed distorted pixels, corner k in row k; NaN where corner k was not seen.

    Raises
    ------
    OptimiseError
        Missing columns or no frame with ``min_corners`` corners.
    """
    need = {"frame", "t_s", "found", "corner", "u_px", "v_px"}
    missing = need - set(corners.columns)
    if missing:
        raise OptimiseError(
            f"se3: corners table lacks columns {sorted(missing)} (docs/contracts.md corners.parquet)"
        )
    c = corners[corners["found"].astype(bool) & (corners["corner"] >= 0)]
    c = c[c["corner"] < n_corners].drop_duplicates(["frame", "corner"])
    if c.empty:
        raise OptimiseError("se3: corners table has no found frame")
    frames = np.sort(c["frame"].unique())
    t = c.groupby("frame")["t_s"].first().reindex(frames).to_numpy(float)
    uv = np.full((len(frames), n_corners, 2), np.nan)
    fi = np.searchsorted(frames, c["frame"].to_numpy())
    ci = c["corner"].to_numpy(int)
    uv[fi, ci, 0] = c["u_px"].to_numpy(float)
    uv[fi, ci, 1] = c["v_px"].to_numpy(float)
    seen = np.isfinite(uv).all(axis=2)
    uv[~seen] = np.nan
    n_seen = seen.sum(axis=1)
    keep = (n_seen >= min_corners) & np.isfinite(t)
    n_partial = int((keep & (n_seen < n_corners)).sum())
    if n_partial:
        log.info("se3: %d found frames with only part of the %d corners used", n_partial, n_corners)
    n_bad = int((~keep).sum())
    if n_bad:
        log.warning("se3: %d found frames with fewer than %d corners skipped", n_bad, min_corners)
    if not keep.any():
        raise OptimiseError(
            f"se3: no frame has {min_corners} or more corners with finite u_px, v_px"
        )
    return frames[keep], t[keep], uv[keep]


def solve_pnp_frames(uv_px, p_B, K, dist):
    """PnP pose T_C_B of every frame (IPPE then Levenberg-Marquardt refinement).

    Parameters
    ----------
    uv_px : ndarray, shape (F, P, 2)
        Observed distorted pixels; NaN rows are corners not seen (left out).
    p_B : ndarray, shape (P, 3)
        Corner positions in the board frame B, metres (planar, z = 0).
    K : ndarray, shape (3, 3)
        Camera matrix, px.
    dist : ndarray, shape (5,)
        [k1, k2, p1, p2, k3].

    Returns
    -------
    T_C_B : ndarray, shape (F, 4, 4)
        Board in camera, metres; NaN where PnP failed or fewer than 4 corners were seen.
    ok : ndarray of bool, shape (F,)
    """
    K = np.asarray(K, np.float64)
    dist = np.asarray(dist, np.float64).ravel()
    obj = np.asarray(p_B, np.float64).reshape(-1, 1, 3)
    T = np.full((len(uv_px), 4, 4), np.nan)
    ok = np.zeros(len(uv_px), bool)
    for i, uv in enumerate(np.asarray(uv_px, np.float64)):
        seen = np.isfinite(uv).all(axis=1)
        if seen.sum() < 4:
            continue
        img = np.ascontiguousarray(uv[seen]).reshape(-1, 1, 2)
        obj_i = obj if seen.all() else np.ascontiguousarray(obj[seen])
        try:
            good, rvec, tvec = cv2.solvePnP(obj_i, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
            if not good:
                continue
            rvec, tvec = cv2.solvePnPRefineLM(obj_i, img, K, dist, rvec, tvec)
        except cv2.error:
            continue
        if np.isfinite(rvec).all() and np.isfinite(tvec).all() and tvec[2, 0] > 0:
            T[i] = tf.T_from_rvec_tvec(rvec.ravel(), tvec.ravel())
            ok[i] = True
    return T, ok


def solve_hand_eye(T_Cm_Bm, T_C_B):
    """Closed-form T_Cm_C and T_Bm_B from pose pairs (robot-world/hand-eye, AX = ZB).

    Parameters
    ----------
    T_Cm_Bm : ndarray, shape (N, 4, 4)
        Board-marker body in the camera-marker body, from the Vicon (A_i), metres.
    T_C_B : ndarray, shape (N, 4, 4)
        Board in the camera optical frame, from PnP (B_i), metres.

    Returns
    -------
    T_Cm_C : ndarray, shape (4, 4)
        Camera optical frame in the camera-marker body (Z), metres.
    T_Bm_B : ndarray, shape (4, 4)
        Board frame in the board-marker body (X), metres.

    Raises
    ------
    OptimiseError
        Fewer than 3 pairs (or fewer than 3 consistent ones), mismatched shapes, or rotations
        too alike to separate X from Z.

    Notes
    -----
    T_Cm_Bm,i @ T_Bm_B = T_Cm_C @ T_C_B,i, i.e. A_i X = Z B_i. Rotation: R_A R_X = R_Z R_B is
    linear in (vec R_X, vec R_Z) via Kronecker products,
    [I (x) R_A, -(R_B^T (x) I)] [vec R_X; vec R_Z] = 0 (Shah 2013, "Solving the robot-world/
    hand-eye calibration problem using the Kronecker product", eq. 11); the null vector is
    scaled to det > 0 and each block projected to SO(3). Translation:
    [R_A, -I] [t_X; t_Z] = R_Z t_B - t_A, linear least squares (Shah eq. 14). This is the
    problem ``cv2.calibrateRobotWorldHandEye`` solves with A = cTw ("world2cam"),
    X = wTb ("base2world"), Z = cTg ("gripper2cam"), B = gTb ("base2gripper").
    Pairs with a gross error (rotation or least-absolute-deviation translation residual
    beyond ``OUTLIER_FACTOR`` times the median pair's plus ``OUTLIER_FLOOR``: a garbled or
    flipped PnP pose) are left out with a WARNING and both solves repeated without them.
    """
    A = np.asarray(T_Cm_Bm, float)
    B = np.asarray(T_C_B, float)
    if A.shape != B.shape or A.ndim != 3 or A.shape[1:] != (4, 4):
        raise OptimiseError(
            f"se3 hand-eye: T_Cm_Bm {A.shape} and T_C_B {B.shape}; expected equal (N, 4, 4)"
        )
    keep = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(B).all(axis=(1, 2))
    A, B = A[keep], B[keep]
    n = len(A)
    if n < 3:
        raise OptimiseError(f"se3 hand-eye: {n} usable pose pairs; need at least 3")
    RA, RB = A[:, :3, :3], B[:, :3, :3]
    eye3 = np.eye(3)
    # rows of each pair: (I (x) R_A) vec X - (R_B^T (x) I) vec Z = 0  (column-major vec)
    M = np.concatenate(
        [
            np.einsum("ij,nkl->nikjl", eye3, RA).reshape(n, 9, 9),
            -np.einsum("nji,kl->nikjl", RB, eye3).reshape(n, 9, 9),
        ],
        axis=2,
    )
    MtM = np.einsum("nij,nik->jk", M, M)
    evals, evecs = np.linalg.eigh(MtM)
    if evals[1] < 1e-9 * max(evals[-1], 1e-300) * n:
        raise OptimiseError(
            "se3 hand-eye: the board rotations are too alike to separate T_Cm_C from T_Bm_B "
            f"(second smallest eigenvalue {evals[1]:.3g}); the board must turn about two axes"
        )
    R_X, R_Z = _rotations_from_null_vector(evecs[:, 0])
    # translations: R_A t_X - t_Z = R_Z t_B - t_A
    lhs = np.concatenate([RA, -np.broadcast_to(eye3, RA.shape)], axis=2).reshape(3 * n, 6)
    rhs = (np.einsum("ij,nj->ni", R_Z, B[:, :3, 3]) - A[:, :3, 3]).reshape(3 * n)
    t_XZ = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    inlier = _consistent_pairs(RA, RB, R_X, R_Z, lhs, rhs)
    if not inlier.all():
        # a PnP pose far off (a flipped or garbled board) pulls a least-squares solution by
        # its full error: solve again without the pairs that disagree with the rest
        log.warning(
            "se3 hand-eye: %d of %d pose pairs left out of the start (their PnP pose disagrees "
            "with the Vicon by more than %g times the median pair plus %.0f deg or %.0f mm)",
            int((~inlier).sum()), n, OUTLIER_FACTOR, np.degrees(OUTLIER_FLOOR[0]),
            1e3 * OUTLIER_FLOOR[1],
        )  # fmt: skip
        if inlier.sum() < 3:
            raise OptimiseError(
                f"se3 hand-eye: {int(inlier.sum())} of {n} pose pairs agree with each other; "
                "need at least 3"
            )
        MtM = np.einsum("nij,nik->jk", M[inlier], M[inlier])
        R_X, R_Z = _rotations_from_null_vector(np.linalg.eigh(MtM)[1][:, 0])
        keep3 = np.repeat(inlier, 3)
        rhs = (np.einsum("ij,nj->ni", R_Z, B[:, :3, 3]) - A[:, :3, 3]).reshape(3 * n)
        t_XZ = np.linalg.lstsq(lhs[keep3], rhs[keep3], rcond=None)[0]
    return tf.make_T(R_Z, t_XZ[3:]), tf.make_T(R_X, t_XZ[:3])


#: A pose pair is left out of the hand-eye start when its rotation or translation residual
#: exceeds OUTLIER_FACTOR times the median pair's plus OUTLIER_FLOOR (rad, m): only gross
#: errors go (a garbled pose, a flipped board), which would drag the least-squares start out
#: of the solver's reach. Residuals grow with distance and tilt, so the margin is wide: the
#: demo's largest pair is 15x the median in rotation (0.9 deg) and 17x in translation
#: (10 mm), and none of its 600 pairs goes.
OUTLIER_FACTOR = 10.0
OUTLIER_FLOOR = (np.radians(2.0), 0.05)


def _rotations_from_null_vector(v):
    """R_X, R_Z from the null vector of Shah's rotation system, scaled to det > 0."""
    X = v[:9].reshape(3, 3, order="F")
    Z = v[9:].reshape(3, 3, order="F")
    if np.linalg.det(X) < 0:
        X, Z = -X, -Z
    return project_SO3(X), project_SO3(Z)


def _consistent_pairs(RA, RB, R_X, R_Z, lhs, rhs, n_irls=30):
    """Pairs whose residuals are within OUTLIER_FACTOR of the median pair's (plus the floor).

    Rotation: the angle of R_A R_X against R_Z R_B. Translation: the residual norm under the
    least-absolute-deviation solution (iteratively reweighted least squares), which gross
    outliers in t_B cannot drag the way they drag the least-squares one.
    """
    n = len(RA)
    ang = tf.rotation_angle(np.einsum("nij,jk->nik", RA, R_X)
                            @ np.swapaxes(np.einsum("ij,njk->nik", R_Z, RB), 1, 2))
    w = np.ones(n)
    for _ in range(n_irls):
        sw = np.repeat(np.sqrt(w), 3)
        t = np.linalg.lstsq(lhs * sw[:, None], rhs * sw, rcond=None)[0]
        res = np.linalg.norm((lhs @ t - rhs).reshape(n, 3), axis=1)
        w = 1.0 / np.maximum(res, 1e-9)
    ok_rot = ang <= OUTLIER_FACTOR * np.median(ang) + OUTLIER_FLOOR[0]
    ok_t = res <= OUTLIER_FACTOR * np.median(res) + OUTLIER_FLOOR[1]
    return ok_rot & ok_t
