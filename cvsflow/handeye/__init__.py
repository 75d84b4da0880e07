"""Hand-eye calibration: a camera's mounting on its carrier from stills, timestamped frames or pose
streams with the carrier's poses (and the clock offset between them)."""

from cvsflow.handeye.frame_stream import calibrate_from_frames
from cvsflow.handeye.stills import calibrate_hand_eye, pair_stills_with_poses
from cvsflow.handeye.stream_fit import StreamsOptions, StreamsResult, estimate_streams, stream_offset
from cvsflow.handeye.stream_model import StreamProblem
from cvsflow.handeye.stream_report import (
    inflate,
    split_half_check,
    split_half_inflation,
    streams_record,
)
from cvsflow.handeye.stream_sim import simulate_streams

__all__ = [
    "calibrate_from_frames", "calibrate_hand_eye", "estimate_streams", "inflate",
    "pair_stills_with_poses", "simulate_streams", "split_half_check", "split_half_inflation",
    "stream_offset", "StreamProblem", "streams_record", "StreamsOptions", "StreamsResult"
]
