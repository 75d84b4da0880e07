"""Checks at the stage boundaries (units, overlap, fit quality) and of the optimisers' results."""

from cvsflow.plausibility.checks import (
    OVERLAP_FLOOR,
    camera_pose_names,
    check_body_fits,
    check_image_size,
    check_marker_scale,
    check_overlap,
    check_pair_distances,
    check_poses_found,
    check_rows,
    check_sync_inputs,
    overlap_share,
)
from cvsflow.plausibility.results import check_se3_result, check_seed_result

__all__ = [
    "camera_pose_names", "check_body_fits", "check_image_size", "check_marker_scale", "check_overlap",
    "check_pair_distances", "check_poses_found", "check_rows", "check_se3_result", "check_seed_result",
    "check_sync_inputs", "overlap_share", "OVERLAP_FLOOR"
]
