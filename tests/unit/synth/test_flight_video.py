"""A rendered flight filmed by a session's camera: the video shows the true trajectory."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from cvsflow.board.model import board_object_points
from cvsflow.corners.detect import detect_corners
from cvsflow.exceptions import ConfigError
from cvsflow.flight.trajectory import T_from_traj
from cvsflow.geometry.transforms import invert_T
from cvsflow.io.files import read_parquet, read_yaml
from cvsflow.io.flightlog import read_tum
from cvsflow.io.media import iter_video_gray
from cvsflow.synth.flight_demo import render_flight
from cvsflow.synth.flight_video import FLIGHT_VIDEO_FILES, render_flight_video
from cvsflow.synth.imaging import project_in_view
from cvsflow.synth.motion import PoseTrack, board_poses

DEMO = yaml.safe_load((Path(__file__).resolve().parents[3] / "config" / "config.yaml")
                     .read_text())["sessions"]["demo"]  # fmt: skip
CAMERA = DEMO["synth"]["camera"]
BOARD = DEMO["board"]


def _session(**synth):
    return {**DEMO, "synth": {**DEMO["synth"], "seed": 3, "n_stills": 4, **synth}}


def test_a_pose_track_is_what_the_renderer_samples():
    """board_poses of a PoseTrack is its function's value at those times (a scalar time too)."""
    def T_C_B(t):
        T = np.repeat(np.eye(4)[None], len(t), axis=0)
        T[:, 2, 3] = 2.0 + 0.5 * t
        return T

    T = board_poses(PoseTrack(T_C_B), np.array([0.0, 0.5, 1.0]))
    np.testing.assert_allclose(T[:, 2, 3], [2.0, 2.25, 2.5])
    assert board_poses(PoseTrack(T_C_B), 0.2).shape == (1, 4, 4)


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
    uv_true = project_in_view(T_C_B, p_B, K, np.array(CAMERA["dist"]))
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


def test_a_range_that_is_not_one_and_a_folder_of_other_files_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="range_m"):
        render_flight_video(_session(), tmp_path / "x", range_m=(3.0, 2.0))
    assert not (tmp_path / "x").exists()
    mine = tmp_path / "recordings"
    mine.mkdir()
    (mine / "video.mp4").write_bytes(b"a user's own video")
    (mine / "notes.txt").write_text("field day")
    with pytest.raises(ConfigError, match="did not write"):
        render_flight_video(_session(), mine, duration_s=1.0)
    assert (mine / "video.mp4").read_bytes() == b"a user's own video"
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt", "video.mp4"]


def test_a_rolling_shutter_flight_filmed_as_video_states_its_error(tmp_path):
    """A 10 s flight at 1-3 m filmed by a rolling-shutter camera (480 rows in 24 ms, MJPEG),
    measured as the flight stage does (corners, PnP with the true lens and its line delay, the
    shear taken out, timed at the board's rows, the rendered sessions' model (T), weighted
    alignment): recovered minus injected error over the stated sigma has z RMS within
    [0.7, 1.4] per axis (alignment fitted to the truth). Stating the shear as a variance
    instead of taking it out leaves roll over 2 (the shear is a bias shared by neighbouring
    frames, which moves the alignment), and timing the frames at their first row over 4."""
    from functools import partial

    from cvsflow.calibration.pnp import estimate_poses
    from cvsflow.corners.extract import extract_corners_parallel, summarise_corners
    from cvsflow.flight.clock import Clock
    from cvsflow.flight.comparison import check_against_truth, evaluate_flight
    from cvsflow.flight.reference import correct_rolling_shutter, reference_covariance_transfer
    from cvsflow.flight.trajectory import reference_from_poses
    from cvsflow.io.media import video_info, video_timing

    ld = 5e-5
    out = tmp_path / "rs"
    render_flight_video(_session(distance_m=[1.0, 3.0], rolling_shutter={"line_delay_s": ld},
                                 codec={"name": "mjpeg"}), out, seed=2, duration_s=10.0)  # fmt: skip
    video = str(out / "video.mp4")
    corners = extract_corners_parallel(partial(iter_video_gray, video, undecodable=True),
                                       video_info(video)["n_frames"], BOARD, n_workers=1)
    inter = bool(summarise_corners(corners, video_timing(video))["inter_coded"])
    K = np.array([[CAMERA["fx_px"], 0, CAMERA["cx_px"]], [0, CAMERA["fy_px"], CAMERA["cy_px"]],
                  [0, 0, 1.0]])
    calib = {"K": K.tolist(), "dist": list(CAMERA["dist"]), "line_delay_s": ld,
             "std": dict.fromkeys(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"), 1e-6)}
    p_B = board_object_points(BOARD)
    poses = estimate_poses(corners, K, np.array(CAMERA["dist"]), BOARD)
    assert poses["valid"].mean() > 0.9
    corrected, shear = correct_rolling_shutter(poses, corners, p_B, calib)
    assert np.nanmedian(np.linalg.norm(shear[:, 3:], axis=1)) > 2e-3  # mrad-level, not noise
    assert np.nanmedian(corrected["reproj_rms_px"]) < np.nanmedian(poses["reproj_rms_px"])
    doc = read_yaml(out / "truth.yaml")
    truth, onboard = read_parquet(out / "truth.parquet"), read_tum(out / "onboard.tum")
    clock = Clock(**doc["clock"])
    z = {}
    for name, p, delay, taken_out in (("taken out", corrected, ld, True),
                                      ("as variance", poses, ld, False),
                                      ("first row", poses, 0.0, False)):
        Sigma, flip, G = reference_covariance_transfer(p, corners, p_B, calib, inter_coded=inter,
                                                       return_terms=True, shear_corrected=taken_out)
        r = evaluate_flight(reference_from_poses(p, corners, delay), onboard, np.array(doc["T_Q_B"]),
                            Sigma, clock=clock, weighted_alignment=True, flip_ref=flip,
                            cal_factor=G)  # fmt: skip
        z[name] = check_against_truth(r, onboard, truth, np.array(doc["T_L_C"]),
                                      clock)["z_rms_truth_alignment"]  # fmt: skip
    assert all(0.7 < v < 1.4 for v in z["taken out"].values()), z["taken out"]
    assert z["as variance"]["roll_rad"] > 2.0, z["as variance"]
    assert z["first row"]["roll_rad"] > 4.0, z["first row"]
