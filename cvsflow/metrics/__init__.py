"""What an error is and how it is summarised: composed pose errors, their statistics (one registry),
cluster-robust covariances.
"""

from cvsflow.metrics.errors import (
    ERROR_DIMS,
    FRAMES,
    REPORT_UNITS,
    error_columns,
    frame_errors,
    pose_errors,
    poses_from_table,
    report_name,
)
from cvsflow.metrics.sandwich import cluster_dof, leverage_corrected_scores
from cvsflow.metrics.statistics import (
    STATISTICS,
    Statistic,
    axis_statistics,
    bootstrap_error_stats,
    error_statistics,
)

__all__ = [
    "axis_statistics", "bootstrap_error_stats", "cluster_dof", "error_columns", "ERROR_DIMS",
    "error_statistics", "frame_errors", "FRAMES", "leverage_corrected_scores", "pose_errors",
    "poses_from_table", "report_name", "REPORT_UNITS", "Statistic", "STATISTICS"
]
