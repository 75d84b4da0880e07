"""Tests of cvsflow.corners.detect: the full detector on rendered boards (order, blur, a wide
lens, a finger over a corner) against the renderer's true corners."""

from __future__ import annotations

import numpy as np
import pytest

from cvsflow.board import order_corners
from cvsflow.corners.detect import detect_corners
from tests.helpers.board_images import board_centre_pose, render_board

BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}  # the demo board, 5x4 inner corners
W, H = 640, 480
K_CENTRED = np.array([[700.0, 0.0, (W - 1) / 2], [0.0, 700.0, (H - 1) / 2], [0.0, 0.0, 1.0]])

# --- scale-aware checks and frames that used to stop the stage (issue 13) -------------------

BOARD_10x7 = {"squares_x": 11, "squares_y": 8, "square_m": 0.055}
WIDE_DIST = [-0.30, 0.11, 0.0, 0.0, -0.02]  # a wide lens, k1 ~ -0.3


def test_order_corners_undoes_every_reordering_of_the_grid():
    """Whatever order the detector returns (as is, reversed, rows or columns mirrored), the
    ordered corners are the same, corner k at board point (k % nx, k // nx)."""
    T_true = board_centre_pose(np.radians([-20.0, 25.0, 35.0]), [-0.1, 0.05, 1.1])
    gray, uv_true = render_board(T_true, K_CENTRED, seed=8)
    grid = uv_true.reshape(4, 5, 2)
    variants = {
        "as is": grid,
        "reversed": grid[::-1, ::-1],
        "rows mirrored": grid[::-1],
        "columns mirrored": grid[:, ::-1],
    }
    for name, g in variants.items():
        ordered, method = order_corners(g.reshape(-1, 2), gray, BOARD)
        assert method == "colour", name
        np.testing.assert_allclose(ordered, uv_true, atol=1e-12, err_msg=name)


def test_order_corners_falls_back_to_continuity_when_ends_look_alike():
    """For a 7x5-square board (both grid ends alike), the order closest to the previous frame
    is kept; with no previous frame the method says the order is unresolved."""
    board = {"squares_x": 7, "squares_y": 5, "square_m": 0.05}
    T_true = board_centre_pose(np.radians([10.0, 5.0, 20.0]), [0.0, 0.0, 0.9], board)
    gray, uv_true = render_board(T_true, K_CENTRED, board=board, seed=9)
    previous = uv_true + 1.5  # the board moved a little since the previous frame
    ordered, method = order_corners(uv_true[::-1], gray, board, previous_px=previous)
    assert method == "continuity"
    np.testing.assert_allclose(ordered, uv_true, atol=1e-12)
    _, method = order_corners(uv_true[::-1], gray, board)
    assert method == "unresolved"


@pytest.mark.parametrize(
    "size, f_px",
    [((640, 480), 520.0), ((1280, 720), 900.0), ((1920, 1080), 1350.0), ((1080, 1920), 1350.0)],
)
def test_detect_corners_keeps_blurred_wide_lens_boards_at_every_resolution(size, f_px):
    """A blurred board near the camera through a k1 = -0.3 lens is kept at every image size
    (the grid check is a share of the square size, not 2 px), corner k within 0.3 px of true k."""
    from tests.helpers.board_images import render_board_distorted

    w, h = size
    K = np.array([[f_px, 0.0, w / 2], [0.0, f_px, h / 2], [0.0, 0.0, 1.0]])
    for i, (z, cx) in enumerate([(0.9, 0.0), (1.0, 0.1)]):
        T = board_centre_pose([0.3, -0.25, 0.1], [cx * z, 0.05, z], BOARD_10x7)
        gray, uv = render_board_distorted(T, K, WIDE_DIST, size, BOARD_10x7, blur_sigma=1.5,
                                          seed=10 + i)
        corners, method = detect_corners(gray, BOARD_10x7)
        assert corners is not None, (size, z, method)
        assert np.linalg.norm(corners - uv, axis=1).max() < 0.3


def _board_with_a_finger_on_corner_12(monkeypatch):
    """A demo board with a grey disc (a fingertip) over corner 12, its true corners, and
    findChessboardCorners stubbed to find the whole grid (as it does on the realistic render
    with a hand over two corners) in the reversed order, half a pixel off."""
    import cvsflow.corners.detect as pose
    from tests.helpers.board_images import render_board_distorted

    K = np.array([[700.0, 0.0, 319.5], [0.0, 700.0, 239.5], [0.0, 0.0, 1.0]])
    T = board_centre_pose([0.2, -0.15, 0.1], [0.0, 0.0, 1.3])
    _, uv = render_board_distorted(T, K, np.zeros(5), (W, H))
    step = np.linalg.norm(uv[1] - uv[0])
    a = np.linspace(0.0, 2.0 * np.pi, 32, endpoint=False)
    finger = uv[12] + step * (0.5 * np.c_[np.cos(a), np.sin(a)] + [0.15, 0.1])
    gray, uv = render_board_distorted(T, K, np.zeros(5), (W, H), occluder=finger, seed=3)
    rng = np.random.default_rng(0)
    found = (uv[::-1] + rng.normal(0.0, 0.5, uv.shape)).astype(np.float32).reshape(-1, 1, 2)
    monkeypatch.setattr(pose, "_find_on_pyramid", lambda *args: (True, found.copy()))
    return gray, uv


def test_detect_corners_keeps_the_corners_a_finger_leaves_with_true_indices(monkeypatch):
    gray, uv = _board_with_a_finger_on_corner_12(monkeypatch)
    corners, method = detect_corners(gray, BOARD)
    assert corners is None and method == "inconsistent"  # the default: not found
    corners, method = detect_corners(gray, BOARD, keep_partial=True)
    assert method == "partial"
    known = np.isfinite(corners).all(axis=1)
    assert not known[12] and known.sum() >= 17
    # in board order despite OpenCV's reversed one: each kept corner is its true corner
    assert np.linalg.norm(corners[known] - uv[known], axis=1).max() < 0.3


def test_detect_corners_keeps_no_partial_board_in_the_wrong_order(monkeypatch):
    # The grid turned by 180 degrees puts every corner's saddle and every square on the wrong
    # colour (the demo board's ends differ): nothing is kept rather than corners misnamed.
    import cvsflow.corners.detect as pose

    gray, _ = _board_with_a_finger_on_corner_12(monkeypatch)

    def turned(corners_px, *args):
        return order_corners(corners_px, *args)[0][::-1].copy(), "colour"

    monkeypatch.setattr(pose, "order_corners", turned)
    corners, method = detect_corners(gray, BOARD, keep_partial=True)
    assert corners is None and method == "inconsistent"
