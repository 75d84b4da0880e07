"""A pose topic of a ROS bag, or ``/tf`` between two named frames, as a pose stream.

:func:`read_bag_pose_stream` gives the stream table of :mod:`cvsflow.io.mocap.streams`
(:data:`~cvsflow.io.mocap.streams.STREAM_COLUMNS`: exact ``t_ns``, ``x_m y_m z_m``, scalar-last
``qx qy qz qw``; ``line`` is the message's index in its topic) through the same checks as a
pose file's (:func:`~cvsflow.io.mocap.streams.stream_table`: quaternion norm, time order,
repeated stamps), so a bag's poses and the same poses in an ASL, TUM or ETH file read to the
same table. A row is ``T_parent_child`` (TF's meaning: ``header.frame_id`` is the parent, the
pose is the child's).

Message types: ``geometry_msgs`` PoseStamped and PoseWithCovarianceStamped (parent
``header.frame_id``; no child frame), TransformStamped and ``nav_msgs/Odometry`` (``frame_id`` to
``child_frame_id``), and TF (``tf2_msgs/TFMessage`` on ``/tf``, ROS 1's ``tf/tfMessage`` too)
between two named frames.

- Frames named and messages of other frames on the topic: those are left out (counted in
  ``attrs["n_other_frames"]``, one WARNING); none matching is a
  :class:`~cvsflow.exceptions.FrameIdError` listing the frames the topic has, with counts.
- Asked ``A -> B`` where the topic stores ``B -> A``: every pose inverted (``attrs["path"]``
  says ``inverted``); the stored direction gives the message's own numbers, bit for bit.
- TF: the direct edge (either direction) if ``/tf`` has it; otherwise the path over the edges
  of ``/tf`` and ``/tf_static``, composed at the stamps every dynamic edge on it shares (static
  edges hold at any time). Dynamic edges that share no stamp are an error: interpolating between
  them is a processing choice (:mod:`cvsflow.geometry.interpolate`), not a reading one.
"""

from __future__ import annotations

import logging
from collections import Counter, deque

import numpy as np
import pandas as pd

from cvsflow.exceptions import BagError, FrameIdError
from cvsflow.geometry import R_from_quat, invert_T, make_T, quat_from_R
from cvsflow.io.mocap.streams import stream_table
from cvsflow.io.rosbag import (
    POSE_COV_STAMPED,
    POSE_STAMPED,
    POSE_TYPES,
    TF_STATIC,
    TF_TYPES,
    TRANSFORM_STAMPED,
    Bag,
    check_time,
    open_bag,
    stamp_ns,
    zero_stamp_error,
)

log = logging.getLogger(__name__)

FORMAT = "rosbag"
POSE_TOPIC = "a pose topic (geometry_msgs PoseStamped, TransformStamped, nav_msgs Odometry, TF)"


def frame_name(name: str) -> str:
    """A TF frame name as compared here: without the leading ``/`` of ROS 1's old tf names.

    Parameters
    ----------
    name : str

    Returns
    -------
    str
    """
    return name[1:] if name.startswith("/") else name


def pose_fields(msg, msgtype: str):
    """``(position, orientation, child_frame_id or None)`` of a pose-carrying message.

    Parameters
    ----------
    msg : object
        A PoseStamped, PoseWithCovarianceStamped, TransformStamped or Odometry message.
    msgtype : str
        Its type (ROS 2 spelling).

    Returns
    -------
    tuple
        Objects with ``x y z`` and ``x y z w``, and the child frame (None for a PoseStamped).
    """
    if msgtype == POSE_STAMPED:
        return msg.pose.position, msg.pose.orientation, None
    if msgtype == POSE_COV_STAMPED:
        return msg.pose.pose.position, msg.pose.pose.orientation, None
    if msgtype == TRANSFORM_STAMPED:
        return msg.transform.translation, msg.transform.rotation, msg.child_frame_id
    return msg.pose.pose.position, msg.pose.pose.orientation, msg.child_frame_id


def _T(v):
    """(N, 4, 4) from rows of x y z qx qy qz qw."""
    v = np.asarray(v, float).reshape(-1, 7)
    return make_T(R_from_quat(v[:, 3:]), v[:, :3])


def _values(T):
    """Rows of x y z qx qy qz qw from (N, 4, 4)."""
    return np.hstack([T[:, :3, 3], quat_from_R(T[:, :3, :3])])


def read_bag_pose_stream(bag, topic: str, parent: str | None = None, child: str | None = None,
                         time: str = "header", in_time_order: bool = True) -> pd.DataFrame:  # fmt: skip
    """The pose stream of a bag's pose topic, or of ``/tf`` between two named frames.

    Parameters
    ----------
    bag : str, Path or list of them
        As :func:`cvsflow.io.rosbag.bag_paths`.
    topic : str
        A PoseStamped, PoseWithCovarianceStamped, TransformStamped, Odometry or TF topic
        (leading ``/`` optional).
    parent : str, optional
        The frame the poses are in (``header.frame_id``; leading ``/`` ignored). Required for TF;
        for a pose topic, messages of other frames are left out.
    child : str, optional
        The frame whose pose is read (``child_frame_id``). Required for TF; not checked for a
        PoseStamped, which has none.
    time : {"header", "receive"}
        Header stamps (exact; zero is a ZeroStampError) or the bag's receive times.
    in_time_order : bool
        As :func:`cvsflow.io.mocap.formats.read_pose_stream` (False: the bag's order, every
        message kept: a pose list).

    Returns
    -------
    DataFrame
        :data:`~cvsflow.io.mocap.streams.STREAM_COLUMNS` of ``T_parent_child``; ``line`` is the
        message index in the topic. ``attrs``: those of ``stream_table`` (``format`` is
        ``rosbag``, ``path`` names the bag and the topic) plus ``bag``, ``topic``, ``msgtype``,
        ``storage``, ``parent``, ``child``, ``time``, ``frames_path`` (``[from, to, "as
        stored" | "inverted", "dynamic" | "static"]`` per edge), ``n_other_frames``.

    Raises
    ------
    TopicNotFoundError, TopicTypeError
        No such topic (the bag's topics listed), or not a pose topic.
    FrameIdError
        No message between the frames named (the topic's frames listed, with counts); several
        frames and none named; a TF topic without both frames named; no TF path between them.
    ZeroStampError
        A zero header stamp with ``time="header"``.
    QuaternionNormError, TimestampOrderError, BagError
        As a pose file's stream (message named), or a topic without messages.
    """
    check_time(time)
    with open_bag(bag) as b:
        name, info = b.topic(topic, POSE_TYPES, POSE_TOPIC)
        if info.msgcount == 0:
            raise BagError(f"{b.label}: topic {name} has no messages")
        if info.msgtype in TF_TYPES:
            t, v, line, attrs = _read_tf(b, name, parent, child, time)
        else:
            t, v, line, attrs = _read_pose_topic(b, name, info.msgtype, parent, child, time)
        attrs.update(bag=b.label, topic=name, msgtype=info.msgtype, storage=b.storage, time=time)
        where = f"{b.label}: topic {name}"
    return stream_table(where, FORMAT, t, v, line, time_unit="ns", in_time_order=in_time_order, attrs=attrs,
                        row_word="message")  # fmt: skip


def _frames_text(counts: Counter) -> str:
    return "; ".join(f"frame_id {p!r} ({n} messages)" if c is None else f"{p!r} -> {c!r} ({n} messages)"
                     for (p, c), n in counts.most_common())  # fmt: skip


def _read_pose_topic(b: Bag, topic, msgtype, parent, child, time):
    """Times, values, message indices and attrs of a pose topic's messages between the frames named."""
    stamped = msgtype in (POSE_STAMPED, POSE_COV_STAMPED)
    t, v, line, pairs = [], [], [], []
    counts: Counter = Counter()
    for index, t_ns, _rx, msg in b.messages(topic, time):
        pos, rot, ch = pose_fields(msg, msgtype)
        pair = (frame_name(msg.header.frame_id), None if stamped else frame_name(ch))
        counts[pair] += 1
        t.append(t_ns)
        v.append((pos.x, pos.y, pos.z, rot.x, rot.y, rot.z, rot.w))
        line.append(index)
        pairs.append(pair)
    want = (None if parent is None else frame_name(parent),
            None if stamped or child is None else frame_name(child))  # fmt: skip

    def matching(w):
        return {pr for pr in counts if w[0] in (None, pr[0]) and w[1] in (None, pr[1])}

    keep, inverted = matching(want), False
    if not keep and None not in want:
        keep, inverted = matching((want[1], want[0])), True
    if not keep or len(keep) > 1:
        why = (f"no message from {parent!r} to {child!r} (either direction)" if not keep and not stamped
               else f"no message has frame_id {parent!r}" if not keep
               else "several frames: name the one meant (parent" + ("" if stamped else " and child") + ")")
        raise FrameIdError(f"{b.label}: topic {topic} ({msgtype}): {why}; its frames: {_frames_text(counts)}")
    [pair] = keep
    mask = np.array([pr == pair for pr in pairs], bool)
    n_other = int((~mask).sum())
    if n_other:
        log.warning("%s: topic %s: %d messages of other frames left out (%s)", b.label, topic, n_other,
                    _frames_text(counts))  # fmt: skip
    t, v, line = np.asarray(t, np.int64)[mask], np.asarray(v, float)[mask], np.asarray(line, np.int64)[mask]
    if inverted:
        v = _values(invert_T(_T(v)))
        pair = (pair[1], pair[0])
    path = [[pair[0], pair[1] if pair[1] is not None else child, "inverted" if inverted else "as stored",
             "dynamic"]]  # fmt: skip
    attrs = {"parent": pair[0], "child": path[0][1], "frames_path": path, "n_other_frames": n_other}
    return t, v, line, attrs


def _scan_tf(b: Bag, topic, time, want, static):
    """Edge counts of a TF topic, and the samples of the edges in ``want`` (None: every edge).

    Returns ``(counts, samples)``, samples ``{edge: [(t_ns, index, values)]}`` in the bag's
    order. A static topic's stamps are not checked (ROS 1 leaves them at zero).
    """
    counts: Counter = Counter()
    samples: dict = {e: [] for e in (want or ())}
    for index, t_msg, _rx, msg in b.messages(topic, "receive"):
        for tr in msg.transforms:
            edge = (frame_name(tr.header.frame_id), frame_name(tr.child_frame_id))
            counts[edge] += 1
            if want is not None and edge not in samples:
                continue
            t_ns = stamp_ns(tr.header.stamp) if time == "header" else t_msg
            if t_ns == 0 and time == "header" and not static:
                raise zero_stamp_error(b.label, topic, index,
                                       f"transform {edge[0]} -> {edge[1]}'s header stamp")  # fmt: skip
            tl, r = tr.transform.translation, tr.transform.rotation
            samples.setdefault(edge, []).append((t_ns, index, (tl.x, tl.y, tl.z, r.x, r.y, r.z, r.w)))
    return counts, samples


def _tf_path(edges, start, goal):
    """The path start -> goal over edges taken either way (breadth first): [(a, b, edge, inverted)]."""
    adj: dict = {}
    for e in edges:
        adj.setdefault(e[0], []).append((e[1], e, False))
        adj.setdefault(e[1], []).append((e[0], e, True))
    prev = {start: None}
    queue = deque([start])
    while queue:
        f = queue.popleft()
        for g, e, inv in adj.get(f, []):
            if g not in prev:
                prev[g] = (f, e, inv)
                queue.append(g)
    if goal not in prev or start == goal:
        return None
    path, f = [], goal
    while prev[f] is not None:
        a, e, inv = prev[f]
        path.append((a, f, e, inv))
        f = a
    return path[::-1]


def _read_tf(b: Bag, topic, parent, child, time):
    """Times, values, message indices and attrs of T_parent_child from TF."""
    is_static = topic == TF_STATIC
    if parent is None or child is None:
        counts, _ = _scan_tf(b, topic, time, set(), is_static)
        raise FrameIdError(f"{b.label}: topic {topic} is TF: name the parent and the child frame; its edges: "
                           + "; ".join(f"{p} -> {c} ({n})" for (p, c), n in counts.most_common()))
    parent, child = frame_name(parent), frame_name(child)
    static: dict = {}
    if TF_STATIC in b.reader.topics and not is_static:
        _c, s = _scan_tf(b, TF_STATIC, time, None, True)
        static = {e: np.asarray(rows[-1][2], float) for e, rows in s.items()}
    counts, samples = _scan_tf(b, topic, time, None if is_static else {(parent, child), (child, parent)},
                               is_static)  # fmt: skip
    if is_static:
        static = {e: np.asarray(rows[-1][2], float) for e, rows in samples.items()}
    if counts[(parent, child)] and counts[(child, parent)]:
        raise FrameIdError(f"{b.label}: topic {topic} has both {parent} -> {child} and {child} -> {parent} "
                           "(a TF cycle): which one is meant is unclear")  # fmt: skip
    edges = set(counts) | set(static)
    path = _tf_path(sorted(edges), parent, child)
    if path is None:
        frames = sorted({f for e in edges for f in e})
        dyn = "; ".join(f"{p} -> {c} ({counts[(p, c)]})" for p, c in sorted(set(counts) - set(static)))
        sta = "; ".join(f"{p} -> {c}" for p, c in sorted(static))
        raise FrameIdError(f"{b.label}: topic {topic}: no TF path from {parent!r} to {child!r}; frames "
                           f"present: {', '.join(frames)}; dynamic edges: {dyn or 'none'}; static edges "
                           f"({TF_STATIC}): {sta or 'none'}")  # fmt: skip
    dynamic = [e for _a, _c, e, _i in path if e not in static]
    if any(e not in samples for e in dynamic):  # a chain: read its dynamic edges
        samples.update(_scan_tf(b, topic, time, set(dynamic), False)[1])
    frames_path = [[a, c, "inverted" if inv else "as stored", "static" if e in static else "dynamic"]
                   for a, c, e, inv in path]  # fmt: skip
    attrs = {"parent": parent, "child": child, "frames_path": frames_path, "n_other_frames": 0}
    if not dynamic:
        raise FrameIdError(f"{b.label}: topic {topic}: {parent} -> {child} goes through static transforms "
                           f"only ({frames_path}): one pose, not a stream")  # fmt: skip
    if len(path) == 1:  # the direct edge: every sample, its own numbers unless inverted
        rows = samples[path[0][2]]
        v = np.array([r[2] for r in rows], float).reshape(-1, 7)
        if path[0][3]:
            v = _values(invert_T(_T(v)))
        return np.array([r[0] for r in rows], np.int64), v, np.array([r[1] for r in rows], np.int64), attrs
    per_edge = {e: {r[0]: r for r in samples[e]} for e in dynamic}
    common = set(per_edge[dynamic[0]])
    for e in dynamic[1:]:
        common &= set(per_edge[e])
    if not common:
        raise FrameIdError(
            f"{b.label}: topic {topic}: the TF path {parent} -> {child} ({frames_path}) goes through "
            f"{len(dynamic)} dynamic edges that share no stamp; composing them needs interpolation, which "
            "reading does not do: read each edge as its own stream"
        )
    t = np.array(sorted(common), np.int64)
    T = np.tile(np.eye(4), (len(t), 1, 1))
    for _a, _c, e, inv in path:
        Te = _T(static[e]) if e in static else _T([per_edge[e][k][2] for k in t.tolist()])
        T = T @ (invert_T(Te) if inv else Te)
    line = np.array([per_edge[dynamic[0]][k][1] for k in t.tolist()], np.int64)
    return t, _values(T), line, attrs
