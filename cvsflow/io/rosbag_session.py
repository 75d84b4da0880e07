"""A session's ``bag`` block: a ROS bag as its camera input and its motion capture.

The config keys (``sessions.<name>.bag``, schema ``cvsflow/workflow/schemas/config.schema.yaml``)::

    bag:
      path: recordings/lab1.bag      # or [part0.bag, part1.bag], a ROS 2 bag folder, .db3, .mcap
      time: header                   # or receive (stamps left at zero); default header
      image_topic: /cam0/image_raw   # the camera input, instead of video
      camera_body: {topic: /vicon/cam/pose, parent: world}          # T_W_Cm, instead of mocap.file
      board_body: {topic: /tf, parent: world, child: board, time: receive}   # T_W_Bm

The three functions here are the interface the workflow's rules are to call; they do not yet
(:func:`cvsflow.workflow.sessions.session_stages` refuses a session with a ``bag`` block):

- :func:`bag_settings` at parse time (as :func:`cvsflow.io.mocap.formats.mocap_settings`):
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

BODIES = ("camera", "board")


def bag_settings(session: str, cfg: dict) -> dict | None:
    """A session's ``bag`` block with its defaults, checked; None when it has none.

    Parameters
    ----------
    session : str
        Session key, for messages.
    cfg : dict
        ``config["sessions"][session]`` (validated against the schema).

    Returns
    -------
    dict or None
        ``path`` (str, or a list of str for a split ROS 1 recording), ``time``, ``image``
        (``{"topic", "time"}`` or None), ``camera_body`` and ``board_body`` (``{"topic",
        "parent", "child", "time"}`` or None).

    Raises
    ------
    ConfigError
        ``image_topic`` beside a ``video``; a body topic beside ``mocap.file``; one body's topic
        without the other's; a block that names no topic.
    """
    block = cfg.get("bag")
    if block is None:
        return None
    where = f"config: sessions.{session}.bag"
    time = block.get("time", "header")
    out = {"path": block["path"], "time": time, "image": None, "camera_body": None, "board_body": None}
    if "image_topic" in block:
        if "video" in cfg:
            raise ConfigError(f"{where}.image_topic: the session also names a video ({cfg['video']}); "
                              "expected one camera input: the bag's image topic or the video")  # fmt: skip
        out["image"] = {"topic": block["image_topic"], "time": time}
    named = [b for b in BODIES if f"{b}_body" in block]
    if named:
        if len(named) == 1:
            missing = next(b for b in BODIES if b not in named)
            raise ConfigError(f"{where}: {named[0]}_body without {missing}_body; expected the poses of "
                              "both marker bodies from the bag (camera_body: T_W_Cm, board_body: "
                              "T_W_Bm)")  # fmt: skip
        export = (cfg.get("mocap") or {}).get("file")
        if export is not None:
            raise ConfigError(f"{where}: camera_body and board_body, and the session also names a "
                              f"motion-capture export (mocap.file: {export}); expected one motion capture: "
                              "the bag's poses or the export")  # fmt: skip
        for b in BODIES:
            spec = block[f"{b}_body"]
            out[f"{b}_body"] = {"topic": spec["topic"], "parent": spec.get("parent"),
                                "child": spec.get("child"), "time": spec.get("time", time)}  # fmt: skip
    if out["image"] is None and not named:
        raise ConfigError(f"{where}: names no topic; expected image_topic (the camera input) and/or "
                          "camera_body and board_body (the marker bodies' poses)")  # fmt: skip
    return out


def bag_frame_source(settings: dict):
    """The frame source and the frame list of a session's bag image topic.

    Parameters
    ----------
    settings : dict
        :func:`bag_settings` (with an ``image``).

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
        :func:`bag_settings` (with both bodies).
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
    spec = settings.get(f"{body}_body") if body in BODIES else None
    if spec is None:
        raise ConfigError(f"{settings['path']}: the session's bag block names no {body}_body")
    return read_bag_pose_stream(settings["path"], spec["topic"], spec["parent"], spec["child"], spec["time"])
