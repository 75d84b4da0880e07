"""Hand-eye calibration: a camera's mounting on its carrier from stills and carrier poses."""

from cvsflow.handeye.stills import calibrate_hand_eye, pair_stills_with_poses

__all__ = [
    "calibrate_hand_eye", "pair_stills_with_poses"
]
