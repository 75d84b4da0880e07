"""`cvsflow handeye --bag`: the frames of an image topic and the carrier's pose topic of a ROS bag
give the result the same frames and poses give from a frame folder and a pose file; bad input."""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml

from cvsflow.cli import main
from cvsflow.handeye.stream_sim import simulate_streams
from tests.helpers.bags import JPEG_TOPIC, Msg, read_csv_rows, write_bag, yac_messages
from tests.helpers.handeye_sim import BOARD, frames_session, write_stream
from tests.helpers.real_data import REAL_DATA

#: What handeye.yaml records of its input (names, paths): the rest must be equal.
INPUT_KEYS = {"input", "frames_dir", "frames_layout", "bag", "image_topic", "bag_time", "poses", "pose_stream",
              "frames", "stills", "frames_undecodable", "camera_poses"}  # fmt: skip


def _run(*argv):
    return main(["handeye", *map(str, argv)])


def _bag_of(frames, poses, path, storage):
    """The frame folder's PNG files as CompressedImage (bytes unchanged) and the ASL stream as
    PoseStamped in frame world, header stamps the files' ns."""
    msgs = [Msg(int(p.stem), "/cam/image/compressed", "sensor_msgs/msg/CompressedImage",
                {"t_ns": int(p.stem), "frame_id": "cam", "format": "png", "data": p.read_bytes()})
            for p in sorted(frames.glob("*.png"))]  # fmt: skip
    msgs += [Msg(t, "/vicon/carrier/pose", "geometry_msgs/msg/PoseStamped", {"t_ns": t, "frame_id": "world", "v": v})
             for t, v in read_csv_rows(poses)]  # fmt: skip
    return write_bag(path, storage, msgs)


def _same_result(a, b):
    """handeye.yaml of a and b equal but for the input's record; a frame folder's file names
    (``<ns>.png``, ``.jpg``) are a bag's frame names (``<ns>``) where warnings name frames."""
    ra, rb = (yaml.safe_load((d / "handeye.yaml").read_text()) for d in (a, b))
    text_a, text_b = (yaml.safe_dump({k: v for k, v in r.items() if k not in INPUT_KEYS}, width=float("inf"))
                      for r in (ra, rb))  # one line per value: names of two lengths wrap apart
    assert re.sub(r"(\d{19})\.(png|jpg)", r"\1", text_a) == text_b
    assert [f["reason"] for f in ra["frames"]] == [f["reason"] for f in rb["frames"]]
    return ra, rb


@pytest.mark.parametrize("storage", ["ros1", "mcap"])
def test_bag_gives_the_result_of_the_frame_folder_and_pose_file(tmp_path, storage, capsys):
    """Rendered frames (PNG) and the carrier's 100 Hz stream, as files and as a bag: handeye.yaml
    equal but for the input's record, T_Cm_C bit for bit; the bag's topics are recorded."""
    frames, poses = frames_session(tmp_path, n=10, extra_after_s=5.0)
    bag = _bag_of(frames, poses, tmp_path / "rec", storage)
    board = ("--inner", "9x6", "--square-m", BOARD["square_m"], "--exact-poses")
    assert _run("--frames", frames, "--poses", poses, *board, "--out", tmp_path / "files") == 0
    assert _run("--bag", bag, "--image-topic", "/cam/image/compressed", "--pose-topic", "/vicon/carrier/pose",
                "--pose-parent", "world", *board, "--out", tmp_path / "bag") == 0  # fmt: skip
    files, from_bag = _same_result(tmp_path / "files", tmp_path / "bag")
    assert files["T_Cm_C"] is not None and from_bag["input"] == "bag"
    assert from_bag["image_topic"] == "/cam/image/compressed" and from_bag["bag_time"] == "header"
    assert "/vicon/carrier/pose" in from_bag["poses"] and from_bag["pose_stream"]["format"] == "rosbag"
    assert [f["name"] for f in from_bag["frames"]] == [p.stem for p in sorted(frames.glob("*.png"))]
    out = capsys.readouterr().out
    assert out.count("T_Cm_C: t = [") == 2


def test_zero_stamps_name_the_receive_time_flag_which_reads_them(tmp_path, capsys):
    """A camera that leaves its header stamps at zero: the error names --receive-time; with it the
    frames are read at their receive times (here the files' ns), the result as from the files."""
    frames, poses = frames_session(tmp_path, n=10)
    msgs = [Msg(int(p.stem), "/cam/image/compressed", "sensor_msgs/msg/CompressedImage",
                {"t_ns": 0, "frame_id": "cam", "format": "png", "data": p.read_bytes()})
            for p in sorted(frames.glob("*.png"))]  # fmt: skip
    msgs += [Msg(t, "/carrier", "geometry_msgs/msg/PoseStamped", {"t_ns": t, "frame_id": "world", "v": v})
             for t, v in read_csv_rows(poses)]  # fmt: skip
    bag = write_bag(tmp_path / "zero", "sqlite3", msgs)
    argv = ("--bag", bag, "--image-topic", "/cam/image/compressed", "--pose-topic", "/carrier", "--inner", "9x6",
            "--square-m", BOARD["square_m"], "--exact-poses", "--dt-offset-s", "0")  # fmt: skip
    assert _run(*argv, "--out", tmp_path / "header") == 1
    err = capsys.readouterr().err
    assert "/cam/image/compressed, message 0:" in err and "is zero" in err and "--receive-time" in err
    assert not (tmp_path / "header").exists()
    assert _run(*argv, "--receive-time", "--out", tmp_path / "receive") == 0
    assert _run("--frames", frames, "--poses", poses, *argv[6:], "--out", tmp_path / "files") == 0
    _same_result(tmp_path / "files", tmp_path / "receive")


def test_bag_bad_input_is_named_and_writes_nothing(tmp_path, capsys):
    """Bag options without --bag, --bag without --image-topic, no pose source, both, a topic the
    bag lacks (its topics listed): one named line each, no output folder."""
    frames, poses = frames_session(tmp_path, n=3)
    bag = _bag_of(frames, poses, tmp_path / "rec", "ros1")
    board = ("--inner", "9x6", "--square-m", "0.0236", "--out", tmp_path / "o")
    cases = [
        (("--frames", frames, "--image-topic", "/c", "--poses", poses), "--image-topic: topics and frames of a ROS bag"),
        (("--bag", bag, "--pose-topic", "/p"), f"--bag {bag}: expected --image-topic"),
        (("--bag", bag, "--image-topic", "/c", "--camera-pose-topic", "/d", "--pose-topic", "/p"),
         "or --camera-pose-topic (the camera's pose in the target frame), one of them"),
        (("--bag", bag, "--image-topic", "/c"), "--poses: the carrier's poses are required"),
        (("--bag", bag, "--image-topic", "/c", "--pose-topic", "/p", "--poses", poses), "--poses and --pose-topic"),
        (("--bag", bag, "--image-topic", "/cam/image", "--pose-topic", "/vicon/carrier/pose"),
         "/cam/image/compressed"),
    ]  # fmt: skip
    for argv, message in cases:
        assert _run(*argv, *board) == 1
        err = capsys.readouterr().err
        assert message in err, err
        assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_yac_bag_gives_the_result_of_the_yac_files(tmp_path):
    """yac: the 30 JPEG frames (bytes unchanged) and body0's stream written by rosbags (sqlite3)
    give the --frames result from cam0/ and body0/data.csv."""
    yac = REAL_DATA / "yac-mocap-aprilgrid"
    if not (yac / "cam0" / "data.csv").is_file():
        pytest.skip(f"real data not available ({yac})")
    bag = write_bag(tmp_path / "yac", "sqlite3", yac_messages(yac, raw=False, tf=False))
    target = ("--target", yac / "calib_mocap-intel_d435i.yaml")
    assert _run("--frames", yac / "cam0", "--poses", yac / "body0" / "data.csv", *target, "--out", tmp_path / "f") == 0
    assert _run("--bag", bag, "--image-topic", JPEG_TOPIC, "--pose-topic", "/mocap/body0/pose", *target,
                "--out", tmp_path / "b") == 0  # fmt: skip
    files, _ = _same_result(tmp_path / "f", tmp_path / "b")
    assert files["frame_counts"]["n_frames"] == 30 and np.isfinite(np.array(files["T_W_B"], float)).all()


def test_camera_pose_topic_gives_the_camera_poses_result(tmp_path):
    """The camera-poses mode on a bag: the detector's camera poses and the marker body's as two
    PoseStamped topics give the result of the same streams as files (30 ms offset estimated)."""
    sim = simulate_streams(21, duration_s=24.0)
    cam = write_stream(tmp_path / "cam.csv", sim["t_cam_ns"], sim["T_B_C"], "asl")
    moc = write_stream(tmp_path / "body.csv", sim["t_mocap_ns"], sim["T_W_Cm"], "asl")
    msgs = [Msg(t, topic, "geometry_msgs/msg/PoseStamped", {"t_ns": t, "frame_id": frame, "v": v})
            for path, topic, frame in ((cam, "/detector/pose", "board"), (moc, "/vicon/body/pose", "world"))
            for t, v in read_csv_rows(path)]  # fmt: skip
    bag = write_bag(tmp_path / "rec", "mcap", msgs)
    assert _run("--camera-poses", cam, "--poses", moc, "--no-split-half", "--out", tmp_path / "files") == 0
    assert _run("--bag", bag, "--camera-pose-topic", "/detector/pose", "--pose-topic", "/vicon/body/pose",
                "--no-split-half", "--out", tmp_path / "bag") == 0  # fmt: skip
    files, from_bag = (yaml.safe_load((tmp_path / d / "handeye.yaml").read_text()) for d in ("files", "bag"))
    assert {k: v for k, v in files.items() if k not in INPUT_KEYS} == {
        k: v for k, v in from_bag.items() if k not in INPUT_KEYS}
    assert abs(files["dt_offset_s"] - 0.03) < 4 * files["dt_offset_std_s"]
    assert from_bag["camera_poses"]["format"] == "rosbag" and "/detector/pose" in from_bag["camera_poses"]["path"]
