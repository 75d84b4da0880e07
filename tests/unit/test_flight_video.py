"""A rendered flight filmed by a session's camera: the video shows the true trajectory."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from cvsflow.calibration import board_object_points
from cvsflow.corners_detect import detect_corners
from cvsflow.errors import ConfigError
from cvsflow.flight.trajectory import T_from_traj
from cvsflow.flight_synth import render_flight
from cvsflow.io import read_parquet, read_yaml
from cvsflow.io.flightlog import read_tum
from cvsflow.io.media import iter_video_gray
from cvsflow.synth.camera import project_points
from cvsflow.synth.flight_video import FLIGHT_VIDEO_FILES, render_flight_video
from cvsflow.synth.motion import PoseTrack, board_poses
from cvsflow.transforms import invert_T

DEMO = yaml.safe_load((Path(__file__).resolve().parents[2] / "config" / "config.yaml")
                     .read_text())["sessions"]["demo"]  # fmt: skip
CAMERA = DEMO["synth"]["camera"]
BOARD = DEMO["board"]


def _session(**synth):
    return {**DEMO, "synth": {**DEMO["synth"], "seed": 3, "n_stills": 4, **synth}}


def test_a_pose_track_is_what_the_renderer_samples():
    T = np.eye(4)
    track = PoseTrack(lambda t: np.repeat(T[None], len(t), axis=0) + t[:, None, None] * 0.0)
    assert board_poses(track, np.array([0.0, 0.5])).shape == (2, 4, 4)


@pytest.mark.parametrize("synth", [{}, {"distance_m": [1.2, 2.5], "codec": {"name": "mjpeg"}}],
                         ids=["legacy writer", "realistic path"])
def test_the_flight_video_shows_the_true_board(tmp_path, synth):
    """The corners detected in the video lie where the true trajectory projects them (within
    0.5 px: corner noise and codec), every frame of the truth has its video frame, and the
    on-board log and clock are render_flight's for the same seed."""
    out = tmp_path / "flight"
    s = render_flight_video(_session(**synth), out, seed=5, duration_s=2.0,
                            range_m=(1.5, 2.5) if not synth else None)
    assert sorted(p.name for p in out.iterdir()) == sorted(FLIGHT_VIDEO_FILES)
    doc = read_yaml(out / "truth.yaml")
    truth = read_parquet(out / "truth.parquet")
    assert len(truth) == s["n_frames"] == 60
    T_C_B = invert_T(np.array(doc["T_L_C"])) @ T_from_traj(truth) @ np.array(doc["T_Q_B"])
    assert np.all((T_C_B[:, 2, 3] > 1.2) & (T_C_B[:, 2, 3] < 2.8))
    K = np.array([[CAMERA["fx_px"], 0, CAMERA["cx_px"]], [0, CAMERA["fy_px"], CAMERA["cy_px"]],
                  [0, 0, 1.0]])
    p_B = board_object_points(BOARD)
    uv_true = project_points(T_C_B, p_B, K, np.array(CAMERA["dist"]))
    errors, n_found = [], 0
    for k, _, gray in iter_video_gray(str(out / "video.mp4")):
        uv, _ = detect_corners(gray, BOARD, subpix_window_px=5)
        if uv is not None and np.isfinite(uv).all():
            n_found += 1
            errors.append(np.abs(uv - uv_true[k]).max())
    assert n_found >= 50
    assert np.median(errors) < 0.2 and max(errors) < 0.5
    demo = render_flight(seed=5, duration_s=2.0, range_m=tuple(s["range_m"]), reference="model")
    onboard = read_tum(out / "onboard.tum")
    assert np.allclose(onboard[["x_m", "y_m", "z_m"]].to_numpy(),
                       demo.onboard[["x_m", "y_m", "z_m"]].to_numpy(), atol=1e-6)
    assert doc["clock"]["dt_offset_s"] == pytest.approx(demo.clock.dt_offset_s)


def test_a_range_that_is_not_one_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="range_m"):
        render_flight_video(_session(), tmp_path / "x", range_m=(3.0, 2.0))
    assert not (tmp_path / "x").exists()
