"""Tests of cvsflow.calibration.lens and .cross_validation: the three lens models against their
truth, the cross-validation's verdict on them, each still's leave-one-out influence."""

from __future__ import annotations

import numpy as np
import pytest

from cvsflow.calibration.bundle import refine_fit
from cvsflow.calibration.cross_validation import RATIO_WARN, cross_validate, leave_one_out
from cvsflow.calibration.lens import lens_model, project_camera_points, unproject
from cvsflow.calibration.outliers import fit_with_outliers
from cvsflow.exceptions import ConfigError
from tests.helpers.calibration_views import (
    SIZE,
    THETA5,
    THETA8,
    THETA_FISH,
    synthetic_views,
    true_poses,
    wide_poses,
)


@pytest.mark.parametrize("model,theta", [("opencv5", THETA5), ("opencv8", THETA8),
                                         ("fisheye4", THETA_FISH)])
def test_project_unproject_round_trip(model, theta):
    """unproject is project's inverse for every model."""
    m = lens_model(model)
    uv = np.array([[320.0, 240.0], [50.0, 40.0], [600.0, 60.0], [100.0, 450.0]])
    v = unproject(uv, theta, m)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0)
    np.testing.assert_allclose(project_camera_points(v, theta, m)[0], uv, atol=1e-6)


def test_unknown_model_is_a_config_error_naming_the_known_ones():
    with pytest.raises(ConfigError, match=r"'kb8'.*fisheye4.*opencv5.*opencv8"):
        lens_model("kb8")


@pytest.mark.parametrize("model,theta,poses", [("opencv8", THETA8, "plan"),
                                               ("fisheye4", THETA_FISH, "wide")])
def test_fit_recovers_truth(model, theta, poses):
    """The rational and fisheye models recover their truth within 4 stated sigmas."""
    rng = np.random.default_rng(4)
    T = true_poses(9) if poses == "plan" else wide_poses(rng, 20, THETA_FISH)
    views = synthetic_views(T, theta, model, 0.1, rng)
    fit, _ = fit_with_outliers(views, SIZE, lens_model(model))
    assert abs(fit.sigma_px - 0.1) < 0.01
    z = (fit.theta - theta) / fit.theta_std
    assert np.all(np.abs(z) < 4.0), z


def test_cross_validation_of_an_adequate_model_is_near_one():
    """Ideal corners of the right model: the halves differ by what their uncertainty predicts."""
    ratios = []
    rng = np.random.default_rng(5)
    for seed in (3, 5, 7):
        views = synthetic_views(true_poses(seed), THETA5, sigma_px=0.15, rng=rng)
        fit, _ = fit_with_outliers(views, SIZE, lens_model("opencv5"), reject=False)
        cv = cross_validate(views, fit)
        assert cv["warning"] is None
        ratios.append(cv["ratio"])
    assert 0.5 < np.sqrt(np.mean(np.square(ratios))) < 1.6


def test_cross_validation_flags_an_inadequate_model():
    """A fisheye seen up to 65 deg off axis: the 5-term model's halves differ far beyond their
    uncertainty; the fisheye model's do not."""
    rng = np.random.default_rng(0)
    views = synthetic_views(wide_poses(rng, 20, THETA_FISH), THETA_FISH, "fisheye4", 0.1, rng)
    bad, _ = fit_with_outliers(views, SIZE, lens_model("opencv5"), reject=False)
    good, _ = fit_with_outliers(views, SIZE, lens_model("fisheye4"), reject=False)
    cv_bad, cv_good = cross_validate(views, bad), cross_validate(views, good)
    assert cv_bad["ratio"] > 2 * RATIO_WARN and cv_bad["warning"]
    assert cv_good["ratio"] < RATIO_WARN and cv_good["warning"] is None


def test_leave_one_out_is_the_refits_and_names_a_still_that_decides():
    """The one-step leave-one-out intrinsics are the full refits' (jackknife std within 5 %);
    a clean set's stills move the projection by less than its uncertainty; the most
    influential still, its corners carrying a k1-like error of ~1 px at 300 px from the centre
    (RMS 0.2 px), moves it by more than that uncertainty, alone."""
    views = synthetic_views(true_poses(5, 10), THETA5, sigma_px=0.1)
    fit, _ = fit_with_outliers(views, SIZE, lens_model("opencv5"), reject=False)
    loo = leave_one_out(views, fit)
    thetas = []
    for i in range(len(views)):
        keep = [j for j in range(len(views)) if j != i]
        f = refine_fit([views[j] for j in keep], SIZE, fit.model, fit.theta, fit.rvecs[keep],
                       fit.tvecs[keep], [fit.inlier[j] for j in keep])
        thetas.append(f.theta)
    thetas = np.array(thetas)
    n = len(thetas)
    std = np.sqrt((n - 1) / n * np.sum((thetas - thetas.mean(0)) ** 2, axis=0))
    np.testing.assert_allclose(loo["std"], std, rtol=0.05)
    shifts = [s["shift_sigma"] for s in loo["influence"]]
    assert max(shifts) < 1.0
    k = int(np.argmax(shifts))
    uv = views[k].uv_px
    views[k].uv_px = THETA5[2:4] + (uv - THETA5[2:4]) * (
        1 + 5e-8 * np.sum((uv - THETA5[2:4]) ** 2, axis=1))[:, None]
    fit2, _ = fit_with_outliers(views, SIZE, lens_model("opencv5"), reject=False)
    shifts2 = [s["shift_sigma"] for s in leave_one_out(views, fit2)["influence"]]
    assert shifts2[k] > 1.0 and sorted(shifts2)[-2] < 1.0
