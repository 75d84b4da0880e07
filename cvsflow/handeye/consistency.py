"""Do the carrier poses and the camera's views describe one motion? Pairing and scale checks.

Two properties of the hand-eye problem ``A_i G = H B_i`` (:mod:`cvsflow.handeye.closed_form`)
hold whatever the unknown mountings are, so they can be checked before solving for them:

- **Rotation angles.** The relative rotation of the carrier between views i and j and that of
  the board in the camera are conjugate (``R_A,ij = R_X R_B,ij R_X^T``), so their *angles* are
  equal. Views paired with the wrong poses break this by tens of degrees, where pose and
  corner noise leave a few tenths (ViSP's Franka set: median 0.17 deg, largest 0.63 deg).
- **Scale.** With the rotation R_X from a closed form (scale free), the translations of every
  pair of views satisfy ``(R_MA - I) t_X - s R_X t_MB = -t_MA`` (Andreff et al. 2001 with an
  unknown scale s of the camera's translations). A board size or a pose unit 10x wrong makes
  s 0.1 or 10 where the Franka set gives 1.13 (its robot poses err by a few mm over motions
  of a few cm).
"""

from __future__ import annotations

import logging

import numpy as np

from cvsflow.exceptions import PosePairingError, ScaleMismatchError
from cvsflow.geometry import invert_T, rotation_angle
from cvsflow.handeye.closed_form import carrier_chain

log = logging.getLogger(__name__)

#: Largest median disagreement (deg) of a view's motion angles with the carrier's that is noise.
MAX_ANGLE_DISAGREEMENT_DEG = 2.0
#: The camera's translations may be this many times larger or smaller than the carrier's.
MAX_SCALE_RATIO = 2.0


def motion_angle_disagreement(T_W_X, T_C_B) -> np.ndarray:
    """|angle of the carrier's relative rotation - angle of the board's in the camera|, all pairs.

    Parameters
    ----------
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier pose in W per view (either mode), m.
    T_C_B : ndarray, shape (N, 4, 4)
        Board in the camera per view (PnP), m.

    Returns
    -------
    D : ndarray, shape (N, N)
        Disagreement of views i and j, rad (0 on the diagonal).
    """
    R_X = np.asarray(T_W_X, float)[:, :3, :3]
    R_B = np.asarray(T_C_B, float)[:, :3, :3]
    n = len(R_X)
    i, j = np.triu_indices(n, 1)
    a = rotation_angle(np.swapaxes(R_X[i], 1, 2) @ R_X[j])
    b = rotation_angle(np.swapaxes(R_B[i], 1, 2) @ R_B[j])
    D = np.zeros((n, n))
    D[i, j] = D[j, i] = np.abs(a - b)
    return D


def check_pose_pairing(T_W_X, T_C_B, view_names, pose_names, max_deg=MAX_ANGLE_DISAGREEMENT_DEG,
                       max_share=0.25) -> np.ndarray:  # fmt: skip
    """Views whose motions disagree with their carrier poses'; an error when the pairing is wrong.

    Each view's disagreement is the median over the other views of
    :func:`motion_angle_disagreement`. When the median view disagrees by more than ``max_deg``,
    or more than ``max_share`` of the views do, the views and poses are not paired right (a
    wrong order, a shifted list): an error naming the worst pairs. Fewer such views are single
    bad poses or bad detections, returned to be left out.

    Parameters
    ----------
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier pose per view, m.
    T_C_B : ndarray, shape (N, 4, 4)
        Board in the camera per view, m.
    view_names, pose_names : sequence of str, length N
        What each view and its pose are (file names), for the message.
    max_deg : float
        Largest median disagreement that is noise, deg.
    max_share : float
        Largest share of views that may disagree before the pairing is called wrong.

    Returns
    -------
    bad : ndarray of bool, shape (N,)
        Views whose median disagreement exceeds ``max_deg`` (few enough to be outliers).

    Raises
    ------
    PosePairingError
        The median view disagrees beyond ``max_deg``, or too many do; the message names the
        worst views with their poses and angles.
    """
    n = len(T_W_X)
    if n < 3:
        return np.zeros(n, bool)
    D = np.degrees(motion_angle_disagreement(T_W_X, T_C_B))
    m = np.array([np.median(np.delete(D[k], k)) for k in range(n)])
    bad = m > max_deg
    if np.median(m) > max_deg or bad.sum() > max_share * n:
        worst = np.argsort(-m)[: min(4, n)]
        pairs = "; ".join(f"{view_names[k]} with {pose_names[k]} ({m[k]:.1f} deg)" for k in worst)
        raise PosePairingError(
            f"hand-eye: the poses and views are not paired right: the angles of the carrier's "
            f"motions and of the camera's (by PnP) disagree by a median of {np.median(m):.1f} deg "
            f"over {n} views, {int(bad.sum())} of them beyond {max_deg:g} deg (expected within "
            f"{max_deg:g} deg: the angles are equal whatever the mountings). Worst pairs: {pairs}. "
            "Check that the poses are in the views' order (or named by them)"
        )
    return bad


def motion_scale(T_W_X, T_C_B, R_X, mode="eye_in_hand") -> float:
    """The scale of the camera's translations against the carrier's (1 when both are right).

    Least squares over every pair of views of ``(R_MA - I) t_X - s R_X t_MB = -t_MA``, with
    ``M_A, M_B`` the motions of the carrier chain and of the board in the camera between the
    two views, and R_X the closed form's rotation of the unknown X that ``M_A X = X M_B``
    (eye-in-hand: X = T_Cm_C, ``M_A = A_i A_j^-1``, ``M_B = B_i B_j^-1``; eye-to-hand: X =
    T_Bm_B, ``M_A = A_i^-1 A_j``, ``M_B = B_i^-1 B_j``; A the carrier chain, B = T_C_B).

    Parameters
    ----------
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier pose per view, m.
    T_C_B : ndarray, shape (N, 4, 4)
        Board in the camera per view, m.
    R_X : ndarray, shape (3, 3)
        Rotation of X (``T_Cm_C`` or ``T_Bm_B``).
    mode : {"eye_in_hand", "eye_to_hand"}

    Returns
    -------
    float
        s: the camera's translations times s match the carrier's.
    """
    A = carrier_chain(T_W_X, mode)
    B = np.asarray(T_C_B, float)
    i, j = np.triu_indices(len(A), 1)
    if mode == "eye_in_hand":
        MA, MB = A[i] @ invert_T(A[j]), B[i] @ invert_T(B[j])
    else:
        MA, MB = invert_T(A[i]) @ A[j], invert_T(B[i]) @ B[j]
    t_MB = MB[:, :3, 3] @ np.asarray(R_X).T  # R_X t_MB per pair
    rows = np.concatenate([MA[:, :3, :3] - np.eye(3), -t_MB[:, :, None]], axis=2)
    sol = np.linalg.lstsq(rows.reshape(-1, 4), -MA[:, :3, 3].ravel(), rcond=None)[0]
    return float(sol[3])


def check_motion_scale(s, size_m=None, size_name="square size", max_ratio=MAX_SCALE_RATIO) -> None:
    """An error when the camera's and the carrier's translations disagree in scale.

    Parameters
    ----------
    s : float
        :func:`motion_scale`.
    size_m : float, optional
        The target's size given (a chessboard's square, an AprilGrid's tag), m, for the message.
    size_name : str
        What ``size_m`` is, for the message.
    max_ratio : float
        Largest accepted ``max(s, 1/s)``.

    Returns
    -------
    None

    Raises
    ------
    ScaleMismatchError
        ``s`` outside ``[1 / max_ratio, max_ratio]`` (or not positive); the message gives the
        factor and the size that would agree.
    """
    if s > 0 and 1.0 / max_ratio <= s <= max_ratio:
        return
    hint = (f"; is the board's {size_name} right (given {size_m:g} m; {size_m * s:.4g} m would "
            "agree)" if size_m and s > 0 else "")  # fmt: skip
    factor = f"{1 / s:.3g} times" if s > 0 else "not in proportion to"
    raise ScaleMismatchError(
        f"hand-eye: the carrier's motion and the board's motion disagree in scale: the camera's "
        f"translations by PnP are {factor} the carrier's (least-squares scale of the hand-eye "
        f"translation equation over every pair of views; expected within a factor {max_ratio:g} "
        f"of 1){hint}, or are the poses' lengths in the unit the format says (m)?"
    )
