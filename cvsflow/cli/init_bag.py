"""``cvsflow init BAG``: a session config from a ROS bag, for the user to check.

Lists the bag's topics (type, count, rate) and guesses the session's ``bag`` block
(:mod:`cvsflow.io.rosbag_session`): the camera's image topic, the time source, and the camera
and board bodies' pose topics or TF frames, by their names; ``TODO`` where the bag cannot tell.
"""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

from cvsflow.io.rosbag import IMAGE, TF_STATIC, bag_paths, list_topics, open_bag, stamp_ns
from cvsflow.io.rosbag_poses import frame_name, pose_fields

#: Image topics that are no camera frame of the board.
NOT_CAMERA = re.compile(r"depth|disparit|infra|(?:^|/)ir(?:/|_|$)|confidence|mask|segment|thermal", re.I)
#: A topic of a motion-capture driver: it breaks a tie between candidates.
MOCAP = re.compile(r"vicon|mocap|optitrack|qualisys|vrpn|natnet|motion_capture|motive", re.I)
CAMERA_BODY = re.compile(r"cam|camera|rig|body|drone|quad|uav|robot|base_link|imu", re.I)
BOARD_BODY = re.compile(r"board|target|grid|checker|charuco|april|calib|fiducial", re.I)
#: TF messages read to learn the frames (a second or so of a busy /tf).
MAX_TF_MESSAGES = 2000


def is_bag(path) -> bool:
    """Whether ``cvsflow init`` should read ``path`` as a bag: a ``.bag``, ``.db3`` or ``.mcap``
    file, or a ROS 2 bag folder (``metadata.yaml`` beside its storage files).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    path = Path(path)
    if path.is_file():
        return path.suffix in (".bag", ".db3", ".mcap")
    return path.is_dir() and (path / "metadata.yaml").is_file()


def topics_text(topics) -> str:
    """The topic listing ``cvsflow init BAG`` prints: topic, type, count, rate.

    Parameters
    ----------
    topics : DataFrame
        :func:`cvsflow.io.rosbag.list_topics`.

    Returns
    -------
    str
        One line per topic (its rate in Hz from the receive times, ``-`` below two messages).
    """
    w = max([len(t) for t in topics["topic"]] + [5])
    wt = max([len(t) for t in topics["msgtype"]] + [4])
    lines = [f"{'topic':<{w}}  {'type':<{wt}}  {'count':>7}  {'rate_hz':>8}"]
    for r in topics.itertuples():
        rate = "-" if r.rate_hz != r.rate_hz else f"{r.rate_hz:.2f}"
        lines.append(f"{r.topic:<{w}}  {r.msgtype:<{wt}}  {r.count:>7}  {rate:>8}")
    return "\n".join(lines)


def _image_topic(topics, notes) -> str:
    imgs = topics[topics["kind"] == "image"]
    other = imgs["topic"].str.contains(NOT_CAMERA)
    if other.any():
        notes.append("image topics left out as depth, IR or masks: " + ", ".join(imgs.loc[other, "topic"]))
    cams = imgs[~other]
    raw = set(cams.loc[cams["msgtype"] == IMAGE, "topic"])
    twins = sorted(t for t in cams["topic"] if t.endswith("/compressed") and t[: -len("/compressed")] in raw)
    if twins:
        notes.append(f"{', '.join(twins)}: image_transport's compressed copy of a raw topic (encoded from it "
                     "again); the raw topic is taken")  # fmt: skip
    cams = cams[~cams["topic"].isin(twins)]
    if len(cams) == 1:
        r = cams.iloc[0]
        notes.append(f"image_topic {r['topic']}: the only camera topic ({r['msgtype']}, {r['count']} frames)")
        return str(r["topic"])
    if len(cams) > 1:
        notes.append("several camera topics: choose image_topic among " + "; ".join(
            f"{r.topic} ({r.msgtype}, {r.count} frames)" for r in cams.itertuples()))  # fmt: skip
    else:
        notes.append("no sensor_msgs Image or CompressedImage topic: set image_topic (or give a video)")
    return "TODO"


def _first(b, topic):
    gen = b.messages(topic, "receive")
    try:
        return next(gen, (None,) * 4)[3]
    finally:
        gen.close()


def _pose_candidates(b, topics) -> list[tuple[dict, str]]:
    """(pose source, the names it is matched by) of every pose topic and TF edge."""
    cands = []
    for r in topics[topics["kind"] == "pose"].itertuples():
        msg = _first(b, r.topic)
        if msg is not None:
            _p, _q, child = pose_fields(msg, r.msgtype)
            src = {"topic": r.topic, "parent": frame_name(msg.header.frame_id)}
            if child is not None:
                src["child"] = frame_name(child)
            cands.append((src, f"{r.topic} {src.get('child', '')}"))
    for r in topics[(topics["kind"] == "tf") & (topics["topic"] != TF_STATIC)].itertuples():
        edges: Counter = Counter()
        gen = b.messages(r.topic, "receive")
        try:
            for k, (_i, _t, _rx, msg) in enumerate(gen):
                if k >= MAX_TF_MESSAGES:
                    break
                edges.update((frame_name(t.header.frame_id), frame_name(t.child_frame_id))
                             for t in msg.transforms)
        finally:
            gen.close()
        cands += [({"topic": r.topic, "parent": p, "child": c}, f"{p} {c}")
                  for (p, c), _n in edges.most_common()]  # fmt: skip
    return cands


def _pick_body(key, pattern, other, cands, tf_topics, notes):
    hits = [s for s, text in cands if pattern.search(text) and not other.search(text)]
    group = [s for s in hits if s["topic"] not in tf_topics] or hits  # its own topic before a TF edge
    mocap = [s for s in group if MOCAP.search(s["topic"])]
    pick = group if len(group) == 1 else mocap if len(mocap) == 1 else []
    if pick:
        others = [s for s in hits if s is not pick[0]]
        notes.append(f"{key}: {pick[0]} (by its name): check it is the motion-capture body"
                     + (f"; also seen: {'; '.join(map(str, others))}" if others else ""))  # fmt: skip
        return pick[0]
    notes.append(f"{key}: several candidates, choose one: {'; '.join(map(str, hits))}" if hits
                 else f"{key}: no pose topic or TF frame named like one: set topic and frames")  # fmt: skip
    return {"topic": "TODO", "parent": "TODO"}


def build_bag_config(bag) -> tuple[dict, list[str], str]:
    """A session config guessed from a bag, the notes for the user, and the topic listing.

    Parameters
    ----------
    bag : str or Path
        A bag (:func:`cvsflow.io.rosbag.bag_paths`).

    Returns
    -------
    session : dict
        ``bag`` (``path``, ``time``, ``image_topic``, ``camera_body``, ``board_body``),
        ``calib_dir`` and ``board`` (TODO: a bag holds neither stills nor the board's size).
    notes : list of str
        What was chosen and why, the other candidates, what to check.
    listing : str
        :func:`topics_text` of the bag.

    Raises
    ------
    BagError
        Not a bag, or unreadable.
    """
    bag_paths(bag)
    topics = list_topics(bag)
    notes = [f"bag: {bag} ({topics.attrs['storage']}, {len(topics)} topics)"]
    block: dict = {"path": str(bag), "time": "header", "image_topic": _image_topic(topics, notes)}
    tf_topics = set(topics.loc[topics["kind"] == "tf", "topic"])
    with open_bag(bag) as b:
        if block["image_topic"] != "TODO":
            msg = _first(b, block["image_topic"])
            if msg is not None and stamp_ns(msg.header.stamp) == 0:
                block["time"] = "receive"
                notes.append("the first frame's header stamp is zero: time is receive (the bag's receive "
                             "times, transport delay included)")  # fmt: skip
        cands = _pose_candidates(b, topics)
    for key, pattern, other in (("camera_body", CAMERA_BODY, BOARD_BODY),
                                ("board_body", BOARD_BODY, CAMERA_BODY)):  # fmt: skip
        block[key] = _pick_body(key, pattern, other, cands, tf_topics, notes)
    if not cands:
        notes.append("no PoseStamped, TransformStamped, Odometry or TF topic: the bodies' poses are TODO "
                     "(or give mocap.file, an export, with markers instead)")  # fmt: skip
    notes.append("calib_dir: TODO (a folder of stills of the board), or camera: <session> to reuse another "
                 "session's calibration; board: TODO (its size), or target: a Kalibr target "
                 "file")  # fmt: skip
    notes.append("dt_offset_s: left out, the sync stage estimates the offset between the frames' and the "
                 "poses' stamps; dt_offset_s: 0 holds it when one clock stamps both (a still camera at "
                 "every frame leaves it unobservable)")  # fmt: skip
    session = {"bag": block, "calib_dir": "TODO", "board": {"squares_x": "TODO", "squares_y": "TODO",
                                                            "square_m": "TODO"}}  # fmt: skip
    return session, notes, topics_text(topics)
