"""Several cameras on one body: extrinsics from shared views, fused board poses, the joint rig fit."""

from cvsflow.rig.extrinsics import calibrate_rig, stereo_extrinsics
from cvsflow.rig.fit import common_times, cross_validate_se3_rig, optimise_se3_rig
from cvsflow.rig.fusion import (
    board_pose_starts,
    fused_board_pose,
    fused_board_pose_best,
    rig_calibration_covariance,
)
from cvsflow.rig.instants import corners_at_instants
from cvsflow.rig.poses import fused_rig_poses
from cvsflow.rig.run import (
    fused_pose_nees,
    heldout_scores,
    name_rig_result,
    rig_camera_entries,
    rig_fit_options,
)

__all__ = [
    "board_pose_starts", "calibrate_rig", "common_times", "corners_at_instants",
    "cross_validate_se3_rig", "fused_board_pose", "fused_board_pose_best", "fused_pose_nees",
    "fused_rig_poses", "heldout_scores", "name_rig_result", "optimise_se3_rig",
    "rig_calibration_covariance", "rig_camera_entries", "rig_fit_options", "stereo_extrinsics"
]
