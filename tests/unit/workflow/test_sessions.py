"""resolve_targets: a session's Kalibr target file read into its board before any rule sees it."""

import pytest

from cvsflow.exceptions import ConfigError
from cvsflow.io.targets import read_target_board
from cvsflow.workflow.sessions import expand_rig_sessions, resolve_targets, session_stages


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
    rig = {"target": str(path), "vicon": "v.csv", "markers": {"camera": {}, "board": {}},
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
