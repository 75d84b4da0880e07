"""The two clocks: angular-speed streams, the time offset (correlation, gesture, refinement) and the
frame pairs.
"""

from cvsflow.sync.offset import synchronise
from cvsflow.sync.pairs import make_pairs
from cvsflow.sync.streams import angular_speed_streams

__all__ = [
    "angular_speed_streams", "make_pairs", "synchronise"
]
