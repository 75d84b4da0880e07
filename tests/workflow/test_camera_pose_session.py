"""A workflow session whose camera input is a camera-pose stream (camera_poses): simulated
streams with known truth through sync, the pose-level fit and the held-out evaluation; ETH's
prime_sense_1 as such a session against `cvsflow handeye --camera-poses` on the same files
(skips without the shared real data); a stream that misses the motion capture stops by name;
the camera body from a marker export instead of a pose stream."""

from __future__ import annotations

import numpy as np
import pandas as pd
import yaml

from cvsflow.cli import main
from cvsflow.geometry import R_from_rvec, invert_T, make_T, rotation_angle, transform_points
from cvsflow.handeye import simulate_streams
from cvsflow.io.mocap.vicon import write_nexus_csv
from tests.helpers.handeye_sim import write_stream
from tests.helpers.mocap_markers import BOARD_LAYOUT_M, BOARD_NAMES, CAMERA_LAYOUT_M, CAMERA_NAMES
from tests.helpers.real_data import need_real_file
from tests.workflow.test_workflow import snakemake, write_config

PS1 = "ethz-hand-eye/prime_sense_color_w_vicon_1/prime_sense_1"
OUTPUTS = ("results/s/pose_fit/result.yaml", "results/s/heldout/pose_fit.yaml", "results/headline.csv")


def _std_mm(rec, name):
    sd = rec["std"][name]
    return np.array([sd["x_mm"], sd["y_mm"], sd["z_mm"]])


def test_simulated_camera_pose_session_end_to_end(tmp_path):
    """No board, stills or video: the stream is the poses table (exact ns), the board body is the
    world; sync finds the 30 ms offset, the fit gives dt, T_Cm_C and T_Bm_B within 4 stated
    errors of the truth, and every frame is scored held-out with a stated per-frame uncertainty."""
    sim = simulate_streams(5, duration_s=30.0)
    cam = write_stream(tmp_path / "cam.csv", sim["t_cam_ns"], sim["T_B_C"], "eth")
    moc = write_stream(tmp_path / "vicon.csv", sim["t_mocap_ns"], sim["T_W_Cm"], "asl")
    write_config(tmp_path, {"sessions": {"s": {"camera_poses": {"file": str(cam), "format": "eth"},
                                               "pose_streams": {"camera": str(moc)}}},
                            "evaluate": {"n_boot": 100}})  # fmt: skip
    snakemake(tmp_path, *OUTPUTS)
    res = tmp_path / "results" / "s"
    poses = pd.read_parquet(res / "poses_raw.parquet")
    assert (poses["t_ns"].to_numpy() == sim["t_cam_ns"]).all() and poses["valid"].all()
    assert not (res / "corners.parquet").exists() and not (res / "camera.yaml").exists()
    sync = yaml.safe_load((res / "sync.yaml").read_text())
    assert sync["method"] == "pose_streams" and abs(sync["dt_offset_s"] - 0.03) < 0.01
    assert sync["details"]["refined"]["dt_s"] == sync["dt_offset_s"]
    fit = yaml.safe_load((res / "pose_fit" / "result.yaml").read_text())
    assert abs(fit["dt_offset_s"] - 0.03) < 4 * fit["dt_offset_std_s"]
    err_mm = 1e3 * (np.array(fit["T_Cm_C"])[:3, 3] - sim["T_Cm_C"][:3, 3])
    assert np.all(np.abs(err_mm) < 4 * _std_mm(fit, "T_Cm_C"))
    err_mm = 1e3 * (np.array(fit["T_Bm_B"])[:3, 3] - sim["T_W_B"][:3, 3])
    assert np.all(np.abs(err_mm) < 4 * _std_mm(fit, "T_Bm_B"))
    assert fit["board_body"] is False and fit["sync"]["method"] == "pose_streams"
    assert fit["offset"]["refined"]["dt_s"] == sync["dt_offset_s"]  # the fit started there
    held = yaml.safe_load((res / "heldout" / "pose_fit.yaml").read_text())
    heldout = pd.read_parquet(res / "heldout" / "pose_fit.parquet")
    assert held["n"] == len(heldout) == len(poses) and len(held["folds"]) == 5
    em = held["error_model"]
    assert 0.55 < em["inside_68_all"] < 0.8 and 0.88 < em["inside_95_all"] < 0.99 and 4 < em["nees_mean"] < 9
    judged = em["judgement"]
    assert judged["verdict"] in ("consistent", "too narrow", "too wide", "wrong shape")
    assert judged["nees_mean"]["low"] < judged["nees_mean"]["median"] < judged["nees_mean"]["high"]
    assert held["per_dim"]["z_m"]["rmse"] < 0.02
    headline = pd.read_csv(tmp_path / "results" / "headline.csv")
    assert "T_Cm_C z" in set(headline[headline["session"] == "s"]["quantity"])


def test_a_stated_offset_is_held_and_a_stream_outside_the_mocap_stops(tmp_path):
    """dt_offset_s in the session fixes the offset (sync writes it as given, the fit holds it); a
    camera stream that lies outside the motion capture stops sync naming the stream's file (not
    a video) and both spans, and no pose-fit output is left."""
    sim = simulate_streams(6, duration_s=20.0)
    cam = write_stream(tmp_path / "cam.csv", sim["t_cam_ns"], sim["T_B_C"], "eth")
    moc = write_stream(tmp_path / "vicon.csv", sim["t_mocap_ns"], sim["T_W_Cm"], "eth")
    write_config(tmp_path, {"sessions": {"s": {"camera_poses": str(cam), "pose_streams": {"camera": str(moc)},
                                               "dt_offset_s": 0.03}}, "evaluate": {"n_boot": 50}})  # fmt: skip
    snakemake(tmp_path, "results/s/pose_fit/result.yaml")
    fit = yaml.safe_load((tmp_path / "results" / "s" / "pose_fit" / "result.yaml").read_text())
    assert fit["dt_offset_s"] is None and fit["dt_used_s"] == 0.03 and fit["sync"]["method"] == "given"
    sync = yaml.safe_load((tmp_path / "results" / "s" / "sync.yaml").read_text())
    assert sync["camera_poses"] == str(cam)
    late = write_stream(tmp_path / "late.csv", sim["t_cam_ns"] + 3600 * 10**9, sim["T_B_C"], "eth")
    other = tmp_path / "other"
    write_config(other, {"sessions": {"s": {"camera_poses": str(late), "pose_streams": {"camera": str(moc)}}}})
    proc = snakemake(other, "results/s/pose_fit/result.yaml", check=False)
    assert proc.returncode != 0
    out = proc.stdout + proc.stderr
    assert "stage sync failed (OverlapError)" in out and "1491754388.034" in out
    failed = next(line for line in out.splitlines() if "stage sync failed" in line)
    assert f"camera poses of {late}" in failed and "video" not in failed.lower()  # the stream by its file
    assert "InputFunctionException" not in out  # no video or corners rule is asked about the session
    assert not (other / "results" / "s" / "pose_fit" / "result.yaml").exists()


def test_eth_prime_sense_1_as_a_session_agrees_with_handeye(tmp_path):
    """ETH's prime_sense_1 (camera poses from target detections, its Vicon body; the target static
    in the Vicon world) as a session: its offset and T_Cm_C agree with `cvsflow handeye
    --camera-poses` on the same files within their stated errors (the same estimator), and its
    held-out evaluation scores every pose."""
    root = need_real_file(f"{PS1}/2017-04-09-18-13-10_W_camera_rgb_image_raw.csv").parent
    cam = next(root.glob("*_W_camera_rgb_image_raw.csv"))
    moc = next(root.glob("*_vicon_prime_sense.csv"))
    write_config(tmp_path, {"sessions": {"s": {"camera_poses": str(cam), "pose_streams": {"camera": str(moc)}}},
                            "evaluate": {"n_boot": 100}})  # fmt: skip
    snakemake(tmp_path, *OUTPUTS)
    fit = yaml.safe_load((tmp_path / "results" / "s" / "pose_fit" / "result.yaml").read_text())
    assert main(["handeye", "--camera-poses", str(cam), "--poses", str(moc), "--out", str(tmp_path / "he")]) == 0
    he = yaml.safe_load((tmp_path / "he" / "handeye.yaml").read_text())
    assert abs(fit["dt_offset_s"] - he["dt_offset_s"]) < np.hypot(fit["dt_offset_std_s"], he["dt_offset_std_s"])
    d_mm = 1e3 * (np.array(fit["T_Cm_C"])[:3, 3] - np.array(he["T_Cm_C"])[:3, 3])
    assert np.all(np.abs(d_mm) < np.hypot(_std_mm(fit, "T_Cm_C"), _std_mm(he, "T_Cm_C")))
    dR = np.array(fit["T_Cm_C"])[:3, :3].T @ np.array(he["T_Cm_C"])[:3, :3]
    assert np.degrees(rotation_angle(dR)) < fit["std"]["T_Cm_C"]["rotation_deg"]
    held = yaml.safe_load((tmp_path / "results" / "s" / "heldout" / "pose_fit.yaml").read_text())
    assert held["n"] >= 1500 and np.isfinite(held["error_model"]["nees_mean"])


def test_a_bad_camera_pose_file_stops_its_stage_by_name(tmp_path):
    """A camera-pose stream with a quaternion that is not unit stops the camera_poses stage with
    the reader's error naming the file and line; no poses table is left."""
    sim = simulate_streams(7, duration_s=5.0)
    cam = write_stream(tmp_path / "cam.csv", sim["t_cam_ns"], sim["T_B_C"], "eth")
    lines = cam.read_text().splitlines()
    cells = lines[4].split(",")
    cells[-1] = str(3 * float(cells[-1]) + 1.0)
    lines[4] = ",".join(cells)
    cam.write_text("\n".join(lines) + "\n")
    moc = write_stream(tmp_path / "vicon.csv", sim["t_mocap_ns"], sim["T_W_Cm"], "eth")
    write_config(tmp_path, {"sessions": {"s": {"camera_poses": str(cam), "pose_streams": {"camera": str(moc)}}}})
    proc = snakemake(tmp_path, "results/s/poses_raw.parquet", check=False)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0 and "stage camera_poses failed (QuaternionNormError)" in out and "cam.csv" in out
    assert not (tmp_path / "results" / "s" / "poses_raw.parquet").exists()


def test_a_camera_pose_session_with_a_marker_export(tmp_path):
    """The camera body from a marker export (mocap.file + markers, a Nexus CSV at 100 Hz on its
    own clock) instead of pose_streams, the target's marker body static: the markers are
    repaired and fitted as for a video session, and sync, the fit (dt, T_Cm_C, T_Bm_B within 4
    stated errors of the truth) and the held-out evaluation run as with pose streams."""
    sim = simulate_streams(8, duration_s=25.0)
    t0_ns = int(sim["t_mocap_ns"][0])  # the export's clock starts at its first sample
    t_s = (sim["t_mocap_ns"] - t0_ns) / 1e9
    assert np.allclose(np.diff(t_s), 0.01, atol=1e-6)  # one frame every 10 ms, as Nexus writes it
    T_W_Bm = make_T(R_from_rvec(np.array([0.1, -0.2, 0.3])), [0.4, -0.2, 0.05])
    rng = np.random.default_rng(8)
    data = {"frame": np.arange(len(t_s)), "t_s": t_s}
    for names, layout, T in ((CAMERA_NAMES, CAMERA_LAYOUT_M, sim["T_W_Cm"]), (BOARD_NAMES, BOARD_LAYOUT_M, T_W_Bm)):
        for name, p in zip(names, layout, strict=True):
            xyz = transform_points(T, p) + rng.normal(0.0, 1e-4, (len(t_s), 3))
            for a, axis in enumerate("xyz"):
                data[f"{name}_{axis}_m"] = xyz[:, a]
    write_nexus_csv(pd.DataFrame(data), tmp_path / "take.csv", 100.0)
    # the camera's clock as the sim has it relative to the motion capture's: dt stays 30 ms
    cam = write_stream(tmp_path / "cam.csv", sim["t_cam_ns"] - t0_ns, sim["T_B_C"], "asl")
    markers = {"camera": {"names": CAMERA_NAMES, "layout_m": CAMERA_LAYOUT_M.tolist()},
               "board": {"names": BOARD_NAMES, "layout_m": BOARD_LAYOUT_M.tolist()}}
    write_config(tmp_path, {"sessions": {"s": {"camera_poses": str(cam), "mocap": {"file": str(tmp_path / "take.csv")},
                                               "markers": markers}}, "evaluate": {"n_boot": 50}})  # fmt: skip
    snakemake(tmp_path, *OUTPUTS)
    res = tmp_path / "results" / "s"
    assert (res / "markers_filled.parquet").exists() and not (res / "corners.parquet").exists()
    sync = yaml.safe_load((res / "sync.yaml").read_text())
    assert sync["method"] == "pose_streams" and abs(sync["dt_offset_s"] - 0.03) < 0.01
    fit = yaml.safe_load((res / "pose_fit" / "result.yaml").read_text())
    assert fit["board_body"] is True and abs(fit["dt_offset_s"] - 0.03) < 4 * fit["dt_offset_std_s"]
    err_mm = 1e3 * (np.array(fit["T_Cm_C"])[:3, 3] - sim["T_Cm_C"][:3, 3])
    assert np.all(np.abs(err_mm) < 4 * _std_mm(fit, "T_Cm_C"))
    T_Bm_B = invert_T(T_W_Bm) @ sim["T_W_B"]
    err_mm = 1e3 * (np.array(fit["T_Bm_B"])[:3, 3] - T_Bm_B[:3, 3])
    assert np.all(np.abs(err_mm) < 4 * _std_mm(fit, "T_Bm_B"))
    held = yaml.safe_load((res / "heldout" / "pose_fit.yaml").read_text())
    assert held["n"] > 0.9 * len(sim["t_cam_ns"]) and np.isfinite(held["error_model"]["nees_mean"])
