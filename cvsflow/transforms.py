"""SE(3)/SO(3) helpers: the only place where rotation representations are converted.

Conventions (design.md)
-----------------------
- ``T_A_B`` is a 4x4 homogeneous transform with p_A = T_A_B @ p_B. Stacks have shape (N, 4, 4).
- Euler angles: roll about x, pitch about y, yaw about z, R = Rz(yaw) @ Ry(pitch) @ Rx(roll),
  which is scipy's extrinsic ``Rotation.from_euler("xyz", [roll, pitch, yaw])``.
- Quaternions are scalar-last ``(qx, qy, qz, qw)`` as in scipy.
- Angle differences are wrapped to (-pi, pi].
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

EULER_SEQ = "xyz"  # extrinsic x, then y, then z: R = Rz Ry Rx


def _writable(a):
    """A float copy: scipy's Rotation rejects read-only buffers, which pandas >= 3 hands out."""
    return np.array(a, dtype=float)


def wrap_angle(angle_rad):
    """Wrap angles to (-pi, pi]."""
    a = np.asarray(angle_rad, dtype=float)
    wrapped = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return wrapped if wrapped.ndim else float(wrapped)


def make_T(R, t):
    """Build transforms from rotations and translations.

    Parameters
    ----------
    R : ndarray, shape (3, 3) or (N, 3, 3)
    t : ndarray, shape (3,) or (N, 3)

    Returns
    -------
    T : ndarray, shape (4, 4) or (N, 4, 4)
    """
    R = np.asarray(R, dtype=float)
    t = np.asarray(t, dtype=float)
    T = np.zeros(R.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_T(T):
    """Inverse of rigid transforms, shape (4, 4) or (N, 4, 4): T_B_A from T_A_B."""
    T = np.asarray(T, dtype=float)
    R_T = np.swapaxes(T[..., :3, :3], -1, -2)
    t = -(R_T @ T[..., :3, 3, None])[..., 0]
    return make_T(R_T, t)


def transform_points(T_A_B, p_B):
    """Map points from frame B into frame A. p_B has shape (..., 3); T_A_B (4, 4) or broadcastable."""
    T_A_B = np.asarray(T_A_B, dtype=float)
    p_B = np.asarray(p_B, dtype=float)
    return (T_A_B[..., :3, :3] @ p_B[..., None])[..., 0] + T_A_B[..., :3, 3]


def R_from_rvec(rvec):
    """Rotation matrices from Rodrigues vectors, shape (3,) or (N, 3) -> (3, 3) or (N, 3, 3)."""
    return Rotation.from_rotvec(_writable(rvec)).as_matrix()


def rvec_from_R(R):
    """Rodrigues vectors from rotation matrices, (3, 3) or (N, 3, 3) -> (3,) or (N, 3)."""
    return Rotation.from_matrix(_writable(R)).as_rotvec()


def T_from_rvec_tvec(rvec, tvec):
    """Transforms from OpenCV's (rvec, tvec) pair; solvePnP's result is T_C_B."""
    return make_T(R_from_rvec(rvec), np.asarray(tvec, dtype=float).reshape(np.shape(rvec)))


def rvec_tvec_from_T(T):
    """(rvec, tvec) of transforms, shapes (3,), (3,) or (N, 3), (N, 3)."""
    T = np.asarray(T, dtype=float)
    return rvec_from_R(T[..., :3, :3]), T[..., :3, 3].copy()


def euler_from_R(R):
    """Roll, pitch, yaw (radians) of rotation matrices; returns shape (3,) or (N, 3).

    Near gimbal lock (|pitch| -> pi/2) roll and yaw are not separable; scipy puts the whole
    rotation about z into one of them and warns, which we silence: the matrix is still exact.
    """
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return Rotation.from_matrix(_writable(R)).as_euler(EULER_SEQ)


def R_from_euler(rpy):
    """Rotation matrices from roll, pitch, yaw (radians), shape (3,) or (N, 3)."""
    return Rotation.from_euler(EULER_SEQ, _writable(rpy)).as_matrix()


def pose6_from_T(T):
    """The chapter's 6-vector [x, y, z, roll, pitch, yaw] (metres, radians) of transforms."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[..., :3, 3], euler_from_R(T[..., :3, :3])], axis=-1)


def T_from_pose6(pose6):
    """Transforms from 6-vectors [x, y, z, roll, pitch, yaw] (metres, radians)."""
    pose6 = np.asarray(pose6, dtype=float)
    return make_T(R_from_euler(pose6[..., 3:6]), pose6[..., :3])


def quat_from_R(R):
    """Scalar-last quaternions (qx, qy, qz, qw) with qw >= 0."""
    q = Rotation.from_matrix(_writable(R)).as_quat()
    return np.where(q[..., 3:4] < 0, -q, q)


def R_from_quat(q_xyzw):
    """Rotation matrices from scalar-last quaternions (qx, qy, qz, qw)."""
    return Rotation.from_quat(_writable(q_xyzw)).as_matrix()


def rotation_angle(R):
    """Angle (radians, in [0, pi]) of rotation matrices."""
    return np.linalg.norm(Rotation.from_matrix(_writable(R)).as_rotvec(), axis=-1)


def mean_rotation(R, weights=None):
    """Chordal L2 mean of rotations (N, 3, 3): the proper mean, not a mean of Euler angles."""
    return Rotation.from_matrix(_writable(R)).mean(weights=weights).as_matrix()


def pose_difference(T_ref, T_est):
    """Composed error ΔT = T_ref⁻¹ T_est, expressed in the reference's own frame."""
    return invert_T(T_ref) @ np.asarray(T_est, dtype=float)
