"""Marker gap repair, low-pass filter, rigid-body fit and 30 Hz tables against synthetic truth."""

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from cvsflow.errors import MocapError
from cvsflow.mocap import (
    BODY_COLUMNS,
    block_average_bodies,
    body_poses,
    downsample_bodies,
    fill_marker_gaps,
    fit_bodies,
    fit_rigid,
    interpolate_bodies,
    learn_layout,
    lowpass_markers,
    refine_layout,
    repair_markers,
)
from cvsflow.transforms import invert_T, make_T, rotation_angle, transform_points

RATE_HZ = 300.0
BOARD_LAYOUT_M = np.array([[0.0, 0.0, 0.0], [0.76, 0.0, 0.0], [0.0, 0.52, 0.0], [0.58, 0.5, 0.0]])
CAMERA_LAYOUT_M = np.array([[0.0, 0.0, 0.0], [0.0, 0.16, 0.0], [0.0, 0.0, 0.12], [0.0, 0.11, 0.17]])
BOARD_NAMES = ["board:B1", "board:B2", "board:B3", "board:B4"]
CAMERA_NAMES = ["camera:C1", "camera:C2", "camera:C3", "camera:C4"]


def _specs(learn=False):
    return {
        "camera": {"names": CAMERA_NAMES, "layout_m": None if learn else CAMERA_LAYOUT_M},
        "board": {"names": BOARD_NAMES, "layout_m": None if learn else BOARD_LAYOUT_M},
    }


def board_motion(t_s, still_s=0.0):
    """True T_W_Bm (N, 4, 4): smooth hand-like motion, still for the first still_s seconds."""
    tau = np.clip(t_s - still_s, 0.0, None)
    rotvec = np.stack(
        [0.5 * np.sin(1.3 * tau), 0.35 * np.sin(0.9 * tau + 0.4), 0.3 * np.sin(0.7 * tau + 1.0)],
        axis=1,
    )
    pos = np.stack(
        [1.0 + 0.3 * np.sin(0.8 * tau), 0.2 * np.sin(1.1 * tau), 1.2 + 0.15 * np.sin(0.6 * tau)],
        axis=1,
    )
    return make_T(Rotation.from_rotvec(rotvec).as_matrix(), pos)


def camera_pose():
    """True T_W_Cm (4, 4), fixed."""
    return make_T(Rotation.from_rotvec([0.05, -0.1, 0.2]).as_matrix(), [-0.5, 0.1, 1.0])


def synthetic_markers(duration_s=4.0, noise_m=0.0, seed=0, still_s=0.0):
    """Marker table of both bodies at 300 Hz with their true poses."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * RATE_HZ))
    frame = np.arange(n)
    t_s = frame / RATE_HZ
    T_W_Bm = board_motion(t_s, still_s)
    T_W_Cm = np.broadcast_to(camera_pose(), (n, 4, 4))
    data = {"frame": frame, "t_s": t_s}
    for names, layout, T in ((CAMERA_NAMES, CAMERA_LAYOUT_M, T_W_Cm), (BOARD_NAMES, BOARD_LAYOUT_M, T_W_Bm)):
        for name, p in zip(names, layout, strict=True):
            xyz = transform_points(T, p) + rng.normal(0.0, noise_m, (n, 3))
            for a, axis in enumerate("xyz"):
                data[f"{name}_{axis}_m"] = xyz[:, a]
    df = pd.DataFrame(data)
    df.attrs["rate_hz"] = RATE_HZ
    df.attrs["markers"] = CAMERA_NAMES + BOARD_NAMES
    return df, T_W_Cm, T_W_Bm


def _pose_errors(T_est, T_true):
    dT = invert_T(T_true) @ T_est
    return np.linalg.norm(dT[:, :3, 3], axis=1), np.degrees(rotation_angle(dT[:, :3, :3]))


def test_fit_rigid_recovers_random_transforms_planar_layout():
    """Kabsch on a planar 4-marker layout recovers random rigid transforms to 1e-9 (no reflections)."""
    rng = np.random.default_rng(11)
    R = Rotation.random(200, random_state=rng).as_matrix()
    T_true = make_T(R, rng.uniform(-3, 3, (200, 3)))
    Q = transform_points(T_true[:, None], BOARD_LAYOUT_M[None])
    T, rms, n_used = fit_rigid(BOARD_LAYOUT_M, Q)
    np.testing.assert_allclose(T, T_true, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(T[:, :3, :3]), 1.0, atol=1e-9)
    assert np.all(rms < 1e-9) and np.all(n_used == 4)


def test_fit_rigid_three_markers_and_degenerate():
    """Three visible markers suffice; two, or three collinear, give NaN (invalid)."""
    rng = np.random.default_rng(12)
    T_true = make_T(Rotation.random(3, random_state=rng).as_matrix(), rng.normal(size=(3, 3)))
    Q = transform_points(T_true[:, None], BOARD_LAYOUT_M[None]).copy()
    Q[0, 3] = np.nan
    Q[1, 2:] = np.nan
    T, rms, n_used = fit_rigid(BOARD_LAYOUT_M, Q)
    np.testing.assert_allclose(T[0], T_true[0], atol=1e-9)
    assert np.isnan(T[1]).all() and n_used[1] == 2
    line = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    T_line, _, _ = fit_rigid(line, transform_points(T_true[2], line)[None])
    assert np.isnan(T_line).all()


def test_fit_bodies_matches_truth_noise_free_and_noisy():
    """Body poses within 1e-6 mm / deg of truth without noise; within 1 mm and 0.1 deg with
    0.3 mm marker noise; schema as contracts; fit_rms_m reflects the noise level."""
    df, T_W_Cm, T_W_Bm = synthetic_markers(duration_s=2.0)
    bodies = fit_bodies(df, _specs())
    assert list(bodies.columns) == BODY_COLUMNS
    for body, T_true in (("camera", T_W_Cm), ("board", T_W_Bm)):
        _, T, valid = body_poses(bodies, body)
        assert valid.all()
        dp, dang = _pose_errors(T, T_true)
        assert dp.max() < 1e-9 and dang.max() < 1e-6
    df, _, T_W_Bm = synthetic_markers(duration_s=2.0, noise_m=0.0003, seed=3)
    bodies = fit_bodies(df, _specs())
    _, T, _ = body_poses(bodies, "board")
    dp, dang = _pose_errors(T, T_W_Bm)
    # noise of 0.3 mm over lever arms of ~0.3 m: about 0.05 deg RMS, 0.2 deg at worst
    assert dp.max() < 0.001 and np.sqrt(np.mean(dang**2)) < 0.06 and dang.max() < 0.2
    rms = bodies.loc[bodies.body == "board", "fit_rms_m"]
    assert 0.0001 < rms.median() < 0.0006


def test_rigid_fill_is_exact_and_flagged():
    """A one-marker gap with three markers measured is filled from the rigid body (exact without
    noise), flagged, counted as rigid, and measured samples are left untouched."""
    df, _, _ = synthetic_markers(duration_s=2.0)
    truth = df.copy()
    cols = [f"board:B2_{a}_m" for a in "xyz"]
    df.loc[100:159, cols] = np.nan  # 0.2 s: longer than max_gap_s, rigid fill still applies
    filled, summary = fill_marker_gaps(df, _specs(), max_gap_s=0.1)
    np.testing.assert_allclose(filled[cols].to_numpy(), truth[cols].to_numpy(), atol=1e-9)
    flags = filled["board:B2_filled"].to_numpy()
    assert flags[100:160].all() and flags.sum() == 60
    assert summary["per_marker"]["board:B2"] == {"measured": 540, "rigid": 60, "interp": 0, "missing": 0}
    assert not filled["board:B1_filled"].any()
    np.testing.assert_array_equal(filled["board:B1_x_m"], truth["board:B1_x_m"])


def test_refined_layout_stops_the_pose_jump_when_a_marker_drops_out():
    """Camera markers placed 1-4 mm off the drawn layout_m, C3 missing for 0.2 s: fitted to the
    drawn layout the static camera's orientation jumps by over 5 mrad at the dropout; with the
    layout the markers show (refine_layout) it stays within 0.01 mrad, and a fully seen body
    keeps the drawn layout's frame (the refined layout fits the drawn one as the markers do)."""
    rng = np.random.default_rng(5)
    df, _, _ = synthetic_markers(duration_s=2.0)
    true_layout = CAMERA_LAYOUT_M + rng.uniform(-0.004, 0.004, CAMERA_LAYOUT_M.shape)
    T_W_Cm = camera_pose()
    for name, p in zip(CAMERA_NAMES, true_layout, strict=True):
        df[[f"{name}_{a}_m" for a in "xyz"]] = transform_points(T_W_Cm, p)
    df.loc[100:159, [f"camera:C3_{a}_m" for a in "xyz"]] = np.nan
    jumps = {}
    for refine in (False, True):
        filled, _ = fill_marker_gaps(df, _specs(), max_gap_s=0.1, refine_layout=refine)
        _, T, valid = body_poses(fit_bodies(filled, _specs(), refine_layout=refine), "camera")
        assert valid.all()
        full = np.r_[0:100, 160:len(df)]
        jumps[refine] = 1e3 * rotation_angle(T[100:160, :3, :3] @ np.swapaxes(T[full[:1], :3, :3], 1, 2)).max()
        np.testing.assert_allclose(T[full], np.broadcast_to(T[0], T[full].shape), atol=1e-12)
    assert jumps[False] > 5.0 and jumps[True] < 0.01
    refined = refine_layout(df, CAMERA_NAMES, CAMERA_LAYOUT_M)
    # the same shape as the true markers (pairwise distances), in the drawn layout's frame
    d = lambda L: np.linalg.norm(L[:, None] - L[None], axis=-1)  # noqa: E731
    np.testing.assert_allclose(d(refined), d(true_layout), atol=1e-9)
    T_fit, _, _ = fit_rigid(CAMERA_LAYOUT_M, refined[None])
    np.testing.assert_allclose(T_fit[0], np.eye(4), atol=1e-9)


def test_repair_summary_warns_of_markers_never_seen_and_long_gaps():
    """vicon_repair.yaml's ``warnings``: none on a clean take; a marker never measured (here
    refilled from its body every sample) is named; over 20 % of the samples missing is counted."""
    df, _, _ = synthetic_markers(duration_s=2.0)
    assert fill_marker_gaps(df, _specs(), max_gap_s=0.1)[1]["warnings"] == []
    bad = df.copy()
    bad[[f"board:B2_{a}_m" for a in "xyz"]] = np.nan
    for n in ("camera:C1", "camera:C2"):
        bad.loc[: len(bad) // 2, [f"{n}_{a}_m" for a in "xyz"]] = np.nan
    _, summary = fill_marker_gaps(bad, _specs(), max_gap_s=0.1)
    text = " | ".join(summary["warnings"])
    assert "markers ['board:B2'] never measured in 600 samples" in text
    camera_gone = df.copy()
    for n in ("camera:C1", "camera:C2", "camera:C3"):
        camera_gone[[f"{n}_{a}_m" for a in "xyz"]] = np.nan
    text = " | ".join(fill_marker_gaps(camera_gone, _specs(), max_gap_s=0.1)[1]["warnings"])
    assert "1800 of 4800 marker samples (37.5 %) stay missing" in text


def test_interpolation_fill_short_gaps_within_1mm():
    """Where only two markers of a body remain, gaps up to max_gap_s are interpolated in time
    within 1 mm of truth (cubic and linear); longer gaps stay NaN, unflagged, counted missing."""
    df, _, _ = synthetic_markers(duration_s=3.0, noise_m=0.0001, seed=4)
    truth, _, _ = synthetic_markers(duration_s=3.0, noise_m=0.0, seed=4)
    short = slice(200, 229)  # 30 samples = 0.1 s
    long = slice(500, 559)  # 60 samples = 0.2 s
    for name in ("board:B1", "board:B2"):
        cols = [f"{name}_{a}_m" for a in "xyz"]
        df.loc[short.start : short.stop, cols] = np.nan
        df.loc[long.start : long.stop, cols] = np.nan
    for method in ("cubic", "linear"):
        filled, summary = fill_marker_gaps(df, _specs(), max_gap_s=0.1, method=method)
        for name in ("board:B1", "board:B2"):
            cols = [f"{name}_{a}_m" for a in "xyz"]
            err = np.linalg.norm(filled.loc[200:229, cols].to_numpy() - truth.loc[200:229, cols].to_numpy(), axis=1)
            assert err.max() < 0.001, (method, err.max())
            assert np.isnan(filled.loc[500:559, cols].to_numpy()).all()
            assert not filled.loc[500:559, f"{name}_filled"].any()
            assert filled.loc[200:229, f"{name}_filled"].all()
            assert summary["per_marker"][name] == {"measured": 810, "rigid": 0, "interp": 30, "missing": 60}
        assert summary["total"]["interp"] == 60 and summary["total"]["missing"] == 120
    bodies = fit_bodies(filled, _specs())
    board = bodies[bodies.body == "board"]
    assert (~board["valid"]).sum() == 60
    assert board.loc[board.frame.between(200, 229), "n_filled"].eq(2).all()


def test_gap_at_take_edge_is_not_extrapolated():
    """A gap touching the start of the take is not interpolated (no data on one side)."""
    df, _, _ = synthetic_markers(duration_s=1.0)
    cols = [f"board:B1_{a}_m" for a in "xyz"] + [f"board:B2_{a}_m" for a in "xyz"]
    df.loc[0:4, cols] = np.nan
    filled, summary = fill_marker_gaps(df, _specs(), max_gap_s=0.1)
    assert np.isnan(filled.loc[0:4, cols].to_numpy()).all()
    assert summary["per_marker"]["board:B1"]["missing"] == 5


def test_lowpass_zero_lag_reduces_noise_and_keeps_gaps():
    """The Butterworth filtfilt reduces 1 mm white noise at least 3-fold on a 1 Hz motion with no
    phase lag (error to truth below 0.33 mm RMS away from edges), and NaN samples stay NaN."""
    rng = np.random.default_rng(5)
    t = np.arange(1500) / RATE_HZ
    truth = 0.1 * np.sin(2 * np.pi * 1.0 * t)
    noisy = truth + rng.normal(0, 0.001, t.size)
    noisy[700:720] = np.nan
    df = pd.DataFrame({"frame": np.arange(t.size), "t_s": t, "m_x_m": noisy, "m_y_m": truth, "m_z_m": truth})
    df.attrs["rate_hz"] = RATE_HZ
    out = lowpass_markers(df, cutoff_hz=6.0, order=2)
    ok = ~np.isnan(noisy)
    assert np.isnan(out["m_x_m"].to_numpy()[700:720]).all()
    err = out["m_x_m"].to_numpy()[ok] - truth[ok]
    idx = np.arange(t.size)[ok]
    interior = (np.abs(idx - 710) > 60) & (idx > 60) & (idx < t.size - 60)
    assert np.std(err[interior]) < 0.00033
    # noise-free: only the 0.08 % gain loss at 1 Hz (1e-4 m), so no lag above 0.2 ms
    np.testing.assert_allclose(out["m_y_m"].to_numpy()[100:-100], truth[100:-100], atol=1e-4)
    with pytest.raises(MocapError, match="cutoff"):
        lowpass_markers(df, cutoff_hz=200.0)


def test_learn_layout_from_still_start():
    """A layout learned from the still first second equals the true layout up to a rigid motion
    (pairwise distances within 0.1 mm), with marker 1 at the origin, marker 2 on +x, z normal to
    markers 1-3; bodies fitted with learned layouts have the same relative motion as the truth."""
    df, _, T_W_Bm = synthetic_markers(duration_s=3.0, noise_m=0.0001, seed=6, still_s=1.2)
    layout = learn_layout(df, BOARD_NAMES, still_s=1.0)
    d_true = np.linalg.norm(BOARD_LAYOUT_M[:, None] - BOARD_LAYOUT_M[None], axis=2)
    d_est = np.linalg.norm(layout[:, None] - layout[None], axis=2)
    assert np.abs(d_est - d_true).max() < 1e-4
    np.testing.assert_allclose(layout[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(layout[1, 1:], 0.0, atol=1e-12)
    np.testing.assert_allclose(layout[2, 2], 0.0, atol=1e-12)
    assert layout[1, 0] > 0
    bodies = fit_bodies(df, _specs(learn=True))
    _, T, _ = body_poses(bodies, "board")
    rel_est = invert_T(T[0]) @ T[-1]
    rel_true = invert_T(T_W_Bm[0]) @ T_W_Bm[-1]
    # relative motions agree up to the (constant) layout frame change: same rotation angle
    assert abs(rotation_angle(rel_est[:3, :3]) - rotation_angle(rel_true[:3, :3])) < 1e-3


def test_learn_layout_without_still_window_fails():
    """A take with no still second raises MocapError saying so."""
    df, _, _ = synthetic_markers(duration_s=2.0)
    with pytest.raises(MocapError, match="no still window"):
        learn_layout(df, BOARD_NAMES, still_s=1.0)


def _constant_rate_bodies(n=300, invalid=()):
    """Bodies table of a rotation at constant angular rate and a linear translation."""
    t = np.arange(n) / RATE_HZ
    omega = np.array([0.3, -0.8, 1.5])  # rad/s
    T = make_T(Rotation.from_rotvec(t[:, None] * omega).as_matrix(), t[:, None] * [0.2, -0.1, 0.05])
    from cvsflow.mocap import _body_frame

    T = T.copy()
    T[list(invalid)] = np.nan
    df = _body_frame(np.arange(n), t, "board", T, np.full(n, 1e-4), np.full(n, 4), np.zeros(n))
    return df, omega


def test_block_average_constant_rate():
    """Block means of 10 samples equal the pose at the block-mean time for constant-rate motion
    (1e-6 m, 1e-4 deg), block time = mean of sample times, and a block with an invalid sample is
    invalid."""
    bodies, omega = _constant_rate_bodies(invalid=(55,))
    lo = block_average_bodies(bodies, 10)
    assert len(lo) == 30 and list(lo.columns) == BODY_COLUMNS
    t_lo, T_lo, valid = body_poses(lo, "board")
    np.testing.assert_allclose(t_lo, (np.arange(30) * 10 + 4.5) / RATE_HZ, atol=1e-12)
    assert not valid[5] and valid[np.arange(30) != 5].all()
    T_true = make_T(Rotation.from_rotvec(t_lo[:, None] * omega).as_matrix(), t_lo[:, None] * [0.2, -0.1, 0.05])
    dp, dang = _pose_errors(T_lo[valid], T_true[valid])
    assert dp.max() < 1e-6 and dang.max() < 1e-4


def test_interpolate_bodies_slerp_exact_for_constant_rate():
    """SLERP + linear interpolation is exact (1e-9) for constant-rate motion at arbitrary times;
    times outside the take or next to an invalid sample are invalid."""
    bodies, omega = _constant_rate_bodies(invalid=(100,))
    rng = np.random.default_rng(7)
    tq = np.concatenate([rng.uniform(0, 299 / RATE_HZ, 50), [-0.01, 2.0, 100.5 / RATE_HZ]])
    out = interpolate_bodies(bodies, tq)
    _, T, valid = body_poses(out, "board")
    assert not valid[-3:].any()
    ok = valid[:50]
    near_bad = np.abs(tq[:50] * RATE_HZ - 100) < 1
    np.testing.assert_array_equal(ok, ~near_bad)
    T_true = make_T(Rotation.from_rotvec(tq[:50, None] * omega).as_matrix(), tq[:50, None] * [0.2, -0.1, 0.05])
    dp, dang = _pose_errors(T[:50][ok], T_true[ok])
    assert dp.max() < 1e-9 and dang.max() < 1e-7


def test_downsample_bodies_modes():
    """downsample_bodies: block gives round(300/30)=10-sample blocks; interp gives a 1/30 s grid
    over the take; an unknown mode raises MocapError."""
    bodies, _ = _constant_rate_bodies(n=600)
    blk = downsample_bodies(bodies, 30.0, "block")  # rate from the sample spacing
    itp = downsample_bodies(bodies, 30.0, "interp", rate_hz=RATE_HZ)
    assert len(blk) == 60
    np.testing.assert_allclose(itp["t_s"], np.arange(60) / 30.0, atol=1e-12)
    with pytest.raises(MocapError, match="mode"):
        downsample_bodies(bodies, 30.0, "median")


def test_figures_have_units_and_data():
    """plot_marker_gaps and plot_fit_residuals return Figures with labelled axes in s and mm, one row
    per marker, and the fill counts in the labels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cvsflow.plots.mocap import plot_fit_residuals, plot_marker_gaps

    df, _, _ = synthetic_markers(duration_s=1.0, noise_m=0.0002, seed=9)
    df.loc[50:59, [f"board:B2_{a}_m" for a in "xyz"]] = np.nan
    filled, summary = fill_marker_gaps(df, _specs(), max_gap_s=0.1)
    fig = plot_marker_gaps(filled, summary)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "Vicon time t (s)"
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert len(labels) == 8 and "board:B2  (10/0/0)" in labels
    plt.close(fig)
    fig = plot_fit_residuals(fit_bodies(filled, _specs()))
    assert "(mm)" in fig.axes[0].get_ylabel() and "(s)" in fig.axes[1].get_xlabel()
    assert len(fig.axes[0].lines) >= 2
    plt.close(fig)


def test_repair_markers_follows_config():
    """repair_markers fills as fill_marker_gaps and low-passes only when filter.enabled."""
    df, _, _ = synthetic_markers(duration_s=1.0, noise_m=0.001, seed=13)
    df.loc[40:45, [f"board:B3_{a}_m" for a in "xyz"]] = np.nan
    cfg = {"max_gap_s": 0.1, "filter": {"enabled": False, "cutoff_hz": 12.0, "order": 2}}
    raw, summary = repair_markers(df, _specs(), cfg)
    assert summary["filter"] is None and summary["total"]["rigid"] == 6
    np.testing.assert_array_equal(raw["board:B1_x_m"], df["board:B1_x_m"])
    cfg["filter"]["enabled"] = True
    smooth, summary = repair_markers(df, _specs(), cfg)
    assert summary["filter"] == {"cutoff_hz": 12.0, "order": 2, "zero_lag": True}
    assert np.std(np.diff(smooth["board:B1_x_m"])) < 0.5 * np.std(np.diff(df["board:B1_x_m"]))


# --------------------------------------------------------------------------- system bodies


def test_bodies_from_poses_round_trip_and_gaps():
    """System poses become a bodies table: same poses back, NaN rows invalid, residual carried."""
    from cvsflow.mocap import bodies_from_poses

    rng = np.random.default_rng(31)
    n = 50
    R = Rotation.from_rotvec(rng.normal(0, 1, (n, 3))).as_matrix()
    T = make_T(R, rng.uniform(-2, 2, (n, 3)))
    T[[3, 4, 20]] = np.nan
    residual = rng.uniform(1e-4, 1e-3, n)
    # an export rounds its rotations (here to 5 decimals); the table re-orthonormalises them
    T_file = T.copy()
    T_file[:, :3, :3] = np.round(T_file[:, :3, :3], 5)
    out = bodies_from_poses(np.arange(n), np.arange(n) / 100.0, "cam", T_file, residual, np.full(n, -1))
    assert list(out.columns) == BODY_COLUMNS
    _, T_back, valid = body_poses(out, "cam")
    assert valid.tolist() == [i not in (3, 4, 20) for i in range(n)]
    assert rotation_angle(np.einsum("nji,njk->nik", T[valid, :3, :3], T_back[valid, :3, :3])).max() < 2e-5
    np.testing.assert_allclose(T_back[valid, :3, 3], T[valid, :3, 3])
    np.testing.assert_allclose(out["fit_rms_m"].to_numpy()[valid], residual[valid])
    assert out["fit_rms_m"].isna().sum() == 3
    assert (out["n_filled"] == 0).all()


def test_bodies_from_poses_refuses_non_rotations():
    """A 'rotation' that is not orthonormal (a mis-parsed export) is an error naming the frame."""
    from cvsflow.mocap import bodies_from_poses

    T = np.tile(np.eye(4), (5, 1, 1))
    T[2, :3, :3] *= 1.5
    with pytest.raises(MocapError, match=r"body 'cam', frame 12: rotation is not orthonormal"):
        bodies_from_poses(np.arange(10, 15), np.arange(5) / 100.0, "cam", T, np.zeros(5), np.zeros(5))


def test_select_system_bodies_renames_and_names_what_is_missing():
    """System bodies are renamed to camera / board; an absent or never-tracked body is named."""
    from cvsflow.mocap import bodies_from_poses, select_system_bodies

    n = 10
    T = np.tile(np.eye(4), (n, 1, 1))
    lost = np.full((n, 4, 4), np.nan)
    parts = [bodies_from_poses(np.arange(n), np.arange(n) / 100.0, name, T_, np.zeros(n), np.full(n, 4))
             for name, T_ in (("rb_cam", T), ("rb_board", T), ("rb_lost", lost))]
    table = pd.concat(parts, ignore_index=True)
    out = select_system_bodies(table, {"camera": "rb_cam", "board": "rb_board"}, source="take.csv")
    assert list(pd.unique(out["body"])) == ["camera", "board"]
    assert len(out) == 2 * n
    with pytest.raises(MocapError, match=r"take.csv: no rigid body 'rb_x' for the board \(the export has 3 bodies"):
        select_system_bodies(table, {"camera": "rb_cam", "board": "rb_x"}, source="take.csv")
    with pytest.raises(MocapError, match=r"'rb_lost' \(board\) is not tracked in any of its 10 frames"):
        select_system_bodies(table, {"camera": "rb_cam", "board": "rb_lost"}, source="take.csv")
