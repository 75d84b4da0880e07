"""cvsflow.workflow.sessions: what each session runs, a Kalibr target file read into its board, and the keys
renamed since the first release."""

import copy

import pytest

from cvsflow.exceptions import ConfigError
from cvsflow.io.targets import read_target_board
from cvsflow.workflow.sessions import (
    camera_poses_settings,
    check_sessions,
    expand_rig_sessions,
    mocap_file,
    resolve_targets,
    session_stages,
    upgrade_config,
)


def test_target_file_becomes_the_board(tmp_path):
    """target: FILE gives the session the file's board; a session without one is the same object."""
    path = tmp_path / "april.yaml"
    path.write_text("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n")
    plain = {"calib_dir": "stills", "board": {"squares_x": 6, "squares_y": 5, "square_m": 0.09}}
    sessions = {"a": {"calib_dir": "stills", "target": str(path)}, "b": plain}
    out = resolve_targets(sessions, read_target_board)
    assert out["a"]["board"] == {"type": "aprilgrid", "tag_cols": 6, "tag_rows": 6, "tag_size_m": 0.088,
                                 "tag_spacing": 0.3}
    assert out["a"]["target"] == str(path) and "board" not in sessions["a"] and out["b"] is plain
    assert session_stages("a", out) == ("calibrate",)


def test_rig_cameras_get_the_targets_board(tmp_path):
    """A rig session's target reaches every camera's session."""
    path = tmp_path / "checker.yaml"
    path.write_text("target_type: checkerboard\ntargetCols: 9\ntargetRows: 6\n"
                    "rowSpacingMeters: 0.025\ncolSpacingMeters: 0.025\n")
    rig = {"target": str(path), "mocap": {"file": "v.csv"}, "markers": {"camera": {}, "board": {}},
           "cameras": [{"name": "a", "calib_dir": "a", "video": "a.mp4"},
                       {"name": "b", "calib_dir": "b", "video": "b.mp4"}]}
    plain, _ = expand_rig_sessions(resolve_targets({"r": rig}, read_target_board))
    assert plain["r-a"]["board"] == plain["r-b"]["board"] == {"squares_x": 10, "squares_y": 7,
                                                              "square_m": 0.025}


def test_bad_targets_name_the_session_and_file(tmp_path):
    """Board and target together, a missing file, an unsupported type: ConfigErrors naming the
    session's key and the file."""
    board = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
    with pytest.raises(ConfigError, match="sessions.s.target: .*board or target"):
        resolve_targets({"s": {"target": "t.yaml", "board": board}}, read_target_board)
    with pytest.raises(ConfigError, match="sessions.s.target: .*missing.yaml: file not found"):
        resolve_targets({"s": {"target": str(tmp_path / "missing.yaml")}}, read_target_board)
    path = tmp_path / "circles.yaml"
    path.write_text("target_type: circlegrid\ntargetCols: 6\ntargetRows: 7\nspacingMeters: 0.02\n")
    with pytest.raises(ConfigError, match=f"sessions.s.target: {path}: target_type='circlegrid'"):
        resolve_targets({"s": {"target": str(path)}}, read_target_board)


def test_aprilgrid_board_block_is_checked_with_the_session(tmp_path):
    """An AprilGrid board with a bad value stops the session's check, naming the session."""
    board = {"type": "aprilgrid", "tag_cols": 6, "tag_rows": 6, "tag_size_m": 0.088, "tag_spacing": 3.0}
    with pytest.raises(ConfigError, match="sessions.s.board: AprilGrid: tag_spacing=3.0"):
        session_stages("s", {"s": {"calib_dir": "x", "board": board}})


SESSION = {
    "calib_dir": "rec/calib", "video": "rec/board.mp4", "mocap": {"file": "rec/take.csv"},
    "board": {"squares_x": 6, "squares_y": 5, "square_m": 0.09},
    "markers": {"camera": {"names": ["c1", "c2", "c3"]}, "board": {"names": ["b1", "b2", "b3"]}},
}


def test_a_full_session_runs_every_stage():
    """Stills, a video and a mocap export with markers run calibrate, poses, mocap and pairs."""
    assert check_sessions({"lab": SESSION})["lab"] == ("calibrate", "poses", "mocap", "pairs")


def test_an_export_without_markers_names_what_to_add():
    """mocap.file without markers stops with a message naming markers.camera.names."""
    s = copy.deepcopy(SESSION)
    del s["markers"]
    with pytest.raises(ConfigError, match=r"sessions\.lab: names a motion-capture export but no markers"):
        check_sessions({"lab": s})


def test_old_vicon_keys_are_read_as_the_new_ones_with_a_warning():
    """sessions.<s>.vicon, the top-level vicon block and synth.vicon_lead_s become mocap.file,
    mocap and synth.mocap_lead_s; each rename is one warning naming both keys."""
    config = {"vicon": {"max_gap_s": 0.2},
              "sessions": {"lab": {"vicon": "take.csv", "mocap": {"format": "motive_csv"}},
                           "demo": {"synth": {"vicon_lead_s": 2.0}}}}
    notes = upgrade_config(config)
    assert config["mocap"] == {"max_gap_s": 0.2} and "vicon" not in config
    assert config["sessions"]["lab"]["mocap"] == {"format": "motive_csv", "file": "take.csv"}
    assert mocap_file(config["sessions"]["lab"]) == "take.csv"
    assert config["sessions"]["demo"]["synth"] == {"mocap_lead_s": 2.0}
    assert len(notes) == 3
    assert any("sessions.lab.vicon is deprecated, use sessions.lab.mocap.file" in n for n in notes)


def test_a_key_given_under_both_names_is_refused():
    """vicon and mocap.file both set: the config says which to keep instead of picking one."""
    config = {"sessions": {"lab": {"vicon": "a.csv", "mocap": {"file": "b.csv"}}}}
    with pytest.raises(ConfigError, match=r"both sessions\.lab\.vicon \(deprecated\) and sessions\.lab\.mocap\.file"):
        upgrade_config(config)


def test_a_config_with_only_new_keys_is_left_as_it_is():
    """No old key: nothing changes and nothing is said."""
    config = {"mocap": {"max_gap_s": 0.1}, "sessions": {"lab": copy.deepcopy(SESSION)}}
    before = copy.deepcopy(config)
    assert upgrade_config(config) == [] and config == before


def test_frame_folder_and_pose_streams_run_every_stage():
    """frames (instead of video) and pose_streams (instead of mocap.file + markers) give a
    session all stages; naming both a video and frames, or an export and pose streams, is
    refused; frames without a camera say what to add."""
    board = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
    streams = {"camera": "body0.csv", "board": "target0.csv"}
    s = {"board": board, "calib_dir": "cam0/data", "frames": "cam0", "pose_streams": streams}
    assert session_stages("s", {"s": s}) == ("calibrate", "poses", "mocap", "pairs")
    with pytest.raises(ConfigError, match="sessions.s: names both video and frames"):
        session_stages("s", {"s": {**s, "video": "v.mp4"}})
    with pytest.raises(ConfigError, match="sessions.s: names both mocap.file and pose_streams"):
        session_stages("s", {"s": {**s, "mocap": {"file": "v.csv"}}})
    with pytest.raises(ConfigError, match=r"names a frame folder \(cam0\) but no calib_dir"):
        session_stages("s", {"s": {"board": board, "frames": "cam0", "pose_streams": streams}})


def test_a_bag_session_runs_every_stage_from_its_topics():
    """A bag's image topic (instead of video or frames) and its two body topics (instead of an
    export and markers) give every stage; the bag's image beside frames, its bodies beside pose
    streams, or an image topic without a camera are refused, naming the key."""
    board = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
    body = {"topic": "/mocap/body0/pose", "parent": "world"}
    bag = {"path": "rec.bag", "image_topic": "/cam0/image_raw", "camera_body": body, "board_body": body}
    s = {"board": board, "calib_dir": "cam0/data", "bag": bag}
    assert session_stages("s", {"s": s}) == ("calibrate", "poses", "mocap", "pairs")
    images_only = {**s, "bag": {"path": "rec.bag", "image_topic": "/cam0/image_raw"}}
    assert session_stages("s", {"s": images_only}) == ("calibrate", "poses")
    with pytest.raises(ConfigError, match=r"sessions.s.bag.image_topic: the session also names frames \(cam0\)"):
        session_stages("s", {"s": {**s, "frames": "cam0"}})
    with pytest.raises(ConfigError, match="sessions.s.bag: camera_body and board_body, and the session also "
                                          "names pose_streams"):  # fmt: skip
        session_stages("s", {"s": {**s, "pose_streams": {"camera": "a.csv", "board": "b.csv"}}})
    with pytest.raises(ConfigError, match=r"names a bag's image topic \(/cam0/image_raw\) but no calib_dir"):
        session_stages("s", {"s": {"board": board, "bag": bag}})


def test_a_camera_pose_session_runs_its_own_stages():
    """camera_poses (a detector's stream instead of images) with the camera body's pose stream,
    the board's optional: stages camera_poses, mocap, pose_fit; the plain path and the
    {file, format} block read alike."""
    streams = {"camera": "vicon.csv"}
    s = {"camera_poses": "cam.csv", "pose_streams": streams}
    assert session_stages("s", {"s": s}) == ("camera_poses", "mocap", "pose_fit")
    moving = {**s, "camera_poses": {"file": "cam.csv", "format": "eth"},
              "pose_streams": {"camera": "vicon.csv", "board": "b.csv"}}  # fmt: skip
    assert session_stages("s", {"s": moving}) == ("camera_poses", "mocap", "pose_fit")
    assert camera_poses_settings("s", s) == {"file": "cam.csv", "format": "auto"}
    assert camera_poses_settings("s", moving) == {"file": "cam.csv", "format": "eth"}
    assert camera_poses_settings("s", {"board": {}}) is None


@pytest.mark.parametrize("key, value, message", [
    ("video", "v.mp4", "names camera_poses and video; expected one camera input"),
    ("frames", "cam0", "names camera_poses and frames; expected one camera input"),
    ("calib_dir", "stills", "names camera_poses and calib_dir; a camera-pose stream needs no intrinsics"),
    ("camera", "other", "names camera_poses and camera; a camera-pose stream needs no intrinsics"),
    ("board", {"squares_x": 6, "squares_y": 5, "square_m": 0.09}, "names camera_poses and board; the "
     "stream's poses are already in the target's frame"),
    ("target", "target.yaml", "names camera_poses and target"),
    ("methods", ["se3"], "names camera_poses and methods; the session is fitted by the pose-level fit"),
])  # fmt: skip
def test_a_camera_pose_session_naming_images_or_a_board_is_refused(key, value, message):
    """Every input a camera-pose session names must be used: images, stills, a camera, a board or
    methods beside camera_poses stop the run before any job, naming both keys."""
    s = {"camera_poses": "cam.csv", "pose_streams": {"camera": "vicon.csv"}, key: value}
    with pytest.raises(ConfigError, match=f"config: sessions.s: {message}"):
        session_stages("s", {"s": s})


def test_a_camera_pose_session_needs_the_camera_body_and_only_it_may_drop_the_board():
    """Without any motion capture the message says what to add; a frame session's pose streams
    still need the board's stream; a bag's image topic is a second camera input."""
    with pytest.raises(ConfigError, match=r"names camera_poses but no motion capture of the camera's "
                                          r"marker body; expected pose_streams: \{camera: FILE\}"):  # fmt: skip
        session_stages("s", {"s": {"camera_poses": "cam.csv"}})
    board = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
    frames = {"board": board, "calib_dir": "cam0/data", "frames": "cam0", "pose_streams": {"camera": "a.csv"}}
    with pytest.raises(ConfigError, match="sessions.s.pose_streams: no board stream; expected board: FILE"):
        session_stages("s", {"s": frames})
    bag = {"camera_poses": "cam.csv", "pose_streams": {"camera": "a.csv"},
           "bag": {"path": "r.bag", "image_topic": "/cam0/image_raw"}}  # fmt: skip
    with pytest.raises(ConfigError, match="names camera_poses and bag.image_topic"):
        session_stages("s", {"s": bag})
    with pytest.raises(ConfigError, match="sessions.s.camera_poses: no file"):
        camera_poses_settings("s", {"camera_poses": {"file": ""}})


def test_the_schema_takes_a_camera_pose_session_without_a_board():
    """The schema accepts camera_poses without board or target (a path or {file, format}) and
    pose_streams without board; it still refuses board and target together and an unknown format."""
    from pathlib import Path

    import yaml
    from snakemake.utils import validate

    repo = Path(__file__).resolve().parents[3]
    schema = str(repo / "cvsflow" / "workflow" / "schemas" / "config.schema.yaml")
    config = yaml.safe_load((repo / "config" / "config.yaml").read_text())
    config["sessions"] = {"eth": {"camera_poses": "cam.csv", "pose_streams": {"camera": "vicon.csv"}},
                          "eth2": {"camera_poses": {"file": "cam.csv", "format": "eth"},
                                   "pose_streams": {"camera": "vicon.csv"}, "dt_offset_s": 0.02}}  # fmt: skip
    validate(config, schema)
    assert set(check_sessions(config["sessions"])["eth"]) == {"camera_poses", "mocap", "pose_fit"}
    bad = copy.deepcopy(config)
    bad["sessions"]["eth"]["camera_poses"] = {"file": "cam.csv", "format": "visp"}
    with pytest.raises(Exception, match="camera_poses"):
        validate(bad, schema)
    both = copy.deepcopy(config)
    both["sessions"]["eth"].update(board={"squares_x": 6, "squares_y": 5, "square_m": 0.09}, target="t.yaml")
    with pytest.raises(Exception, match="board"):
        validate(both, schema)
