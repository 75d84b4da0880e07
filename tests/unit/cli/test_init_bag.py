"""`cvsflow init BAG` and a session's bag block: topics listed, the likely topics filled in, TODO
where the bag cannot tell; the block passes the schema and its readers give the files' data."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml
from snakemake.utils import validate

from cvsflow import cli
from cvsflow.exceptions import ConfigError
from cvsflow.io.frames import frame_list, iter_frames_gray
from cvsflow.io.mocap.formats import read_pose_stream
from cvsflow.io.rosbag_session import bag_frame_source, read_bag_body
from cvsflow.workflow.config import DEMO_CONFIG, SCHEMA
from cvsflow.workflow.sessions import bag_settings, check_sessions
from tests.helpers.bags import JPEG_TOPIC, RAW_TOPIC, Msg, write_bag, yac_messages
from tests.helpers.real_data import REAL_DATA

YAC = REAL_DATA / "yac-mocap-aprilgrid"
T0 = 1_700_000_000_000_000_000


@pytest.fixture(scope="module")
def yac_bag(tmp_path_factory):
    """A ROS 1 bag of 4 yac frames (JPEG and raw) and the first 100 poses of each body, /tf too."""
    if not (YAC / "cam0" / "data").is_dir():
        pytest.skip(f"real data not available ({YAC})")
    return write_bag(tmp_path_factory.mktemp("yac") / "yac", "ros1", yac_messages(YAC, n_frames=4, n_poses=100))


def test_init_bag_lists_topics_and_fills_the_likely_ones(yac_bag, tmp_path, capsys):
    out = tmp_path / "s.yaml"
    assert cli.main(["init", str(yac_bag), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "/mocap/body0/pose           geometry_msgs/msg/PoseStamped" in printed and "wrote" in printed
    assert "dt_offset_s: left out, the sync stage estimates" in printed
    text = out.read_text()
    assert "# /tf                         tf2_msgs/msg/TFMessage" in text
    cfg = yaml.safe_load(text)["sessions"]["yac"]
    assert cfg["bag"] == {"path": str(yac_bag), "time": "header", "image_topic": RAW_TOPIC,
                          "camera_body": {"topic": "/mocap/body0/pose", "parent": "world"},
                          "board_body": {"topic": "/mocap/target0/pose", "parent": "world"}}  # fmt: skip
    assert cfg["calib_dir"] == "TODO" and cfg["board"]["square_m"] == "TODO"
    assert "compressed copy of a raw topic" in text and "also seen: {'topic': '/tf', 'parent': 'world'" in text
    # with the TODOs filled the block passes the schema and the session runs every stage
    cfg.update(calib_dir=str(YAC / "cam0" / "data"), board={"squares_x": 7, "squares_y": 6, "square_m": 0.03})
    config = {**yaml.safe_load(DEMO_CONFIG.read_text()), "sessions": {"yac": copy.deepcopy(cfg)}}
    validate(config, str(SCHEMA))
    assert check_sessions(config["sessions"]) == {"yac": ("calibrate", "poses", "mocap", "pairs")}
    assert cli.main(["init", str(yac_bag), "--out", str(out)]) == 1
    assert "exists; cvsflow init never overwrites a file" in capsys.readouterr().err


def test_init_bag_todo_where_it_cannot_tell(tmp_path, capsys):
    """Two camera topics, zero stamps, poses named like no body: TODO with the candidates."""
    img = {"frame_id": "c", "encoding": "mono8", "pixels": np.zeros((4, 4), np.uint8)}
    msgs = [Msg(T0 + k, t, "sensor_msgs/msg/Image", {"t_ns": 0, **img}) for k in range(2) for t in ("/left", "/right")]
    msgs += [Msg(T0 + k, "/odom", "nav_msgs/msg/Odometry", {"t_ns": T0 + k, "frame_id": "odom", "child": "x",
                                                             "v": [0, 0, 0, 0, 0, 0, 1]}) for k in range(3)]
    bag = write_bag(tmp_path / "two", "mcap", msgs)
    assert cli.main(["init", str(bag), "--name", "lab"]) == 0
    text = (tmp_path / "two_session.yaml").read_text()
    cfg = yaml.safe_load(text)["sessions"]["lab"]["bag"]
    assert cfg["image_topic"] == "TODO" and cfg["camera_body"] == {"topic": "TODO", "parent": "TODO"}
    assert "several camera topics: choose image_topic among /left" in text
    assert "camera_body: no pose topic or TF frame named like one" in text
    one = write_bag(tmp_path / "one", "ros1", msgs[:1])
    assert cli.main(["init", str(one)]) == 0
    cfg = yaml.safe_load((tmp_path / "one_session.yaml").read_text())["sessions"]["one"]["bag"]
    assert cfg["image_topic"] == "/left" and cfg["time"] == "receive"


def test_session_readers_give_the_files_data(yac_bag):
    """bag_frame_source and read_bag_body: the frame folder's frames and the CSVs' stream tables."""
    s = bag_settings("yac", {"bag": {"path": str(yac_bag), "image_topic": JPEG_TOPIC,
                                     "camera_body": {"topic": "/tf", "parent": "world", "child": "body0"},
                                     "board_body": {"topic": "/mocap/target0/pose", "parent": "world"}}})
    source, frames = bag_frame_source(s)
    assert frames[["frame", "t_ns", "t_s"]].equals(frame_list(YAC / "cam0")[["frame", "t_ns", "t_s"]].iloc[:4])
    for (f, t, g), (fr, tr, gr) in zip(source(1, 3), list(iter_frames_gray(YAC / "cam0", 1, 3)), strict=True):
        assert (f, t) == (fr, tr) and np.array_equal(g, gr)
    cols = ["t_ns", "t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]
    for body, name in (("camera", "body0"), ("board", "target0")):
        assert read_bag_body(s, body)[cols].equals(read_pose_stream(YAC / name / "data.csv")[cols].iloc[:100])


def test_bag_settings_refuse_what_contradicts():
    base = {"path": "x.bag", "image_topic": "/c"}
    assert bag_settings("s", {}) is None
    with pytest.raises(ConfigError, match=r"sessions.s.bag.image_topic: the session also names video \(v.mp4\)"):
        bag_settings("s", {"bag": base, "video": "v.mp4"})
    body = {"topic": "/p", "parent": "world"}
    with pytest.raises(ConfigError, match="camera_body without board_body"):
        bag_settings("s", {"bag": {**base, "camera_body": body}})
    with pytest.raises(ConfigError, match=r"also names a motion-capture export \(mocap.file: t.csv\)"):
        bag_settings("s", {"bag": {**base, "camera_body": body, "board_body": body}, "mocap": {"file": "t.csv"}})
    with pytest.raises(ConfigError, match="names no topic"):
        bag_settings("s", {"bag": {"path": "x.bag"}})
    s = bag_settings("s", {"bag": {"path": "x.bag", "time": "receive", "camera_body": body,
                                   "board_body": {**body, "time": "header"}}})  # fmt: skip
    assert s["image"] is None and s["camera_body"]["time"] == "receive" and s["board_body"]["time"] == "header"


def test_init_on_a_damaged_bag_names_it_and_writes_nothing(tmp_path, capsys):
    bag = tmp_path / "cut.bag"
    bag.write_bytes(b"#ROSBAG V2.0\n" + b"\0" * 10)
    assert cli.main(["init", str(bag)]) == 1
    assert str(bag) in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.bag"]
