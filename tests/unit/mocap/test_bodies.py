"""Rigid-body fit (rule mocap_bodies) and 30 Hz tables (rule mocap_resample) against synthetic truth."""

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import MocapError
from cvsflow.geometry.rigid import fit_rigid
from cvsflow.geometry.transforms import invert_T, make_T, rotation_angle, transform_points
from cvsflow.mocap.bodies import (
    BODY_COLUMNS,
    block_average_bodies,
    body_poses,
    downsample_bodies,
    fit_bodies,
    interpolate_bodies,
)
from cvsflow.mocap.repair import fill_marker_gaps
from tests.helpers.mocap_markers import BOARD_LAYOUT_M, RATE_HZ, body_specs, synthetic_markers


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
    bodies = fit_bodies(df, body_specs())
    assert list(bodies.columns) == BODY_COLUMNS
    for body, T_true in (("camera", T_W_Cm), ("board", T_W_Bm)):
        _, T, valid = body_poses(bodies, body)
        assert valid.all()
        dp, dang = _pose_errors(T, T_true)
        assert dp.max() < 1e-9 and dang.max() < 1e-6
    df, _, T_W_Bm = synthetic_markers(duration_s=2.0, noise_m=0.0003, seed=3)
    bodies = fit_bodies(df, body_specs())
    _, T, _ = body_poses(bodies, "board")
    dp, dang = _pose_errors(T, T_W_Bm)
    # noise of 0.3 mm over lever arms of ~0.3 m: about 0.05 deg RMS, 0.2 deg at worst
    assert dp.max() < 0.001 and np.sqrt(np.mean(dang**2)) < 0.06 and dang.max() < 0.2
    rms = bodies.loc[bodies.body == "board", "fit_rms_m"]
    assert 0.0001 < rms.median() < 0.0006


def _constant_rate_bodies(n=300, invalid=()):
    """Bodies table of a rotation at constant angular rate and a linear translation."""
    t = np.arange(n) / RATE_HZ
    omega = np.array([0.3, -0.8, 1.5])  # rad/s
    T = make_T(Rotation.from_rotvec(t[:, None] * omega).as_matrix(), t[:, None] * [0.2, -0.1, 0.05])
    from cvsflow.mocap.bodies import _body_frame

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


def test_fit_residuals_figure_has_units_and_data():
    """plot_fit_residuals returns a Figure with labelled axes in mm and s and a line per body."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cvsflow.plots.mocap import plot_fit_residuals

    df, _, _ = synthetic_markers(duration_s=1.0, noise_m=0.0002, seed=9)
    df.loc[50:59, [f"board:B2_{a}_m" for a in "xyz"]] = np.nan
    filled, summary = fill_marker_gaps(df, body_specs(), max_gap_s=0.1)
    fig = plot_fit_residuals(fit_bodies(filled, body_specs()))
    assert "(mm)" in fig.axes[0].get_ylabel() and "(s)" in fig.axes[1].get_xlabel()
    assert len(fig.axes[0].lines) >= 2
    plt.close(fig)


# --------------------------------------------------------------------------- system bodies


def test_bodies_from_poses_round_trip_and_gaps():
    """System poses become a bodies table: same poses back, NaN rows invalid, residual carried."""
    from cvsflow.mocap.bodies import bodies_from_poses

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
    from cvsflow.mocap.bodies import bodies_from_poses

    T = np.tile(np.eye(4), (5, 1, 1))
    T[2, :3, :3] *= 1.5
    with pytest.raises(MocapError, match=r"body 'cam', frame 12: rotation is not orthonormal"):
        bodies_from_poses(np.arange(10, 15), np.arange(5) / 100.0, "cam", T, np.zeros(5), np.zeros(5))


def test_select_system_bodies_renames_and_names_what_is_missing():
    """System bodies are renamed to camera / board; an absent or never-tracked body is named."""
    from cvsflow.mocap.bodies import bodies_from_poses, select_system_bodies

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
