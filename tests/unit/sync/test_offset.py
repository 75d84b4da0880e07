"""Synchronisation (angular speed, gesture) against a synthetic session with known offset."""

import re

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import InputError, OverlapError, SyncError
from cvsflow.geometry.transforms import invert_T, make_T, rotation_angle
from cvsflow.mocap.bodies import fit_bodies
from cvsflow.sync.offset import given_offset, sync_angular_speed, synchronise
from cvsflow.sync.offset_refine import refine_offset_rotations
from cvsflow.sync.pairs import build_pairs
from cvsflow.sync.streams import (
    angular_speed_cvs,
    angular_speed_streams,
    angular_speed_vicon,
    check_take_covers_video,
)
from tests.helpers.sync_session import DT_OFFSET_S, FPS, RATE_HZ, make_session


@pytest.fixture(scope="module")
def session():
    return make_session()


@pytest.fixture(scope="module")
def clean_session():
    """Marker noise off: the pose targets hold before marker noise (a 0.3 mm marker noise on the
    0.17 m camera body already tilts it by ~0.1 deg, i.e. ~3 mm at the board 1.5 m away)."""
    return make_session(duration_video_s=6.0, noise_m=0.0, seed=5)


def test_angular_speed_is_invariant_to_marker_offsets():
    """Noise-free, the CVS angular speed of T_C_B equals the Vicon angular speed of T_Cm_Bm over
    the same instants (0.2 %), although T_Cm_C and T_Bm_B are unknown to the Vicon side."""
    poses, bodies, _ = make_session(duration_video_s=4.0, noise_m=0.0, rot_noise_rad=0.0,
                                    pos_noise_m=0.0, drop_frac=0.0, seed=1)
    t_mid, w_c = angular_speed_cvs(poses)
    _, w_v = angular_speed_vicon(bodies, 1.0 / FPS, t_grid_s=t_mid + DT_OFFSET_S)
    # SLERP between 300 Hz samples: 0.2 % at the sharpest turn
    np.testing.assert_allclose(w_c, w_v, rtol=2e-3, atol=1e-3)
    assert np.nanmax(w_c) > 0.5


def test_sync_angular_speed_within_3ms(session):
    """Cross-correlation + refinement recovers the offset within 3 ms, with 0.3 mm marker noise,
    0.1 deg / 1 mm CVS noise and 5 % frames without a board; quality above 0.5."""
    poses, bodies, _ = session
    out = sync_angular_speed(poses, bodies, max_offset_s=10.0, min_quality=0.5)
    assert abs(out["dt_offset_s"] - DT_OFFSET_S) < 0.003, out
    assert out["method"] == "angular_speed"
    assert 0.5 < out["quality"] <= 1.0
    assert abs(out["details"]["dt_coarse_s"] - DT_OFFSET_S) < 0.02


@pytest.mark.parametrize("seed", [1, 2])
def test_sync_angular_speed_refined_within_1ms(seed):
    """The seeds on which the former angular-speed mismatch refinement was -2.9 and +3.4 ms off:
    the relative-rotation-angle refinement is within 1 ms of the true offset (0.3 ms seen on
    seeds 0..7), records itself in details, and its jackknife standard error is positive and
    below 1 ms."""
    poses, bodies, _ = make_session(seed=seed)
    out = sync_angular_speed(poses, bodies, max_offset_s=10.0, min_quality=0.5)
    d = out["details"]
    assert abs(out["dt_offset_s"] - DT_OFFSET_S) < 0.001, d
    assert d["refinement"] == "relative_rotation_angles"
    assert d["dt_refined_s"] == out["dt_offset_s"]
    assert 0.0 < d["dt_sigma_s"] < 0.001
    assert d["n_refine_pairs"] > 10 * d["n_refine_frames"]  # baselines 1..15 frames
    # a tenth of a degree of CVS noise and 0.3 mm of marker noise: residual angle RMS ~0.2 deg
    assert np.radians(0.05) < d["residual_rms_rad"] < np.radians(0.5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sync_at_60_fps_with_noisy_poses(seed):
    """60 fps and 0.5 deg of PnP rotation noise (a board 2-4 m away): frame to frame the speed
    noise is sqrt(2) x 0.5 deg x 60 /s and the quality falls under the 0.25 minimum (0.01-0.30);
    over the 0.1 s baseline it is above 0.9 and the offset within 1 ms."""
    poses, bodies, _ = make_session(fps=60, rot_noise_rad=np.radians(0.5), seed=seed)
    out = sync_angular_speed(poses, bodies, max_offset_s=10.0, min_quality=0.25)
    assert out["quality"] > 0.9 and out["details"]["window_frames"] == 6
    assert abs(out["dt_offset_s"] - DT_OFFSET_S) < 0.001
    frame_to_frame = sync_angular_speed(poses, bodies, max_offset_s=10.0, min_quality=0.0,
                                        speed_window_s=1 / 60)  # fmt: skip
    assert frame_to_frame["quality"] < 0.35


def test_sync_leaves_out_pose_flips(session):
    """Video poses flipped by 30 deg (PnP's ambiguity), single frames and a run of 3, made the
    former correlation peak land seconds off on a rendered session: they are left out
    (exactly those with a pose) and the offset stays within 1 ms."""
    poses, bodies, _ = session
    flipped = poses.copy()
    rows = np.array([40, 41, 42, 120, 200, 300])
    rows = rows[flipped.loc[rows, "valid"].to_numpy()]
    R = Rotation.from_rotvec(flipped.loc[rows, ["rvec_0", "rvec_1", "rvec_2"]].to_numpy(copy=True))
    flipped.loc[rows, ["rvec_0", "rvec_1", "rvec_2"]] = (R * Rotation.from_rotvec([np.radians(30.0), 0.0, 0.0])).as_rotvec()
    out = sync_angular_speed(flipped, bodies, max_offset_s=10.0, min_quality=0.5)
    assert out["details"]["n_jump_frames"] == len(rows)
    assert abs(out["dt_offset_s"] - DT_OFFSET_S) < 0.001, out


def _rotation_stream(t_s):
    """A smooth, hand-like R_Cm_Bm(t) (several frequencies about all three axes)."""
    rotvec = np.stack([
        0.4 * np.sin(2 * np.pi * 0.7 * t_s) + 0.1 * np.sin(2 * np.pi * 2.3 * t_s + 1.0),
        0.3 * np.sin(2 * np.pi * 0.5 * t_s + 0.4) + 0.05 * np.sin(2 * np.pi * 3.1 * t_s),
        0.2 * np.sin(2 * np.pi * 0.9 * t_s + 2.0),
    ], axis=1)
    return Rotation.from_rotvec(rotvec).as_matrix()


@pytest.mark.parametrize("smooth_s", [0.0, 0.01])
def test_refine_offset_rotations_invariant_to_mounting(smooth_s):
    """Noise-free, with arbitrary constant rotations on both sides (R_C_B = R_C_Cm R_Cm_Bm
    R_Bm_B), 10 % of the frames and a 0.1 s Vicon gap missing, started 12 ms off: the offset
    is recovered within 0.05 ms (the Gaussian smoothing is symmetric: no time shift). The angle
    residual is below 0.01 deg unsmoothed; the 10 ms Gaussian damps the 3 Hz component by 2 %,
    which leaves at most 0.1 deg."""
    dt_true = 1.2345
    t_v = np.arange(0.0, 9.0, 1.0 / RATE_HZ)
    R_v = _rotation_stream(t_v)
    valid_v = np.ones(len(t_v), bool)
    valid_v[(t_v > 4.0) & (t_v < 4.1)] = False
    t_c = np.arange(0.0, 6.0, 1.0 / FPS)
    A = Rotation.from_rotvec([0.3, -1.2, 2.0]).as_matrix()
    B = Rotation.from_rotvec([2.5, 0.4, -0.7]).as_matrix()
    R_c = A @ _rotation_stream(t_c + dt_true) @ B
    valid_c = np.random.default_rng(0).uniform(size=len(t_c)) > 0.1
    out = refine_offset_rotations(t_c, R_c, valid_c, t_v, R_v, valid_v, dt_true + 0.012, search_s=1.0 / FPS,
                                  smooth_s=smooth_s)
    assert abs(out["dt_s"] - dt_true) < 5e-5, out
    assert out["residual_rms_rad"] < np.radians(0.01 if smooth_s == 0.0 else 0.1)
    # frames whose Vicon time, anywhere in the search range, falls in the gap take no part
    in_gap = (t_c + dt_true + 0.012 + 1.0 / FPS > 4.0 - 1.0 / RATE_HZ) & (t_c + dt_true + 0.012 - 1.0 / FPS < 4.1)
    assert out["n_frames"] <= int((valid_c & ~in_gap).sum())


def test_refine_offset_rotations_too_few_pairs():
    """Fewer than 20 frame pairs: no estimate (dt_s None), no exception."""
    t_v = np.arange(0.0, 3.0, 1.0 / RATE_HZ)
    t_c = np.arange(0.0, 0.2, 1.0 / FPS)
    out = refine_offset_rotations(t_c, _rotation_stream(t_c), np.ones(len(t_c), bool), t_v, _rotation_stream(t_v),
                                  np.ones(len(t_v), bool), 0.0, search_s=0.01, max_baseline=2)
    assert out["dt_s"] is None and out["n_pairs"] < 20


def test_smooth_rotations_keeps_time_and_masks_holes():
    """A constant-rate turn is its own Gaussian mean (to 1e-9 rad): smoothing shifts nothing in
    time; samples within 2.5 sigma of an invalid one, or of either end, are marked invalid."""
    from cvsflow.sync.offset_refine import _smooth_rotations

    t = np.arange(0.0, 1.0, 1.0 / RATE_HZ)
    R = Rotation.from_rotvec(np.outer(1.7 * t, [0.36, 0.48, 0.8])).as_matrix()
    valid = np.ones(len(t), bool)
    valid[150] = False
    q, ok = _smooth_rotations(t, R, valid, 0.01)
    half = int(np.ceil(2.5 * 0.01 * RATE_HZ))
    expect = valid.copy()
    expect[150 - half : 150 + half + 1] = False
    expect[:half] = expect[-half:] = False
    np.testing.assert_array_equal(ok, expect)
    err = (Rotation.from_quat(q[ok]).inv() * Rotation.from_matrix(R[ok])).magnitude()
    assert err.max() < 1e-9


def test_sync_gesture_within_one_frame(session):
    """The chapter's forward-tilt onsets give the offset within 10 ms (a third of a frame)."""
    poses, bodies, _ = session
    out = synchronise(poses, bodies, method="gesture", max_offset_s=10.0, min_quality=0.1)
    assert abs(out["dt_offset_s"] - DT_OFFSET_S) < 0.010, out
    assert 0.0 <= out["quality"] <= 1.0


def test_sync_unrelated_streams_refused():
    """Video and Vicon of two different motions: SyncError (quality below min_quality)."""
    poses, _, _ = make_session(duration_video_s=8.0, seed=2)
    _, bodies, _ = make_session(duration_video_s=8.0, seed=3)
    with pytest.raises(SyncError, match="quality|edge"):
        sync_angular_speed(poses, bodies, max_offset_s=3.0, min_quality=0.5)


def test_sync_peak_at_search_boundary_refused(session):
    """A search range that stops short of the true offset puts the peak at its edge: SyncError."""
    poses, bodies, _ = session
    with pytest.raises(SyncError, match="edge of the search range"):
        sync_angular_speed(poses, bodies, max_offset_s=2.3, min_quality=0.0)


def test_take_shorter_than_video_names_both_spans(session):
    """A take lasting under 20 % of the video stops sync (InputError naming both spans); the
    pairs side (a take overlapping 14 % of the video) is
    test_pairs.py::test_pairs_take_overlapping_14_percent_names_both_spans."""
    poses, bodies, _ = session
    tiny = bodies[bodies["t_s"] < 2.0]
    with pytest.raises(InputError, match=r"take spans 0\.000\.\.1\.997 s.*video spans 0\.000\.\.11\.967 s"):
        sync_angular_speed(poses, tiny)
    with pytest.raises(InputError, match="does not cover the video"):
        check_take_covers_video((0.0, 10.0), (0.0, 11.0), dt_offset_s=2.0)


def test_partial_overlap_uses_what_overlaps(session):
    """A take that stops 1 s before the video ends: sync still finds the offset, reports the
    overlap share (about 92 %) and a warning under min_overlap_share (the pairs side is
    test_pairs.py::test_pairs_partial_overlap_uses_what_overlaps)."""
    poses, bodies, _ = session
    t_end = DT_OFFSET_S + float(poses["t_s"].max()) - 1.0
    cut = bodies[bodies["t_s"] <= t_end]
    out = synchronise(poses, cut, max_offset_s=10.0, min_quality=0.2, min_overlap_share=0.95)
    assert abs(out["dt_offset_s"] - DT_OFFSET_S) < 0.002
    inside = (poses["t_s"] + DT_OFFSET_S <= t_end).mean()
    assert abs(out["overlap_share"] - inside) < 0.01
    assert 0.9 < out["overlap_share"] < 0.95
    assert len(out["warnings"]) == 1 and "min_overlap_share 0.95" in out["warnings"][0]
    quiet = synchronise(poses, cut, max_offset_s=10.0, min_quality=0.2, min_overlap_share=0.8)
    assert quiet["warnings"] == []


@pytest.mark.parametrize("end", ["first", "second"])
def test_take_covering_half_the_video_synchronises_with_a_warning(session, end):
    """A take covering the first (or second) half of the video: before, 'correlation peak at the
    edge of the search range' (the search wanted half the video inside the take, so the true
    lag sat on its edge); now the offset within 3 ms, overlap_share 0.5 and one warning naming
    both spans, as docs/failures.md says for any overlap of at least 20 %."""
    poses, bodies, _ = session
    t_cut = DT_OFFSET_S + 0.5 * float(poses["t_s"].max())
    cut = bodies[bodies["t_s"] <= t_cut] if end == "first" else bodies[bodies["t_s"] >= t_cut]
    out = synchronise(poses, cut, max_offset_s=30.0, min_quality=0.25)
    assert abs(out["dt_offset_s"] - DT_OFFSET_S) < 0.003
    assert abs(out["overlap_share"] - 0.5) < 0.01
    (warning,) = out["warnings"]
    assert re.search(r"only 5\d\.\d % of the video frames fall inside the Vicon take .*video frames span "
                     r"0\.000\.\.11\.967 s.*the take spans \d+\.\d{3}\.\.\d+\.\d{3} s", warning)


def test_take_overlapping_too_little_says_so_with_both_spans(session):
    """Where the overlap limits the search the sync says the overlap is too short, with both
    spans: the best lag on the limit (not 'at the edge of the search range'), or no lag at all;
    a take covering 20 % of a 12 s video needs quality 0.5 (its best lag, 2 s off, scored 0.29,
    which min_quality 0.25 would have taken)."""
    poses, bodies, _ = session
    t_v = float(poses["t_s"].max())
    late = bodies[bodies["t_s"] >= DT_OFFSET_S + 0.4 * t_v]
    spans = r"the video spans 0\.000\.\.11\.967 s \(11\.967 s, video clock\), the take 7\.1\d\d\.\.15\.367 s"
    with pytest.raises(OverlapError, match=r"overlap of the take and the video is too short: the best lag "
                       rf"\(dt = .* inside the take, at the limit of the search .*{spans}"):
        sync_angular_speed(poses, late, max_offset_s=10.0, min_quality=0.5, min_overlap_frac=0.8)
    with pytest.raises(OverlapError, match=r"too short: no lag within \+-10\.0 s puts \d+ % of the video's "
                       rf"frames with a board inside the take .*{spans}"):
        sync_angular_speed(poses, late, max_offset_s=10.0, min_quality=0.5, min_overlap_frac=0.9)
    early = bodies[bodies["t_s"] <= DT_OFFSET_S + 0.2 * t_v]
    with pytest.raises(SyncError, match=r"below min_quality 0\.5 .*take is shorter than the video.*"
                       r"the take 0\.000\.\.4\.\d{3} s"):
        synchronise(poses, early, max_offset_s=30.0, min_quality=0.25)


def test_streams_for_the_figure(session):
    """angular_speed_streams returns both streams with matching lengths and the video window."""
    poses, bodies, _ = session
    s = angular_speed_streams(poses, bodies)
    assert len(s["t_cvs_s"]) == len(s["omega_cvs_rad_s"]) == len(poses) - 1
    assert len(s["t_vicon_s"]) == len(s["omega_vicon_rad_s"])


def test_sync_figure(session):
    """plot_sync draws both streams before the offset (each on its own clock) and after it on the
    Vicon clock with deg/s and s axis labels, and the aligned residual is small compared with the
    signal (median |diff| < 20 % of median speed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cvsflow.plots.mocap import plot_sync

    poses, bodies, _ = session
    fig = plot_sync(poses, bodies, {"dt_offset_s": DT_OFFSET_S, "quality": 0.9, "method": "angular_speed"})
    ax_raw, ax0, ax1 = fig.axes
    assert "before" in ax_raw.get_title() and "after" in ax0.get_title()
    video_raw, video_shifted = ax_raw.lines[1].get_xdata(), ax0.lines[1].get_xdata()
    assert np.allclose(video_shifted - video_raw, DT_OFFSET_S)
    assert "deg/s" in ax0.get_ylabel() and ax1.get_xlabel() == "Vicon time t (s)"
    resid = ax1.lines[0].get_ydata()
    speed = ax0.lines[1].get_ydata()
    assert np.nanmedian(np.abs(resid)) < 0.2 * np.nanmedian(np.abs(speed))
    plt.close(fig)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A 4 s session rendered by cvsflow.synth (marker noise off, dropouts on), read back from
    its Nexus CSV through the whole Vicon half."""
    import copy
    from pathlib import Path

    import yaml

    synth = pytest.importorskip("cvsflow.synth.render")
    from cvsflow.io.mocap.formats import read_markers
    from cvsflow.mocap.repair import fill_marker_gaps

    cfg_path = Path(__file__).resolve().parents[3] / "config" / "config.yaml"
    session_cfg = copy.deepcopy(yaml.safe_load(cfg_path.read_text())["sessions"]["demo"])
    session_cfg["synth"].update(duration_s=4.0, n_stills=1, marker_noise_sigma_m=0.0)
    out = tmp_path_factory.mktemp("render") / "demo"
    synth.render_session(session_cfg, out)
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    mk = session_cfg["markers"]
    markers = read_markers(out / "vicon.csv", names=mk["camera"]["names"] + mk["board"]["names"])
    specs = {
        body: {"names": mk[body]["names"], "layout_m": np.array([truth[key][n] for n in mk[body]["names"]])}
        for body, key in (("camera", "markers_Cm_m"), ("board", "markers_Bm_m"))
    }
    filled, summary = fill_marker_gaps(markers, specs, max_gap_s=0.1)
    bodies = fit_bodies(filled, specs)
    frames = pd.read_parquet(out / "truth_frames.parquet")
    return truth, frames, bodies, summary


def test_rendered_session_bodies_within_1mm_01deg(rendered):
    """On the rendered session (dropouts filled), camera and board body poses are within 1 mm and
    0.1 deg of truth (T_W_Cm; T_W_Bm = T_W_Cm T_Cm_C T_C_B inv(T_Bm_B) at the true offset)."""
    from cvsflow.geometry.transforms import R_from_quat
    from cvsflow.mocap.bodies import body_poses, interpolate_bodies

    truth, frames, bodies, summary = rendered
    assert summary["total"]["missing"] == 0 and summary["total"]["rigid"] > 0
    T_W_Cm = np.array(truth["T_W_Cm"])
    T_C_B = make_T(R_from_quat(frames[["qx", "qy", "qz", "qw"]].to_numpy(copy=True)), frames[["x_m", "y_m", "z_m"]].to_numpy())
    T_W_Bm = T_W_Cm @ np.array(truth["T_Cm_C"]) @ T_C_B @ invert_T(np.array(truth["T_Bm_B"]))
    at = interpolate_bodies(bodies, frames["t_s"].to_numpy() + truth["dt_offset_s"])
    for body, T_true in (("board", T_W_Bm), ("camera", np.broadcast_to(T_W_Cm, T_W_Bm.shape))):
        _, T, ok = body_poses(at, body)
        assert ok.all()
        dT = invert_T(T_true) @ T
        assert np.linalg.norm(dT[:, :3, 3], axis=1).max() < 0.001, body
        assert np.degrees(rotation_angle(dT[:, :3, :3])).max() < 0.1, body


def test_rendered_session_sync_within_3ms(rendered):
    """Angular-speed sync of the true video poses plus 0.1 deg rotation noise against the
    rendered Vicon export recovers truth.yaml's dt_offset_s within 2 ms (0.4 ms seen; the
    issue asks for 3 ms)."""
    truth, frames, bodies, _ = rendered
    rng = np.random.default_rng(21)
    R = Rotation.from_quat(frames[["qx", "qy", "qz", "qw"]].to_numpy(copy=True))
    R = R * Rotation.from_rotvec(rng.normal(0.0, np.radians(0.1), (len(frames), 3)))
    rvec = R.as_rotvec()
    poses = pd.DataFrame({
        "frame": frames["frame"], "t_s": frames["t_s"], "valid": frames["in_view"],
        "rvec_0": rvec[:, 0], "rvec_1": rvec[:, 1], "rvec_2": rvec[:, 2],
        "x_m": frames["x_m"], "y_m": frames["y_m"], "z_m": frames["z_m"],
    })
    out = sync_angular_speed(poses, bodies, max_offset_s=10.0, min_quality=0.5)
    assert abs(out["dt_offset_s"] - truth["dt_offset_s"]) < 0.002, (out, truth["dt_offset_s"])
    pairs = build_pairs(poses, bodies, out["dt_offset_s"], mode="interp")
    assert len(pairs) == int(frames["in_view"].sum())


def test_given_offset_is_written_not_searched(session):
    """A session that states its offset gets it in sync.yaml as given (no quality, no search),
    with the overlap checked at that offset."""
    poses, bodies, _ = session
    out = given_offset(poses, bodies, DT_OFFSET_S)
    assert out["dt_offset_s"] == DT_OFFSET_S and out["method"] == "given" and out["quality"] is None
    assert out["overlap_share"] == pytest.approx(1.0) and out["warnings"] == []
    with pytest.raises(OverlapError, match="video frames"):
        given_offset(poses, bodies, DT_OFFSET_S + 1e4)
