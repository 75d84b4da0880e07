"""cvsflow init on a recording of timestamped frames and pose streams (ASL/EuRoC, as yac's)."""

import cv2
import numpy as np
import yaml

from cvsflow import cli
from cvsflow.io.targets import read_target_board
from cvsflow.workflow.sessions import resolve_targets, session_stages
from tests.helpers.real_data import need_real_file

T0 = 1_606_153_863_000_000_000
TARGET = "target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n"


def _stream(path, t_ns, xyz):
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = [f"{t},{x},{y},{z},0.0,0.0,0.0,1.0" for t, (x, y, z) in zip(t_ns, xyz, strict=True)]
    path.write_text("timestamp [ns],x,y,z,qx,qy,qz,qw\n" + "\n".join(rows) + "\n")


def asl_recording(root, stream_start_ns=T0):
    """cam0 (5 frames over 2 s), body0 (a moving body at 20 Hz), target0 (a still one), a target."""
    (root / "cam0" / "data").mkdir(parents=True)
    t_frames = T0 + 500_000_000 + np.arange(5, dtype=np.int64) * 400_000_000
    for t in t_frames:
        cv2.imwrite(str(root / "cam0" / "data" / f"{t}.png"), np.full((48, 64), 128, np.uint8))
    (root / "cam0" / "data.csv").write_text("#timestamp [ns],filename\n" + "".join(f"{t},{t}.png\n" for t in t_frames))
    t_s = stream_start_ns + np.arange(60, dtype=np.int64) * 50_000_000
    k = np.arange(60)[:, None]
    _stream(root / "body0" / "data.csv", t_s, np.hstack([0.01 * k, 0.02 * k, np.ones_like(k)]))
    _stream(root / "target0" / "data.csv", t_s, np.tile([1.3, -0.4, 0.03], (60, 1)))
    (root / "target.yaml").write_text(TARGET)
    return root


def test_init_writes_a_frame_session_with_its_pose_streams(tmp_path, capsys):
    """The camera folder as frames, the moving stream as the camera's body and the still one as
    the board's, dt_offset_s 0 for one clock, se3 alone for few frames, the target file; the
    session runs every stage."""
    rec = asl_recording(tmp_path / "rec")
    out = tmp_path / "session.yaml"
    assert cli.main(["init", str(rec), "--out", str(out), "--name", "s"]) == 0
    cfg = yaml.safe_load(out.read_text())["sessions"]["s"]
    assert cfg["frames"] == str(rec) and cfg["calib_dir"] == str(rec / "cam0" / "data")
    assert cfg["pose_streams"] == {"camera": str(rec / "body0" / "data.csv"),
                                   "board": str(rec / "target0" / "data.csv")}
    assert cfg["dt_offset_s"] == 0.0 and cfg["methods"] == ["se3"] and cfg["target"] == str(rec / "target.yaml")
    assert "video" not in cfg and "mocap" not in cfg and "markers" not in cfg
    assert "one clock" in out.read_text() and "travels farthest" in capsys.readouterr().out
    sessions = resolve_targets({"s": cfg}, read_target_board)
    assert session_stages("s", sessions) == ("calibrate", "poses", "mocap", "pairs")


def test_init_on_streams_of_another_clock_leaves_the_offset_to_sync(tmp_path):
    """Pose streams that do not cover the frame times: no dt_offset_s, a note naming both spans."""
    rec = asl_recording(tmp_path / "rec", stream_start_ns=T0 + 3_600_000_000_000)
    out = tmp_path / "session.yaml"
    assert cli.main(["init", str(rec), "--out", str(out), "--name", "s"]) == 0
    cfg = yaml.safe_load(out.read_text())["sessions"]["s"]
    assert "dt_offset_s" not in cfg and "two clocks" in out.read_text()


def test_init_on_the_yac_recording(tmp_path):
    """yac's folder: its cam0, body0 as the camera's body, target0 as the board's, one clock,
    its Kalibr target file."""
    root = need_real_file("yac-mocap-aprilgrid/cam0/data.csv").parents[1]
    out = tmp_path / "yac.yaml"
    assert cli.main(["init", str(root), "--out", str(out), "--name", "yac"]) == 0
    cfg = yaml.safe_load(out.read_text())["sessions"]["yac"]
    assert cfg["pose_streams"] == {"camera": str(root / "body0" / "data.csv"),
                                   "board": str(root / "target0" / "data.csv")}
    assert cfg["dt_offset_s"] == 0.0 and cfg["target"].endswith("calib_mocap-intel_d435i.yaml")
    assert cfg["calib_dir"] == str(root / "cam0" / "data")
