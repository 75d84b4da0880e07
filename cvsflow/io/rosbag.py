"""ROS 1 and ROS 2 bags (sqlite3 and MCAP storage) as inputs: opening, topics, messages.

Read with ``rosbags`` (pure Python, no ROS install), whose one reader covers ROS 1 ``.bag``
files (one, or the ``.bag`` files of a split recording), ROS 2 bag folders (``metadata.yaml``
beside ``.db3`` or ``.mcap`` files) and bare ``.db3`` / ``.mcap`` files, and names message types
the ROS 2 way in all of them (``sensor_msgs/msg/Image``, also for a ROS 1 bag, whose files say
``sensor_msgs/Image``). Every function takes ``bag``: a path, or a list of ``.bag`` paths.

The readers built on this module:

- :mod:`cvsflow.io.rosbag_images`: an image topic as a frame source with the interface of
  :func:`cvsflow.io.frames.iter_frames_gray` (header stamps as exact int64 ns);
- :mod:`cvsflow.io.rosbag_poses`: a pose topic, or ``/tf`` between two named frames, as the
  pose-stream table of :mod:`cvsflow.io.mocap.streams`;
- :mod:`cvsflow.io.rosbag_session`: a session's ``bag`` block (the config keys, the readers the
  workflow's rules call).

Times: a header stamp is ``sec * 1_000_000_000 + nanosec`` in integers (exact); ``time="receive"``
takes the bag's receive (log) time instead, for publishers that leave the stamp at zero (which is
a :class:`~cvsflow.exceptions.ZeroStampError` otherwise). Failures are named errors
(:class:`~cvsflow.exceptions.BagError` and its subclasses) naming the bag, the topic and the
message index.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from cvsflow.exceptions import BagError, TopicNotFoundError, TopicTypeError, ZeroStampError

log = logging.getLogger(__name__)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")  # the second: ROS 1's old tf package
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_COV_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE_TYPES = (POSE_STAMPED, POSE_COV_STAMPED, TRANSFORM_STAMPED, ODOMETRY, *TF_TYPES)
TF_STATIC = "/tf_static"
TIME_SOURCES = ("header", "receive")
STORAGES = ("ros1", "ros2-sqlite3", "ros2-mcap")
NS_PER_S = 1_000_000_000
#: What a bag is, for messages.
EXPECTED_BAG = ("expected a ROS 1 .bag file (or the .bag files of a split recording), a ROS 2 bag folder "
                "(metadata.yaml beside .db3 or .mcap files), or a .db3 / .mcap file")  # fmt: skip


def stamp_ns(stamp) -> int:
    """Exact nanoseconds of a ROS time (``sec``, ``nanosec``).

    Parameters
    ----------
    stamp : builtin_interfaces/msg/Time
        As ``rosbags`` deserialises it (ROS 1 times too).

    Returns
    -------
    int
    """
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def bag_paths(bag) -> tuple[list[Path], str]:
    """The paths ``rosbags`` opens for ``bag``, and the bag's storage.

    Parameters
    ----------
    bag : str, Path or list of them
        A ROS 1 ``.bag`` (or the ``.bag`` files of a split recording), a ROS 2 bag folder, a
        bare ``.db3`` / ``.mcap`` file, or a folder without ``metadata.yaml`` holding exactly
        one ``.db3`` / ``.mcap`` file (read as that file).

    Returns
    -------
    paths : list of Path
    storage : {"ros1", "ros2-sqlite3", "ros2-mcap"}

    Raises
    ------
    BagError
        Nothing given, a path missing, several paths that are not all ``.bag`` files, or not a
        bag by its name.
    """
    items = [bag] if isinstance(bag, (str, Path)) else list(bag)
    paths = [Path(p) for p in items]
    if not paths:
        raise BagError(f"no bag given; {EXPECTED_BAG}")
    missing = [str(p) for p in paths if not p.exists()]
    if missing:
        raise BagError(f"{', '.join(missing)}: bag not found; {EXPECTED_BAG}")
    if all(p.suffix == ".bag" and p.is_file() for p in paths):
        return paths, "ros1"
    if len(paths) > 1:
        raise BagError(f"{', '.join(map(str, paths))}: several paths are the .bag files of one split ROS 1 "
                       "recording; a ROS 2 bag is one folder (or one .db3 / .mcap file)")  # fmt: skip
    p = paths[0]
    if p.is_dir():
        files = sorted(p.glob("*.mcap")) + sorted(p.glob("*.db3"))
        if (p / "metadata.yaml").is_file() and files:
            kinds = {_storage_of(f) for f in files}
            if len(kinds) == 1:
                return [p], kinds.pop()
        if not (p / "metadata.yaml").is_file() and len(files) == 1:
            return [files[0]], _storage_of(files[0])
        raise BagError(f"{p}: a folder with {'a' if (p / 'metadata.yaml').is_file() else 'no'} metadata.yaml "
                       f"and {len(files)} .db3 / .mcap files; {EXPECTED_BAG}")  # fmt: skip
    if p.suffix in (".db3", ".mcap"):
        return [p], _storage_of(p)
    raise BagError(f"{p}: not a bag by its name; {EXPECTED_BAG}")


def _storage_of(path: Path) -> str:
    return "ros2-mcap" if path.suffix == ".mcap" else "ros2-sqlite3"


def check_time(time: str) -> None:
    """Refuse a time source other than ``header`` or ``receive``.

    Parameters
    ----------
    time : str

    Returns
    -------
    None

    Raises
    ------
    ValueError
        Another value.
    """
    if time not in TIME_SOURCES:
        raise ValueError(f"time={time!r}; expected one of {', '.join(TIME_SOURCES)}")


def topics_text(topics: dict) -> str:
    """The topics of a bag, one line each: name, type, message count.

    Parameters
    ----------
    topics : dict
        ``rosbags``' ``reader.topics`` (name -> TopicInfo).

    Returns
    -------
    str
    """
    if not topics:
        return "  (none: an empty bag)"
    w = max(len(n) for n in topics)
    return "\n".join(f"  {name:<{w}}  {info.msgtype or 'several types'}  ({info.msgcount} messages)"
                     for name, info in sorted(topics.items()))  # fmt: skip


@dataclass
class Bag:
    """An open bag: ``rosbags``' reader, the storage, and how messages name the bag.

    Attributes
    ----------
    reader : rosbags.highlevel.AnyReader
    storage : str
        One of :data:`STORAGES`.
    label : str
        The bag's path(s), for messages.
    """

    reader: object
    storage: str
    label: str

    def topic(self, topic: str, allowed: tuple[str, ...], what: str):
        """The topic's name as in the bag and its ``TopicInfo``, checked against ``allowed`` types.

        Parameters
        ----------
        topic : str
            Topic name; the leading ``/`` may be left out.
        allowed : tuple of str
            Message types that can give ``what``.
        what : str
            What the topic should be, for messages (``"an image topic"``).

        Returns
        -------
        name : str
        info : rosbags TopicInfo
            ``msgtype``, ``msgcount``, ``connections``.

        Raises
        ------
        TopicNotFoundError
            No such topic: the message lists every topic of the bag (name, type, count).
        TopicTypeError
            A topic of another type: the message lists the topics that are of ``allowed`` types.
        """
        topics = self.reader.topics
        name = topic if topic in topics else (f"/{topic}" if f"/{topic}" in topics else None)
        if name is None:
            raise TopicNotFoundError(f"{self.label}: no topic {topic!r} (expected {what}); the bag has:\n"
                                     f"{topics_text(topics)}")  # fmt: skip
        info = topics[name]
        if info.msgtype not in allowed:
            fitting = {n: i for n, i in topics.items() if i.msgtype in allowed}
            raise TopicTypeError(f"{self.label}: topic {name} is {info.msgtype or 'of several types'}, not "
                                 f"{what} ({', '.join(allowed)}); the topics that are:\n"
                                 f"{topics_text(fitting)}")  # fmt: skip
        return name, info

    def messages(self, topic: str, time: str = "header", start: int = 0, stop: int | None = None,
                 check_zero: bool = True) -> Iterator[tuple[int, int, int, object]]:  # fmt: skip
        """The messages of one topic in the bag's (receive-time) order, deserialised.

        Parameters
        ----------
        topic : str
            The topic's name as in the bag (:meth:`topic`).
        time : {"header", "receive"}
            Which time is ``t_ns``: the message's ``header.stamp`` or the bag's receive time.
        start, stop : int
            Message indices ``[start, stop)``; those before ``start`` are not deserialised.
        check_zero : bool
            A zero header stamp is a :class:`ZeroStampError` (with ``time="header"``).

        Returns
        -------
        iterator of (int, int, int, object)
            ``(index, t_ns, t_receive_ns, message)``, index 0-based in the topic.

        Raises
        ------
        BagError
            A message that does not deserialise as its type (index named).
        ZeroStampError
            A zero header stamp (``time="header"``, ``check_zero``).
        """
        from rosbags.highlevel import AnyReaderError

        check_time(time)
        conns = [c for c in self.reader.connections if c.topic == topic]
        for index, (conn, t_rx, raw) in enumerate(self.reader.messages(conns)):
            if index < start:
                continue
            if stop is not None and index >= stop:
                return
            try:
                msg = self.reader.deserialize(raw, conn.msgtype)
            except (AnyReaderError, KeyError, ValueError, IndexError) as exc:
                raise BagError(f"{self.label}: topic {topic}, message {index}: cannot be deserialised as "
                               f"{conn.msgtype}: {exc}") from exc  # fmt: skip
            if time == "receive":
                t_ns = int(t_rx)
            else:
                t_ns = stamp_ns(msg.header.stamp) if hasattr(msg, "header") else int(t_rx)
                if check_zero and t_ns == 0:
                    raise zero_stamp_error(self.label, topic, index)
            yield index, t_ns, int(t_rx), msg


def zero_stamp_error(label: str, topic: str, index: int, what: str = "its header stamp") -> ZeroStampError:
    """The error for a zero header stamp, saying how to read receive times instead.

    Parameters
    ----------
    label : str
        The bag.
    topic : str
    index : int
        The message's index in its topic.
    what : str
        Whose stamp (``its header stamp``, ``transform world -> body0's stamp``).

    Returns
    -------
    ZeroStampError
    """
    return ZeroStampError(
        f"{label}: topic {topic}, message {index}: {what} is zero (its publisher never set it); read the "
        "bag's receive times instead: time: receive in the session's bag block, --receive-time on cvsflow "
        "handeye, time='receive' in Python (receive times include the transport delay)"
    )


@contextmanager
def open_bag(bag) -> Iterator[Bag]:
    """An open :class:`Bag`, closed on leaving.

    Parameters
    ----------
    bag : str, Path or list of them
        As :func:`bag_paths`.

    Returns
    -------
    contextmanager of Bag

    Raises
    ------
    BagError
        Not a bag (:func:`bag_paths`), or ``rosbags`` cannot open it (damaged; a ROS 1 bag not
        indexed, as a recorder killed leaves it; a ROS 2 bag without type definitions whose
        types are not ROS 2 Humble's).
    """
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    paths, storage = bag_paths(bag)
    label = ", ".join(map(str, paths))
    # Used only for a bag that carries no message definitions (ROS 2 Humble's sqlite3 bags): the
    # image, pose and TF types are the same in every ROS 2 distribution.
    typestore = get_typestore(Stores.ROS1_NOETIC if storage == "ros1" else Stores.ROS2_HUMBLE)
    reader = AnyReader(paths, default_typestore=typestore)
    try:
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError, AssertionError) as exc:
        hint = ("; a ROS 1 bag whose recorder was stopped before it wrote the index: run `rosbag reindex` "
                "on it" if storage == "ros1" and "index" in str(exc).lower() else "")  # fmt: skip
        raise BagError(f"{label}: cannot be read as a {storage} bag ({exc}){hint}") from exc
    try:
        yield Bag(reader, storage, label)
    finally:
        reader.close()


def topic_kind(msgtype: str | None) -> str:
    """What a message type gives cvsflow: ``image``, ``tf``, ``pose`` or ``other``.

    Parameters
    ----------
    msgtype : str or None
        ROS 2 spelling (``sensor_msgs/msg/Image``).

    Returns
    -------
    str
    """
    if msgtype in IMAGE_TYPES:
        return "image"
    if msgtype in TF_TYPES:
        return "tf"
    return "pose" if msgtype in POSE_TYPES else "other"


def list_topics(bag) -> pd.DataFrame:
    """The topics of a bag: name, type, kind, message count and rate (receive times).

    Reads every message's receive time once (raw bytes, nothing deserialised).

    Parameters
    ----------
    bag : str, Path or list of them
        As :func:`bag_paths`.

    Returns
    -------
    DataFrame
        One row per topic, by name: ``topic``, ``msgtype`` (ROS 2 spelling), ``kind``
        (:func:`topic_kind`), ``count``, ``rate_hz`` (``(count - 1) / (last - first)`` receive
        time; NaN below two messages), ``t_first_ns``, ``t_last_ns`` (receive times, -1 for an
        empty topic). ``attrs``: ``bag``, ``storage``, ``start_ns``, ``end_ns``.

    Raises
    ------
    BagError
        As :func:`open_bag`.
    """
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    seen: Counter = Counter()
    with open_bag(bag) as b:
        topics = b.reader.topics
        for conn, t_ns, _raw in b.reader.messages():
            first.setdefault(conn.topic, t_ns)
            last[conn.topic] = t_ns
            seen[conn.topic] += 1
    rows = []
    for name, info in sorted(topics.items()):
        n = seen[name]
        span = last.get(name, 0) - first.get(name, 0)
        rate = (n - 1) * 1e9 / span if n > 1 and span > 0 else float("nan")
        rows.append({"topic": name, "msgtype": info.msgtype or "several types",
                     "kind": topic_kind(info.msgtype), "count": n, "rate_hz": rate,
                     "t_first_ns": first.get(name, -1), "t_last_ns": last.get(name, -1)})  # fmt: skip
    columns = ["topic", "msgtype", "kind", "count", "rate_hz", "t_first_ns", "t_last_ns"]
    df = pd.DataFrame(rows, columns=columns)
    df = df.astype({"count": "int64", "t_first_ns": "int64", "t_last_ns": "int64"})
    df.attrs = {"bag": b.label, "storage": b.storage, "start_ns": min(first.values(), default=-1),
                "end_ns": max(last.values(), default=-1)}  # fmt: skip
    return df
