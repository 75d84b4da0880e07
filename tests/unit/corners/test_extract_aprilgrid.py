"""The corners stage on an AprilGrid video: extract_corners dispatches on board.type, every frame
is detected on its own with true ids, the summary names the detector, PnP takes the table, and a
video without the grid is a named error."""

import functools

import numpy as np
import pytest

from cvsflow.calibration import estimate_poses
from cvsflow.corners import extract_corners, extract_corners_parallel, summarise_corners
from cvsflow.exceptions import InputError
from cvsflow.geometry import transforms as tf
from cvsflow.synth.board_image import aprilgrid_texture
from cvsflow.synth.imaging import undistortion_grid
from tests.helpers.aprilgrid_images import DIST, GRID, SIZE, K, look_at_grid, render_aprilgrid

BOARD = GRID.config()


@functools.cache
def frames():
    """(poses (4, 4, 4), [(frame, t_s, gray)], truth uv (4, 144, 2)): three views, one cut by the
    image border, and a frame without the grid; frame 4 undecodable."""
    texture, xy_n = aprilgrid_texture(GRID), undistortion_grid(K, DIST, SIZE)
    poses = [look_at_grid(GRID, 1.2, 20.0, 30.0, 10.0), look_at_grid(GRID, 1.0, 35.0, 100.0, -20.0),
             look_at_grid(GRID, 1.3, 10.0, 0.0, 0.0, offset_m=(0.45, 0.2))]
    out, truth = [], []
    for i, T in enumerate(poses):
        gray, uv = render_aprilgrid(T, texture=texture, xy_n=xy_n, seed=i)
        out.append((i, i / 30, gray))
        truth.append(uv)
    out += [(3, 0.1, np.full((SIZE[1], SIZE[0]), 90, np.uint8)), (4, 4 / 30, None)]
    return np.array(poses), out, np.array(truth)


def test_extract_corners_takes_an_aprilgrid():
    """Found frames carry their true ids (within 0.3 px), the partial view its subset; the
    grid-less and undecodable frames are kept as not found; the summary names the detector."""
    poses, video, truth = frames()
    corners = extract_corners(iter(video), BOARD)
    assert corners.attrs["order_methods"] == {"aprilgrid": 3, "not_found": 1, "undecodable": 1}
    for frame in range(3):
        block = corners[corners["frame"] == frame]
        uv = block[["u_px", "v_px"]].to_numpy()
        assert np.linalg.norm(uv - truth[frame][block["corner"]], axis=1).max() < 0.3
    assert corners["frame"].eq(2).sum() < 100 < corners["frame"].eq(0).sum()
    summary = summarise_corners(corners)
    assert summary["n_found"] == 3 and summary["detector"].startswith("apriltag3 x2 + aruco")


def test_pnp_takes_aprilgrid_corners():
    """estimate_poses on the table gives the true T_C_B in Kalibr's frame (z_B towards C)."""
    poses, video, _ = frames()
    est = estimate_poses(extract_corners(iter(video), BOARD), K, DIST, BOARD)
    assert est["valid"].tolist() == [True, True, True, False, False]
    for frame in range(3):
        row = est.iloc[frame]
        R = tf.R_from_rvec(row[["rvec_0", "rvec_1", "rvec_2"]].to_numpy(float))
        assert tf.rotation_angle(R.T @ poses[frame][:3, :3]) < np.radians(0.1)
        np.testing.assert_allclose(row[["x_m", "y_m", "z_m"]].to_numpy(float), poses[frame][:3, 3], atol=2e-3)
        assert R[2, 2] < 0


def test_a_video_without_the_grid_is_a_named_error():
    """No frame with the AprilGrid: an InputError naming the grid and the frame count."""
    _, video, _ = frames()

    def source(start, stop):
        return iter([(0, 0.0, video[3][2]), (1, 0.1, None)])

    with pytest.raises(InputError, match="6x6 AprilGrid was found in none of its 2 frames"):
        extract_corners_parallel(source, 2, BOARD, n_workers=1)
