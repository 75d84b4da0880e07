"""cvsflow init on a camera-pose stream and its marker body's stream (ETH ASL's hand-eye sets): a
session with camera_poses and pose_streams, which file is which read from the content."""

import numpy as np
import yaml

from cvsflow import cli
from cvsflow.geometry import R_from_rvec, make_T
from cvsflow.handeye import simulate_streams
from cvsflow.workflow.sessions import camera_poses_settings, session_stages
from tests.helpers.handeye_sim import write_stream
from tests.helpers.real_data import need_real_file


def _recording(root):
    """A camera-pose stream (ETH CSV), its body's Vicon stream and another body's (ASL). The body's
    frame is turned half about its x axis (a mounting like any other) so that the world's origin
    lies behind it: a body's stream is then no candidate for the camera's poses."""
    root.mkdir()
    sim, other = simulate_streams(8, duration_s=20.0), simulate_streams(9, duration_s=20.0)
    write_stream(root / "cam_W_camera.csv", sim["t_cam_ns"], sim["T_B_C"], "eth")
    flip = make_T(R_from_rvec(np.array([np.pi, 0.0, 0.0])), np.zeros(3))
    write_stream(root / "vicon_camera.csv", sim["t_mocap_ns"], sim["T_W_Cm"] @ flip, "asl")
    write_stream(root / "vicon_other.csv", sim["t_mocap_ns"], other["T_W_Cm"], "asl")
    return root


def test_init_on_a_folder_finds_the_camera_poses_and_their_body(tmp_path, capsys):
    """The stream with the target in front of the camera in every row is camera_poses, the body
    whose rotation follows it pose_streams.camera; the session is one the workflow runs."""
    rec = _recording(tmp_path / "rec")
    out = tmp_path / "s.yaml"
    assert cli.main(["init", str(rec), "--out", str(out), "--name", "s"]) == 0
    s = yaml.safe_load(out.read_text())["sessions"]["s"]
    assert s == {"camera_poses": str(rec / "cam_W_camera.csv"), "pose_streams": {"camera": str(rec / "vicon_camera.csv")}}
    assert session_stages("s", {"s": s}) == ("camera_poses", "mocap", "pose_fit")
    assert camera_poses_settings("s", s)["format"] == "auto"
    printed = capsys.readouterr().out
    assert "its angular speed follows the camera's with quality" in printed and "no board body" in printed


def test_init_on_a_camera_pose_file_and_on_a_body_file(tmp_path, capsys):
    """A camera-pose CSV given as the recording: the session beside it (name from the file); a
    body's stream given instead is refused, saying why, and nothing is written."""
    rec = _recording(tmp_path / "rec")
    assert cli.main(["init", str(rec / "cam_W_camera.csv")]) == 0
    out = rec / "cam_W_camera_session.yaml"
    s = yaml.safe_load(out.read_text())["sessions"]["cam_W_camera"]
    assert s["pose_streams"]["camera"] == str(rec / "vicon_camera.csv")
    assert cli.main(["init", str(rec / "vicon_camera.csv"), "--out", str(tmp_path / "b.yaml")]) == 1
    err = capsys.readouterr().err
    assert "the target is in front of the camera in" in err and "is it a motion-capture body's stream?" in err
    assert not (tmp_path / "b.yaml").exists()


def test_init_tells_the_body_from_its_inverse_by_the_hand_eye_fit(tmp_path, capsys):
    """A body's stream and its inverse (the world in the body, as some exports write it) turn at
    the same angular speed, so the speed alone cannot choose; the hand-eye fit can: a constant
    mounting fits the body, not its inverse. The inverse sorts last by name, where a tie on
    quality alone would take it."""
    rec = _recording(tmp_path / "rec")
    sim = simulate_streams(8, duration_s=20.0)
    flip = make_T(R_from_rvec(np.array([np.pi, 0.0, 0.0])), np.zeros(3))
    write_stream(rec / "z_inverse.csv", sim["t_mocap_ns"], np.linalg.inv(sim["T_W_Cm"] @ flip), "asl")
    out = tmp_path / "s.yaml"
    assert cli.main(["init", str(rec / "cam_W_camera.csv"), "--out", str(out), "--name", "s"]) == 0
    s = yaml.safe_load(out.read_text())["sessions"]["s"]
    assert s["pose_streams"]["camera"] == str(rec / "vicon_camera.csv")
    printed = capsys.readouterr().out
    assert "follow the camera's rotation about as well" in printed and "took vicon_camera.csv" in printed


def test_init_on_eth_prime_sense_1(tmp_path):
    """ETH's prime_sense_1 folder: the camera's poses and its Vicon body, by content."""
    cam = need_real_file("ethz-hand-eye/prime_sense_color_w_vicon_1/prime_sense_1/"
                         "2017-04-09-18-13-10_W_camera_rgb_image_raw.csv")  # fmt: skip
    out = tmp_path / "ps1.yaml"
    assert cli.main(["init", str(cam.parent), "--out", str(out), "--name", "ps1"]) == 0
    s = yaml.safe_load(out.read_text())["sessions"]["ps1"]
    assert s["camera_poses"] == str(cam) and s["pose_streams"]["camera"].endswith("_vicon_prime_sense.csv")


def test_init_on_eth_5_falcon_takes_the_body_a_mounting_fits(tmp_path, capsys):
    """ETH's 5_falcon: two Vicon streams (falcon_vicon, vicon_falcon) follow the camera's angular
    speed equally; the one a constant mounting fits is the camera's body."""
    cam = need_real_file("ethz-hand-eye/5_falcon/5_falcon_merged-2017-04-07-12-36-38_W_d.csv")
    out = tmp_path / "f.yaml"
    assert cli.main(["init", str(cam), "--out", str(out), "--name", "f"]) == 0
    s = yaml.safe_load(out.read_text())["sessions"]["f"]
    assert s["pose_streams"]["camera"].endswith("_vicon_falcon-2017-04-07-12-36-38.csv")
    assert "took 5_falcon_merged_vicon_falcon" in capsys.readouterr().out
