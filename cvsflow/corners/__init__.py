"""The corners stage: a board's corners in every video frame (extract, track, predict, detect, refine,
grid).
"""

from cvsflow.corners.detect import detect_corners
from cvsflow.corners.extract import extract_corners, extract_corners_parallel, summarise_corners

__all__ = [
    "detect_corners", "extract_corners", "extract_corners_parallel", "summarise_corners"
]
