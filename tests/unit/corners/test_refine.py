"""Tests of cvsflow.corners.refine: sub-pixel refinement of a candidate grid and the edges' blur."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.helpers.board_images import board_centre_pose, render_board

BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}  # the demo board, 5x4 inner corners
W, H = 640, 480
K_CENTRED = np.array([[700.0, 0.0, (W - 1) / 2], [0.0, 700.0, (H - 1) / 2], [0.0, 0.0, 1.0]])


def test_refine_corners_from_corners_outside_the_image_does_not_raise():
    """Initial corners beyond the image border (cornerSubPix used to assert 'initial corner is
    outside the image') are clipped into it: a result or None, never a cv2.error."""
    from cvsflow.corners.refine import refine_corners

    T = board_centre_pose([0.0, 0.0, 0.0], [0.0, 0.0, 1.2])
    gray, uv = render_board(T, K_CENTRED, seed=3)
    shifted = uv.copy()
    shifted[0] = [-3.0, -7.5]
    shifted[-1] = [W + 2.0, H + 0.4]
    refine_corners(gray, shifted, BOARD)  # must not raise
    assert refine_corners(gray, uv + 0.8, BOARD) is not None


def test_a_corner_hidden_before_and_still_off_skips_the_second_refinement():
    # A corner put a quarter of a square off: cornerSubPix from there cannot reach it, the
    # second refinement (from where its neighbours put it) can. Marked as hidden by a hand in
    # the earlier frame, it fails the refinement at once instead (the partial check follows).
    from cvsflow.corners.refine import _refine_corners

    T = board_centre_pose([0.0, 0.0, 0.0], [0.0, 0.0, 1.2])
    gray, uv = render_board(T, K_CENTRED, seed=5)
    start = uv.copy()
    step = np.linalg.norm(uv[1] - uv[0])
    start[7] += (0.25 * step, 0.1 * step)
    hidden = np.zeros(len(uv), bool)
    rescued, first = _refine_corners(gray, start, BOARD, 5, 0.08)
    assert rescued is not None and np.abs(rescued - uv).max() < 0.5
    assert first[2][7] > first[1][7]  # off its neighbours after the first cornerSubPix
    hidden[3] = True  # another corner hidden before: the retry still runs
    assert _refine_corners(gray, start, BOARD, 5, 0.08, hidden)[0] is not None
    hidden[7] = True
    corners, again = _refine_corners(gray, start, BOARD, 5, 0.08, hidden)
    assert corners is None and np.array_equal(again[0], first[0])


@pytest.mark.parametrize("sigma_px", [1.0, 2.0, 3.5])
def test_edge_blur_px_measures_a_known_gaussian_blur(sigma_px):
    """A chessboard blurred by a known Gaussian: the edge-profile estimate is within 15 %."""
    from cvsflow.corners.refine import edge_blur_px

    board = {"squares_x": 7, "squares_y": 6, "square_m": 0.03}
    sq, x0, y0 = 40, 60, 50  # square size and the outer corner of square (0, 0), px
    img = np.full((360, 400), 220.0)
    for j in range(6):
        for i in range(7):
            if (i + j) % 2 == 0:
                img[y0 + j * sq:y0 + (j + 1) * sq, x0 + i * sq:x0 + (i + 1) * sq] = 30.0
    gray = cv2.GaussianBlur(img, (0, 0), sigma_px).round().astype(np.uint8)
    k = np.arange(6 * 5)
    corners = np.column_stack([x0 + sq * (1 + k % 6), y0 + sq * (1 + k // 6)]).astype(float) - 0.5
    got = edge_blur_px(gray, corners, board)
    assert abs(got - sigma_px) < 0.15 * sigma_px, got
