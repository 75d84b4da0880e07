"""Motion-capture exports, one reader per format (Vicon, OptiTrack, Qualisys), behind the format registry."""
