"""Rigid-body layouts (learned from a still window, refined to the markers) against synthetic truth."""

import numpy as np
import pytest

from cvsflow.exceptions import MocapError
from cvsflow.geometry.rigid import fit_rigid
from cvsflow.geometry.transforms import invert_T, rotation_angle, transform_points
from cvsflow.mocap.bodies import body_poses, fit_bodies
from cvsflow.mocap.layout import learn_layout, refine_layout
from cvsflow.mocap.repair import fill_marker_gaps
from tests.helpers.mocap_markers import (
    BOARD_LAYOUT_M,
    BOARD_NAMES,
    CAMERA_LAYOUT_M,
    CAMERA_NAMES,
    body_specs,
    camera_pose,
    synthetic_markers,
)


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
        filled, _ = fill_marker_gaps(df, body_specs(), max_gap_s=0.1, refine_layout=refine)
        _, T, valid = body_poses(fit_bodies(filled, body_specs(), refine_layout=refine), "camera")
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
    bodies = fit_bodies(df, body_specs(learn=True))
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
