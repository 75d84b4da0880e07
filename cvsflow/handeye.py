"""Hand-eye calibration from chessboard stills, each with a pose of the camera's carrier.

Frames (design.md): ``W`` the pose source's world (robot base, motion-capture world), ``C`` the
camera optical frame, ``B`` the board (origin at inner corner 0, z into the board). The carrier
X is what the pose source tracks: the robot end-effector or a marker body.

- ``eye_in_hand``: the camera rides on the carrier (X = ``Cm``), the board is fixed in W.
  Unknowns ``T_Cm_C`` (camera in carrier) and ``T_W_B`` (board in world);
  ``T_C_B,i = inv(T_Cm_C) @ inv(T_W_Cm,i) @ T_W_B``.
- ``eye_to_hand``: the board rides on the carrier (X = ``Bm``), the camera is fixed in W.
  Unknowns ``T_W_C`` (camera in world) and ``T_Bm_B`` (board in carrier);
  ``T_C_B,i = inv(T_W_C) @ T_W_Bm,i @ T_Bm_B``.

Both are ``T_C_B,i = inv(H) @ A_i @ G`` with ``A_i = inv(T_W_Cm,i)`` or ``T_W_Bm,i``; H is the
"hand-eye" transform (``T_Cm_C`` or ``T_W_C``) and G the target (``T_W_B`` or ``T_Bm_B``): the
robot-world/hand-eye problem ``A_i G = H B_i`` with ``B_i = T_C_B,i`` from PnP.

Method
------
1. Corners per still with :func:`cvsflow.calibration.find_board` and ordered with
   :func:`cvsflow.calibration.order_corners` (the board's colour fixes corner 0, so every
   still shares one board frame; for boards whose ends look alike the order of each still is
   chosen so its relative rotations match the carrier's); PnP per still
   (:func:`cvsflow.optimise.se3_start.solve_pnp_frames`).
2. Closed form: ``cv2.calibrateHandEye`` (Tsai, Park, Horaud, Andreff, Daniilidis) or
   ``cv2.calibrateRobotWorldHandEye`` (Shah, Li); G from the mean of ``inv(A_i) H B_i``.
3. Outlier screen: with the carrier poses taken as exact, each still's reprojection RMS under
   the fit of the other stills; the worst is rejected while it exceeds 4x the median.
4. Refinement: H, G (and optionally fx, fy, cx, cy, distortion) minimising the corner
   reprojection error over all stills, ``scipy.optimize.least_squares`` with the analytic
   Jacobian; projection and its derivatives from :mod:`cvsflow.geometry.camera`. By default the
   carrier poses are not exact: each still's pose error (a turn about the carrier origin and a
   shift) is an unknown with a zero-mean isotropic prior, the corner, rotation and position
   sigmas estimated together (Foerstner's variance components). Without it, robot or mocap
   pose errors of a few mm are absorbed into H and G: on ViSP's Franka set the plain fit
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
from scipy.optimize import least_squares

from cvsflow import transforms as tf
from cvsflow.calibration import board_object_points, board_pattern, find_board, order_corners
from cvsflow.errors import CalibrationError, InputError
from cvsflow.geometry.camera import INTRINSIC_NAMES, project_points_jac
from cvsflow.geometry.transforms import right_jacobian_SO3
from cvsflow.optimise.se3_cov import covariances
from cvsflow.optimise.se3_start import solve_pnp_frames

log = logging.getLogger(__name__)

MODES = ("eye_in_hand", "eye_to_hand")
#: Closed-form solvers: OpenCV's hand-eye (AX = XB) and robot-world/hand-eye (AX = ZB) methods.
CLOSED_FORM_METHODS = {
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "park": cv2.CALIB_HAND_EYE_PARK,
    "horaud": cv2.CALIB_HAND_EYE_HORAUD,
    "andreff": cv2.CALIB_HAND_EYE_ANDREFF,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
    "shah": cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH,
    "li": cv2.CALIB_ROBOT_WORLD_HAND_EYE_LI,
}
ROBOT_WORLD_METHODS = ("shah", "li")
#: Names of the hand-eye transform H and the target G per mode.
FRAME_NAMES = {"eye_in_hand": ("T_Cm_C", "T_W_B"), "eye_to_hand": ("T_W_C", "T_Bm_B")}
POSE_STD_KEYS = ("rx_deg", "ry_deg", "rz_deg", "x_mm", "y_mm", "z_mm")
#: Fewest stills: three poses give two motions, the least that fixes a hand-eye rotation.
MIN_STILLS = 3
#: Smallest angle (deg) between two motion axes for the rotation to be determined.
MIN_AXIS_SPREAD_DEG = 5.0


def _check_mode(mode):
    if mode not in MODES:
        raise InputError(f"hand-eye mode {mode!r}; expected one of {list(MODES)}")


def carrier_chain(T_W_X, mode):
    """``A_i`` of ``T_C_B,i = inv(H) A_i G``: inv(T_W_Cm) eye-in-hand, T_W_Bm eye-to-hand.

    Parameters
    ----------
    T_W_X : array_like, shape (..., 4, 4)
        Carrier pose(s) in W, m.
    mode : {"eye_in_hand", "eye_to_hand"}
        Which body the carrier X is: the camera's (Cm) or the board's (Bm).

    Returns
    -------
    A : ndarray, shape (..., 4, 4)
        ``T_Cm_W`` (eye-in-hand) or ``T_W_Bm`` (eye-to-hand), m.

    Raises
    ------
    InputError
        An unknown ``mode``.
    """
    _check_mode(mode)
    T_W_X = np.asarray(T_W_X, float)
    return tf.invert_T(T_W_X) if mode == "eye_in_hand" else T_W_X


def predict_T_C_B(T_W_X, T_H, T_G, mode):
    """Board in camera per still, (N, 4, 4), from carrier poses and the two unknowns.

    Parameters
    ----------
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier pose in the pose source's world W per still (T_W_Cm or T_W_Bm), m.
    T_H : ndarray, shape (4, 4)
        The hand-eye transform H: ``T_Cm_C`` (eye-in-hand) or ``T_W_C`` (eye-to-hand), m.
    T_G : ndarray, shape (4, 4)
        The target G: ``T_W_B`` (eye-in-hand) or ``T_Bm_B`` (eye-to-hand), m.
    mode : {"eye_in_hand", "eye_to_hand"}
        Which body the carrier X is: the camera's (Cm) or the board's (Bm).

    Returns
    -------
    T_C_B : ndarray, shape (N, 4, 4)
        ``inv(H) @ A_i @ G`` per still, m.
    """
    return tf.invert_T(T_H) @ carrier_chain(T_W_X, mode) @ T_G


def mean_transform(T):
    """Chordal mean rotation and mean translation of transforms (N, 4, 4).

    Parameters
    ----------
    T : array_like, shape (N, 4, 4)
        Transforms between the same two frames (estimates of one transform), m.

    Returns
    -------
    ndarray, shape (4, 4)
        Rotation: the chordal (Frobenius) mean projected onto SO(3); translation: the
        arithmetic mean, m.
    """
    T = np.asarray(T, float)
    return tf.make_T(tf.mean_rotation(T[:, :3, :3]), T[:, :3, 3].mean(axis=0))


# --------------------------------------------------------------------------- closed form


def motion_axis_spread_deg(T_W_X) -> float:
    """Largest angle (deg, in [0, 90]) between the rotation axes of the carrier's motions.

    The motions are those from the first pose to each other pose; rotations under 2 deg give
    no usable axis. A hand-eye rotation needs two motions about non-parallel axes (Tsai 1989).

    Parameters
    ----------
    T_W_X : array_like, shape (N, 4, 4)
        Carrier pose in W per still, m.

    Returns
    -------
    float
        The spread, deg; 0.0 when fewer than two motions rotate by more than 2 deg.
    """
    T_W_X = np.asarray(T_W_X, float)
    R_rel = np.swapaxes(T_W_X[:1, :3, :3], 1, 2) @ T_W_X[1:, :3, :3]
    w = tf.rvec_from_R(R_rel).reshape(-1, 3) if len(R_rel) else np.zeros((0, 3))
    ang = np.linalg.norm(w, axis=1)
    axes = w[ang > np.radians(2.0)] / ang[ang > np.radians(2.0), None]
    if len(axes) < 2:
        return 0.0
    c = np.clip(np.abs(axes @ axes.T), 0.0, 1.0)
    return float(np.degrees(np.arccos(c.min())))


def closed_form_hand_eye(T_W_X, T_C_B, mode="eye_in_hand", method="park"):
    """Closed-form H and G from carrier poses and PnP board poses.

    Parameters
    ----------
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier in world per still (``T_W_Cm`` eye-in-hand, ``T_W_Bm`` eye-to-hand), metres.
    T_C_B : ndarray, shape (N, 4, 4)
        Board in camera per still (PnP), metres.
    mode : str
        ``eye_in_hand`` or ``eye_to_hand``.
    method : str
        A key of ``CLOSED_FORM_METHODS``.

    Returns
    -------
    T_H : ndarray, shape (4, 4)
        ``T_Cm_C`` (eye-in-hand) or ``T_W_C`` (eye-to-hand), metres.
    T_G : ndarray, shape (4, 4)
        ``T_W_B`` (eye-in-hand) or ``T_Bm_B`` (eye-to-hand), metres.

    Raises
    ------
    CalibrationError
        Fewer than 3 stills, or OpenCV failing.

    Notes
    -----
    ``cv2.calibrateHandEye`` solves ``gripper2base_i @ cam2gripper @ target2cam_i = const``;
    with gripper2base = inv(A_i) that constant is G and cam2gripper is H (OpenCV's docs: pass
    base2gripper for eye-to-hand). ``cv2.calibrateRobotWorldHandEye`` solves
    ``world2cam_i @ base2world = gripper2cam @ base2gripper_i``; with world2cam = B_i and
    base2gripper = A_i, base2world = inv(G) and gripper2cam = inv(H).
    """
    if method not in CLOSED_FORM_METHODS:
        raise InputError(f"closed-form method {method!r}; expected one of {list(CLOSED_FORM_METHODS)}")
    A = carrier_chain(T_W_X, mode)
    B = np.asarray(T_C_B, float)
    if len(A) < MIN_STILLS or A.shape != B.shape:
        raise CalibrationError(
            f"hand-eye closed form: {len(A)} carrier poses and {len(B)} board poses; expected "
            f"equal counts, at least {MIN_STILLS}"
        )
    try:
        if method in ROBOT_WORLD_METHODS:
            R_bw, t_bw, R_gc, t_gc = cv2.calibrateRobotWorldHandEye(
                list(B[:, :3, :3]), list(B[:, :3, 3]), list(A[:, :3, :3]), list(A[:, :3, 3]),
                method=CLOSED_FORM_METHODS[method],
            )
            T_H = tf.invert_T(tf.make_T(R_gc, np.ravel(t_gc)))
            T_G = tf.invert_T(tf.make_T(R_bw, np.ravel(t_bw)))
            return T_H, T_G
        A_inv = tf.invert_T(A)
        R_cg, t_cg = cv2.calibrateHandEye(
            list(A_inv[:, :3, :3]), list(A_inv[:, :3, 3]), list(B[:, :3, :3]), list(B[:, :3, 3]),
            method=CLOSED_FORM_METHODS[method],
        )
    except cv2.error as exc:
        raise CalibrationError(f"hand-eye closed form ({method}): OpenCV failed ({exc})") from exc
    T_H = tf.make_T(R_cg, np.ravel(t_cg))
    if not np.isfinite(T_H).all():
        raise CalibrationError(f"hand-eye closed form ({method}): no finite solution")
    return T_H, mean_transform(A_inv @ T_H @ B)


# --------------------------------------------------------------------------- refinement


def p_G_of(T_G, p_B):
    """The board corners in G's parent frame (W eye-in-hand, Bm eye-to-hand), (P, 3).

    Parameters
    ----------
    T_G : ndarray, shape (4, 4)
        The target G (``T_W_B`` or ``T_Bm_B``), m.
    p_B : ndarray, shape (P, 3)
        The corners in B, m.

    Returns
    -------
    ndarray, shape (P, 3)
        ``T_G`` applied to ``p_B``, m.
    """
    return p_B @ T_G[:3, :3].T + T_G[:3, 3]


class _Model:
    """Corner residuals of ``T_C_B,i = inv(H) A_i G`` and their Jacobian, whitened.

    x = [w_H (3, rad), t_H (3, m), w_G (3, rad), t_G (3, m), free intrinsics (k),
    then with ``pose_noise`` one [rho_i (3, rad), tau_i (3, m)] per still], with
    R_H = R0_H expm([w_H]x), R_G = R0_G expm([w_G]x) and the carrier pose of still i taken as
    R_W_X,i = expm([rho_i]x) R_W_X,i (a turn about the carrier's origin), t_W_X,i + tau_i.
    Residuals: corner errors / sigma_px, then rho / sigma_rot_rad and tau / sigma_pos_m (the
    carrier poses' errors as unknowns with zero-mean priors: errors in variables).
    """

    def __init__(self, T_W_X, mode, uv, p_B, T0_H, T0_G, intr0, free, pose_noise=False,
                 sigmas=(1.0, 1e-3, 1e-3)):  # fmt: skip
        self.T_W_X, self.mode = np.asarray(T_W_X, float), mode
        self.uv, self.p_B = uv, p_B
        self.R0_H, self.R0_G = T0_H[:3, :3], T0_G[:3, :3]
        self.x0_pose = np.concatenate([np.zeros(3), T0_H[:3, 3], np.zeros(3), T0_G[:3, 3]])
        self.intr0 = np.asarray(intr0, float)
        self.free = np.array([n in free for n in INTRINSIC_NAMES])
        self.k = 12 + int(self.free.sum())
        self.pose_noise = bool(pose_noise)
        self.sigma_px, self.sigma_pos_m, self.sigma_rot_rad = sigmas
        n, P = len(uv), uv.shape[1]
        # row groups of the residual vector: corners, rho priors, tau priors
        self.groups = {"corners": slice(0, 2 * n * P)}
        if self.pose_noise:
            self.groups["rot"] = slice(2 * n * P, 2 * n * P + 3 * n)
            self.groups["pos"] = slice(2 * n * P + 3 * n, 2 * n * P + 6 * n)

    def x0(self):
        delta = np.zeros(6 * len(self.uv)) if self.pose_noise else np.zeros(0)
        return np.concatenate([self.x0_pose, self.intr0[self.free], delta])

    def unpack(self, x):
        T_H = tf.make_T(self.R0_H @ tf.R_from_rvec(x[0:3]), x[3:6])
        T_G = tf.make_T(self.R0_G @ tf.R_from_rvec(x[6:9]), x[9:12])
        intr = self.intr0.copy()
        intr[self.free] = x[12:self.k]
        return T_H, T_G, intr

    def carrier(self, x, rows=slice(None)):
        """The carrier poses the model uses (with the estimated errors removed), (n, 4, 4)."""
        T = self.T_W_X[rows]
        if not self.pose_noise:
            return T
        d = x[self.k:].reshape(-1, 6)[rows]
        return tf.make_T(tf.R_from_rvec(d[:, :3]) @ T[:, :3, :3], T[:, :3, 3] + d[:, 3:])

    def _project(self, A, T_H, T_G, intr, want_jac=False):
        K = np.array([[intr[0], 0.0, intr[2]], [0.0, intr[1], intr[3]], [0.0, 0.0, 1.0]])
        R_H = T_H[:3, :3]
        p_G = p_G_of(T_G, self.p_B)
        p_A = np.einsum("nij,pj->npi", A[:, :3, :3], p_G) + A[:, None, :3, 3]
        p_C = (p_A - T_H[:3, 3]) @ R_H  # R_H^T (p_A - t_H), (n, P, 3)
        uv, J_p, J_i = project_points_jac(p_C, K, intr[4:])
        return (uv, p_C, J_p, J_i) if want_jac else uv

    def project(self, x):
        T_H, T_G, intr = self.unpack(x)
        return self._project(carrier_chain(self.carrier(x), self.mode), T_H, T_G, intr)

    def residuals(self, x):
        r = [(self.project(x) - self.uv).ravel() / self.sigma_px]
        if self.pose_noise:
            d = x[self.k:].reshape(-1, 6)
            r += [d[:, :3].ravel() / self.sigma_rot_rad, d[:, 3:].ravel() / self.sigma_pos_m]
        return np.concatenate(r)

    def jacobian(self, x):
        T_H, T_G, intr = self.unpack(x)
        A = carrier_chain(self.carrier(x), self.mode)
        _, p_C, J_p, J_i = self._project(A, T_H, T_G, intr, want_jac=True)
        n, P = p_C.shape[:2]
        J = np.zeros((n, P, 2, len(x)))
        R_H, R_G = T_H[:3, :3], T_G[:3, :3]
        # d p_C / d w_H = [p_C]x Jr(w_H); d p_C / d t_H = -R_H^T
        J[..., 0:3] = J_p @ (tf.skew(p_C) @ right_jacobian_SO3(x[0:3]))
        J[..., 3:6] = J_p @ (-R_H.T)
        # d p_C / d p_G = R_H^T R_A; d p_G / d w_G = -R_G [p_B]x Jr(w_G); d p_G / d t_G = I
        M = np.einsum("ji,njk->nik", R_H, A[:, :3, :3])  # (n, 3, 3)
        d_pG_dw = -R_G @ tf.skew(self.p_B) @ right_jacobian_SO3(x[6:9])  # (P, 3, 3)
        J_pG = np.einsum("npij,njk->npik", J_p, M)  # (n, P, 2, 3)
        J[..., 6:9] = np.einsum("npij,pjk->npik", J_pG, d_pG_dw)
        J[..., 9:12] = J_pG
        J[..., 12:self.k] = J_i[..., self.free]
        if self.pose_noise:
            # carrier of still i: R' = expm([rho]x) R_W_X, t' = t_W_X + tau; Jl the left
            # Jacobian of SO(3), Jl(rho) = Jr(rho)^T
            d = x[self.k:].reshape(-1, 6)
            T_X = self.carrier(x)
            Jl = np.swapaxes(np.stack([right_jacobian_SO3(r) for r in d[:, :3]]), 1, 2)
            J_pA = J_p @ R_H.T  # (n, P, 2, 3): d uv / d p_A
            if self.mode == "eye_to_hand":  # p_A = R' p_G + t'
                u = np.einsum("nij,pj->npi", T_X[:, :3, :3], p_G_of(T_G, self.p_B))
                dA_drho = -tf.skew(u) @ Jl[:, None]
                dA_dtau = np.broadcast_to(np.eye(3), (n, 1, 3, 3))
            else:  # p_A = R'^T (p_G - t')
                v = p_G_of(T_G, self.p_B)[None] - T_X[:, None, :3, 3]
                Rt = np.swapaxes(T_X[:, :3, :3], 1, 2)[:, None]
                dA_drho = Rt @ tf.skew(v) @ Jl[:, None]
                dA_dtau = -np.broadcast_to(Rt, (n, 1, 3, 3))
            cols = self.k + 6 * np.arange(n)
            for j in range(3):
                J[np.arange(n), :, :, cols + j] = (J_pA @ dA_drho[..., j : j + 1])[..., 0]
                J[np.arange(n), :, :, cols + 3 + j] = (J_pA @ dA_dtau[..., j : j + 1])[..., 0]
        J = J.reshape(-1, len(x)) / self.sigma_px
        if self.pose_noise:
            prior = np.zeros((6 * n, len(x)))
            k3 = np.arange(3 * n)
            rot_cols = self.k + 6 * (k3 // 3) + k3 % 3
            prior[k3, rot_cols] = 1.0 / self.sigma_rot_rad
            prior[3 * n + k3, rot_cols + 3] = 1.0 / self.sigma_pos_m
            J = np.vstack([J, prior])
        return J

    def jacobian_fixed(self, x):
        """Whitened derivatives of the residuals w.r.t. the fixed intrinsics, (m, 9 - k)."""
        T_H, T_G, intr = self.unpack(x)
        A = carrier_chain(self.carrier(x), self.mode)
        J_i = self._project(A, T_H, T_G, intr, want_jac=True)[3][..., ~self.free]
        J = J_i.reshape(-1, int((~self.free).sum())) / self.sigma_px
        n_prior = 6 * len(self.uv) if self.pose_noise else 0
        return np.vstack([J, np.zeros((n_prior, J.shape[1]))])

    def still_rms(self, x):
        e = self.project(x) - self.uv
        return np.sqrt(np.mean(np.sum(e**2, axis=-1), axis=1))


def _intrinsics_vector(camera):
    K = np.asarray(camera["K"], float)
    dist = np.asarray(camera.get("dist", np.zeros(5)), float).ravel()
    if K.shape != (3, 3) or dist.size != 5:
        raise InputError(f"camera: K {K.shape}, dist {dist.shape}; expected (3, 3) and 5 values")
    return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dist])


#: Variance-component iterations (Foerstner 1979) and their stop: every factor within 1e-2.
VCE_MAX_ITER = 40
VCE_TOL = 1e-2
#: Floors of the estimated carrier-pose sigmas (m, rad): below them the prior is exact anyway.
SIGMA_FLOOR = {"pos": 1e-7, "rot": 1e-8}


def refine_hand_eye(uv_px, p_B, T_W_X, camera, T0_H, T0_G, mode="eye_in_hand",
                    free_intrinsics=(), pose_noise=True, pose_sigma_m=None, pose_sigma_rad=None):
    """Least-squares H, G (and the free intrinsics) by corner reprojection over all stills.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Corners of each still in board order, px.
    p_B : ndarray, shape (P, 3)
        The corners in B, metres.
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier in world per still, metres.
    camera : dict
        ``K`` (3x3, px), ``dist`` (5 values): the start (and the values of fixed intrinsics).
    T0_H, T0_G : ndarray, shape (4, 4)
        Start, e.g. from :func:`closed_form_hand_eye`.
    mode : str
    free_intrinsics : sequence of str
        Names among ``fx fy cx cy k1 k2 p1 p2 k3`` to refine; empty keeps the camera fixed.
    pose_noise : bool
        Model the carrier poses' errors (a rotation about the carrier origin and a translation
        per still, zero-mean, isotropic) as unknowns with priors; without it the carrier poses
        are taken as exact and only the corners carry noise.
    pose_sigma_m, pose_sigma_rad : float, optional
        The priors' standard deviations; each one not given is estimated from the data with
        the corner sigma (variance components).

    Returns
    -------
    dict
        ``T_H``, ``T_G`` (4, 4), ``intrinsics`` (9,), ``cov`` (n, n) of ``param_names``
        (rotations as local errors about the solution's child axes, rad; translations m),
        including the fixed intrinsics' uncertainty when ``camera["std"]`` gives it (names in
        ``intrinsic_std_propagated``), ``sigma_px``, ``sigma_pos_m``, ``sigma_rot_rad``
        (estimated or given; None without pose noise), ``carrier_residuals`` ((N, 6)
        estimated carrier-pose errors, rad and m),
        ``still_rms_px`` (N,), ``rms_px``, ``param_names``, ``nfev``, ``vce_iterations``.

    Notes
    -----
    Without pose noise the covariance is ``s^2 (J^T J)^-1`` (``cvsflow.optimise.se3_cov.
    covariances``, linear loss). With pose noise the three groups (corners, carrier
    rotations, carrier translations) get their variances by Foerstner's variance-component
    estimation, ``sigma_g^2 <- sigma_g^2 v_g^T v_g / r_g`` with the redundancy
    ``r_g = m_g - tr(N^-1 J_g^T J_g)`` of the whitened problem, iterated with the fit until
    every factor is within 1e-2 of 1; the covariance is then ``N^-1`` (each group's
    ``v^T v / r`` being 1).
    """
    bad = [n for n in free_intrinsics if n not in INTRINSIC_NAMES]
    if bad:
        raise InputError(f"free intrinsics {bad}; expected names among {list(INTRINSIC_NAMES)}")
    uv = np.asarray(uv_px, float)
    T_W_X = np.asarray(T_W_X, float)
    p_B = np.asarray(p_B, float)
    intr0 = _intrinsics_vector(camera)
    free = tuple(free_intrinsics)
    sig = {"corners": 0.5, "pos": pose_sigma_m or 1e-3, "rot": pose_sigma_rad or np.radians(0.05)}
    fixed = {"corners": False, "pos": pose_sigma_m is not None, "rot": pose_sigma_rad is not None}
    T_H, T_G, intr = np.asarray(T0_H, float), np.asarray(T0_G, float), intr0
    delta = np.zeros(6 * len(uv))
    nfev, n_iter = 0, 0
    for it in range(1, (VCE_MAX_ITER if pose_noise else 1) + 1):
        n_iter = it
        model = _Model(T_W_X, mode, uv, p_B, T_H, T_G, intr, free, pose_noise,
                       (sig["corners"], sig["pos"], sig["rot"]))  # fmt: skip
        x0 = model.x0()
        if pose_noise:
            x0[model.k:] = delta
        sol = least_squares(model.residuals, x0, jac=model.jacobian, method="lm",
                            x_scale="jac", max_nfev=200)  # fmt: skip
        nfev += int(sol.nfev)
        T_H, T_G, intr = model.unpack(sol.x)
        delta = sol.x[model.k:]
        if not pose_noise:
            break
        J, r = model.jacobian(sol.x), model.residuals(sol.x)
        N_inv = _inverse(J.T @ J)
        worst = 0.0
        for g, rows in model.groups.items():
            red = rows.stop - rows.start - float(np.einsum("ij,ji->", N_inv, J[rows].T @ J[rows]))
            if fixed[g] or red <= 1e-9:
                continue
            factor = float(r[rows] @ r[rows]) / red
            sig[g] = max(sig[g] * np.sqrt(factor), SIGMA_FLOOR.get(g, 0.0))
            worst = max(worst, abs(factor - 1.0) if sig[g] > SIGMA_FLOOR.get(g, 0.0) else 0.0)
        if worst < VCE_TOL:
            break
    # Covariance about the solution itself: re-centred so the rotation errors are about the
    # axes of the solution's child frames.
    at = _Model(T_W_X, mode, uv, p_B, T_H, T_G, intr, free, pose_noise,
                (sig["corners"], sig["pos"], sig["rot"]))  # fmt: skip
    x_hat = at.x0()
    if pose_noise:
        x_hat[at.k:] = delta
    J = at.jacobian(x_hat)
    if pose_noise:
        cov = _inverse(J.T @ J)[: at.k, : at.k]
        sigma_px = sig["corners"]
    else:
        r = at.residuals(x_hat) * sig["corners"]  # px
        clusters = np.repeat(np.arange(len(uv)), uv.shape[1] * 2)
        cov, _, _, sigma2, _ = covariances(J * sig["corners"], r, "linear", 1.0, clusters)
        sigma_px = float(np.sqrt(sigma2))
    # The fixed intrinsics are not exact: their calibration std (camera["std"], e.g. from
    # `cvsflow calibrate`) enters through the solution's sensitivity to them,
    # S = -(J^T J)^-1 J^T J_fixed (as cvsflow.optimise.se3_cov.fixed_sensitivity, linear loss).
    fixed_names = [nm for nm in INTRINSIC_NAMES if nm not in free]
    given = camera.get("std") if isinstance(camera.get("std"), dict) else {}
    sd_fixed = np.array([float(given.get(nm) or 0.0) for nm in fixed_names])
    propagated = [nm for nm, v in zip(fixed_names, sd_fixed, strict=True) if v > 0]
    if propagated:
        J_fixed = at.jacobian_fixed(x_hat)
        S = -(_inverse(J.T @ J) @ (J.T @ J_fixed))[: at.k]
        cov = cov + (S * sd_fixed**2) @ S.T
    rms = at.still_rms(x_hat)
    return {
        "intrinsic_std_propagated": propagated,
        "T_H": T_H, "T_G": T_G, "intrinsics": intr, "cov": cov,
        "sigma_px": float(sigma_px),
        "sigma_pos_m": float(sig["pos"]) if pose_noise else None,
        "sigma_rot_rad": float(sig["rot"]) if pose_noise else None,
        "carrier_residuals": delta.reshape(-1, 6) if pose_noise else np.zeros((len(uv), 6)),
        "still_rms_px": rms,
        "rms_px": float(np.sqrt(np.mean(rms**2))),
        "param_names": [*(f"H_{s}" for s in ("wx", "wy", "wz", "x", "y", "z")),
                        *(f"G_{s}" for s in ("wx", "wy", "wz", "x", "y", "z")),
                        *(n for n in INTRINSIC_NAMES if n in free_intrinsics)],
        "nfev": nfev, "vce_iterations": n_iter,
    }  # fmt: skip


def leave_one_out_rms(uv_px, p_B, T_W_X, camera, fit, mode, free_intrinsics=()):
    """Each still's reprojection RMS (px) under the fit of the other stills, poses as exact.

    A still with a grossly wrong carrier pose pulls an all-stills fit towards itself and
    spreads its error over the others; fitted without it, it stands out.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Corners of each still in board order, px.
    p_B : ndarray, shape (P, 3)
        The corners in B, m.
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier pose in the pose source's world W per still (T_W_Cm or T_W_Bm), m.
    camera : dict
        ``K`` (3x3, px), ``dist`` (5 values): the start and the fixed intrinsics.
    fit : dict
        The all-stills fit of :func:`refine_hand_eye` (``T_H``, ``T_G``, ``intrinsics``,
        ...); each refit starts from it.
    mode : {"eye_in_hand", "eye_to_hand"}
        Which body the carrier X is: the camera's (Cm) or the board's (Bm).
    free_intrinsics : sequence of str, default ()
        Intrinsics refined with H and G (names in ``INTRINSIC_NAMES``).

    Returns
    -------
    ndarray, shape (N,)
        Reprojection RMS of still i under the fit without it (pose noise off: the carrier
        poses exact), px.
    """
    n = len(uv_px)
    out = np.empty(n)
    for i in range(n):
        keep = np.arange(n) != i
        f = refine_hand_eye(uv_px[keep], p_B, T_W_X[keep], camera, fit["T_H"], fit["T_G"], mode,
                            free_intrinsics, pose_noise=False)  # fmt: skip
        intr = f["intrinsics"]
        m = _Model(T_W_X[i : i + 1], mode, uv_px[i : i + 1], p_B, f["T_H"], f["T_G"], intr, ())
        out[i] = m.still_rms(m.x0())[0]
    return out


def _inverse(N):
    """Inverse of a normal matrix: LU (the priors make it positive definite), SVD if singular.

    numpy's SVD is ~1000x slower than LU on these badly scaled matrices.
    """
    try:
        return np.linalg.inv(N)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(N)


def _deviation(T_ref, T):
    """[w (rad, about the child axes of T_ref), t (m, in the parent)] of T against T_ref."""
    return np.concatenate([tf.rvec_from_R(T_ref[:3, :3].T @ T[:3, :3]), T[:3, 3] - T_ref[:3, 3]])


def jackknife_std(uv_px, p_B, T_W_X, camera, fit, mode, free_intrinsics, **kw):
    """Delete-one-still jackknife standard errors of a refined fit, same order as ``fit['cov']``.

    ``sqrt((n-1)/n sum_i (theta_(i) - mean theta_(.))^2)`` (Efron and Tibshirani 1993, eq.
    11.5), each refit started at the full fit; None with fewer than 5 stills.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Corners of each still in board order, px.
    p_B : ndarray, shape (P, 3)
        The corners in B, m.
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier pose in the pose source's world W per still (T_W_Cm or T_W_Bm), m.
    camera : dict
        ``K`` (3x3, px), ``dist`` (5 values): the start and the fixed intrinsics.
    fit : dict
        The all-stills fit of :func:`refine_hand_eye` (``T_H``, ``T_G``, ``intrinsics``,
        ...); each refit starts from it.
    mode : {"eye_in_hand", "eye_to_hand"}
        Which body the carrier X is: the camera's (Cm) or the board's (Bm).
    free_intrinsics : sequence of str
        Intrinsics refined with H and G (names in ``INTRINSIC_NAMES``).
    **kw
        Passed to :func:`refine_hand_eye` (``pose_noise``, ``pose_sigma_m``, ...).

    Returns
    -------
    ndarray, shape (12 + n_free,) or None
        Standard errors of H's rotation (rad, about its child axes) and translation (m), then
        G's likewise, then the free intrinsics (px, or unitless for distortion); None with
        fewer than ``MIN_STILLS + 2`` stills.
    """
    n = len(uv_px)
    if n < MIN_STILLS + 2:
        return None
    devs = []
    for i in range(n):
        keep = np.arange(n) != i
        f = refine_hand_eye(uv_px[keep], p_B, T_W_X[keep], camera, fit["T_H"], fit["T_G"], mode,
                            free_intrinsics, **kw)  # fmt: skip
        d_intr = (f["intrinsics"] - fit["intrinsics"])[
            [k for k, nm in enumerate(INTRINSIC_NAMES) if nm in free_intrinsics]
        ]
        devs.append(np.concatenate([_deviation(fit["T_H"], f["T_H"]),
                                    _deviation(fit["T_G"], f["T_G"]), d_intr]))  # fmt: skip
    devs = np.asarray(devs)
    return np.sqrt((n - 1) / n * np.sum((devs - devs.mean(axis=0)) ** 2, axis=0))


def _pose_std(std6):
    """Standard errors of one transform for the YAML: deg about the child axes, mm in the parent."""
    s = np.asarray(std6, float)
    out = {k: float(v) for k, v in zip(POSE_STD_KEYS, np.r_[np.degrees(s[:3]), 1e3 * s[3:]],
                                       strict=True)}  # fmt: skip
    out["rotation_deg"] = float(np.degrees(np.linalg.norm(s[:3])))
    out["translation_mm"] = float(1e3 * np.linalg.norm(s[3:]))
    return out


# --------------------------------------------------------------------------- the session


def detect_still_corners(images, board, subpix_window_px=11):
    """Ordered corners of each still, or the reason there are none.

    Parameters
    ----------
    images : sequence of (str, ndarray)
        ``(name, gray)``: the still's name and its 8-bit grayscale image.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.

    Returns
    -------
    list of dict
        ``name``, ``uv_px`` ((P, 2) in board order, or None), ``order`` (how the 180-degree
        ambiguity was decided), ``reason``.
    """
    out = []
    for name, gray in images:
        gray = np.asarray(gray)
        if gray.ndim == 3:
            gray = cv2.cvtColor(gray, cv2.COLOR_BGR2GRAY)
        corners = find_board(gray, board, subpix_window_px)
        if corners is None:
            nx, ny = board_pattern(board)
            out.append({"name": name, "uv_px": None, "order": None,
                        "reason": f"no {nx}x{ny} chessboard found"})  # fmt: skip
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

    Returns
    -------
    dict
        handeye.yaml content (see the README): ``mode``, the two transforms as 4x4 lists
        (``T_Cm_C`` and ``T_W_B``, or ``T_W_C`` and ``T_Bm_B``), ``std`` of each (deg about the
        child axes, mm in the parent; the larger of ``std_gauss_newton`` and
        ``std_jackknife``), ``closed_form``, ``rms_px``, ``sigma_px``, ``intrinsics``,
        ``stills`` (name, pose, used, reason, rms_px) and ``n_used``.

    Raises
    ------
    InputError
        Image and pose counts differ, or a bad mode, method or camera.
    CalibrationError
        Fewer than 3 usable stills, or carrier motions about one axis only.
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
    det = detect_still_corners(images, board, subpix_window_px)
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
    if any(det[i]["order"] != "colour" for i in idx):
        uv, flipped = _resolve_flips(uv, p_B, T_W_X[idx], cam)
    T_C_B, ok = solve_pnp_frames(uv, p_B, K, dist)
    for k, i in enumerate(idx):
        if not ok[k]:
            records[i]["reason"] = "PnP failed"
    keep = ok.copy()
    spread = motion_axis_spread_deg(T_W_X[np.array(idx)[keep]])
    if spread < MIN_AXIS_SPREAD_DEG:
        raise CalibrationError(
            f"hand-eye: the carrier's motions between the {int(keep.sum())} usable stills turn "
            f"about axes at most {spread:.1f} deg apart (expected at least "
            f"{MIN_AXIS_SPREAD_DEG:g} deg): rotate the carrier about two different axes"
        )
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
    fit = screen
    if pose_noise:
        fit = refine_hand_eye(uv[keep], p_B, T_W_X[sel], cam, T0_H, T0_G, mode,
                              free_intrinsics, **opts)  # fmt: skip
    rms = fit["still_rms_px"]
    d_X = fit["carrier_residuals"]
    for k, i in enumerate(sel):
        records[i].update(used=True, reason="ok", rms_px=float(rms[k]))
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
        "std": {name_H: _pose_std(std[:6]), name_G: _pose_std(std[6:12])},
        "std_method": ("larger of " if jk is not None else "") + (
            "the Gauss-Newton covariance with the carrier-pose errors modelled (variance "
            "components)" if pose_noise else "Gauss-Newton s^2 (J^T J)^-1 (poses as exact)")
        + (" and the delete-one-still jackknife" if jk is not None else
           " (too few stills for a jackknife)"),
        "std_gauss_newton": {name_H: _pose_std(std_gn[:6]), name_G: _pose_std(std_gn[6:12])},
        "std_jackknife": None if jk is None else {name_H: _pose_std(jk[:6]),
                                                  name_G: _pose_std(jk[6:12])},
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
        "board": {"inner": list(board_pattern(board)), "square_m": float(board["square_m"])},
        "n_stills": len(images),
        "n_used": int(len(sel)),
        "stills": records,
    }  # fmt: skip
    log.info("hand-eye (%s): %d of %d stills, RMS %.3f px", mode, len(sel), len(images),
             fit["rms_px"])  # fmt: skip
    return result


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
