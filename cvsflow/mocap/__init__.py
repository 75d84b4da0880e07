"""Motion capture after reading: marker layouts, gap repair, rigid bodies and their resampled tables."""

from cvsflow.mocap.bodies import (
    bodies_from_poses,
    body_poses,
    downsample_bodies,
    fit_bodies,
    select_system_bodies,
)
from cvsflow.mocap.layout import resolve_layouts
from cvsflow.mocap.repair import repair_markers
from cvsflow.mocap.stream_bodies import bodies_from_streams

__all__ = [
    "bodies_from_poses", "bodies_from_streams", "body_poses", "downsample_bodies", "fit_bodies",
    "repair_markers", "resolve_layouts", "select_system_bodies"
]
