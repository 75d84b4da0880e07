"""Camera calibration: intrinsics from stills and the board pose per frame by PnP (:mod:`.pnp`).

:func:`calibrate_camera` (:mod:`.intrinsics`) runs the stills' calibration: each corner refined
in its own window (:mod:`.still_corners`), the fit of the intrinsics and the stills' board poses
with their covariance (:mod:`.bundle`; lens models opencv5, opencv8, fisheye4 in :mod:`.lens`),
outlying corners and stills left out and named (:mod:`.outliers`), the projection uncertainty
(:mod:`.projection_uncertainty`), the cross-validation of two interleaved halves and each still's
influence (:mod:`.cross_validation`), the stills' geometry and plain verdicts (:mod:`.quality`),
and camera.yaml's sections that state them (:mod:`.assess`).
"""

from cvsflow.calibration.intrinsics import (
    INTRINSIC_STD_NAMES,
    calibrate_camera,
    find_board,
    view_corners,
)
from cvsflow.calibration.pnp import estimate_poses
from cvsflow.calibration.pose_stream import poses_from_stream
from cvsflow.calibration.projection_uncertainty import uncertainty_map_of

__all__ = [
    "calibrate_camera", "estimate_poses", "find_board", "INTRINSIC_STD_NAMES", "poses_from_stream",
    "uncertainty_map_of",
    "view_corners"
]
