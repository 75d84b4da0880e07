"""`cvsflow handeye --frames` and `--camera-poses`: timestamped frames or a camera pose stream with
the carrier's pose stream; handeye.yaml, the offset and what is not observable, bad input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from cvsflow.cli import main
from cvsflow.handeye.stream_sim import simulate_streams
from tests.helpers.handeye_sim import BOARD, CAMERA, T0, T_CM_C_TRUE, K, frames_session, write_stream
from tests.helpers.real_data import REAL_DATA


def _run(*argv):
    return main(["handeye", *map(str, argv)])


def test_camera_poses_gives_offset_mountings_and_split_half(tmp_path, capsys):
    """Simulated streams (ETH camera CSV, ASL motion capture) with a 30 ms offset: handeye.yaml
    holds dt within 4 of its std, T_Cm_C within 4 std, the split-half check and its rows."""
    sim = simulate_streams(21, duration_s=24.0)
    cam = write_stream(tmp_path / "cam.csv", sim["t_cam_ns"], sim["T_B_C"], "eth")
    moc = write_stream(tmp_path / "body.csv", sim["t_mocap_ns"], sim["T_W_Cm"], "asl")
    assert _run("--camera-poses", cam, "--poses", moc, "--out", tmp_path / "out") == 0
    res = yaml.safe_load((tmp_path / "out" / "handeye.yaml").read_text())
    assert res["camera_poses"]["format"] == "eth" and res["poses"]["format"] == "asl"
    assert abs(res["dt_offset_s"] - 0.03) < 4 * res["dt_offset_std_s"]
    err_mm = 1e3 * (np.array(res["T_Cm_C"])[:3, 3] - sim["T_Cm_C"][:3, 3])
    sd = res["std"]["T_Cm_C"]
    assert np.all(np.abs(err_mm) < 4 * np.array([sd["x_mm"], sd["y_mm"], sd["z_mm"]]))
    assert res["split_half"]["n"] == 13 and len(res["split_half"]["rows"]) == 13
    assert res["observability"]["dt"]["observable"] and res["std_inflated_by"] >= 1.0
    out = capsys.readouterr().out
    assert "(t_poses = t_camera + dt)" in out and "split-half check:" in out


def test_camera_poses_of_still_views_say_dt_is_not_observable(tmp_path, capsys):
    """30 still views seconds apart: dt_offset_s null in handeye.yaml with the reason, and the
    console says so; the hand-eye still comes out."""
    sim = simulate_streams(17, duration_s=60.0, still=True, n_gaps=0, dt_offset_s=0.0)
    t = (sim["t_cam_ns"] - sim["t_cam_ns"][0]) / 1e9
    pick = np.searchsorted(t, (np.arange(30) + 0.5) * 2.0)
    cam = write_stream(tmp_path / "cam.csv", sim["t_cam_ns"][pick], sim["T_B_C"][pick], "asl")
    moc = write_stream(tmp_path / "body.csv", sim["t_mocap_ns"], sim["T_W_Cm"], "asl")
    assert _run("--camera-poses", cam, "--poses", moc, "--out", tmp_path / "out", "--no-split-half") == 0
    res = yaml.safe_load((tmp_path / "out" / "handeye.yaml").read_text())
    assert res["dt_offset_s"] is None and res["dt_offset_std_s"] is None
    assert "nearly still" in res["observability"]["dt"]["reason"] and res["T_Cm_C"] is not None
    assert "dt_offset_s: not determined (" in capsys.readouterr().out


def test_camera_poses_bad_input_is_named(tmp_path, capsys):
    """A pose list where a stream is needed, and streams that do not overlap: one named line, no
    handeye.yaml."""
    sim = simulate_streams(23, duration_s=12.0)
    cam = write_stream(tmp_path / "cam.csv", sim["t_cam_ns"], sim["T_B_C"], "asl")
    moc = write_stream(tmp_path / "body.csv", sim["t_mocap_ns"] + 500 * 10**9, sim["T_W_Cm"], "asl")
    assert _run("--camera-poses", cam, "--poses", moc, "--pose-format", "visp", "--out", tmp_path / "o") == 1
    assert "--pose-format visp: the frames and camera-poses modes take a time-stamped pose stream" in (
        capsys.readouterr().err)
    assert _run("--camera-poses", cam, "--poses", moc, "--dt-offset-s", "0", "--out", tmp_path / "o") == 1
    err = capsys.readouterr().err
    assert "0 of" in err and "fall inside the motion capture" in err and "motion capture 1491" in err
    assert not (tmp_path / "o" / "handeye.yaml").exists()


def test_frames_with_a_pose_stream_and_intrinsics_from_the_frames(tmp_path):
    """Rendered frames named by ns + the carrier's ASL stream, no --camera: intrinsics calibrated
    from the frames (in handeye.yaml), T_Cm_C within 2 mm / 0.2 deg, the frame after the stream
    named and left out, the per-frame mocap-chain reprojection (and leave-one-out) recorded."""
    frames, poses = frames_session(tmp_path, extra_after_s=5.0)
    assert _run("--frames", frames, "--poses", poses, "--inner", "9x6", "--square-m", BOARD["square_m"],
                "--out", tmp_path / "out", "--exact-poses") == 0  # fmt: skip
    res = yaml.safe_load((tmp_path / "out" / "handeye.yaml").read_text())
    assert res["intrinsics"]["calibration"]["source"] == "calibrated from the same frames"
    assert abs(res["intrinsics"]["K"][0][0] - K[0, 0]) < 3.0
    e_mm = 1e3 * np.linalg.norm(np.array(res["T_Cm_C"])[:3, 3] - T_CM_C_TRUE[:3, 3])
    assert e_mm < 2.0
    outside = [f for f in res["frames"] if f["reason"] == "outside the pose stream"]
    assert len(outside) == 1 and res["frame_counts"]["n_outside_stream"] == 1
    used = [s for s in res["stills"] if s["used"]]
    assert len(used) == 14 and all(s["chain_rms_px"] < 1.0 and s["chain_rms_loo_px"] < 1.5 for s in used)
    assert (tmp_path / "out" / "handeye_views.png").stat().st_size > 0  # those numbers as a figure
    assert res["dt_offset_s"] is None and "held at 0 s" in res["observability"]["dt"]["reason"]


def test_frames_given_known_intrinsics_and_offset(tmp_path):
    """--camera and --dt-offset-s: the offset is held as given and said so."""
    frames, poses = frames_session(tmp_path, n=10)
    cam = tmp_path / "camera.yaml"
    cam.write_text(yaml.safe_dump({"K": K.tolist(), "dist": [0.0] * 5, "width": 640, "height": 480}))
    assert _run("--frames", frames, "--poses", poses, "--inner", "9x6", "--square-m", BOARD["square_m"],
                "--camera", cam, "--dt-offset-s", "0", "--out", tmp_path / "out") == 0  # fmt: skip
    res = yaml.safe_load((tmp_path / "out" / "handeye.yaml").read_text())
    assert res["dt_used_s"] == 0.0 and res["observability"]["dt"]["reason"].startswith("given (0 s)")
    assert np.linalg.norm(np.array(res["T_Cm_C"])[:3, 3] - T_CM_C_TRUE[:3, 3]) < 2e-3
    assert CAMERA["K"][0, 0] == res["intrinsics"]["K"][0][0]


def test_frames_without_timestamps_is_named(tmp_path, capsys):
    """A frame folder named by frame numbers: one named line, no handeye.yaml."""
    d = tmp_path / "frames"
    d.mkdir()
    cv2.imwrite(str(d / "0001.png"), np.zeros((48, 64), np.uint8))
    poses = write_stream(tmp_path / "body.csv", T0 + np.arange(3) * 10**7, np.stack([np.eye(4)] * 3), "asl")
    assert _run("--frames", d, "--poses", poses, "--inner", "9x6", "--square-m", "0.02", "--out", tmp_path / "o") == 1
    assert "carry no timestamp in their name" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_yac_frames_with_the_aprilgrid(tmp_path):
    """yac: 30 AprilGrid frames (csv naming .png for .jpg files) and the camera body's ASL stream,
    intrinsics from the frames: dt not observable (stills, the camera nearly still at each) and
    said so; T_W_B in Kalibr's grid frame near the target body (axes within 1 deg); the
    mocap-chain reprojection per frame with its leave-one-out figure."""
    yac = REAL_DATA / "yac-mocap-aprilgrid"
    if not (yac / "cam0" / "data.csv").is_file():
        pytest.skip(f"real data not available ({yac})")
    assert _run("--frames", yac / "cam0", "--poses", yac / "body0" / "data.csv", "--target",
                yac / "calib_mocap-intel_d435i.yaml", "--out", tmp_path / "out") == 0  # fmt: skip
    res = yaml.safe_load((tmp_path / "out" / "handeye.yaml").read_text())
    assert res["dt_offset_s"] is None and "nearly still" in res["observability"]["dt"]["reason"]
    assert res["frame_counts"]["n_frames"] == 30 and res["n_used"] >= 25
    used = [s for s in res["stills"] if s["used"]]
    assert all(s["chain_rms_loo_px"] < 5.0 for s in used)
    assert np.median([s["chain_rms_loo_px"] for s in used]) < 2.0
