"""Test bags written by ``rosbags`` itself: ROS 1, ROS 2 sqlite3 and ROS 2 MCAP (compressed variants too).

:func:`write_bag` writes a list of :class:`Msg` to a ROS 1 ``.bag`` or a ROS 2 bag folder;
:func:`yac_messages` turns the yac mocap recording (``cam0/data/<ns>.jpg``, ``body0/data.csv``,
``target0/data.csv``) into these messages:

==============================  =====================  ===========================================
topic                           type                   content
==============================  =====================  ===========================================
``/cam0/image_raw/compressed``  CompressedImage        the JPEG file's bytes, unchanged; ``jpeg``
``/cam0/image_raw``             Image ``bgr8``         ``cv2.imread(IMREAD_COLOR)`` of the file
``/mocap/body0/pose``           PoseStamped            body0/data.csv, frame_id ``world``
``/mocap/target0/pose``         PoseStamped            target0/data.csv, frame_id ``world``
``/tf``                         TFMessage              ``world -> body0``, ``world -> target0``
``/tf_static``                  TFMessage              ``map -> world``, ``body0 -> cam0``
==============================  =====================  ===========================================

Header stamps are the files' nanoseconds and the CSVs' numbers as Python's ``float`` reads them;
receive times are the stamps plus :data:`IMAGE_DELAY_NS` / :data:`POSE_DELAY_NS`, so that the two
time sources differ. The static transforms are made up, for the TF chain tests.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

IMAGE_DELAY_NS = 5_000_000
POSE_DELAY_NS = 1_000_000
T_MAP_WORLD = (0.5, -1.25, 0.1, 0.0, 0.0, 0.3826834323650898, 0.9238795325112867)  # 45 deg yaw
T_BODY0_CAM0 = (0.03, -0.02, 0.05, -0.5, 0.5, -0.5, 0.5)
#: tf2_msgs/TFMessage, which rosbags' ROS 1 Noetic typestore lacks (its md5 comes out as ROS 1's)
TF2_MSG_DEF = "geometry_msgs/TransformStamped[] transforms"
STORAGES = ("ros1", "ros1-lz4", "ros1-bz2", "sqlite3", "sqlite3-zstd", "mcap", "mcap-zstd")
JPEG_TOPIC = "/cam0/image_raw/compressed"
RAW_TOPIC = "/cam0/image_raw"


@dataclass
class Msg:
    """One message to write: receive time (ns), topic, type (ROS 2 spelling) and fields (:func:`_build`)."""

    t_receive_ns: int
    topic: str
    msgtype: str
    fields: dict


def _time(ts, t_ns):
    s, ns = divmod(int(t_ns), 1_000_000_000)
    return ts.types["builtin_interfaces/msg/Time"](sec=s, nanosec=ns)


def _header(ts, ros1, t_ns, frame_id, seq=0):
    return ts.types["std_msgs/msg/Header"](stamp=_time(ts, t_ns), frame_id=frame_id,
                                           **({"seq": seq} if ros1 else {}))  # fmt: skip


def _pose(T, v):
    return T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=v[0], y=v[1], z=v[2]),
                                       orientation=T["geometry_msgs/msg/Quaternion"](x=v[3], y=v[4], z=v[5],
                                                                                     w=v[6]))  # fmt: skip


def _transform_stamped(ts, ros1, t_ns, parent, child, v, seq=0):
    T = ts.types
    return T["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, ros1, t_ns, parent, seq), child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2]),
            rotation=T["geometry_msgs/msg/Quaternion"](x=v[3], y=v[4], z=v[5], w=v[6])),
    )  # fmt: skip


def _build(ts, ros1, m: Msg, seq: int):
    """The message of ``m``. Fields: Image ``t_ns, frame_id, encoding, pixels`` (+ ``step``,
    ``is_bigendian``); CompressedImage ``t_ns, frame_id, format, data``; PoseStamped ``t_ns,
    frame_id, v`` (x y z qx qy qz qw); Odometry and TransformStamped also ``child``; TFMessage
    ``transforms``: a list of (t_ns, parent, child, v)."""
    T, f = ts.types, m.fields
    if m.msgtype == "sensor_msgs/msg/Image":
        px = np.ascontiguousarray(f["pixels"])
        h, w = px.shape[:2]
        row = px.reshape(h, -1).view(np.uint8)
        step = int(f.get("step", row.shape[1]))
        if step > row.shape[1]:
            row = np.pad(row, ((0, 0), (0, step - row.shape[1])))
        return T[m.msgtype](header=_header(ts, ros1, f["t_ns"], f["frame_id"], seq), height=h, width=w,
                            encoding=f["encoding"], is_bigendian=int(f.get("is_bigendian", 0)), step=step,
                            data=row.reshape(-1).copy())  # fmt: skip
    if m.msgtype == "sensor_msgs/msg/CompressedImage":
        return T[m.msgtype](header=_header(ts, ros1, f["t_ns"], f["frame_id"], seq), format=f["format"],
                            data=np.frombuffer(f["data"], dtype=np.uint8))  # fmt: skip
    if m.msgtype == "geometry_msgs/msg/PoseStamped":
        return T[m.msgtype](header=_header(ts, ros1, f["t_ns"], f["frame_id"], seq), pose=_pose(T, f["v"]))
    if m.msgtype == "nav_msgs/msg/Odometry":
        zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        return T[m.msgtype](
            header=_header(ts, ros1, f["t_ns"], f["frame_id"], seq), child_frame_id=f["child"],
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=_pose(T, f["v"]), covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)),
        )  # fmt: skip
    if m.msgtype == "geometry_msgs/msg/TransformStamped":
        return _transform_stamped(ts, ros1, f["t_ns"], f["frame_id"], f["child"], f["v"], seq)
    if m.msgtype == "tf2_msgs/msg/TFMessage":
        return T[m.msgtype](transforms=[_transform_stamped(ts, ros1, t, p, c, v) for t, p, c, v in f["transforms"]])
    raise ValueError(f"no builder for {m.msgtype}")


def write_bag(path, storage: str, messages: list[Msg]) -> Path:
    """Write ``messages`` (by receive time) to a new bag of ``storage`` (:data:`STORAGES`).

    ``ros1`` (``-lz4``, ``-bz2``: compressed chunks) writes ``path.bag``; ``sqlite3`` (``-zstd``:
    each message compressed) and ``mcap`` (``-zstd``: compressed chunks) the ROS 2 folder
    ``path`` (rosbag2 version 8, ROS 2 Humble's types). Returns the bag's path.
    """
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ros1 = storage.startswith("ros1")
    out = Path(path).with_suffix(".bag") if ros1 else Path(path)
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:
        ts.register(get_types_from_msg(TF2_MSG_DEF, "tf2_msgs/msg/TFMessage"))
        writer = Writer1(out)
        if storage != "ros1":
            writer.set_compression({"ros1-lz4": Writer1.CompressionFormat.LZ4,
                                    "ros1-bz2": Writer1.CompressionFormat.BZ2}[storage])  # fmt: skip
    else:
        writer = Writer2(out, version=8,
                         storage_plugin=StoragePlugin.MCAP if storage.startswith("mcap") else StoragePlugin.SQLITE3)
        if storage == "sqlite3-zstd":
            writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
        elif storage == "mcap-zstd":
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    try:
        with writer:
            conns, seqs = {}, {}
            for m in sorted(messages, key=lambda m: m.t_receive_ns):
                if m.topic not in conns:
                    conns[m.topic] = writer.add_connection(m.topic, m.msgtype, typestore=ts)
                    seqs[m.topic] = 0
                writer.write(conns[m.topic], int(m.t_receive_ns), serialize(_build(ts, ros1, m, seqs[m.topic]),
                                                                              m.msgtype))  # fmt: skip
                seqs[m.topic] += 1
    except BaseException:
        shutil.rmtree(out, ignore_errors=True) if out.is_dir() else out.unlink(missing_ok=True)
        raise
    return out


def yac_frames(data_dir) -> list[tuple[int, Path]]:
    """``(t_ns, jpeg)`` of the yac recording's ``cam0/data/<ns>.jpg``, by time."""
    files = sorted(Path(data_dir, "cam0", "data").glob("*.jpg"), key=lambda p: int(p.stem))
    return [(int(p.stem), p) for p in files]


def read_csv_rows(path) -> list[tuple[int, list[float]]]:
    """``(t_ns, [x, y, z, qx, qy, qz, qw])`` of a yac pose CSV, numbers as Python's float reads them."""
    rows = []
    for line in Path(path).read_text().splitlines()[1:]:
        if line.strip():
            cells = line.split(",")
            rows.append((int(cells[0]), [float(c) for c in cells[1:8]]))
    return rows


def yac_messages(data_dir, compressed=True, raw=True, poses=True, tf=True, zero_stamps=False,
                 n_frames=None, n_poses=None) -> list[Msg]:  # fmt: skip
    """The yac recording as bag messages (the module docstring's table).

    ``zero_stamps`` sets the image header stamps to 0 (receive times kept); ``n_frames`` and
    ``n_poses`` keep the first frames and the first poses of each body only.
    """
    data_dir = Path(data_dir)
    frames = yac_frames(data_dir)[:n_frames]
    out = []
    for t_ns, p in frames:
        stamp = 0 if zero_stamps else t_ns
        if compressed:
            out.append(Msg(t_ns + IMAGE_DELAY_NS, JPEG_TOPIC, "sensor_msgs/msg/CompressedImage",
                           {"t_ns": stamp, "frame_id": "cam0", "format": "jpeg", "data": p.read_bytes()}))
        if raw:
            out.append(Msg(t_ns + IMAGE_DELAY_NS, RAW_TOPIC, "sensor_msgs/msg/Image",
                           {"t_ns": stamp, "frame_id": "cam0", "encoding": "bgr8",
                            "pixels": cv2.imread(str(p), cv2.IMREAD_COLOR)}))  # fmt: skip
    if tf:
        out.append(Msg(frames[0][0] - 1_000_000_000, "/tf_static", "tf2_msgs/msg/TFMessage",
                       {"transforms": [(0, "map", "world", T_MAP_WORLD), (0, "body0", "cam0", T_BODY0_CAM0)]}))
    for body in ("body0", "target0") if poses or tf else ():
        for t_ns, v in read_csv_rows(data_dir / body / "data.csv")[:n_poses]:
            if poses:
                out.append(Msg(t_ns + POSE_DELAY_NS, f"/mocap/{body}/pose", "geometry_msgs/msg/PoseStamped",
                               {"t_ns": t_ns, "frame_id": "world", "v": v}))
            if tf:
                out.append(Msg(t_ns + POSE_DELAY_NS, "/tf", "tf2_msgs/msg/TFMessage",
                               {"transforms": [(t_ns, "world", body, v)]}))
    return out
