"""SO(3)/SE(3): the only place where rotation representations are converted.

Conventions (docs/developer/conventions.md)
-------------------------------------------
- ``T_A_B`` is a 4x4 homogeneous transform with p_A = T_A_B @ p_B. Stacks have shape (N, 4, 4).
  Composition is the matrix product when the inner letters match: ``T_A_C = T_A_B @ T_B_C``.
- Rotation vectors (OpenCV's Rodrigues vectors, axis times angle in radians) are the
  exponential coordinates of SO(3): :func:`R_from_rvec` is exp, :func:`rvec_from_R` is log.
- Euler angles: roll about x, pitch about y, yaw about z, R = Rz(yaw) @ Ry(pitch) @ Rx(roll),
  which is scipy's extrinsic ``Rotation.from_euler("xyz", [roll, pitch, yaw])``.
- Quaternions are scalar-last ``(qx, qy, qz, qw)`` as in scipy.
- Angle differences are wrapped to (-pi, pi].
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

EULER_SEQ = "xyz"  # extrinsic x, then y, then z: R = Rz Ry Rx


def _writable(a):
    """A float copy: scipy's Rotation rejects read-only buffers, which pandas >= 3 hands out."""
    return np.array(a, dtype=float)


def wrap_angle(angle_rad):
    """Wrap angles to (-pi, pi].

    Parameters
    ----------
    angle_rad : float or array_like, any shape
        Angles, radians.

    Returns
    -------
    wrapped : float or ndarray, same shape
        The same angles in (-pi, pi], radians (a float for a scalar input).
    """
    a = np.asarray(angle_rad, dtype=float)
    wrapped = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return wrapped if wrapped.ndim else float(wrapped)


def make_T(R, t):
    """Build transforms T_A_B from rotations R_A_B and translations t_A_B.

    Parameters
    ----------
    R : ndarray, shape (3, 3) or (N, 3, 3)
        Rotations R_A_B.
    t : ndarray, shape (3,) or (N, 3)
        Translations t_A_B (origin of B in A), metres.

    Returns
    -------
    T : ndarray, shape (4, 4) or (N, 4, 4)
        Homogeneous transforms T_A_B.
    """
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_T(T):
    """Inverse of rigid transforms: T_B_A from T_A_B.

    Parameters
    ----------
    T : ndarray, shape (4, 4) or (N, 4, 4)
        Rigid transforms T_A_B, metres.

    Returns
    -------
    T_inv : ndarray, same shape
        T_B_A = [R^T, -R^T t], computed in closed form (not by a general matrix inverse).
    """
    T = np.asarray(T, dtype=float)
    R_T = np.swapaxes(T[..., :3, :3], -1, -2)
    t = -(R_T @ T[..., :3, 3, None])[..., 0]
    return make_T(R_T, t)


def transform_points(T_A_B, p_B):
    """Map points from frame B into frame A.

    Parameters
    ----------
    T_A_B : ndarray, shape (4, 4) or broadcastable to (..., 4, 4)
        Transform of B in A, metres.
    p_B : ndarray, shape (..., 3)
        Points in B, metres.

    Returns
    -------
    p_A : ndarray, shape (..., 3)
        The same points in A, metres: R_A_B p_B + t_A_B.
    """
    T_A_B = np.asarray(T_A_B, dtype=float)
    p_B = np.asarray(p_B, dtype=float)
    return (T_A_B[..., :3, :3] @ p_B[..., None])[..., 0] + T_A_B[..., :3, 3]


def skew(v):
    """Cross-product matrices [v]x with [v]x w = v x w.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Vectors (any unit).

    Returns
    -------
    S : ndarray, shape (..., 3, 3)
        Skew-symmetric matrices, the hat map of so(3).
    """
    v = np.asarray(v, float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S


def right_jacobian_SO3(w):
    """Right Jacobian of SO(3): exp(w + d) = exp(w) exp(Jr(w) d) to first order.

    Parameters
    ----------
    w : array_like, shape (3,)
        Rotation vector, rad.

    Returns
    -------
    Jr : ndarray, shape (3, 3)
        ``I - (1 - cos th) / th^2 [w]x + (th - sin th) / th^3 [w]x^2``, th = |w| (Chirikjian
        2011, eq. 10.86); ``I - [w]x / 2`` below th = 1e-8.
    """
    w = np.asarray(w, float)
    th = np.linalg.norm(w)
    W = skew(w)
    if th < 1e-8:
        return np.eye(3) - 0.5 * W
    # Chirikjian (2011) eq. 10.86
    return np.eye(3) - (1 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * (W @ W)


def right_jacobian_inv_SO3(w):
    """Inverse right Jacobian of SO(3) at rotation vectors: ``log(exp(w) exp(d)) = w + Jr^-1(w) d``.

    Parameters
    ----------
    w : array_like, shape (..., 3)
        Rotation vectors, rad (|w| < pi).

    Returns
    -------
    Jr_inv : ndarray, shape (..., 3, 3)
        ``I + [w]x / 2 + (1 / th^2 - (1 + cos th) / (2 th sin th)) [w]x^2``, th = |w|
        (Chirikjian 2011, eq. 10.86); the series value 1/12 of the last factor below th = 1e-6.
    """
    w = np.asarray(w, float)
    th = np.linalg.norm(w, axis=-1)
    W = skew(w)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0, 1.0 / ths**2 - (1 + np.cos(ths)) / (2 * ths * np.sin(ths)))
    return np.eye(3) + 0.5 * W + c[..., None, None] * (W @ W)


def project_SO3(M):
    """Nearest rotation matrix (Frobenius norm) to a 3x3 matrix or a stack of them.

    Parameters
    ----------
    M : array_like, shape (3, 3) or (N, 3, 3)

    Returns
    -------
    R : ndarray, shape of M
        ``U diag(1, 1, sign det(U V^T)) V^T`` from the SVD M = U S V^T (det R = +1): the
        rotation maximising trace(R^T M), i.e. Kabsch's solution for a cross-covariance M.
    """
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=float))
    D = np.zeros(U.shape)
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = np.where(np.linalg.det(U @ Vt) < 0, -1.0, 1.0)
    return U @ D @ Vt


def R_from_rvec(rvec):
    """Rotation matrices from Rodrigues vectors (the exponential map of SO(3)).

    Parameters
    ----------
    rvec : array_like, shape (3,) or (N, 3)
        Rotation vectors, axis times angle, radians (OpenCV's ``rvec``).

    Returns
    -------
    R : ndarray, shape (3, 3) or (N, 3, 3)
        Rotation matrices.
    """
    return Rotation.from_rotvec(_writable(rvec)).as_matrix()


def rvec_from_R(R):
    """Rodrigues vectors from rotation matrices (the logarithm of SO(3)).

    Parameters
    ----------
    R : array_like, shape (3, 3) or (N, 3, 3)
        Rotation matrices.

    Returns
    -------
    rvec : ndarray, shape (3,) or (N, 3)
        Rotation vectors, radians, angle in [0, pi].
    """
    return Rotation.from_matrix(_writable(R)).as_rotvec()


def T_from_rvec_tvec(rvec, tvec):
    """Transforms from OpenCV's (rvec, tvec) pair; solvePnP's result is T_C_B.

    Parameters
    ----------
    rvec : array_like, shape (3,) or (N, 3)
        Rotation vectors of R_A_B, radians.
    tvec : array_like, shape (3,) or (N, 3), or anything of that size
        Translations t_A_B, metres.

    Returns
    -------
    T_A_B : ndarray, shape (4, 4) or (N, 4, 4)
    """
    return make_T(R_from_rvec(rvec), np.asarray(tvec, dtype=float).reshape(np.shape(rvec)))


def rvec_tvec_from_T(T):
    """OpenCV's (rvec, tvec) of transforms.

    Parameters
    ----------
    T : array_like, shape (4, 4) or (N, 4, 4)
        Transforms T_A_B, metres.

    Returns
    -------
    rvec : ndarray, shape (3,) or (N, 3)
        Rotation vectors of R_A_B, radians.
    tvec : ndarray, shape (3,) or (N, 3)
        Translations t_A_B, metres (a copy).
    """
    T = np.asarray(T, dtype=float)
    return rvec_from_R(T[..., :3, :3]), T[..., :3, 3].copy()


def euler_from_R(R):
    """Roll, pitch, yaw of rotation matrices, R = Rz(yaw) Ry(pitch) Rx(roll).

    Parameters
    ----------
    R : array_like, shape (3, 3) or (N, 3, 3)
        Rotation matrices.

    Returns
    -------
    rpy : ndarray, shape (3,) or (N, 3)
        Roll, pitch, yaw, radians; pitch in [-pi/2, pi/2].

    Notes
    -----
    Near gimbal lock (|pitch| -> pi/2) roll and yaw are not separable; scipy puts the whole
    rotation about z into one of them and warns, which we silence: the matrix is still exact.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return Rotation.from_matrix(_writable(R)).as_euler(EULER_SEQ)


def euler_jacobian(R, side="right"):
    """How roll, pitch, yaw (:func:`euler_from_R`) move with a small rotation of R.

    Parameters
    ----------
    R : array_like, shape (3, 3) or (N, 3, 3)
        Rotation matrices.
    side : {"right", "left"}
        ``"right"``: the rotation is R Exp(delta), delta about R's own (body) axes, as the
        se3 fit perturbs its mountings; ``"left"``: Exp(delta) R, delta about the outer
        frame's axes.

    Returns
    -------
    J : ndarray, shape (3, 3) or (N, 3, 3)
        d(roll, pitch, yaw) / d(delta), rad per rad; a covariance C of delta gives the
        Euler angles' J C J^T. Singular at gimbal lock (|pitch| = pi/2).
    """
    rpy = euler_from_R(R)
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    zero, one = np.zeros_like(r), np.ones_like(r)
    if side == "right":
        # body rate = E d(rpy) for R = Rz(yaw) Ry(pitch) Rx(roll)
        E = [[one, zero, -np.sin(p)],
             [zero, np.cos(r), np.sin(r) * np.cos(p)],
             [zero, -np.sin(r), np.cos(r) * np.cos(p)]]  # fmt: skip
    elif side == "left":
        E = [[np.cos(y) * np.cos(p), -np.sin(y), zero],
             [np.sin(y) * np.cos(p), np.cos(y), zero],
             [-np.sin(p), zero, one]]  # fmt: skip
    else:
        raise ValueError(f"side must be 'right' or 'left', not {side!r}")
    E = np.moveaxis(np.array(E, dtype=float), (0, 1), (-2, -1))
    return np.linalg.inv(E)


def R_from_euler(rpy):
    """Rotation matrices from roll, pitch, yaw, R = Rz(yaw) Ry(pitch) Rx(roll).

    Parameters
    ----------
    rpy : array_like, shape (3,) or (N, 3)
        Roll, pitch, yaw, radians.

    Returns
    -------
    R : ndarray, shape (3, 3) or (N, 3, 3)
    """
    return Rotation.from_euler(EULER_SEQ, _writable(rpy)).as_matrix()


def pose6_from_T(T):
    """The chapter's 6-vector [x, y, z, roll, pitch, yaw] of transforms.

    Parameters
    ----------
    T : array_like, shape (4, 4) or (N, 4, 4)
        Transforms T_A_B, metres.

    Returns
    -------
    pose6 : ndarray, shape (6,) or (N, 6)
        t_A_B (m) and the Euler angles of R_A_B (rad, :func:`euler_from_R`).
    """
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[..., :3, 3], euler_from_R(T[..., :3, :3])], axis=-1)


def T_from_pose6(pose6):
    """Transforms from the chapter's 6-vectors [x, y, z, roll, pitch, yaw].

    Parameters
    ----------
    pose6 : array_like, shape (6,) or (N, 6)
        Translation (m) and roll, pitch, yaw (rad).

    Returns
    -------
    T : ndarray, shape (4, 4) or (N, 4, 4)
    """
    pose6 = np.asarray(pose6, dtype=float)
    return make_T(R_from_euler(pose6[..., 3:6]), pose6[..., :3])


def quat_from_R(R):
    """Scalar-last unit quaternions of rotation matrices, sign chosen so that qw >= 0.

    Parameters
    ----------
    R : array_like, shape (3, 3) or (N, 3, 3)
        Rotation matrices.

    Returns
    -------
    q_xyzw : ndarray, shape (4,) or (N, 4)
        ``(qx, qy, qz, qw)``, qw >= 0.
    """
    q = Rotation.from_matrix(_writable(R)).as_quat()
    return np.where(q[..., 3:4] < 0, -q, q)


def R_from_quat(q_xyzw):
    """Rotation matrices from scalar-last quaternions.

    Parameters
    ----------
    q_xyzw : array_like, shape (4,) or (N, 4)
        ``(qx, qy, qz, qw)``; normalised by scipy.

    Returns
    -------
    R : ndarray, shape (3, 3) or (N, 3, 3)
    """
    return Rotation.from_quat(_writable(q_xyzw)).as_matrix()


def rotation_angle(R):
    """Angle of rotation matrices.

    Parameters
    ----------
    R : array_like, shape (3, 3) or (N, 3, 3)

    Returns
    -------
    angle_rad : float or ndarray, shape () or (N,)
        The norm of the rotation vector, radians in [0, pi].
    """
    return np.linalg.norm(Rotation.from_matrix(_writable(R)).as_rotvec(), axis=-1)


def mean_rotation(R, weights=None):
    """Chordal L2 mean of rotations: the proper mean, not a mean of Euler angles.

    Parameters
    ----------
    R : array_like, shape (N, 3, 3)
        Rotation matrices.
    weights : array_like, shape (N,), optional
        Non-negative weights; default equal.

    Returns
    -------
    R_mean : ndarray, shape (3, 3)
        The rotation minimising the weighted sum of squared Frobenius distances (scipy's
        ``Rotation.mean``).
    """
    return Rotation.from_matrix(_writable(R)).mean(weights=weights).as_matrix()


def block_mean_quats(q_xyzw):
    """Quaternion mean of each block of rotations (Markley et al. 2007).

    Parameters
    ----------
    q_xyzw : ndarray, shape (B, F, 4)
        B blocks of F scalar-last unit quaternions each.

    Returns
    -------
    q_mean : ndarray, shape (B, 4)
        Per block the largest eigenvector of sum q q^T, scalar-last, sign arbitrary; equal to
        the chordal mean of :func:`mean_rotation` to first order.

    Notes
    -----
    Each block's quaternions are first put in the hemisphere of its first one, so that q and
    -q (the same rotation) do not cancel.
    """
    q = q_xyzw
    sign = np.sign(np.einsum("bfi,bi->bf", q, q[:, 0]))
    sign[sign == 0] = 1.0
    q = q * sign[..., None]
    M = np.einsum("bfi,bfj->bij", q, q)
    _, vecs = np.linalg.eigh(M)
    return vecs[:, :, -1]


def pose_difference(T_ref, T_est):
    """Composed error dT = T_ref^-1 T_est, expressed in the reference's own frame.

    Parameters
    ----------
    T_ref : array_like, shape (4, 4) or (N, 4, 4)
        Reference transforms T_A_B, metres.
    T_est : array_like, same shape
        Estimates of the same transforms.

    Returns
    -------
    dT : ndarray, same shape
        T_ref^-1 T_est: identity for a perfect estimate; translation in the reference's B.
    """
    return invert_T(T_ref) @ np.asarray(T_est, dtype=float)


def pose_error_left(T_est, T_ref):
    """Error of poses as ``[dt, dtheta]`` with the rotation perturbed on the left.

    ``T_est = (exp([dtheta]x) R_ref, t_ref + dt)``: the convention of the fused board pose's
    and the flight reference's covariances (``cvsflow.rig.fusion.fused_board_pose``), in the
    poses' own frame A of ``T_A_B``.

    Parameters
    ----------
    T_est, T_ref : array_like, shape (..., 4, 4)
        Estimated and reference transforms T_A_B, metres.

    Returns
    -------
    ndarray, shape (..., 6)
        ``t_est - t_ref`` (m), then ``log(R_est R_ref^T)`` (rad), both in A.
    """
    T_est, T_ref = np.asarray(T_est, dtype=float), np.asarray(T_ref, dtype=float)
    R = T_est[..., :3, :3] @ np.swapaxes(T_ref[..., :3, :3], -1, -2)
    d_r = rvec_from_R(R.reshape(-1, 3, 3)).reshape(R.shape[:-2] + (3,))
    return np.concatenate([T_est[..., :3, 3] - T_ref[..., :3, 3], d_r], axis=-1)
