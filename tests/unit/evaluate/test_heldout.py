"""Tests of composed pose errors, time-block folds, cross-validation and block bootstrap."""

from __future__ import annotations

import numpy as np
import pytest

from cvsflow import metrics
from cvsflow.evaluate import heldout as ev
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import transforms as tf
from cvsflow.optimise.se3_sim import simulate_session


def test_pure_yaw_error_of_one_degree():
    """R_est = Rz(1 deg) R_true at a tilted pose: yaw error 1 deg, roll/pitch 0, angle 1 deg
    (in C), translation error zero; to 1e-9."""
    T_true = tf.T_from_pose6([[0.1, -0.2, 2.0, 0.4, -0.3, 0.2]])
    T_est = T_true.copy()
    T_est[:, :3, :3] = tf.R_from_euler([0.0, 0.0, np.radians(1.0)]) @ T_true[:, :3, :3]
    e = metrics.pose_errors(T_true, T_est, frame="C").iloc[0]
    assert e["err_yaw_rad"] == pytest.approx(np.radians(1.0), abs=1e-9)
    assert e["err_roll_rad"] == pytest.approx(0.0, abs=1e-9)
    assert e["err_pitch_rad"] == pytest.approx(0.0, abs=1e-9)
    assert e["err_angle_rad"] == pytest.approx(np.radians(1.0), abs=1e-9)
    assert e["err_dist_m"] == pytest.approx(0.0, abs=1e-12)


def test_translation_error_in_C_and_in_B():
    """A 5 mm shift along C's x: error (5, 0, 0) mm in C; in B it is R_true^T (5, 0, 0) mm,
    computed by hand for a board yawed by 90 deg (-> (0, -5, 0) mm)."""
    T_true = tf.T_from_pose6([[0.0, 0.0, 2.0, 0.0, 0.0, np.pi / 2]])
    T_est = T_true.copy()
    T_est[:, 0, 3] += 0.005
    eC = metrics.pose_errors(T_true, T_est, frame="C").iloc[0]
    eB = metrics.pose_errors(T_true, T_est, frame="B").iloc[0]
    np.testing.assert_allclose([eC.err_x_m, eC.err_y_m, eC.err_z_m], [0.005, 0, 0], atol=1e-12)
    np.testing.assert_allclose([eB.err_x_m, eB.err_y_m, eB.err_z_m], [0, -0.005, 0], atol=1e-12)
    assert eB.err_dist_m == pytest.approx(0.005)


def test_rotation_error_frame_B_is_right_composition():
    """R_est = R_true Rx(2 deg): in B the error is a 2 deg roll; in C the same angle, other axes."""
    T_true = tf.T_from_pose6([[0.0, 0.0, 2.0, 0.0, 0.0, np.pi / 2]])
    T_est = T_true.copy()
    T_est[:, :3, :3] = T_true[:, :3, :3] @ tf.R_from_euler([np.radians(2.0), 0, 0])
    eB = metrics.pose_errors(T_true, T_est, frame="B").iloc[0]
    eC = metrics.pose_errors(T_true, T_est, frame="C").iloc[0]
    assert eB.err_roll_rad == pytest.approx(np.radians(2.0), abs=1e-9)
    assert eC.err_pitch_rad == pytest.approx(np.radians(2.0), abs=1e-9)  # B's x is C's y
    assert eC.err_angle_rad == pytest.approx(eB.err_angle_rad, abs=1e-12)


def test_pose_errors_bad_input():
    """Mismatched shapes and an unknown frame raise OptimiseError naming the problem."""
    with pytest.raises(OptimiseError, match="expected \\(N, 4, 4\\)"):
        metrics.pose_errors(np.eye(4)[None], np.eye(4)[None].repeat(2, 0))
    with pytest.raises(OptimiseError, match="frame 'W'"):
        metrics.pose_errors(np.eye(4)[None], np.eye(4)[None], frame="W")


def test_time_blocks_are_contiguous_balanced_and_seeded():
    """Folds hold whole blocks, near-equal in count; the same seed gives the same folds."""
    t = np.arange(900) / 30.0
    fold = ev.make_time_blocks(t, 3.0, 5, seed=3)
    block = (t // 3.0).astype(int)
    for b in np.unique(block):
        assert len(set(fold[block == b])) == 1
    counts = np.bincount(fold, minlength=5)
    assert counts.min() >= 180 - 90 and counts.max() <= 180 + 90
    np.testing.assert_array_equal(fold, ev.make_time_blocks(t, 3.0, 5, seed=3))
    assert not np.array_equal(fold, ev.make_time_blocks(t, 3.0, 5, seed=4))
    with pytest.raises(OptimiseError, match="fewer than 5 folds"):
        ev.make_time_blocks(t[:30], 3.0, 5, seed=0)


def test_a_short_tail_block_joins_the_one_before():
    """The portrait 1080p render's board was found over 10.07 s: in 2 s blocks its last 0.07 s
    (3 frames) was a fold of its own for every seed that left it alone in one. The tail now
    joins the block before, so every fold gets one 2 s block; a tail of over half a block
    stays a block."""
    t = np.arange(303) / 30.0  # 0 .. 10.067 s
    for seed in range(8):
        counts = np.bincount(ev.make_time_blocks(t, 2.0, 5, seed=seed), minlength=5)
        assert counts.min() >= 60 and counts.sum() == 303, (seed, counts)
    with pytest.raises(OptimiseError, match="5 blocks of 2.0 s"):
        ev.make_time_blocks(t, 2.0, 6, seed=0)
    t = np.arange(340) / 30.0  # 0 .. 11.3 s: a 1.3 s tail is a sixth block
    fold = ev.make_time_blocks(t, 2.0, 6, seed=0)
    assert (fold == fold[-1]).sum() == (t >= 10.0).sum() == 40


def test_cross_validation_held_out_errors_match_pnp_noise():
    """Held-out se3 errors on a 20 s session: every frame scored once by a fit that did not
    see it; their spread is below 2 mm in x and y, 15 mm in z and 1.5 deg in angle, and the
    mean error is within 3 standard errors of zero in x."""
    s = simulate_session(21, duration_s=20.0)
    folds_done = []
    held, fits = ev.cross_validate_se3(
        s["corners"], s["bodies"], s["camera"], s["board"], s["truth"]["dt_offset_s"],
        n_folds=4, block_s=2.5, seed=0, progress=folds_done.append,
    )  # fmt: skip
    assert len(fits) == 4 and held["frame"].is_unique and len(held) == 600
    assert folds_done == [1, 2, 3, 4]
    summ = metrics.axis_statistics(held[metrics.error_columns()].to_numpy(float))
    assert summ["x_m"]["std"] < 0.002 and summ["y_m"]["std"] < 0.002 and summ["z_m"]["std"] < 0.015
    assert np.degrees(held["err_angle_rad"]).quantile(0.95) < 1.5
    assert abs(summ["x_m"]["mean"]) < 3 * summ["x_m"]["std"] / np.sqrt(len(held) / 30)
    assert {"d6_x_m", "d6_yaw_rad", "fold", "error_frame"} <= set(held.columns)


def test_se3_figures_build_with_labelled_axes():
    """The three se3 figures build from synthetic tables with unit-labelled axes."""
    import matplotlib

    matplotlib.use("Agg")
    from cvsflow.plots import se3 as plots

    rng = np.random.default_rng(9)
    n = 300
    errors = {"t_s": np.arange(n) / 30.0, "error_frame": "C"}
    for d in metrics.ERROR_DIMS:
        errors[f"err_{d}"] = rng.normal(0, 1e-3, n)
        errors[f"d6_{d}"] = rng.normal(0, 1e-3, n)
    import pandas as pd

    errors = pd.DataFrame(errors)
    f1 = plots.plot_heldout_errors(errors)
    f2 = plots.plot_error_bands(errors, np.full((n, 6), 1e-3))
    f3 = plots.plot_parameter_correlation(
        {"correlation": {"names": ["fx", "fy"], "matrix": [[1.0, 0.97], [0.97, 1.0]]}}
    )
    assert "(mm)" in f1.axes[0].get_xlabel() and "(deg)" in f1.axes[3].get_xlabel()
    assert "(s)" in f2.axes[-1].get_xlabel() and "(mm)" in f2.axes[0].get_ylabel()
    assert f3.axes[0].get_xticklabels()[0].get_text() == "fx"
    import matplotlib.pyplot as plt

    plt.close("all")
