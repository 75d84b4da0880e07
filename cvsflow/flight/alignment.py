"""Frame alignment of a flight: Umeyama (SE(3), Sim(3)), yaw-only, and the constant rotations
(hand-eye) linking the reference's and the on-board orientation streams.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import InputError, OptimiseError
from cvsflow.geometry import make_T, mean_rotation, project_SO3, rotation_angle, umeyama

# --------------------------------------------------------------------------------------------
# Frame alignment
# --------------------------------------------------------------------------------------------


@dataclass
class Alignment:
    """A similarity ``p_ref = s R p_est + t`` mapping the estimate's world into the reference's.

    Attributes
    ----------
    T_ref_est : ndarray, shape (4, 4)
        Rigid part (R, t); for flights this is T_C_L.
    scale : float
        s (1 for SE(3) and yaw-only).
    method : str
        ``se3``, ``sim3``, ``yaw``, ``se3w`` (:func:`align_weighted`) or ``given``.
    floor_m2 : float
        ``se3w`` only: the variance per axis added to the reference's in the weights, m^2.
    """

    T_ref_est: np.ndarray
    scale: float = 1.0
    method: str = "se3"
    floor_m2: float = float("nan")

    def apply_points(self, p_est):
        """Map points (N, 3) from the estimate's world into the reference's."""
        R, t = self.T_ref_est[:3, :3], self.T_ref_est[:3, 3]
        return self.scale * (np.asarray(p_est, float) @ R.T) + t

    def apply_T(self, T_est):
        """Map poses (N, 4, 4) of the estimate into the reference world (positions scaled)."""
        T = np.array(T_est, dtype=float)
        T[:, :3, 3] = self.apply_points(T[:, :3, 3])
        T[:, :3, :3] = self.T_ref_est[:3, :3] @ T[:, :3, :3]
        return T


def _check_points(p_ref, p_est, n_min):
    """Shapes and finiteness of two point sets, n_min points at least."""
    p_ref = np.asarray(p_ref, dtype=float)
    p_est = np.asarray(p_est, dtype=float)
    if p_ref.shape != p_est.shape or p_ref.ndim != 2 or p_ref.shape[1] != 3:
        raise OptimiseError(
            f"alignment: point sets of shapes {p_ref.shape} and {p_est.shape}; "
            "expected two (N, 3) arrays"
        )
    if not (np.isfinite(p_ref).all() and np.isfinite(p_est).all()):
        raise OptimiseError("alignment: non-finite points; pass valid pairs only")
    if len(p_ref) < n_min:
        raise OptimiseError(f"alignment: {len(p_ref)} point pairs; at least {n_min} needed")
    return p_ref, p_est


def umeyama_alignment(p_ref, p_est, with_scale: bool = False) -> Alignment:
    """Least-squares similarity (or rigid) transform from estimate to reference points.

    Parameters
    ----------
    p_ref, p_est : ndarray, shape (N, 3)
        Associated positions, reference world and estimate world, metres.
    with_scale : bool
        Sim(3) when True, SE(3) otherwise.

    Returns
    -------
    Alignment
        ``p_ref ≈ s R p_est + t``: :func:`cvsflow.geometry.umeyama` (evo's
        ``umeyama_alignment``).

    Raises
    ------
    OptimiseError
        Fewer than 3 pairs, non-finite values, or points all on one spot.
    """
    y, x = _check_points(p_ref, p_est, 3)
    T, s = umeyama(x, y, with_scale)
    return Alignment(T, s, "sim3" if with_scale else "se3")


def _R_between(a, b):
    """Smallest rotation taking unit vector a onto unit vector b, shape (3, 3)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if np.linalg.norm(v) < 1e-12:
        if c > 0:
            return np.eye(3)
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return Rotation.from_rotvec(np.pi * axis / np.linalg.norm(axis)).as_matrix()
    return Rotation.from_rotvec(
        v / np.linalg.norm(v) * np.arctan2(np.linalg.norm(v), c)
    ).as_matrix()


def align_yaw(p_ref, p_est, z_est_in_ref=(0.0, 0.0, 1.0)) -> Alignment:
    """Four-DoF alignment: a rotation about the vertical only, plus a translation.

    For estimators whose roll and pitch are observable (gravity), only the heading and the
    origin of their world are arbitrary.

    Parameters
    ----------
    p_ref, p_est : ndarray, shape (N, 3)
        Associated positions, metres.
    z_est_in_ref : array_like, shape (3,)
        Direction of the estimate world's z axis expressed in the reference world (known
        from levelling; default: the two z axes coincide).

    Returns
    -------
    Alignment
        ``R = Rot(z_est_in_ref, psi) R0`` with R0 the smallest rotation taking e_z onto
        ``z_est_in_ref``; psi and t in closed form (least squares).

    Raises
    ------
    OptimiseError
        Fewer than 2 pairs or non-finite values.
    """
    y, x = _check_points(p_ref, p_est, 2)
    R0 = _R_between(np.array([0.0, 0.0, 1.0]), np.asarray(z_est_in_ref, dtype=float))
    yl = y @ R0  # reference points in a frame whose z is the estimate's z: R0^T y
    xc, yc = x - x.mean(0), yl - yl.mean(0)
    # minimise sum |yc - Rz(psi) xc|^2 -> psi = atan2(sum(x*y' - y*x'), sum(x*x' + y*y'))
    psi = np.arctan2(
        np.sum(xc[:, 0] * yc[:, 1] - xc[:, 1] * yc[:, 0]),
        np.sum(xc[:, 0] * yc[:, 0] + xc[:, 1] * yc[:, 1]),
    )
    Rz = Rotation.from_euler("z", psi).as_matrix()
    R = R0 @ Rz
    t = y.mean(0) - R @ x.mean(0)
    return Alignment(make_T(R, t), 1.0, "yaw")


def align_weighted(p_ref, p_est, Sigma_ref_p, n_iter: int = 3, floor_m2=None) -> Alignment:
    """Rigid alignment weighted by the reference's position covariance and a fitted floor.

    Minimises ``sum_i e_i^T (Sigma_i + s^2 I)^-1 e_i`` with ``e_i = p_ref,i - R p_est,i - t``:
    a far, small board's depth noise (tens of mm along the line of sight) no longer turns and
    shifts the alignment, while ``s^2``, the variance per axis the reference does not explain
    (the on-board error, estimated from the residuals as
    ``max(mean |e|^2 - mean tr Sigma, 0) / 3``), keeps the near frames from taking all the
    weight. Started from :func:`umeyama_alignment`; ``s^2`` and (R, t) alternate ``n_iter`` times.

    Parameters
    ----------
    p_ref, p_est : ndarray, shape (N, 3)
        Associated positions, reference world and estimate world, metres.
    Sigma_ref_p : ndarray, shape (N, 3, 3)
        Covariance of each reference position, m^2, reference world.
    n_iter : int
        Alternations of the floor and the fit.
    floor_m2 : float, optional
        A given ``s^2`` (m^2), not fitted: the same weights as another fit's (the truth check
        fits the true poses with the evaluation's weights).

    Returns
    -------
    Alignment
        Method ``se3w``, ``floor_m2`` the ``s^2`` used; ``p_ref ≈ R p_est + t``.

    Raises
    ------
    OptimiseError
        Fewer than 3 pairs, non-finite values, or a covariance that is not (N, 3, 3) and finite.
    """
    y, x = _check_points(p_ref, p_est, 3)
    S = np.asarray(Sigma_ref_p, float)
    if S.shape != (len(y), 3, 3) or not np.isfinite(S).all():
        raise OptimiseError(
            f"weighted alignment: covariance of shape {S.shape} (finite: "
            f"{bool(np.isfinite(S).all())}); expected ({len(y)}, 3, 3), finite"
        )
    al = umeyama_alignment(y, x)
    tr = float(np.mean(np.trace(S, axis1=1, axis2=2)))
    for _ in range(n_iter if floor_m2 is None else 1):
        R0, t0 = al.T_ref_est[:3, :3], al.T_ref_est[:3, 3]
        e = y - x @ R0.T - t0
        s2 = (max(float(np.mean(np.sum(e * e, axis=1))) - tr, 0.0) / 3.0
              if floor_m2 is None else float(floor_m2))  # fmt: skip
        # whitening: L_i^T e_i with L_i L_i^T = (Sigma_i + s^2 I)^-1
        L = np.linalg.cholesky(np.linalg.inv(S + (s2 + 1e-12) * np.eye(3)))
        xr = x @ R0.T

        def residual(v, xr=xr, L=L, t0=t0):
            r = y - xr @ Rotation.from_rotvec(v[:3]).as_matrix().T - (t0 + v[3:])
            return np.einsum("nji,nj->ni", L, r).ravel()

        v = least_squares(residual, np.zeros(6), method="lm").x
        R = Rotation.from_rotvec(v[:3]).as_matrix() @ R0
        al = Alignment(make_T(R, t0 + v[3:]), 1.0, "se3w", s2)
    return al


def align_trajectories(p_ref, p_est, method: str = "se3", z_est_in_ref=(0.0, 0.0, 1.0)):
    """Dispatch to :func:`umeyama_alignment` (``se3``, ``sim3``) or :func:`align_yaw` (``yaw``).

    Parameters
    ----------
    p_ref, p_est : ndarray, shape (N, 3)
        Associated positions of the reference and the estimate, each in its own world, m.
    method : {"se3", "sim3", "yaw"}, default "se3"
        Rigid, rigid plus scale, or rotation about the vertical plus translation.
    z_est_in_ref : array_like, shape (3,), default (0, 0, 1)
        ``yaw`` only: the estimate world's z axis in the reference world.

    Returns
    -------
    Alignment
        ``p_ref ≈ s R p_est + t`` (s = 1 unless ``sim3``).

    Raises
    ------
    InputError
        An unknown ``method``.
    OptimiseError
        Too few pairs or degenerate points (from the solvers).
    """
    if method == "se3":
        return umeyama_alignment(p_ref, p_est, False)
    if method == "sim3":
        return umeyama_alignment(p_ref, p_est, True)
    if method == "yaw":
        return align_yaw(p_ref, p_est, z_est_in_ref)
    raise InputError(f"alignment method {method!r}; expected 'se3', 'sim3' or 'yaw'")


def _hand_eye_rotation(R_ref_C_B, R_est_L_Q, lags=(3, 10, 30)):
    """R_Q_B from relative rotations: their axes satisfy v_Q = R_Q_B v_B (Park and Martin 1994)."""
    vB, vQ = [], []
    for h in lags:
        if len(R_ref_C_B) <= h:
            continue
        vB.append(
            Rotation.from_matrix(np.swapaxes(R_ref_C_B[:-h], -1, -2) @ R_ref_C_B[h:]).as_rotvec()
        )
        vQ.append(
            Rotation.from_matrix(np.swapaxes(R_est_L_Q[:-h], -1, -2) @ R_est_L_Q[h:]).as_rotvec()
        )
    if not vB:
        return np.eye(3)
    vB, vQ = np.concatenate(vB), np.concatenate(vQ)
    return project_SO3(vQ.T @ vB)  # Kabsch: min sum |vQ - X vB|^2


def rotation_alignment(R_ref_C_B, R_est_L_Q, R_Q_B=None, weights=None, n_iter: int = 10):
    """Constant rotations linking two orientation streams: R_C_B ≈ R_C_L R_L_Q R_Q_B.

    Closed-form chordal means; when ``R_Q_B`` is not given it is estimated too: started from
    the axes of relative rotations (Park and Martin, IEEE TRA 10(5), 1994), then alternated
    with R_C_L (the rotation part of a hand-eye calibration; needs rotation about two axes).

    Parameters
    ----------
    R_ref_C_B : ndarray, shape (N, 3, 3)
        Reference orientations of the board in C.
    R_est_L_Q : ndarray, shape (N, 3, 3)
        On-board orientations of the body in L, at the same instants.
    R_Q_B : ndarray, shape (3, 3), optional
        Known board mounting; None: estimated.
    weights : ndarray, shape (N,), optional
        Non-negative weights.

    Returns
    -------
    R_C_L, R_Q_B : ndarray, shape (3, 3)
    """
    fixed = R_Q_B is not None
    R_QB = _hand_eye_rotation(R_ref_C_B, R_est_L_Q) if R_Q_B is None else np.asarray(R_Q_B, float)
    R_CL = mean_rotation(R_ref_C_B @ R_QB.T @ np.swapaxes(R_est_L_Q, -1, -2), weights)
    if fixed:
        return R_CL, R_QB
    for _ in range(n_iter):
        R_QB = mean_rotation(np.swapaxes(R_est_L_Q, -1, -2) @ R_CL.T @ R_ref_C_B, weights)
        R_CL_new = mean_rotation(R_ref_C_B @ R_QB.T @ np.swapaxes(R_est_L_Q, -1, -2), weights)
        done = rotation_angle(R_CL_new.T @ R_CL) < 1e-10
        R_CL = R_CL_new
        if done:
            break
    return R_CL, R_QB
