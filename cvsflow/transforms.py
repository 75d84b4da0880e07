"""Former home of the SE(3)/SO(3) helpers, kept so that existing imports keep working.

Everything lives in :mod:`cvsflow.geometry.transforms` now; import from
:mod:`cvsflow.geometry` in new code.
"""

from cvsflow.geometry.transforms import (  # noqa: F401  (re-exported)
    EULER_SEQ,
    R_from_euler,
    R_from_quat,
    R_from_rvec,
    T_from_pose6,
    T_from_rvec_tvec,
    _writable,
    block_mean_quats,
    euler_from_R,
    invert_T,
    make_T,
    mean_rotation,
    pose6_from_T,
    pose_difference,
    pose_error_left,
    quat_from_R,
    rotation_angle,
    rvec_from_R,
    rvec_tvec_from_T,
    skew,
    transform_points,
    wrap_angle,
)
