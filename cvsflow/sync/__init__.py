"""The two clocks: angular-speed streams, the time offset (correlation, gesture, refinement) and the
frame pairs.
"""

from cvsflow.sync.offset import given_offset, main_lobe, masked_ncc, synchronise
from cvsflow.sync.offset_refine import refine_offset_rotations
from cvsflow.sync.pairs import make_pairs
from cvsflow.sync.streams import angular_speed_streams

__all__ = [
    "angular_speed_streams", "given_offset", "main_lobe", "make_pairs", "masked_ncc",
    "refine_offset_rotations", "synchronise"
]
