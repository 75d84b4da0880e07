"""Rendered images of a Kalibr AprilGrid with their true corners (cvsflow.synth's area renderer)."""

import cv2
import numpy as np

from cvsflow.board import AprilGrid
from cvsflow.synth.board_image import aprilgrid_texture, render_board
from cvsflow.synth.imaging import project_in_view, undistortion_grid

#: The yac target: 6x6 tag36h11, 0.088 m tags, spacing 0.3.
GRID = AprilGrid(6, 6, 0.088, 0.3)
SIZE = (640, 480)
K = np.array([[610.0, 0.0, 321.3], [0.0, 608.0, 242.1], [0.0, 0.0, 1.0]])
DIST = np.array([0.08, -0.15, 0.0005, -0.0008, 0.05])


def look_at_grid(grid, distance_m, tilt_deg, tilt_axis_deg, roll_deg, offset_m=(0.0, 0.0)):
    """T_C_B (4, 4) of the grid's centre ``distance_m`` ahead of the camera, its face to the camera.

    ``tilt_deg`` about the in-plane axis at ``tilt_axis_deg``, ``roll_deg`` about the grid's
    normal (0: B's y up in the image), the centre shifted by ``offset_m`` (C's x, y, metres).
    """
    # Face-on: B's x = C's x, B's y = -C's y, B's z = -C's z (out of the face, to the camera).
    R_roll = cv2.Rodrigues(np.array([0.0, 0.0, np.radians(roll_deg)]))[0]
    a = np.radians(tilt_axis_deg)
    R_tilt = cv2.Rodrigues(np.radians(tilt_deg) * np.array([np.cos(a), np.sin(a), 0.0]))[0]
    R = R_tilt @ np.diag([1.0, -1.0, -1.0]) @ R_roll
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.array([offset_m[0], offset_m[1], distance_m]) - R @ grid.tag_centres().mean(axis=0)
    return T


def render_aprilgrid(T_C_B, grid=GRID, texture=None, xy_n=None, K=K, dist=DIST, size=SIZE,
                     blur_sigma_px=0.8, noise_sigma=2.0, background=0.35, exposure=235.0, seed=0):
    """A grey image (H, W) uint8 of the grid and the true distorted pixels (4 N, 2) of every corner id."""
    texture = texture if texture is not None else aprilgrid_texture(grid)
    xy_n = xy_n if xy_n is not None else undistortion_grid(K, dist, size)
    layer = render_board(T_C_B, texture, xy_n, K, dist)
    img = exposure * (layer[..., 0] + (1.0 - layer[..., 1]) * background).astype(np.float64)
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
    img += np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    gray = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    return gray, project_in_view(np.asarray(T_C_B, float), grid.object_points(), K, dist)
