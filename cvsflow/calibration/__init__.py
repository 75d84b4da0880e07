"""Camera calibration: intrinsics from stills (:mod:`.intrinsics`) and the board pose per frame by PnP
(:mod:`.pnp`).
"""

from cvsflow.calibration.intrinsics import (
    INTRINSIC_STD_NAMES,
    calibrate_camera,
    find_board,
    view_corners,
)
from cvsflow.calibration.pnp import estimate_poses
from cvsflow.calibration.projection_uncertainty import uncertainty_map_of

__all__ = [
    "calibrate_camera", "estimate_poses", "find_board", "INTRINSIC_STD_NAMES", "uncertainty_map_of",
    "view_corners"
]
