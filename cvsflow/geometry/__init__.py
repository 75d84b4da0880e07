"""The one home of geometry: every other module calls these, none re-implements them.

- :mod:`cvsflow.geometry.transforms`: SO(3)/SE(3): make, invert, compose (``@``), apply,
  exp/log (rvec), skew, the right Jacobian, the nearest rotation, Euler, quaternions, pose6,
  rotation means, composed differences.
- :mod:`cvsflow.geometry.rigid`: least-squares rigid fits: batched and weighted (Kabsch), one
  set with scale (Umeyama).
- :mod:`cvsflow.geometry.interpolate`: poses in time: a stream's sample period, interpolation
  (linear + SLERP).
- :mod:`cvsflow.geometry.camera`: the camera model (OpenCV's 5-term distortion) and its
  Jacobian.

Pure numpy/scipy: nothing here imports I/O, plotting or another cvsflow stage.
"""

from cvsflow.geometry.camera import (
    INTRINSIC_NAMES,
    distort_normalised,
    pose_jacobian,
    project_points,
    project_points_jac,
    project_poses,
)
from cvsflow.geometry.interpolate import (
    PoseCurve,
    PoseInterpolant,
    bracket,
    interpolate_quats,
    interpolate_T,
    sample_period,
    slerp,
)
from cvsflow.geometry.rigid import fit_rigid, umeyama
from cvsflow.geometry.transforms import (
    EULER_SEQ,
    R_from_euler,
    R_from_quat,
    R_from_rvec,
    T_from_pose6,
    T_from_rvec_tvec,
    block_mean_quats,
    euler_from_R,
    euler_jacobian,
    invert_T,
    make_T,
    mean_rotation,
    pose6_from_T,
    pose_difference,
    pose_error_left,
    project_SO3,
    quat_from_R,
    right_jacobian_inv_SO3,
    right_jacobian_SO3,
    rotation_angle,
    rvec_from_R,
    rvec_tvec_from_T,
    skew,
    transform_points,
    wrap_angle,
)

__all__ = [
    "block_mean_quats", "bracket", "distort_normalised", "euler_from_R", "euler_jacobian",
    "EULER_SEQ", "fit_rigid", "interpolate_quats", "interpolate_T", "INTRINSIC_NAMES", "invert_T",
    "make_T", "mean_rotation", "pose6_from_T", "pose_difference", "pose_error_left",
    "pose_jacobian", "PoseCurve", "PoseInterpolant", "project_points", "project_points_jac",
    "project_poses", "project_SO3", "quat_from_R", "R_from_euler", "R_from_quat", "R_from_rvec",
    "right_jacobian_inv_SO3", "right_jacobian_SO3", "rotation_angle", "rvec_from_R",
    "rvec_tvec_from_T", "sample_period", "skew", "slerp", "T_from_pose6", "T_from_rvec_tvec",
    "transform_points", "umeyama", "wrap_angle"
]
