"""The session renderer: synthetic calibration stills, a hand-held board video, a Vicon export.

The maths (camera, board texture, motion, markers, effects, session planning) lives in the
modules of this package and does no file I/O; :mod:`cvsflow.synth.render` (``render_session``,
``render_stills``) is the edge that writes a session's files.
"""
