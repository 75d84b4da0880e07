"""A session's ``bag`` block: a ROS bag as its camera input and its motion capture.

The config keys (``sessions.<name>.bag``, schema ``cvsflow/workflow/schemas/config.schema.yaml``)::

    bag:
      path: recordings/lab1.bag      # or [part0.bag, part1.bag], a ROS 2 bag folder, .db3, .mcap
      time: header                   # or receive (stamps left at zero); default header
      image_topic: /cam0/image_raw   # the camera input, instead of video or frames
      camera_body: {topic: /vicon/cam/pose, parent: world}   # T_W_Cm, instead of mocap.file, pose_streams
      board_body: {topic: /tf, parent: world, child: board, time: receive}   # T_W_Bm

What the workflow calls (the block's check lives with the other session checks):

- :func:`cvsflow.workflow.sessions.bag_settings` at parse time (as
  :func:`cvsflow.io.mocap.formats.mocap_settings`):
  the block with its defaults, checked against the session's other inputs, without opening
  the bag;
- :func:`bag_frame_source` in the corners stage: the frame source (``source(start, stop)``
  yielding ``(frame, t_s, gray)``) and the frame list (exact ``t_ns``), as a video's or a
  frame folder's;
- :func:`read_bag_body` in the motion-capture stage: one body's pose stream, the table
  :func:`cvsflow.io.mocap.formats.read_pose_stream` gives for the same poses in a file.
"""

from __future__ import annotations

from functools import partial

import pandas as pd

from cvsflow.exceptions import ConfigError
from cvsflow.io.rosbag_images import bag_frame_list, iter_bag_gray
from cvsflow.io.rosbag_poses import read_bag_pose_stream


def bag_frame_source(settings: dict):
    """The frame source and the frame list of a session's bag image topic.

    Parameters
    ----------
    settings : dict
        :func:`cvsflow.workflow.sessions.bag_settings` (with an ``image``).

    Returns
    -------
    source : callable
        ``source(start, stop)`` yielding ``(frame, t_s, gray)`` with damaged frames as None
        (``iter_bag_gray(..., undecodable=True)``), picklable: the ``source`` of
        :func:`cvsflow.corners.extract_corners_parallel`.
    frames : DataFrame
        :func:`cvsflow.io.rosbag_images.bag_frame_list`: ``frame``, ``t_ns`` (exact), ``t_s``;
        ``len(frames)`` is the ``n_frames`` the corners stage cuts its chunks by, and
        :func:`cvsflow.io.frames.add_frame_ns` puts ``t_ns`` into the corners table.

    Raises
    ------
    ConfigError
        The block has no ``image_topic``.
    TopicNotFoundError, TopicTypeError, ZeroStampError, BagError
        As :func:`~cvsflow.io.rosbag_images.bag_frame_list`.
    """
    if settings.get("image") is None:
        raise ConfigError(f"{settings['path']}: the session's bag block names no image_topic")
    image = settings["image"]
    frames = bag_frame_list(settings["path"], image["topic"], image["time"])
    source = partial(iter_bag_gray, settings["path"], image["topic"], undecodable=True, time=image["time"])
    return source, frames


def read_bag_body(settings: dict, body: str) -> pd.DataFrame:
    """One marker body's pose stream from a session's bag.

    Parameters
    ----------
    settings : dict
        :func:`cvsflow.workflow.sessions.bag_settings` (with both bodies).
    body : {"camera", "board"}

    Returns
    -------
    DataFrame
        :data:`cvsflow.io.mocap.streams.STREAM_COLUMNS` of ``T_W_Cm`` or ``T_W_Bm`` (exact
        ``t_ns``), as :func:`cvsflow.io.rosbag_poses.read_bag_pose_stream` reads it.

    Raises
    ------
    ConfigError
        The block has no poses for that body.
    TopicNotFoundError, TopicTypeError, FrameIdError, ZeroStampError, PoseStreamError, BagError
        As :func:`~cvsflow.io.rosbag_poses.read_bag_pose_stream`.
    """
    spec = settings.get(f"{body}_body") if body in ("camera", "board") else None
    if spec is None:
        raise ConfigError(f"{settings['path']}: the session's bag block names no {body}_body")
    return read_bag_pose_stream(settings["path"], spec["topic"], spec["parent"], spec["child"], spec["time"])
