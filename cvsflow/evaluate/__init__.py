"""Held-out evaluation, method comparison, seed scoring, per-run analysis, the summary, the headline
table and the report's verdict.
"""

from cvsflow.evaluate.by_view import errors_by_view, view_geometry
from cvsflow.evaluate.headline import (
    flight_headline,
    headline_rst,
    headline_table,
    pose_fit_headline,
    rig_headline,
    session_headline,
)
from cvsflow.evaluate.heldout import (
    compare_heldout,
    cross_validate_se3,
    heldout_blocks,
    make_time_blocks,
    se3_run_tables,
)
from cvsflow.evaluate.heldout_seed import cross_validate_seed
from cvsflow.evaluate.heldout_streams import (
    cross_validate_streams,
    fit_pose_streams,
    fold_options,
    heldout_summary,
    pose_fit_record,
    stream_inputs,
    stream_sync,
)
from cvsflow.evaluate.summary import summary_row
from cvsflow.evaluate.verdict import flight_verdict, median_distance_m, session_verdict, verdict_rst

__all__ = [
    "compare_heldout", "cross_validate_se3", "cross_validate_seed", "cross_validate_streams",
    "fit_pose_streams", "fold_options", "heldout_summary", "pose_fit_headline", "pose_fit_record",
    "stream_inputs", "stream_sync",
    "flight_headline", "headline_rst",
    "headline_table", "heldout_blocks", "make_time_blocks", "rig_headline", "se3_run_tables",
    "session_headline", "session_verdict", "flight_verdict", "median_distance_m", "summary_row",
    "verdict_rst", "errors_by_view", "view_geometry",
]
