"""Tests of cvsflow.calibration.projection_uncertainty: mean-frames against Monte Carlo and mrcal."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd

from cvsflow.board import SUBPIX_CRITERIA, board_object_points
from cvsflow.calibration.bundle import StillView
from cvsflow.calibration.lens import K_dist, lens_model
from cvsflow.calibration.outliers import fit_with_outliers
from cvsflow.calibration.projection_uncertainty import (
    mean_frames_reprojection,
    projection_covariance,
    projection_jacobian,
    uncertainty_map,
    uncertainty_map_of,
    uncertainty_summary,
    worst_direction_std,
)
from tests.helpers.calibration_views import SIZE, THETA5, synthetic_views, true_poses
from tests.helpers.real_data import REAL_DATA

M5 = lens_model("opencv5")
PTS = np.array([[319.5, 239.5], [40.0, 30.0], [600.0, 450.0], [320.0, 20.0]])


def test_predicted_covariance_matches_monte_carlo():
    """Refit noisy ideal corners 30 times: the spread of the mean-frames reprojection of fixed
    points (through the true poses) matches the predicted covariance, at infinity and 1.2 m."""
    T = true_poses(7)
    rng = np.random.default_rng(2)
    fits = [fit_with_outliers(synthetic_views(T, THETA5, sigma_px=0.2, rng=rng), SIZE, M5,
                              reject=False)[0] for _ in range(30)]
    for distance_m in (np.inf, 1.2):
        errs = np.array([mean_frames_reprojection(f.theta, M5, f.T_C_B(), T, PTS, distance_m,
                                                  theta_ref=THETA5) - PTS for f in fits])
        C_pred = np.mean([projection_covariance(f, PTS, distance_m) for f in fits], axis=0)
        for g in range(len(PTS)):
            C_emp = np.cov(errs[:, g].T)
            ratio = np.sqrt(np.linalg.eigvalsh(C_emp)[1] / np.linalg.eigvalsh(C_pred[g])[1])
            assert 0.65 < ratio < 1.4, (distance_m, g, ratio)
        nees = np.einsum("dgi,gij,dgj->dg", errs, np.linalg.inv(C_pred), errs)
        assert 1.4 < nees.mean() < 2.7, distance_m


def test_infinity_uses_rotations_only():
    """At infinity the board translations do not enter; at a finite range they do."""
    fit, _ = fit_with_outliers(synthetic_views(true_poses(7), THETA5), SIZE, M5, reject=False)
    J, q = projection_jacobian(fit, PTS, np.inf)
    cols = np.r_[[9 + 6 * i + k for i in range(len(fit.rvecs)) for k in (3, 4, 5)]]
    assert np.all(J[:, :, cols] == 0)
    np.testing.assert_allclose(q, PTS, atol=1e-6)
    Jd, _ = projection_jacobian(fit, PTS, 1.0)
    assert np.abs(Jd[:, :, cols]).max() > 0


def test_map_and_summary_shapes():
    """The map's grid, the summary's points: centre <= worst covered <= worst image."""
    views = synthetic_views(true_poses(7), THETA5)
    fit, _ = fit_with_outliers(views, SIZE, M5, reject=False)
    m = uncertainty_map(fit, views, step_px=32)
    assert m["sigma_px"].shape == (len(m["v_px"]), len(m["u_px"])) == m["covered"].shape
    assert m["covered"].any() and np.all(m["sigma_px"] > 0)
    s = uncertainty_summary(fit, views, step_px=32)
    for key in ("at_distance", "at_infinity"):
        assert s[key]["centre"] <= s[key]["worst_covered"] <= s[key]["worst_image"]
        assert len(s[key]["corners"]) == 4
    assert 0.5 < s["distance_m"] < 3.0


def test_map_from_the_calibrations_files_is_the_fits():
    """uncertainty_map_of(camera.yaml, calib_corners) refits the used corners to the same map."""
    views = synthetic_views(true_poses(7), THETA5)
    fit, _ = fit_with_outliers(views, SIZE, M5, reject=False)
    table = pd.concat([pd.DataFrame({"image": v.name, "corner": v.ids, "u_px": v.uv_px[:, 0],
                                     "v_px": v.uv_px[:, 1], "X_m": v.p_B[:, 0],
                                     "Y_m": v.p_B[:, 1], "used": True}) for v in views])
    K, d = K_dist(fit.theta, M5)
    camera = {"model": "opencv5", "K": K.tolist(), "dist": d.tolist(), "width": 640,
              "height": 480}
    m = uncertainty_map_of(camera, table, np.inf, step_px=64)
    np.testing.assert_allclose(m["sigma_px"], uncertainty_map(fit, views, np.inf, 64)["sigma_px"],
                               rtol=1e-4)


def test_reproduces_mrcal_on_opencv_stills():
    """mrcal 2.2 (no rejection, regularisation or board warp; 5 px corners) states at infinity
    centre 0.1353, corners 10.4366 4.7066 11.3644 5.3888 px: with mrcal's sigma (np.std of
    the residuals) the same numbers come out here."""
    stills = sorted((REAL_DATA / "opencv-chessboard").glob("left*.jpg"))
    if not stills:
        import pytest

        pytest.skip("OpenCV's sample stills not available")
    board = {"squares_x": 10, "squares_y": 7, "square_m": 0.025}
    p_B = board_object_points(board)
    views = []
    for p in stills:  # mrcal_peer's corners: OpenCV's order, no flags, 5 px window
        g = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        ok, c = cv2.findChessboardCorners(g, (9, 6), None)
        c = cv2.cornerSubPix(g, c, (5, 5), (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2)
        views.append(StillView(p.name, np.arange(54), p_B, c.astype(float)))
    fit, _ = fit_with_outliers(views, (640, 480), M5, reject=False)
    res = np.concatenate([r.ravel() for r in fit.residual_px])
    pts = np.array([[319.5, 239.5], [0, 0], [639, 0], [0, 479], [639, 479]])
    s = worst_direction_std(projection_covariance(fit, pts, np.inf, sigma_px=np.std(res)))
    np.testing.assert_allclose(s, [0.1353, 10.4366, 4.7066, 11.3644, 5.3888], rtol=0.01)
    np.testing.assert_allclose(fit.theta[[0, 3]], [532.8271, 233.8560], atol=0.01)
