"""Pose topics and /tf of a bag as pose streams: the yac bodies read from ROS 1, sqlite3 and MCAP bags
are the CSVs' stream tables bit for bit; other message types, inverses, TF chains, and each
bad input named."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from cvsflow.exceptions import FrameIdError, QuaternionNormError, TopicNotFoundError, ZeroStampError
from cvsflow.geometry import invert_T
from cvsflow.io.mocap.formats import read_pose_stream
from cvsflow.io.mocap.streams import STREAM_COLUMNS, stream_T
from cvsflow.io.rosbag_poses import read_bag_pose_stream
from tests.helpers.bags import POSE_DELAY_NS, T_BODY0_CAM0, T_MAP_WORLD, Msg, write_bag, yac_messages
from tests.helpers.real_data import REAL_DATA

YAC = REAL_DATA / "yac-mocap-aprilgrid"
COLS = [c for c in STREAM_COLUMNS if c != "line"]
T0 = 1_700_000_000_123_456_789


@pytest.fixture(scope="module", params=["ros1", "sqlite3", "mcap"])
def yac_bag(request, tmp_path_factory):
    """The yac bodies as PoseStamped topics and on /tf (with made-up static transforms)."""
    if not (YAC / "body0" / "data.csv").is_file():
        pytest.skip(f"real data not available ({YAC})")
    return write_bag(tmp_path_factory.mktemp(request.param) / "yac", request.param,
                     yac_messages(YAC, compressed=False, raw=False))  # fmt: skip


def _T(v):
    from cvsflow.geometry import R_from_quat, make_T

    v = np.asarray(v, float).reshape(-1, 7)
    return make_T(R_from_quat(v[:, 3:]), v[:, :3])


def test_pose_topics_and_tf_equal_the_csvs(yac_bag):
    """PoseStamped and the /tf edge give the CSV's stream table: exact ns, every value bit for bit."""
    for body in ("body0", "target0"):
        csv = read_pose_stream(YAC / body / "data.csv")
        got = read_bag_pose_stream(yac_bag, f"/mocap/{body}/pose")
        assert list(got.columns) == STREAM_COLUMNS and got["t_ns"].dtype == np.int64
        assert got[COLS].equals(csv[COLS]) and got.attrs["parent"] == "world" and got.attrs["format"] == "rosbag"
    tf = read_bag_pose_stream(yac_bag, "tf", parent="/world", child="body0")
    assert tf[COLS].equals(read_pose_stream(YAC / "body0" / "data.csv")[COLS])


N_POSES = 200


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory):
    """The first 200 poses of each yac body, PoseStamped and /tf, in an MCAP bag."""
    if not (YAC / "body0" / "data.csv").is_file():
        pytest.skip(f"real data not available ({YAC})")
    return write_bag(tmp_path_factory.mktemp("small") / "yac", "mcap",
                     yac_messages(YAC, compressed=False, raw=False, n_poses=N_POSES))  # fmt: skip


def test_receive_times_inverse_and_chain(small_bag):
    csv = read_pose_stream(YAC / "body0" / "data.csv").iloc[:N_POSES]
    got = read_bag_pose_stream(small_bag, "/mocap/body0/pose", time="receive")
    assert np.array_equal(got["t_ns"].to_numpy(), csv["t_ns"].to_numpy() + POSE_DELAY_NS)
    inv = read_bag_pose_stream(small_bag, "/tf", parent="body0", child="world")
    assert inv.attrs["frames_path"] == [["body0", "world", "inverted", "dynamic"]]
    assert np.abs(stream_T(csv) @ stream_T(inv) - np.eye(4)).max() < 1e-12
    chain = read_bag_pose_stream(small_bag, "/tf", parent="map", child="cam0")
    assert [p[3] for p in chain.attrs["frames_path"]] == ["static", "dynamic", "static"]
    assert np.array_equal(chain["t_ns"].to_numpy(), csv["t_ns"].to_numpy())
    expect = _T(T_MAP_WORLD) @ stream_T(csv) @ _T(T_BODY0_CAM0)
    assert np.abs(stream_T(chain) - expect).max() < 1e-12
    back = read_bag_pose_stream(small_bag, "/tf", parent="cam0", child="map")
    assert np.abs(stream_T(back) - invert_T(expect)).max() < 1e-12


def test_frames_that_do_not_match_are_listed(small_bag):
    with pytest.raises(FrameIdError, match=r"no message has frame_id 'map'; its frames: frame_id 'world' \(200"):
        read_bag_pose_stream(small_bag, "/mocap/body0/pose", parent="map")
    with pytest.raises(FrameIdError, match=r"no TF path from 'world' to 'drone'; frames present: body0, cam0, map, "
                                           r"target0, world; dynamic edges: world -> body0 \(200\)"):  # fmt: skip
        read_bag_pose_stream(small_bag, "/tf", parent="world", child="drone")
    with pytest.raises(FrameIdError, match="name the parent and the child frame; its edges: world -> body0"):
        read_bag_pose_stream(small_bag, "/tf")
    with pytest.raises(FrameIdError, match="2 dynamic edges that share no stamp"):
        read_bag_pose_stream(small_bag, "/tf", parent="body0", child="target0")
    with pytest.raises(FrameIdError, match="static transforms only"):
        read_bag_pose_stream(small_bag, "/tf", parent="map", child="world")
    with pytest.raises(TopicNotFoundError, match=r"no topic '/mocap/body1/pose'.*the bag has:\n  /mocap/body0/pose  "):
        read_bag_pose_stream(small_bag, "/mocap/body1/pose")


# ----------------------------------------------------------------- synthetic bags (no data needed)


def _v(i):
    a = 0.1 * i
    return [1.0 + i, -2.0, 0.5 * i, 0.0, 0.0, np.sin(a / 2), np.cos(a / 2)]


def _poses(topic, msgtype, n=5, parent="odom", child="base_link", t0=T0):
    return [Msg(t0 + i * 10_000_000 + 500_000, topic, msgtype,
                {"t_ns": t0 + i * 10_000_000, "frame_id": parent, "child": child, "v": _v(i)}) for i in range(n)]


@pytest.mark.parametrize("msgtype", ["geometry_msgs/msg/TransformStamped", "nav_msgs/msg/Odometry"])
def test_transform_and_odometry_topics(tmp_path, msgtype):
    bag = write_bag(tmp_path / "b", "mcap", _poses("/p", msgtype))
    got = read_bag_pose_stream(bag, "/p")
    assert (got.attrs["parent"], got.attrs["child"]) == ("odom", "base_link")
    assert np.array_equal(got[["x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]].to_numpy(), np.array([_v(i) for i in range(5)]))
    assert got["t_ns"].tolist() == [T0 + i * 10_000_000 for i in range(5)] and got["line"].tolist() == list(range(5))
    inv = read_bag_pose_stream(bag, "/p", parent="base_link", child="odom")
    assert np.abs(stream_T(got) @ stream_T(inv) - np.eye(4)).max() < 1e-12
    with pytest.raises(FrameIdError, match=r"no message from 'map' to 'base_link' \(either direction\); its frames: "
                                           r"'odom' -> 'base_link' \(5 messages\)"):  # fmt: skip
        read_bag_pose_stream(bag, "/p", parent="map", child="base_link")


def test_mixed_frames_zero_stamps_and_bad_quaternions(tmp_path, caplog):
    stamped = "geometry_msgs/msg/PoseStamped"
    msgs = _poses("/p", stamped, 4, parent="world") + _poses("/p", stamped, 2, parent="map", t0=T0 + 5)
    bag = write_bag(tmp_path / "mixed", "ros1", msgs)
    with pytest.raises(FrameIdError, match=r"several frames.*'world' \(4 messages\).*'map' \(2 messages\)"):
        read_bag_pose_stream(bag, "/p")
    with caplog.at_level(logging.WARNING):
        got = read_bag_pose_stream(bag, "/p", parent="map")
    assert len(got) == 2 and got.attrs["n_other_frames"] == 4 and "4 messages of other frames left out" in caplog.text
    zero = _poses("/p", stamped, 3)
    zero[1].fields["t_ns"] = 0
    bag = write_bag(tmp_path / "zero", "sqlite3", zero)
    with pytest.raises(ZeroStampError, match="topic /p, message 1: its header stamp is zero"):
        read_bag_pose_stream(bag, "/p")
    assert read_bag_pose_stream(bag, "/p", time="receive")["t_ns"].tolist() == [m.t_receive_ns for m in zero]
    bad = _poses("/p", stamped, 3)
    bad[2].fields["v"] = [0, 0, 0, 0, 0, 0.5, 0.5]
    bag = write_bag(tmp_path / "quat", "mcap", bad)
    with pytest.raises(QuaternionNormError, match=r"topic /p, message 2: quaternion .* has norm 0.707"):
        read_bag_pose_stream(bag, "/p")
