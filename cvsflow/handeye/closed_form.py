"""The hand-eye problem ``A_i G = H B_i``: frames, the carrier chain and the closed-form solvers.

Frames (docs/methods.md): ``W`` the pose source's world (robot base, motion-capture world), ``C`` the
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

The closed form is ``cv2.calibrateHandEye`` (Tsai, Park, Horaud, Andreff, Daniilidis) or
``cv2.calibrateRobotWorldHandEye`` (Shah, Li); G from the mean of ``inv(A_i) H B_i``. Its
refinement is :mod:`cvsflow.handeye.reprojection`, the tool around both :mod:`cvsflow.handeye.stills`.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from cvsflow.exceptions import CalibrationError, InputError
from cvsflow.geometry import transforms as tf

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
#: Fewest stills: three poses give two motions, the least that fixes a hand-eye rotation.
MIN_STILLS = 3
#: Smallest angle (deg) between two motion axes for the rotation to be determined.
MIN_AXIS_SPREAD_DEG = 5.0


#: Keys of a transform's standard errors in a result file: deg about the child axes, mm in the parent.
POSE_STD_KEYS = ("rx_deg", "ry_deg", "rz_deg", "x_mm", "y_mm", "z_mm")


def pose_std_record(std6) -> dict:
    """A transform's standard errors for a result file: deg about the child axes, mm in the parent.

    Parameters
    ----------
    std6 : array_like, shape (6,)
        Rotation (rad, about the child frame's axes) then translation (m) standard errors.

    Returns
    -------
    dict
        :data:`POSE_STD_KEYS` plus ``rotation_deg`` and ``translation_mm`` (the norms).
    """
    s = np.asarray(std6, float)
    out = {k: float(v) for k, v in zip(POSE_STD_KEYS, np.r_[np.degrees(s[:3]), 1e3 * s[3:]], strict=True)}
    out["rotation_deg"] = float(np.degrees(np.linalg.norm(s[:3])))
    out["translation_mm"] = float(1e3 * np.linalg.norm(s[3:]))
    return out


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
