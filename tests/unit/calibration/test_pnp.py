"""Tests of cvsflow.calibration.pnp: PnP against exact synthetic truth, on detected corners and on a rendered session."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest

from cvsflow.board.model import board_object_points
from cvsflow.calibration.pnp import POSE_COLUMNS, estimate_poses
from cvsflow.corners.detect import detect_corners
from cvsflow.corners.extract import extract_corners
from cvsflow.exceptions import InputError
from cvsflow.geometry import transforms as tf
from tests.helpers.board_images import (
    BOARD,  # the demo board, 5x4 inner corners
    board_centre_pose,
    random_board_poses,
    render_board,
)
from tests.helpers.sessions import synth_session_cfg

W, H = 640, 480
# Principal point at the pixel centre of the image, so that turning the image by 180 degrees
# is exactly a turn of the camera by 180 degrees about its optical axis.
K_CENTRED = np.array([[700.0, 0.0, (W - 1) / 2], [0.0, 700.0, (H - 1) / 2], [0.0, 0.0, 1.0]])
K_DEMO = np.array([[702.0, 0.0, 331.5], [0.0, 698.0, 247.0], [0.0, 0.0, 1.0]])
DIST_DEMO = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02])


def _T_C_B(rpy, t_C_B):
    """Board pose in the camera from roll/pitch/yaw relative to a fronto-parallel board."""
    return tf.make_T(tf.R_from_euler(rpy), t_C_B)


def _corners_table(frames_uv, t0=0.0):
    """corners.parquet-style table from a list of (N, 2) arrays (None: board not found)."""
    blocks = []
    for f, uv in enumerate(frames_uv):
        if uv is None:
            blocks.append(
                pd.DataFrame(
                    {"frame": [f], "t_s": [t0 + f / 30], "found": [False], "corner": [-1],
                     "u_px": [np.nan], "v_px": [np.nan]}
                )
            )
        else:
            n = len(uv)
            blocks.append(
                pd.DataFrame(
                    {"frame": f, "t_s": t0 + f / 30, "found": True, "corner": np.arange(n),
                     "u_px": uv[:, 0], "v_px": uv[:, 1]}
                )
            )
    return pd.concat(blocks, ignore_index=True)


def _project(T_C_B, K, dist, board=BOARD):
    """Distorted pixel positions (N, 2) of the board's inner corners."""
    uv, _ = cv2.projectPoints(
        board_object_points(board), tf.rvec_from_R(T_C_B[:3, :3]), T_C_B[:3, 3], K, dist
    )
    return uv.reshape(-1, 2)


def _T_est(row):
    """T_C_B of a poses_raw row. Copies: pandas may hand out read-only arrays (see
    test_transforms.py::test_R_from_rvec_accepts_read_only_arrays)."""
    rvec = np.array(row[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float))
    tvec = np.array(row[["x_m", "y_m", "z_m"]].to_numpy(float))
    return tf.T_from_rvec_tvec(rvec, tvec)


def _angle_between(T_a, T_b):
    """Rotation angle (rad) of the relative rotation between two transforms."""
    return float(tf.rotation_angle(T_a[:3, :3].T @ T_b[:3, :3]))


# --------------------------------------------------------------------------------------------
# PnP against exact projections


def test_estimate_poses_recovers_known_poses_with_distortion_and_noise():
    """With 0.2 px noise on exact distorted projections of 100 random poses (0.8 to 2.5 m),
    PnP keeps all 20 corners and recovers position within 0.5 % of the distance, orientation
    with median error < 0.3 degrees and 95th percentile < 0.8 degrees (a 36 x 27 cm grid at
    2.5 m spans only ~100 px, so its tilt is the least certain part)."""
    rng = np.random.default_rng(1)
    poses_true = random_board_poses(100, seed=2)
    uvs = [_project(T, K_DEMO, DIST_DEMO) + rng.normal(0, 0.2, (20, 2)) for T in poses_true]
    poses = estimate_poses(_corners_table(uvs), K_DEMO, DIST_DEMO, BOARD)
    assert list(poses.columns) == POSE_COLUMNS
    assert poses["valid"].all()
    assert (poses["n_inliers"] == 20).all()
    # RMS of a 2-D error with 0.2 px per coordinate, less the 6 fitted degrees of freedom
    assert poses["reproj_rms_px"].between(0.1, 0.4).all()
    angle_deg = []
    for T_true, (_, row) in zip(poses_true, poses.iterrows(), strict=True):
        T_est = _T_est(row)
        dist_m = np.linalg.norm(T_true[:3, 3])
        assert np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) < 0.005 * dist_m
        angle_deg.append(np.degrees(_angle_between(T_true, T_est)))
        # Euler columns describe the same rotation as the rvec columns
        rpy = np.array(row[["roll_rad", "pitch_rad", "yaw_rad"]].to_numpy(float))
        np.testing.assert_allclose(tf.R_from_euler(rpy), T_est[:3, :3], atol=1e-9)
    assert np.median(angle_deg) < 0.3
    assert np.percentile(angle_deg, 95) < 0.8


def test_estimate_poses_exact_projections_give_exact_pose():
    """Noise-free projections give the pose to 1e-6 m and 1e-6 rad and ~0 reprojection RMS."""
    poses_true = random_board_poses(5, seed=3)
    uvs = [_project(T, K_DEMO, DIST_DEMO) for T in poses_true]
    poses = estimate_poses(_corners_table(uvs), K_DEMO, DIST_DEMO, BOARD)
    for T_true, (_, row) in zip(poses_true, poses.iterrows(), strict=True):
        np.testing.assert_allclose(row[["x_m", "y_m", "z_m"]].to_numpy(float), T_true[:3, 3],
                                   atol=1e-6)
        T_est = _T_est(row)
        assert _angle_between(T_true, T_est) < 1e-6
        assert row["reproj_rms_px"] < 1e-4


def test_estimate_poses_rejects_an_outlier_corner():
    """One corner moved by 30 px is left out by RANSAC (19 inliers), the pose stays accurate."""
    T_true = board_centre_pose(np.radians([20, -15, 10]), [0.1, -0.05, 1.4])
    uv = _project(T_true, K_DEMO, DIST_DEMO)
    uv[7] += [30.0, -20.0]
    poses = estimate_poses(_corners_table([uv]), K_DEMO, DIST_DEMO, BOARD)
    row = poses.iloc[0]
    assert row["valid"] and row["n_inliers"] == 19
    np.testing.assert_allclose(row[["x_m", "y_m", "z_m"]].to_numpy(float), T_true[:3, 3],
                               atol=1e-5)


def test_estimate_poses_keeps_not_found_frames_invalid():
    """Frames without a board stay in the table, one row each, valid=False with NaN pose."""
    T_true = board_centre_pose(np.radians([5, 5, 5]), [0.0, 0.0, 1.2])
    uv = _project(T_true, K_DEMO, DIST_DEMO)
    poses = estimate_poses(_corners_table([None, uv, None]), K_DEMO, DIST_DEMO, BOARD)
    assert poses["frame"].tolist() == [0, 1, 2]
    assert poses["valid"].tolist() == [False, True, False]
    assert poses.loc[[0, 2], ["x_m", "roll_rad", "rvec_0"]].isna().all().all()
    assert poses.loc[[0, 2], "n_inliers"].tolist() == [0, 0]


def test_estimate_poses_carries_exact_ns_of_a_timestamped_source():
    """A corners table with t_ns (a frame folder's) gives poses with the same exact t_ns."""
    T_true = board_centre_pose(np.radians([5, 5, 5]), [0.0, 0.0, 1.2])
    uv = _project(T_true, K_DEMO, DIST_DEMO)
    corners = _corners_table([None, uv])
    t_ns = np.array([1606153907495166540, 1606153915653051138], np.int64)
    corners.insert(2, "t_ns", t_ns[corners["frame"].to_numpy()])
    poses = estimate_poses(corners, K_DEMO, DIST_DEMO, BOARD)
    assert poses["t_ns"].tolist() == t_ns.tolist() and list(poses.columns[:3]) == ["frame", "t_s", "t_ns"]


def test_estimate_poses_is_reproducible_for_a_seed():
    """Two runs with the same seed on noisy corners with outliers give identical tables."""
    rng = np.random.default_rng(4)
    uvs = []
    for T in random_board_poses(10, seed=5):
        uv = _project(T, K_DEMO, DIST_DEMO) + rng.normal(0, 0.3, (20, 2))
        uv[rng.integers(0, 20, 2)] += rng.normal(0, 15, (2, 2))
        uvs.append(uv)
    table = _corners_table(uvs)
    a = estimate_poses(table, K_DEMO, DIST_DEMO, BOARD, seed=11)
    b = estimate_poses(table, K_DEMO, DIST_DEMO, BOARD, seed=11)
    pd.testing.assert_frame_equal(a, b)


def test_estimate_poses_bad_tables_raise_input_error_naming_the_frame():
    """Missing columns, or a found frame with a repeated corner, are InputErrors naming it."""
    uv = _project(board_centre_pose([0, 0, 0], [0, 0, 1.0]), K_DEMO, DIST_DEMO)
    table = _corners_table([uv, uv])
    with pytest.raises(InputError, match="missing columns.*u_px"):
        estimate_poses(table.drop(columns="u_px"), K_DEMO, DIST_DEMO, BOARD)
    broken = table.copy()
    broken.loc[(broken["frame"] == 1) & (broken["corner"] == 5), "corner"] = 4
    with pytest.raises(InputError, match="frame 1"):
        estimate_poses(broken, K_DEMO, DIST_DEMO, BOARD)
    nan_table = table.copy()
    nan_table.loc[3, "u_px"] = np.nan
    with pytest.raises(InputError, match="frame 0.*non-finite"):
        estimate_poses(nan_table, K_DEMO, DIST_DEMO, BOARD)


def test_estimate_poses_uses_the_corners_a_frame_has():
    """A found frame with a subset of the corners (a hand over the board) gets its pose from
    them, close to the truth; a subset on one grid row, or under MIN_INLIERS corners, is
    invalid; n_corners counts them."""
    rng = np.random.default_rng(21)
    T = board_centre_pose([0.2, -0.1, 0.05], [0.05, -0.02, 1.1])
    uv = _project(T, K_DEMO, DIST_DEMO) + rng.normal(0.0, 0.05, (20, 2))
    table = _corners_table([uv, uv, uv])
    keep = {0: np.arange(20), 1: np.array([0, 1, 2, 5, 6, 7, 10, 11, 12, 16, 17]),
            2: np.arange(5, 10)}  # frame 2: one grid row only
    table = table[[c in keep[f] for f, c in zip(table["frame"], table["corner"], strict=True)]]
    poses = estimate_poses(table, K_DEMO, DIST_DEMO, BOARD)
    assert poses["n_corners"].tolist() == [20, 11, 5]
    assert poses["valid"].tolist() == [True, True, False]
    for i in (0, 1):
        T_est = _T_est(poses.iloc[i])
        assert np.linalg.norm(T_est[:3, 3] - T[:3, 3]) < 0.004
        assert _angle_between(T_est, T) < np.deg2rad(0.3)


# --------------------------------------------------------------------------------------------
# Corner order: the same physical corner always carries the same index


@pytest.mark.parametrize("seed", range(6))
def test_detect_corners_on_rendered_image_matches_true_corners(seed):
    """On a rendered board at a random pose, detected corner k is within 0.3 px of true
    corner k (no index flip), and PnP on them is within 1 % of distance and 0.5 degrees."""
    T_true = random_board_poses(1, seed=100 + seed)[0]
    gray, uv_true = render_board(T_true, K_CENTRED, seed=seed)
    corners, method = detect_corners(gray, BOARD)
    assert corners is not None
    assert method == "colour"
    err = np.linalg.norm(corners - uv_true, axis=1)
    assert err.max() < 0.3
    poses = estimate_poses(_corners_table([corners]), K_CENTRED, np.zeros(5), BOARD)
    T_est = _T_est(poses.iloc[0])
    assert np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) < 0.01 * np.linalg.norm(T_true[:3, 3])
    assert np.degrees(_angle_between(T_true, T_est)) < 0.5


@pytest.mark.parametrize("yaw_deg", [0.0, 90.0, 180.0, -150.0])
def test_image_turned_180_degrees_gives_the_same_physical_pose(yaw_deg):
    """Turning the image by 180 degrees (OpenCV then tends to return the grid from the other
    end) yields the pose Rz(pi) T_C_B: the same physical board pose, never a flipped board."""
    T_true = board_centre_pose(np.radians([15.0, -10.0, yaw_deg]), [0.05, 0.03, 1.3])
    gray, uv_true = render_board(T_true, K_CENTRED, seed=7)
    gray_turned = cv2.rotate(gray, cv2.ROTATE_180)
    T_turn = tf.make_T(tf.R_from_euler([0.0, 0.0, np.pi]), np.zeros(3))
    for img, T_expected, uv_expected in [
        (gray, T_true, uv_true),
        (gray_turned, T_turn @ T_true, np.array([W - 1, H - 1]) - uv_true),
    ]:
        corners, _ = detect_corners(img, BOARD)
        assert np.abs(corners - uv_expected).max() < 0.3
        poses = estimate_poses(_corners_table([corners]), K_CENTRED, np.zeros(5), BOARD)
        T_est = _T_est(poses.iloc[0])
        assert np.linalg.norm(T_est[:3, 3] - T_expected[:3, 3]) < 0.005
        assert np.degrees(_angle_between(T_expected, T_est)) < 0.3


# --------------------------------------------------------------------------------------------
# Against the renderer's truth (cvsflow.synth): a short rendered session


@pytest.fixture(scope="module")
def rendered_session(tmp_path_factory):
    """A 4 s rendered session (120 frames) with its truth, corners and PnP poses (true K)."""
    synth = pytest.importorskip("cvsflow.synth.render")
    from cvsflow.io.files import read_parquet, read_yaml
    from cvsflow.io.media import iter_video_gray

    out = tmp_path_factory.mktemp("synth") / "session"
    synth.render_session(synth_session_cfg(4.0), out)
    truth = read_yaml(out / "truth.yaml")
    K = np.array(truth["camera"]["K"])
    dist = np.array(truth["camera"]["dist"])
    corners = extract_corners(iter_video_gray(out / "video.mp4"), BOARD)
    poses = estimate_poses(corners, K, dist, BOARD)
    return {
        "frames": read_parquet(out / "truth_frames.parquet"),
        "truth_corners": read_parquet(out / "truth_corners.parquet"),
        "corners": corners,
        "poses": poses,
    }


def test_rendered_board_found_when_wholly_in_view(rendered_session):
    """The board is found in >= 95 % of the frames where it is wholly in view (measured:
    120 of 120 on 4 s; 842 of 853 on a 30 s render, the misses blurred by 1.7 to 4.3 px),
    and never where it is not."""
    found = rendered_session["corners"].groupby("frame")["found"].first()
    in_view = rendered_session["frames"].set_index("frame")["in_view"].reindex(found.index)
    assert in_view.sum() >= 100
    assert found[in_view].mean() >= 0.95
    assert not found[~in_view].any()


def test_rendered_corner_k_is_true_corner_k(rendered_session):
    """Every detected corner k lies within 1 px of the true corner k (no index flips, no
    misplaced outer corner); median error below 0.15 px (measured 0.07 px, max 0.58 px)."""
    corners = rendered_session["corners"]
    merged = corners[corners["found"]].merge(
        rendered_session["truth_corners"], on=["frame", "corner"], suffixes=("", "_true")
    )
    assert len(merged) == 20 * corners.loc[corners["found"], "frame"].nunique()
    err = np.hypot(merged["u_px"] - merged["u_px_true"], merged["v_px"] - merged["v_px_true"])
    assert err.max() < 1.0
    assert np.median(err) < 0.15


def test_rendered_pnp_pose_errors(rendered_session):
    """With the true intrinsics, PnP position error has median < 1 % of distance (measured
    0.03 %) and angle error median < 0.5 degrees (measured 0.05 to 0.13 degrees)."""
    poses = rendered_session["poses"]
    p = poses[poses["valid"]].merge(rendered_session["frames"], on="frame", suffixes=("", "_t"))
    assert len(p) >= 0.95 * rendered_session["frames"]["in_view"].sum()
    T_est = tf.T_from_rvec_tvec(np.array(p[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float)),
                                np.array(p[["x_m", "y_m", "z_m"]].to_numpy(float)))
    t_true = p[["x_m_t", "y_m_t", "z_m_t"]].to_numpy(float)
    R_true = tf.R_from_quat(np.array(p[["qx", "qy", "qz", "qw"]].to_numpy(float)))
    rel_pos = np.linalg.norm(T_est[:, :3, 3] - t_true, axis=1) / np.linalg.norm(t_true, axis=1)
    angle_deg = np.degrees(tf.rotation_angle(np.swapaxes(R_true, 1, 2) @ T_est[:, :3, :3]))
    assert np.median(rel_pos) < 0.01
    assert np.median(angle_deg) < 0.5
    assert np.percentile(angle_deg, 95) < 1.0
    assert p["reproj_rms_px"].median() < 0.3


def test_squares_x_and_y_swapped_relabel_the_board_frame_consistently():
    """docs/failures.md: squares_x and squares_y swapped (5x6 for the demo's 6x5 board) is no
    error: the detector reads the same corners as the transposed grid, so every PnP pose is the
    true one times one fixed T_B_B' (a quarter turn about the board normal plus a shift within
    the board): a consistent result in a relabelled board frame, which se3 absorbs into T_Bm_B."""
    swapped = {**BOARD, "squares_x": BOARD["squares_y"], "squares_y": BOARD["squares_x"]}
    truth = random_board_poses(6, seed=3)
    frames = [(k, k / 30.0, render_board(T, K_DEMO, seed=k)[0]) for k, T in enumerate(truth)]
    poses = {}
    for name, board in (("right", BOARD), ("swapped", swapped)):
        corners = extract_corners(frames, board, track=False)
        table = estimate_poses(corners, K_DEMO, np.zeros(5), board).set_index("frame")
        poses[name] = {f: tf.T_from_rvec_tvec(r[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float),
                                              r[["x_m", "y_m", "z_m"]].to_numpy(float))
                       for f, r in table[table["valid"]].iterrows()}
    both = sorted(set(poses["right"]) & set(poses["swapped"]))
    assert len(both) >= 4 and set(poses["swapped"]) == set(poses["right"])  # found alike
    T_B_Bs = np.array([tf.invert_T(poses["right"][f]) @ poses["swapped"][f] for f in both])
    spread = tf.rotation_angle(np.swapaxes(T_B_Bs[0, :3, :3], 0, 1) @ T_B_Bs[:, :3, :3])
    assert np.degrees(spread).max() < 0.5  # one fixed relabelling
    assert np.abs(T_B_Bs[:, :3, 3] - T_B_Bs[0, :3, 3]).max() < 0.005
    R = T_B_Bs[0, :3, :3]
    assert abs(R[2, 2] - 1.0) < 1e-3  # about the board normal, z still into the board
    assert abs(np.degrees(tf.rotation_angle(R)) - 90.0) < 0.5
    assert abs(T_B_Bs[0, 2, 3]) < 1e-3  # a shift within the board's plane
