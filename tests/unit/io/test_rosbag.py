"""Opening bags of every storage, the topic listing, and the errors for what is not a bag."""

from __future__ import annotations

import sqlite3

import pytest

from cvsflow.exceptions import BagError, TopicNotFoundError
from cvsflow.io.rosbag import bag_paths, list_topics, open_bag
from cvsflow.io.rosbag_poses import read_bag_pose_stream
from tests.helpers.bags import Msg, write_bag

T0 = 1_700_000_000_000_000_000
STAMPED = "geometry_msgs/msg/PoseStamped"


def _poses(n, t0=T0, topic="/p"):
    return [Msg(t0 + i * 10_000_000, topic, STAMPED, {"t_ns": t0 + i * 10_000_000, "frame_id": "world",
                                                       "v": [float(i), 0, 0, 0, 0, 0, 1]}) for i in range(n)]


@pytest.mark.parametrize("storage", ["ros1", "ros1-lz4", "ros1-bz2", "sqlite3", "sqlite3-zstd", "mcap", "mcap-zstd"])
def test_list_topics_every_storage(tmp_path, storage):
    """Name, type, kind, count, rate from receive times; compressed chunks and messages read the same."""
    msgs = _poses(11) + [Msg(T0 + 1, "/tf", "tf2_msgs/msg/TFMessage", {"transforms": [(T0, "a", "b", [0] * 6 + [1])]})]
    bag = write_bag(tmp_path / "b", storage, msgs)
    df = list_topics(bag).set_index("topic")
    assert df.loc["/p", "msgtype"] == STAMPED and df.loc["/p", "kind"] == "pose" and df.loc["/tf", "kind"] == "tf"
    assert df.loc["/p", "count"] == 11 and df.loc["/p", "rate_hz"] == pytest.approx(100.0)
    assert df.attrs["storage"] == ("ros1" if storage.startswith("ros1") else f"ros2-{storage.split('-')[0]}")
    assert read_bag_pose_stream(bag, "/p")["x_m"].tolist() == [float(i) for i in range(11)]


def test_bare_files_split_bags_and_bags_without_definitions(tmp_path):
    for storage, suffix in (("mcap", ".mcap"), ("sqlite3", ".db3")):
        [file] = write_bag(tmp_path / storage, storage, _poses(6)).glob(f"*{suffix}")
        assert bag_paths(file)[1] == f"ros2-{storage}" and len(read_bag_pose_stream(file, "/p")) == 6
    a = write_bag(tmp_path / "part0", "ros1", _poses(3))
    b = write_bag(tmp_path / "part1", "ros1", _poses(3, T0 + 30_000_000))
    assert read_bag_pose_stream([a, b], "/p")["t_ns"].tolist() == [T0 + i * 10_000_000 for i in range(6)]
    # ROS 2 Humble's sqlite3 bags carry no message definitions: Humble's types read them
    folder = write_bag(tmp_path / "humble", "sqlite3", _poses(4))
    [db] = folder.glob("*.db3")
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions")
    assert len(read_bag_pose_stream(folder, "/p")) == 4


def test_what_is_not_a_bag_is_named(tmp_path):
    with pytest.raises(BagError, match="missing.bag: bag not found; expected a ROS 1 .bag file"):
        list_topics(tmp_path / "missing.bag")
    fake = tmp_path / "fake.bag"
    fake.write_text("not a bag")
    with pytest.raises(BagError, match="fake.bag: cannot be read as a ros1 bag"):
        list_topics(fake)
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="a folder with no metadata.yaml and 0 .db3 / .mcap files"):
        list_topics(tmp_path / "empty")
    (tmp_path / "poses.txt").write_text("x")
    with pytest.raises(BagError, match="poses.txt: not a bag by its name"):
        list_topics(tmp_path / "poses.txt")
    ros2 = write_bag(tmp_path / "r2", "mcap", _poses(2))
    with pytest.raises(BagError, match="several paths are the .bag files of one split ROS 1 recording"):
        bag_paths([ros2, fake])
    with open_bag(ros2) as b, pytest.raises(TopicNotFoundError, match=r"no topic '/q'.*the bag has:\n  /p  "):
        b.topic("/q", (STAMPED,), "a pose topic")


def test_unindexed_ros1_bag_says_reindex(tmp_path):
    """A recorder killed before it wrote the index: rosbag reindex is named."""
    bag = write_bag(tmp_path / "b", "ros1", _poses(50))
    data = bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=r"cut.bag: cannot be read as a ros1 bag .*run `rosbag reindex` on it"):
        list_topics(cut)
