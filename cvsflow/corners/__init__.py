"""The corners stage: a board's corners in every video frame (extract, track, predict, detect, refine,
grid).
"""

from cvsflow.corners.detect import detect_corners
from cvsflow.corners.extract import extract_corners, extract_corners_parallel, summarise_corners
from cvsflow.corners.grid import (
    MAX_GRID_DEVIATION_FRAC,
    deviation_limit_px,
    grid_deviation,
    local_spacing,
)
from cvsflow.corners.refine import BLUR_WINDOW_SIGMAS, edge_blur_px

__all__ = [
    "BLUR_WINDOW_SIGMAS", "detect_corners", "deviation_limit_px", "edge_blur_px",
    "extract_corners", "extract_corners_parallel", "grid_deviation", "local_spacing",
    "MAX_GRID_DEVIATION_FRAC", "summarise_corners"
]
