"""Tests of the rendered multi-camera session (cvsflow.synth.rig_session, synth.render's rig functions)
and of its expansion into per-camera sessions (cvsflow.workflow.sessions.expand_rig_sessions), against
the renderer's own truth."""

from __future__ import annotations

import copy
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from cvsflow.calibration.intrinsics import view_corners
from cvsflow.exceptions import ConfigError
from cvsflow.geometry.transforms import invert_T, rotation_angle
from cvsflow.io.mocap.vicon import read_nexus_csv
from cvsflow.rig.extrinsics import stereo_extrinsics
from cvsflow.synth.imaging import project_in_view
from cvsflow.synth.motion import CameraView, board_poses
from cvsflow.synth.render import render_rig_camera, render_rig_mocap
from cvsflow.synth.rig_session import (
    camera_session_config,
    make_rig_truth,
    rig_vicon_recording,
    shared_views,
    true_board_poses_C0,
)
from cvsflow.synth.session import make_rig
from cvsflow.synth.spec import VICON_RATE_HZ, parse_session_config, random_streams
from cvsflow.workflow.sessions import check_sessions, expand_rig_sessions

REPO = Path(__file__).resolve().parents[3]


def stereo_cfg(duration_s=1.0, n_stills=5, n_shared=3):
    """config/stereo.yaml's rig session, shortened for tests."""
    with open(REPO / "config" / "stereo.yaml") as fh:
        cfg = copy.deepcopy(yaml.safe_load(fh)["sessions"]["stereo"])
    cfg["synth"].update(duration_s=duration_s, n_stills=n_stills, n_shared_stills=n_shared)
    return cfg


@pytest.fixture(scope="module")
def truth():
    return make_rig_truth(stereo_cfg())


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The short rig rendered: the mocap files and both cameras' folders."""
    base = tmp_path_factory.mktemp("rig") / "stereo"
    base.mkdir()
    cfg = stereo_cfg()
    out = {"mocap": render_rig_mocap(cfg, base / "vicon.csv", base / "truth.yaml"), "dir": base}
    for cam in ("left", "right"):
        out[cam] = render_rig_camera(cfg, cam, base / cam)
    return out


def test_camera_config_takes_the_rigs_keys_and_its_own():
    """A camera's mono session: the rig's synth keys, its own over them, no clock_offset_s."""
    cfg = stereo_cfg()
    right = camera_session_config(cfg, 1)
    assert right["synth"]["fps"] == 25.0 and right["synth"]["camera"]["fx_px"] == 655.0
    assert right["synth"]["seed"] == cfg["synth"]["seed"]
    assert "clock_offset_s" not in right["synth"] and "n_shared_stills" not in right["synth"]
    assert right["board"] == cfg["board"] and right["markers"] == cfg["markers"]
    bad = stereo_cfg()
    bad["cameras"][1]["synth"]["fx_px"] = 600.0
    with pytest.raises(ConfigError, match=r"cameras\[right\].synth: unknown keys \['fx_px'\]"):
        camera_session_config(bad, 1)


def test_camera_zero_is_the_mono_session_and_the_others_sit_as_designed(truth):
    """Camera 0's rig is make_rig of its mono session; camera 1 is at its designed pose from it."""
    spec0 = parse_session_config(camera_session_config(stereo_cfg(), 0))
    mono = make_rig(spec0, random_streams(spec0.seed)["mounting"])
    np.testing.assert_array_equal(truth.T_Cm_C[0], mono.T_Cm_C)
    assert truth.dt_offset_s[0] == mono.dt_offset_s
    assert truth.dt_offset_s[1] == pytest.approx(mono.dt_offset_s - 0.84, abs=1e-12)
    s1 = truth.specs[1]
    designed = invert_T(s1.T_Cm_C_design) @ spec0.T_Cm_C_design
    np.testing.assert_allclose(truth.T_C_C0(1), designed, atol=1e-12)
    assert np.linalg.norm(truth.T_C_C0(1)[:3, 3]) == pytest.approx(1.0, abs=0.001)  # the baseline
    # the marker placement error moves both cameras on the body alike
    assert rotation_angle(truth.T_Cm_C[1][:3, :3] @ s1.T_Cm_C_design[:3, :3].T) > 1e-4


def test_a_camera_view_is_camera_zeros_motion_at_the_same_vicon_time(truth):
    """T_C1_B(t1) = T_C1_C0 T_C0_B(t0) with t1 + dt1 = t0 + dt0."""
    t1 = np.array([0.0, 0.37, 2.5, 7.9])
    view = truth.view(1)
    assert isinstance(view, CameraView)
    t0 = t1 + truth.dt_offset_s[1] - truth.dt_offset_s[0]
    np.testing.assert_allclose(board_poses(view, t1), truth.T_C_C0(1) @ board_poses(truth.motion, t0),
                               atol=1e-12)
    np.testing.assert_allclose(true_board_poses_C0(truth, t1 + truth.dt_offset_s[1]),
                               board_poses(truth.motion, t0), atol=1e-12)


def test_vicon_take_covers_every_cameras_video(truth):
    """The take starts before and ends after each camera's video on the Vicon clock."""
    markers, _, _ = rig_vicon_recording(truth)
    t_end = len(markers) / VICON_RATE_HZ
    for spec, dt in zip(truth.specs, truth.dt_offset_s, strict=True):
        assert dt > 0.5 and dt + spec.duration_s < t_end - 1.0


def test_rendered_cameras_have_their_own_rates_and_files(rendered):
    """Each camera's folder: its stills, the shared views, a video at its own frame rate."""
    base = rendered["dir"]
    for cam, fps, n in (("left", 30.0, 30), ("right", 25.0, 25)):
        folder = base / cam
        assert sorted(p.name for p in folder.iterdir()) == sorted(
            ["calib", "shared", "video.mp4", "truth.yaml", "truth_frames.parquet", "truth_corners.parquet"])
        assert len(list((folder / "calib").glob("still_*.png"))) == 5
        assert sorted(p.name for p in (folder / "shared").iterdir()) == [f"shared_{v:03d}.png" for v in range(3)]
        cap = cv2.VideoCapture(str(folder / "video.mp4"))
        assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(fps)
        assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == n
        frames = pd.read_parquet(folder / "truth_frames.parquet")
        np.testing.assert_allclose(np.diff(frames["t_s"]), 1.0 / fps)
        doc = yaml.safe_load((folder / "truth.yaml").read_text())
        assert doc["rig"]["camera"] == cam and doc["fps"] == fps
    rig = yaml.safe_load((base / "truth.yaml").read_text())
    assert [c["name"] for c in rig["cameras"]] == ["left", "right"]
    assert [c["fps"] for c in rig["cameras"]] == [30.0, 25.0]
    vicon = read_nexus_csv(base / "vicon.csv")
    # the rig's markers stand still (0.3 mm noise), the board's move
    assert np.nanstd(vicon["rig:R2_x_m"]) < 0.001 < np.nanstd(vicon["board:B1_x_m"])
    assert vicon["t_s"].iloc[-1] > max(c["dt_offset_s"] for c in rig["cameras"]) + 1.0


def test_rendered_frames_show_the_board_where_the_rig_truth_puts_it(rendered, truth):
    """Each camera's truth_corners are the rig truth's board (C0, Vicon clock) projected into it."""
    for i, cam in enumerate(("left", "right")):
        folder = rendered["dir"] / cam
        frames = pd.read_parquet(folder / "truth_frames.parquet")
        corners = pd.read_parquet(folder / "truth_corners.parquet")
        spec = truth.specs[i]
        T = truth.T_C_C0(i) @ true_board_poses_C0(truth, frames["t_s"].to_numpy() + truth.dt_offset_s[i])
        uv = project_in_view(T, spec.board.corners_B(), spec.K, spec.dist)
        got = corners[["u_px", "v_px"]].to_numpy().reshape(uv.shape)
        np.testing.assert_allclose(got, uv, atol=1e-9)


def test_shared_views_are_seen_whole_by_both_cameras_where_the_truth_says(rendered, truth):
    """view_corners finds the whole board in each camera's shared stills within 0.5 px of the
    true corners, in board order; stereo_extrinsics on them finds the rendered baseline."""
    T_C0_B = shared_views(truth)
    tables, cameras = [], []
    for i, cam in enumerate(("left", "right")):
        spec = truth.specs[i]
        paths = sorted((rendered["dir"] / cam / "shared").glob("*.png"))
        table = view_corners([(p.name, cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for p in paths],
                             spec.board.config(), subpix_window_px=5)
        assert sorted(table["image"].unique()) == [p.name for p in paths]
        for v, (_, g) in enumerate(table.groupby("image")):
            uv = project_in_view(truth.T_C_C0(i) @ T_C0_B[v], spec.board.corners_B(), spec.K, spec.dist)
            assert np.max(np.linalg.norm(g[["u_px", "v_px"]].to_numpy() - uv, axis=1)) < 0.5, (cam, v)
        tables.append(table)
        cameras.append({"K": spec.K.tolist(), "dist": spec.dist.tolist()})
    rig = stereo_extrinsics(tables, cameras)
    T = np.asarray(rig["cameras"][0]["T_Ci_C0"])
    assert np.linalg.norm(T[:3, 3] - truth.T_C_C0(1)[:3, 3]) < 0.01
    assert rotation_angle(T[:3, :3] @ truth.T_C_C0(1)[:3, :3].T) < 0.005


def test_a_rig_camera_with_the_realistic_renderer_is_refused():
    cfg = stereo_cfg()
    cfg["cameras"][1]["synth"]["image_size"] = [320, 240]
    make_rig_truth(cfg)  # size and rate are the fast renderer's too
    cfg["synth"]["preset"] = "realistic"
    with pytest.raises(ConfigError, match="fast renderer"):
        make_rig_truth(cfg)


def test_camera_zero_keeps_the_reference_clock():
    cfg = stereo_cfg()
    cfg["cameras"][0]["synth"]["clock_offset_s"] = 0.1
    with pytest.raises(ConfigError, match=r"cameras\[left\].synth.clock_offset_s"):
        make_rig_truth(cfg)
    cfg = stereo_cfg()
    cfg["cameras"][1]["synth"]["clock_offset_s"] = -5.0
    with pytest.raises(ConfigError, match="before the Vicon take"):
        make_rig_truth(cfg)


def test_rig_session_expands_into_plain_sessions():
    """Sessions without cameras pass through as they are; a rig gives its mocap and cameras."""
    demo = {"synth": {"seed": 7}, "board": {"squares_x": 6, "squares_y": 5, "square_m": 0.09},
            "markers": {"camera": {"names": ["a", "b", "c"]}, "board": {"names": ["d", "e", "f"]}}}
    plain, rigs = expand_rig_sessions({"demo": demo})
    assert plain == {"demo": demo} and plain["demo"] is demo and rigs == {}
    plain, rigs = expand_rig_sessions({"demo": demo, "stereo": stereo_cfg()})
    assert list(plain) == ["demo", "stereo", "stereo-left", "stereo-right"]
    assert plain["stereo"]["mocap"]["file"] == "data/stereo/vicon.csv" and "synth" not in plain["stereo"]
    assert plain["stereo-right"] == {"board": demo["board"], "calib_dir": "data/stereo/right/calib",
                                     "video": "data/stereo/right/video.mp4"}
    assert rigs["stereo"]["sessions"] == ["stereo-left", "stereo-right"]
    assert rigs["stereo"]["shared_dirs"] == ["data/stereo/left/shared", "data/stereo/right/shared"]
    stages = check_sessions(plain)
    assert stages["stereo"] == ("mocap",) and stages["stereo-left"] == ("calibrate", "poses")
    real = {"mocap": {"file": "take.csv"}, "board": demo["board"], "markers": demo["markers"],
            "cameras": [{"name": "a", "calib_dir": "ca", "video": "va.mp4"}, {"name": "b", "calib_dir": "cb"}]}
    with pytest.raises(ConfigError, match=r"cameras\[b\]: video is missing"):
        expand_rig_sessions({"r": real})
    with pytest.raises(ConfigError, match="already a session"):
        expand_rig_sessions({"r": dict(real, cameras=real["cameras"][:1]), "r-a": demo})
    with pytest.raises(ConfigError, match=r"sessions\.r\.methods: a rig is fitted by optimise_se3_rig"):
        expand_rig_sessions({"r": dict(real, methods=["se3"])})


def test_a_sessions_methods_override_the_global_ones():
    """methods on a session wins over optimise.methods for it alone (the workflow's METHODS)."""
    from cvsflow.workflow.sessions import session_methods

    sessions = {"a": {"board": {}}, "b": {"board": {}, "methods": ["se3"]}}
    assert session_methods("a", sessions, ["seed", "se3"]) == ("seed", "se3")
    assert session_methods("b", sessions, ["seed", "se3"]) == ("se3",)
