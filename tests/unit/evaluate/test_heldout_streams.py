"""cvsflow.evaluate.heldout_streams and cvsflow.calibration.pose_stream: a camera-pose session's
tables, its pose-level fit and held-out evaluation, on simulated streams with known truth."""

import re

import numpy as np
import pytest

from cvsflow.calibration import poses_from_stream
from cvsflow.calibration.pnp import POSE_COLUMNS
from cvsflow.evaluate import (
    cross_validate_streams,
    fit_pose_streams,
    fold_options,
    heldout_summary,
    pose_fit_record,
    stream_inputs,
    stream_sync,
)
from cvsflow.exceptions import InputError, OverlapError
from cvsflow.geometry import R_from_rvec, invert_T, make_T, rotation_angle
from cvsflow.handeye import simulate_streams
from cvsflow.metrics import ERROR_DIMS
from cvsflow.mocap import bodies_from_streams


def _tables(sim, T_W_Bm=None):
    """poses_raw and bodies tables of a simulated pair (board body static at W, or moving)."""
    poses = poses_from_stream(sim["t_cam_ns"], sim["T_B_C"])
    t_m = sim["t_mocap_ns"]
    if T_W_Bm is None:
        bodies = bodies_from_streams(t_m, sim["T_W_Cm"], t_m[:1], np.eye(4)[None])
    else:
        bodies = bodies_from_streams(t_m, T_W_Bm @ sim["T_W_Cm"], t_m, T_W_Bm)
    return poses, bodies


def test_a_camera_pose_stream_is_a_poses_table_with_exact_times():
    """Same columns and units as the poses stage (T_C_B), t_ns exact, all valid; times that go
    back are refused naming the row."""
    sim = simulate_streams(3, duration_s=5.0)
    poses = poses_from_stream(sim["t_cam_ns"], sim["T_B_C"])
    assert list(poses.columns) == POSE_COLUMNS[:2] + ["t_ns"] + POSE_COLUMNS[2:]
    assert (poses["t_ns"].to_numpy() == sim["t_cam_ns"]).all() and poses["valid"].all()
    T_C_B = invert_T(sim["T_B_C"])
    assert np.allclose(poses[["x_m", "y_m", "z_m"]].to_numpy(), T_C_B[:, :3, 3])
    R = R_from_rvec(poses[["rvec_0", "rvec_1", "rvec_2"]].to_numpy()).reshape(-1, 3, 3)
    assert np.allclose(R, T_C_B[:, :3, :3], atol=1e-12)
    t_back = sim["t_cam_ns"].copy()
    t_back[7] = t_back[6]
    with pytest.raises(InputError, match=r"cam.csv: row 7 at \d+ ns does not follow row 6"):
        poses_from_stream(t_back, sim["T_B_C"], source="cam.csv")


def test_stream_inputs_give_the_camera_body_in_the_board_body():
    """Without a board body the camera body's poses pass as they are; with a moving board body
    the fit's mocap stream is T_Bm_Cm = T_W_Bm^-1 T_W_Cm."""
    sim = simulate_streams(4, duration_s=5.0)
    frames, t_cam, T_B_C, t_m, T_Bm_Cm = stream_inputs(*_tables(sim))
    assert (frames == np.arange(len(t_cam))).all() and (t_cam == sim["t_cam_ns"]).all()
    assert np.allclose(T_B_C, sim["T_B_C"]) and np.allclose(T_Bm_Cm, sim["T_W_Cm"])
    tau = (sim["t_mocap_ns"] - sim["t_mocap_ns"][0]) / 1e9
    T_W_Bm = make_T(R_from_rvec(np.stack([0.3 * np.sin(tau), 0.2 * tau, 0 * tau], 1)).reshape(-1, 3, 3),
                    np.stack([tau, np.cos(tau), 0 * tau + 1.0], 1))  # fmt: skip
    _, _, _, _, T_rel = stream_inputs(*_tables(sim, T_W_Bm))
    assert np.allclose(T_rel, sim["T_W_Cm"], atol=1e-9)


def test_the_pose_fit_finds_the_truth_within_its_stated_errors():
    """On simulated streams (known offset, correlated detector noise) the session's fit gives dt,
    T_Cm_C and T_Bm_B within 3 stated standard errors, named as the session names them."""
    sim = simulate_streams(1)
    _, *streams = stream_inputs(*_tables(sim))
    res, split = fit_pose_streams(*streams)
    assert abs(res.dt_offset_s - sim["dt_offset_s"]) < 3 * res.dt_offset_std_s
    for k, a in enumerate("xyz"):
        assert abs(res.T_Cm_C[k, 3] - sim["T_Cm_C"][k, 3]) < 3 * res.std[f"T_Cm_C_{a}"]
    assert np.degrees(rotation_angle(res.T_Cm_C[:3, :3].T @ sim["T_Cm_C"][:3, :3])) < 0.3
    rec = pose_fit_record(res, split, board_body=False)
    assert "T_W_B" not in rec and np.allclose(rec["T_Bm_B"], res.T_W_B)
    assert set(rec["std"]) == {"T_Cm_C", "T_Bm_B"} and "the motion-capture world" in rec["frames"]
    assert "split_half" in rec and rec["board_body"] is False
    held = fit_pose_streams(*streams, dt_offset_s=0.03, split_half=False)[0]
    assert held.dt_offset_s is None and held.dt_used_s == 0.03 and "dt_offset_s" not in held.std


def test_fold_options_start_where_the_full_fit_started():
    """The folds start at the refined (else coarse) offset and estimate dt; a stated offset, or
    none found, is held."""
    o = fold_options({"coarse": {"dt_s": 0.03}, "refined": {"dt_s": 0.021}}, 0.019)
    assert o.estimate_dt and o.dt_init_s == 0.021
    assert fold_options({"coarse": {"dt_s": 0.03}, "refined": None}, 0.019).dt_init_s == 0.03
    none = fold_options({"coarse": {"dt_s": None}, "refined": None}, 0.0)
    assert not none.estimate_dt and none.dt_init_s == 0.0
    given = fold_options({}, 0.5, dt_offset_s=0.1)
    assert not given.estimate_dt and given.dt_init_s == 0.1


@pytest.mark.parametrize("frame", ["C", "B"])
def test_heldout_errors_and_their_stated_uncertainty_on_simulated_streams(frame):
    """Folds of contiguous time blocks, every frame scored once by a fit that did not see it; the
    stated per-frame uncertainty covers the held-out errors about as it says (68 / 95 %, NEES
    about 6) and the table has the video sessions' held-out columns."""
    sim = simulate_streams(2, duration_s=30.0)
    frames, *streams = stream_inputs(*_tables(sim))
    opts = fold_options({"refined": {"dt_s": 0.025}}, 0.025)
    heldout, fits, score = cross_validate_streams(frames, *streams, opts, n_folds=5, block_s=2.0, seed=0,
                                                  frame=frame)  # fmt: skip
    assert len(heldout) == len(frames) and sorted(heldout["frame"]) == list(frames)
    assert set(heldout["fold"]) == set(range(5)) and len(fits) == 5
    for d in ERROR_DIMS:
        assert {f"err_{d}", f"sigma_{d}"} <= set(heldout.columns)
    assert (heldout["error_frame"] == frame).all() and np.isfinite(heldout["nees"]).all()
    assert all(abs(f["dt_offset_s"] - sim["dt_offset_s"]) < 0.005 for f in fits)
    assert 0.55 < score["inside_68_all"] < 0.8 and 0.88 < score["inside_95_all"] < 0.99
    assert 4.0 < score["nees_mean"] < 9.0
    assert set(score["lag1_autocorr"]) == set(ERROR_DIMS) and 0 < score["n_effective"] <= len(heldout)
    assert 0 < score["inside_95_tolerance"] < score["inside_68_tolerance"] < 0.2
    summary = heldout_summary(heldout, fits, score, n_boot=50)
    assert summary["n"] == len(heldout) and summary["error_model"]["inside_95_all"] == score["inside_95_all"]
    assert summary["per_dim"]["x_m"]["rmse"] < 0.02


def test_a_moving_board_body_gives_the_target_in_its_body():
    """With a board body that moves (a hand-held target) the fit's second mounting is T_Bm_B, the
    target in its body, found within 3 stated errors; sync's search finds the offset."""
    sim = simulate_streams(11, duration_s=25.0)
    tau = (sim["t_mocap_ns"] - sim["t_mocap_ns"][0]) / 1e9
    T_W_Bm = make_T(R_from_rvec(np.stack([0.3 * np.sin(tau), 0.2 * np.cos(0.7 * tau), 0.1 * tau], 1)).reshape(-1, 3, 3),
                    np.stack([0.2 * tau, np.cos(tau), 0 * tau + 1.0], 1))  # fmt: skip
    poses, bodies = _tables(sim, T_W_Bm)
    sync = stream_sync(poses, bodies)
    assert sync["method"] == "pose_streams" and abs(sync["dt_offset_s"] - 0.03) < 0.01
    _, *streams = stream_inputs(poses, bodies)
    res, _ = fit_pose_streams(*streams, dt_start_s=sync["dt_offset_s"], offset=sync["details"], split_half=False)
    assert res.offset["refined"]["dt_s"] == sync["dt_offset_s"]
    for k, a in enumerate("xyz"):
        assert abs(res.T_W_B[k, 3] - sim["T_W_B"][k, 3]) < 3 * res.std[f"T_W_B_{a}"]
    assert pose_fit_record(res, None, board_body=True)["frames"].count("board marker body Bm") == 1


def test_sync_messages_name_the_camera_pose_stream_not_a_video():
    """A camera-pose stream an hour after the motion capture stops sync with an OverlapError that
    names the stream's file, its poses and the motion capture (both spans), never "video"; one
    that overlaps partly warns in the same words and sync.yaml names the stream."""
    sim = simulate_streams(12, duration_s=20.0)
    poses, bodies = _tables(sim)
    late = poses.assign(t_s=poses["t_s"] + 3600.0, t_ns=poses["t_ns"] + 3600 * 10**9)
    with pytest.raises(OverlapError) as err:
        stream_sync(late, bodies, stream="data/cam.csv")
    msg = str(err.value)
    assert "video" not in msg.lower() and "vicon" not in msg.lower()
    assert re.search(r"only 0 of \d+ camera poses of data/cam\.csv \(0\.0 %\) fall inside the motion capture "
                     r"\(expected at least 20 % and 30 poses\): camera poses of data/cam\.csv span "
                     r"\d+\.\d{3}\.\.\d+\.\d{3} s, i\.e\. .* on the motion-capture clock .*the motion capture spans", msg)
    t_cut_s = float(bodies["t_s"].min()) + 0.6 * float(bodies["t_s"].max() - bodies["t_s"].min())
    sync = stream_sync(poses, bodies[bodies["t_s"] <= t_cut_s], stream="data/cam.csv")
    assert sync["camera_poses"] == "data/cam.csv" and 0.2 < sync["overlap_share"] < 0.8
    assert sync["warnings"] and all("video" not in w.lower() and "data/cam.csv" in w for w in sync["warnings"])
