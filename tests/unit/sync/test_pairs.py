"""Pairs (block and interpolated frame association) against a synthetic session with known offset."""

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import NoUsableRowsError, OverlapError
from cvsflow.geometry.transforms import invert_T, make_T, pose6_from_T, rotation_angle, wrap_angle
from cvsflow.mocap.bodies import block_average_bodies, interpolate_bodies
from cvsflow.sync.pairs import build_pairs, make_pairs
from tests.helpers.sync_session import DT_OFFSET_S, T_BM_B, T_CM_C, make_session


@pytest.fixture(scope="module")
def session():
    return make_session()


@pytest.fixture(scope="module")
def clean_session():
    """Marker noise off: the pose targets hold before marker noise (a 0.3 mm marker noise on the
    0.17 m camera body already tilts it by ~0.1 deg, i.e. ~3 mm at the board 1.5 m away)."""
    return make_session(duration_video_s=6.0, noise_m=0.0, seed=5)


def test_pairs_take_overlapping_14_percent_names_both_spans(session):
    """A take that overlaps only 14 % of the video at the offset stops pairs (OverlapError, both
    spans); the sync side of a short take is test_sync.py::test_take_shorter_than_video_names_both_spans."""
    poses, bodies, _ = session
    short = bodies[bodies["t_s"] < 4.0]
    with pytest.raises(OverlapError, match=r"pairs: only \d+ of 360 video frames \(1\d\.\d %\).*"
                       r"video frames span 0\.000\.\.11\.967 s.*take spans"):
        build_pairs(poses, short, DT_OFFSET_S, mode="interp")


def test_pairs_partial_overlap_uses_what_overlaps(session):
    """A take that stops 1 s before the video ends: pairs keeps exactly the frames inside the
    take, in both modes, with the share and warning in attrs (the sync side is
    test_sync.py::test_partial_overlap_uses_what_overlaps)."""
    poses, bodies, _ = session
    t_end = DT_OFFSET_S + float(poses["t_s"].max()) - 1.0
    cut = bodies[bodies["t_s"] <= t_end]
    inside = (poses["t_s"] + DT_OFFSET_S <= t_end).mean()
    pairs = build_pairs(poses, cut, DT_OFFSET_S, mode="interp", min_overlap_share=0.95)
    assert pairs["t_vicon_s"].max() <= t_end
    full = build_pairs(poses, bodies, DT_OFFSET_S, mode="interp")
    assert abs(len(pairs) - int((full["t_vicon_s"] <= t_end).sum())) <= 1  # the last sample
    assert pairs.attrs["warnings"] and abs(pairs.attrs["overlap_share"] - inside) < 0.01
    lo = block_average_bodies(cut, 10)
    pb = build_pairs(poses, lo, DT_OFFSET_S, mode="block", min_overlap_share=0.8)
    assert 0.9 * len(pairs) < len(pb) <= len(pairs) + 1 and pb.attrs["warnings"] == []


def test_pairs_zero_rows_names_counts(session):
    """Pairs with no valid CVS pose: NoUsableRowsError naming both counts, not an empty table."""
    poses, bodies, _ = session
    none = poses.assign(valid=False)
    with pytest.raises(NoUsableRowsError, match=r"0 of 360 video frames.*0 frames with a CVS pose"):
        build_pairs(none, bodies, DT_OFFSET_S, mode="interp")


def test_pairs_interp_match_truth(clean_session):
    """interp pairs: T_Cm_Bm = inv(T_W_Cm) T_W_Bm within 1 mm / 0.1 deg of truth; composing with
    the true T_Cm_C and T_Bm_B gives T_C_B within 1 mm / 0.1 deg; CVS columns pass through; P*
    is the wrapped 6-vector difference (eq. 1.5); only valid CVS frames."""
    poses, bodies, T_true = clean_session
    pairs = build_pairs(poses, bodies, DT_OFFSET_S, mode="interp")
    assert len(pairs) == int(poses["valid"].sum())
    np.testing.assert_allclose(pairs["t_vicon_s"] - pairs["t_s"], DT_OFFSET_S, atol=1e-12)
    q = pairs[["cmbm_qx", "cmbm_qy", "cmbm_qz", "cmbm_qw"]].to_numpy(copy=True)
    T_Cm_Bm = make_T(Rotation.from_quat(q).as_matrix(), pairs[["cmbm_x_m", "cmbm_y_m", "cmbm_z_m"]].to_numpy())
    T_C_B = invert_T(T_CM_C) @ T_Cm_Bm @ T_BM_B
    dT = invert_T(T_true[pairs["frame"].to_numpy()]) @ T_C_B
    assert np.linalg.norm(dT[:, :3, 3], axis=1).max() < 0.001
    assert np.degrees(rotation_angle(dT[:, :3, :3])).max() < 0.1
    sel = poses.set_index("frame").loc[pairs["frame"]]
    np.testing.assert_allclose(pairs["cvs_rvec_0"], sel["rvec_0"], atol=1e-12)
    np.testing.assert_allclose(pairs["cvs_z_m"], sel["z_m"], atol=1e-12)

    def T_of(prefix):
        qq = pairs[[f"{prefix}_q{c}" for c in "xyzw"]].to_numpy(copy=True)
        return make_T(Rotation.from_quat(qq).as_matrix(), pairs[[f"{prefix}_{c}_m" for c in "xyz"]].to_numpy())

    P_star = pose6_from_T(T_of("wbm")) - pose6_from_T(T_of("wcm"))
    P_star[:, 3:] = wrap_angle(P_star[:, 3:])
    got = pairs[[f"vic_{n}" for n in ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")]].to_numpy()
    np.testing.assert_allclose(got, P_star, atol=1e-9)
    assert np.all(np.abs(got[:, 3:]) <= np.pi)


def test_pairs_block_nearest_within_half_block(clean_session):
    """block pairs take the nearest 10-sample block (its time within 16.7 ms of the frame's Vicon
    time), and a block mean equals the SLERP pose at the block time within 0.5 mm / 0.05 deg."""
    poses, bodies, _ = clean_session
    lo = block_average_bodies(bodies, 10)
    pb = build_pairs(poses, lo, DT_OFFSET_S, mode="block")
    assert len(pb) == len(build_pairs(poses, bodies, DT_OFFSET_S, mode="interp"))
    t_blk = lo.loc[lo.body == "board", "t_s"].to_numpy()
    gap = np.abs(pb["t_vicon_s"].to_numpy()[:, None] - t_blk[None])
    k = np.argmin(gap, axis=1)
    assert gap[np.arange(len(k)), k].max() <= 0.5 / 30 + 1e-9
    at_blocks = interpolate_bodies(bodies, t_blk[k])
    wbm_blk = lo[lo.body == "board"].reset_index(drop=True).loc[k, ["x_m", "y_m", "z_m"]].to_numpy()
    np.testing.assert_allclose(pb[["wbm_x_m", "wbm_y_m", "wbm_z_m"]].to_numpy(), wbm_blk, atol=1e-12)
    board_at = at_blocks[at_blocks.body == "board"]
    d = np.linalg.norm(board_at[["x_m", "y_m", "z_m"]].to_numpy() - wbm_blk, axis=1)
    assert d.max() < 0.0005  # curvature bias of a 33 ms mean: a T^2 / 24
    q_blk = lo[lo.body == "board"].reset_index(drop=True).loc[k, ["qx", "qy", "qz", "qw"]].to_numpy(copy=True)
    q_at = board_at[["qx", "qy", "qz", "qw"]].to_numpy(copy=True)
    ang = (Rotation.from_quat(q_blk).inv() * Rotation.from_quat(q_at)).magnitude()
    assert np.degrees(ang).max() < 0.05


def test_make_pairs_picks_the_configured_table(clean_session):
    """make_pairs uses the 30 Hz table for block and the native table for interp."""
    poses, bodies, _ = clean_session
    lo = block_average_bodies(bodies, 10)
    pd.testing.assert_frame_equal(make_pairs(poses, bodies, lo, DT_OFFSET_S, resample="block"),
                                  build_pairs(poses, lo, DT_OFFSET_S, mode="block"))
    pd.testing.assert_frame_equal(make_pairs(poses, bodies, lo, DT_OFFSET_S, resample="interp"),
                                  build_pairs(poses, bodies, DT_OFFSET_S, mode="interp"))
