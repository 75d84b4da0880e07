"""Tests of cvsflow.calibration.bundle and .outliers: the fit, its covariance, its outliers."""

from __future__ import annotations

import cv2
import numpy as np

from cvsflow.calibration.bundle import _residuals_and_jacobian, initial_fit
from cvsflow.calibration.lens import K_dist, lens_model
from cvsflow.calibration.outliers import fit_with_outliers, still_verdicts
from tests.helpers.calibration_views import SIZE, THETA5, synthetic_views, true_poses

M5 = lens_model("opencv5")


def test_fit_is_opencvs_minimum():
    """On the same corners the fit lands on calibrateCamera's answer."""
    views = synthetic_views(true_poses(3), THETA5, sigma_px=0.1)
    fit, _ = fit_with_outliers(views, SIZE, M5, reject=False)
    obj = [v.p_B.astype(np.float32) for v in views]
    img = [v.uv_px.astype(np.float32) for v in views]
    crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    _, K, d, _, _ = cv2.calibrateCamera(obj, img, SIZE, None, None, criteria=crit)
    np.testing.assert_allclose(fit.theta[:4], [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], atol=2e-3)
    np.testing.assert_allclose(fit.theta[4:], d.ravel(), atol=2e-5)


def test_jacobian_matches_finite_differences():
    """OpenCV's analytic Jacobians assembled into the fit's J agree with central differences."""
    views = synthetic_views(true_poses(3, 5), THETA5, sigma_px=0.1)
    theta, rv, tv = initial_fit(views, SIZE, M5)
    inl = [np.ones(len(v.ids), bool) for v in views]
    _, J, _ = _residuals_and_jacobian(views, M5, theta, rv, tv, inl)
    x0 = np.r_[theta, np.c_[rv, tv].ravel()]

    def res(x):
        th, p = x[:9], x[9:].reshape(-1, 6)
        return _residuals_and_jacobian(views, M5, th, p[:, :3], p[:, 3:], inl, False)[0]

    for k in np.random.default_rng(0).choice(len(x0), 12, replace=False):
        h = 1e-6 * max(1.0, abs(x0[k]))
        xp, xm = x0.copy(), x0.copy()
        xp[k] += h
        xm[k] -= h
        np.testing.assert_allclose((res(xp) - res(xm)) / (2 * h), J[:, k],
                                   atol=1e-4 * max(1, np.abs(J[:, k]).max()))


def test_stated_std_covers_truth_and_equals_opencvs():
    """Ideal corners (iid Gaussian): the std gives RMS z ~ 1 and covers the truth at the
    nominal rate; OpenCV's stdDeviationsIntrinsics on the same corners is the same number."""
    T = true_poses(5)
    rng = np.random.default_rng(1)
    z = []
    for i in range(24):
        views = synthetic_views(T, THETA5, sigma_px=0.15, rng=rng)
        fit, _ = fit_with_outliers(views, SIZE, M5, reject=False)
        z.append((fit.theta - THETA5) / fit.theta_std)
        if i < 2:
            K, d = K_dist(fit.theta, M5)
            out = cv2.calibrateCameraExtended(
                [v.p_B.astype(np.float32) for v in views],
                [v.uv_px.astype(np.float32) for v in views], SIZE, K, d,
                flags=cv2.CALIB_USE_INTRINSIC_GUESS,
                criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-15))
            np.testing.assert_allclose(np.ravel(out[5])[:9], fit.theta_std, rtol=1e-3)
    assert 0.75 < np.sqrt(np.mean(np.square(z))) < 1.25
    assert 0.58 < np.mean(np.abs(np.array(z)) < 1) < 0.78  # nominal 68.3 %


def test_outliers_found_named_and_still_named():
    """Corners moved by 2.9 px are left out, each named with its residual; the still that lost
    17 % of its corners is named; with rejection off the same corners are named, none left out."""
    views = synthetic_views(true_poses(5), THETA5, sigma_px=0.1)
    bad = {2: [3, 10, 17, 24, 31, 33], 7: [20]}
    for i, ks in bad.items():
        views[i].uv_px[ks] += np.array([2.5, -1.5])
    fit, rej = fit_with_outliers(views, SIZE, M5)
    want = {(views[i].name, k) for i, ks in bad.items() for k in ks}
    assert {(r.still, r.corner) for r in rej} == want
    assert all("px" in r.reason and "sigma" in r.reason and r.z > 4 for r in rej)
    assert np.allclose(fit.theta[:4], THETA5[:4], atol=1.0)
    named = [v["name"] for v in still_verdicts(views, fit, rej) if v["flagged"]]
    assert named == [views[2].name]
    fit0, rej0 = fit_with_outliers(views, SIZE, M5, reject=False)
    assert {(r.still, r.corner) for r in rej0} <= want and all(r.round == 0 for r in rej0)
    assert fit0.n_used == sum(len(v.ids) for v in views)
    assert fit0.sigma_px > 2 * fit.sigma_px


def test_still_with_a_systematic_error_is_named():
    """A still whose corners are alternately 0.2 px left and right (2 sigma each, few beyond
    the rejection threshold; an error no pose absorbs) is named by its chi-square, alone."""
    views = synthetic_views(true_poses(5), THETA5, sigma_px=0.1)
    parity = (views[4].ids % 7 + views[4].ids // 7) % 2
    views[4].uv_px[:, 0] += np.where(parity == 0, 0.2, -0.2)
    fit, rej = fit_with_outliers(views, SIZE, M5)
    v = {x["name"]: x for x in still_verdicts(views, fit, rej)}
    assert v[views[4].name]["flagged"]
    assert not any(x["flagged"] for n, x in v.items() if n != views[4].name)
