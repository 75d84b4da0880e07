"""What an error is and how it is summarised: composed pose errors, their statistics, cluster-robust
covariances.
"""

from cvsflow.metrics.errors import (
    ERROR_DIMS,
    FRAMES,
    error_columns,
    error_moments,
    frame_errors,
    pose_errors,
    poses_from_table,
)
from cvsflow.metrics.sandwich import cluster_dof, leverage_corrected_scores

__all__ = [
    "cluster_dof", "error_columns", "ERROR_DIMS", "error_moments", "frame_errors", "FRAMES",
    "leverage_corrected_scores", "pose_errors", "poses_from_table"
]
