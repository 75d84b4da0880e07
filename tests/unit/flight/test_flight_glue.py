"""Helpers the flight stage uses to build a real flight's reference covariance."""

import cv2
import numpy as np

from cvsflow.board.model import board_object_points
from cvsflow.flight.reference import corner_noise_per_axis, sigma_columns, sigma_from_columns


def test_corner_noise_per_axis_recovers_the_simulated_noise():
    """PnP's 2-D reprojection RMS over 20 corners, converted, gives the per-axis noise (5 %)."""
    rng = np.random.default_rng(12)
    p_B = board_object_points({"squares_x": 6, "squares_y": 5, "square_m": 0.09})
    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    sigma = 0.4
    rms = []
    for _ in range(300):
        rvec = rng.normal(0, 0.3, 3)
        tvec = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(1.0, 3.0)])
        uv, _ = cv2.projectPoints(p_B, rvec, tvec, K, None)
        uv = uv.reshape(-1, 2) + rng.normal(0, sigma, (len(p_B), 2))
        ok, rv, tv = cv2.solvePnP(p_B, uv, K, None, flags=cv2.SOLVEPNP_IPPE)
        proj, _ = cv2.projectPoints(p_B, rv, tv, K, None)
        rms.append(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uv) ** 2, axis=1))))
    est = corner_noise_per_axis(np.sqrt(np.mean(np.square(rms))), len(p_B))
    assert abs(est / sigma - 1) < 0.05


def test_sigma_columns_round_trip():
    """(N, 6, 6) covariances survive the flat S00..S55 columns exactly."""
    rng = np.random.default_rng(1)
    A = rng.normal(size=(4, 6, 6))
    Sigma = A @ np.swapaxes(A, 1, 2)
    np.testing.assert_array_equal(sigma_from_columns(sigma_columns(Sigma)), Sigma)

