"""Tests of the PnP covariance propagation and the error prediction model."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest

from cvsflow import metrics
from cvsflow import uncertainty as un
from cvsflow.board.model import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import transforms as tf
from cvsflow.optimise.se3_sim import simulate_session
from cvsflow.optimise.se3_start import corner_arrays, solve_pnp_frames
from tests.helpers.uncertainty_draws import TRUTH_T, draw_transfer

K = np.array([[700.0, 0, 320.0], [0, 700.0, 240.0], [0, 0, 1]])
DIST = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02])
BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}


def test_pnp_covariance_matches_monte_carlo():
    """The propagated 6x6 covariance of (rvec, tvec) matches the scatter of 400 noisy PnP
    solutions (0.5 px noise): per-axis standard deviations within 15 %."""
    rng = np.random.default_rng(0)
    p_B = board_object_points(BOARD)
    rvec, tvec = np.array([0.3, -0.4, 0.1]), np.array([-0.1, 0.05, 2.0])
    uv, _ = cv2.projectPoints(p_B.reshape(-1, 1, 3), rvec, tvec, K, DIST)
    sols = []
    for _ in range(400):
        noisy = uv + rng.normal(0, 0.5, uv.shape)
        _, r, t = cv2.solvePnP(p_B.reshape(-1, 1, 3), noisy, K, DIST, rvec.copy()[:, None],
                               tvec.copy()[:, None], useExtrinsicGuess=True)  # fmt: skip
        sols.append(np.r_[r.ravel(), t.ravel()])
    cov = un.pnp_covariance(rvec[None], tvec[None], p_B, K, DIST, 0.5)[0]
    np.testing.assert_allclose(np.std(sols, axis=0), np.sqrt(np.diag(cov)), rtol=0.15)


def test_propagated_pose_covariance_matches_monte_carlo_of_composed_errors():
    """Propagated covariance of the composed error in C equals the covariance of composed
    errors of samples drawn from Cov(rvec, tvec): std within 10 %."""
    rng = np.random.default_rng(1)
    rvec, tvec = np.array([[0.5, -0.3, 0.2]]), np.array([[0.1, 0.0, 2.5]])
    A = rng.normal(size=(6, 6)) * np.r_[[1e-3] * 3, [2e-3] * 3]
    cov_rt = (A @ A.T)[None]
    cov_e = un.propagated_pose_covariance(rvec, tvec, cov_rt)[0]
    x = rng.multivariate_normal(np.r_[rvec[0], tvec[0]], cov_rt[0], 4000)
    T0 = np.repeat(tf.T_from_rvec_tvec(rvec, tvec), len(x), 0)
    e = metrics.pose_errors(T0, tf.T_from_rvec_tvec(x[:, :3], x[:, 3:]))[metrics.error_columns()]
    np.testing.assert_allclose(e.std().to_numpy(), np.sqrt(np.diag(cov_e)), rtol=0.1)
    cov6 = un.pose6_covariance(rvec, tvec, cov_rt)[0]
    np.testing.assert_allclose(cov6[:3, :3], cov_rt[0, 3:, 3:], rtol=1e-6)


def _model_data(rng, n, a, b, gamma, corr):
    """Features and errors drawn from model (M) itself, with a known error correlation."""
    feats = pd.DataFrame(
        {"log_distance": np.log(rng.uniform(1.0, 4.0, n)), "tilt_rad": rng.uniform(0, 0.7, n),
         "radius_norm": rng.uniform(0, 0.4, n)}
    )  # fmt: skip
    Z = (feats[list(un.FEATURES)] - feats[list(un.FEATURES)].mean()) / feats[list(un.FEATURES)].std()
    v = np.exp(rng.normal(0, 0.5, (n, 6))) * np.array([1e-6] * 3 + [1e-4] * 3)
    sigma = np.sqrt(a**2 * v + b**2) * np.exp(Z.to_numpy() @ gamma)[:, None]
    L = np.linalg.cholesky(corr)
    e = (rng.normal(size=(n, 6)) @ L.T) * sigma
    for j, d in enumerate(metrics.ERROR_DIMS):
        feats[f"pnp_var_{d}"] = v[:, j]
    return feats, pd.DataFrame(e, columns=metrics.error_columns())


def test_error_model_bands_calibrated_on_its_own_data():
    """Errors drawn from model (M) (a = 1.5, a floor b, feature effects, correlated dims):
    fitted on 3000 frames, on 3000 others 68 % and 95 % bands hold 68 +- 3 % and 95 +- 2 %,
    NEES is 6 +- 0.5, and a is recovered within 10 %."""
    rng = np.random.default_rng(2)
    corr = np.eye(6) + 0.3 * (np.ones((6, 6)) - np.eye(6))
    gamma = np.array([0.3, -0.2, 0.1])
    b = np.array([3e-4] * 3 + [3e-3] * 3)
    f, e = _model_data(rng, 6000, 1.5, b, gamma, corr)
    model = un.fit_error_model(f[:3000], e[:3000])
    sc = un.score_error_model(model, f[3000:], e[3000:])
    assert abs(sc["inside_68_all"] - 0.6827) < 0.03
    assert abs(sc["inside_95_all"] - 0.95) < 0.02
    assert abs(sc["nees_mean"] - 6.0) < 0.5
    for d in metrics.ERROR_DIMS:
        assert model[d]["a"] == pytest.approx(1.5, rel=0.1)


def test_error_model_detects_overconfidence():
    """A model fitted on errors 1x but scored on errors 2x as large reports far fewer than
    95 % inside its band and NEES well above 6 (the score is not vacuous)."""
    rng = np.random.default_rng(3)
    f, e = _model_data(rng, 2000, 1.0, np.full(6, 1e-4), np.zeros(3), np.eye(6))
    model = un.fit_error_model(f[:1000], e[:1000], use_features=False)
    sc = un.score_error_model(model, f[1000:], 2.0 * e[1000:])
    assert sc["inside_95_all"] < 0.75 and sc["nees_mean"] > 18


def test_error_features_geometry():
    """A face-on board centred on the optical axis at 2 m: distance 2 m, tilt 0, radius 0."""
    p_B = board_object_points(BOARD)
    centre = p_B.mean(axis=0)
    frames = pd.DataFrame(
        {"frame": [0], "cvs_rvec_0": [0.0], "cvs_rvec_1": [0.0], "cvs_rvec_2": [0.0],
         "cvs_x_m": [-centre[0]], "cvs_y_m": [-centre[1]], "cvs_z_m": [2.0]}
    )  # fmt: skip
    feats, cov = un.error_features(frames, p_B, K, DIST, 0.3)
    assert feats["distance_m"].iloc[0] == pytest.approx(2.0)
    assert feats["tilt_rad"].iloc[0] == pytest.approx(0.0, abs=1e-7)
    assert feats["radius_norm"].iloc[0] == pytest.approx(0.0, abs=1e-12)
    assert cov.shape == (1, 6, 6) and feats["pnp_var_z_m"].iloc[0] > feats["pnp_var_x_m"].iloc[0]


def test_fit_error_model_bad_input():
    """Missing columns and too few frames raise OptimiseError naming the problem."""
    rng = np.random.default_rng(4)
    f, e = _model_data(rng, 10, 1.0, np.full(6, 1e-4), np.zeros(3), np.eye(6))
    with pytest.raises(OptimiseError, match=">= 20"):
        un.fit_error_model(f, e)
    with pytest.raises(OptimiseError, match="missing columns"):
        un.fit_error_model(f.drop(columns=["tilt_rad"]), e)


def _fit_with_std(**std):
    """A fold's se3 result with independent parameter errors of the given std (others 0)."""
    names = ["fx", "fy", "k1", "k2", "p1", "p2"] + [
        f"{b}_{s}" for b in ("T_Cm_C", "T_Bm_B") for s in ("rx_rad", "ry_rad", "rz_rad", "x_m", "y_m", "z_m")
    ] + ["dt_offset_s"]  # fmt: skip
    return {"fold": 0, "K": K.tolist(), "dist": DIST.tolist(), "T_Cm_C": np.eye(4).tolist(),
            "T_Bm_B": np.eye(4).tolist(), "std_errors_cluster": {n: std.get(n, 0.0) for n in names},
            "correlation": {"names": names, "matrix": np.eye(len(names)).tolist()}}  # fmt: skip


def test_parameter_covariance_of_a_camera_mounting_rotation():
    """A camera mounting rotation error w about C's x axis (std 1 mrad) moves the reference
    board at 2 m on the axis by -w x t: err_y std 2 mm, err_roll std 1 mrad, nothing else;
    independent fx, fy errors (std 7 px at f 700, 1 %) move the PnP depth by their mean:
    err_z std 2 m x 1 % / sqrt(2) = 14 mm (within 5 %)."""
    p_B = board_object_points(BOARD)
    c = p_B.mean(axis=0)
    frames = pd.DataFrame({"fold": [0], "cvs_rvec_0": [0.0], "cvs_rvec_1": [0.0], "cvs_rvec_2": [0.0],
                           "cvs_x_m": [-c[0]], "cvs_y_m": [-c[1]], "cvs_z_m": [2.0],
                           "ref_qx": [0.0], "ref_qy": [0.0], "ref_qz": [0.0], "ref_qw": [1.0],
                           "ref_x_m": [-c[0]], "ref_y_m": [-c[1]], "ref_z_m": [2.0]})  # fmt: skip
    cov, cov_k = un.parameter_covariance(frames, p_B, [_fit_with_std(T_Cm_C_rx_rad=1e-3)])
    sd = np.sqrt(np.diag(cov[0]))
    assert sd[3] == pytest.approx(1e-3, rel=1e-3)
    assert sd[1] == pytest.approx(np.hypot(2.0, c[1]) * 1e-3, rel=1e-2)
    assert sd[0] < 1e-9 and sd[4] < 1e-9 and sd[5] < 1e-9 and np.abs(cov_k).max() == 0
    cov, cov_k = un.parameter_covariance(frames, p_B, [_fit_with_std(fx=7.0, fy=7.0)])
    assert np.sqrt(cov[0, 2, 2]) == pytest.approx(0.02 / np.sqrt(2), rel=0.05)
    np.testing.assert_allclose(cov, cov_k, atol=1e-15)
    with pytest.raises(OptimiseError, match="no fit for fold"):
        un.parameter_covariance(frames.assign(fold=3), p_B, [_fit_with_std()])


def test_parameter_covariance_of_the_time_offset_is_the_reference_speed():
    """A board moving along C's x at 0.5 m/s while turning about C's z at 1 rad/s, 30 frames a
    second, and a time offset of std 1 ms: with ``time_offset`` each frame's error gets std
    0.5 mm in x and 1 mrad in yaw (within 2 %, ends included, one-sided there), nothing in
    y, z, roll, pitch; without it (the default) the time offset adds nothing."""
    p_B = board_object_points(BOARD)
    t_s = np.arange(9) / 30.0
    yaw = 1.0 * t_s
    R = tf.R_from_euler(np.c_[np.zeros((len(t_s), 2)), yaw])
    p = np.c_[0.5 * t_s - 0.2, np.full(len(t_s), -0.2), np.full(len(t_s), 2.0)]
    q = tf.quat_from_R(R).reshape(-1, 4)
    rv = tf.rvec_from_R(R).reshape(-1, 3)
    frames = pd.DataFrame({"fold": 0, "t_vicon_s": t_s + 2.0,
                           **{f"cvs_rvec_{j}": rv[:, j] for j in range(3)},
                           "cvs_x_m": p[:, 0], "cvs_y_m": p[:, 1], "cvs_z_m": p[:, 2],
                           **{f"ref_q{a}": q[:, i] for i, a in enumerate("xyzw")},
                           "ref_x_m": p[:, 0], "ref_y_m": p[:, 1], "ref_z_m": p[:, 2]})  # fmt: skip
    fit = _fit_with_std(dt_offset_s=1e-3)
    cov, _ = un.parameter_covariance(frames, p_B, [fit], time_offset=True)
    sd = np.sqrt(np.einsum("nii->ni", cov))
    np.testing.assert_allclose(sd[:, 0], 0.5e-3, rtol=0.02)
    np.testing.assert_allclose(sd[:, 5], 1e-3, rtol=0.02)
    assert sd[:, 1:5].max() < 2e-5
    cov0, _ = un.parameter_covariance(frames, p_B, [fit])
    assert np.abs(cov0).max() == 0


def test_parameter_model_bands_calibrated_on_its_own_data():
    """Errors drawn from model (P) (random per-frame parameter covariances P_i, K_i, scales
    c = 1.5, k = 0.5, floor b, a bias): fitted on 2000 frames, on 2000 others the 68 % and
    95 % bands hold 68 +- 3 % and 95 +- 2 %, NEES (full covariance) is 6 +- 0.5, c within 15 %."""
    rng = np.random.default_rng(5)
    n = 4000
    scale = np.array([1e-3] * 3 + [3e-3] * 3)

    def spd():
        A = rng.normal(size=(n, 6, 6)) * scale[None, :, None] * np.exp(rng.normal(0, 0.7, (n, 1, 1)))
        return A @ np.swapaxes(A, 1, 2) / 6

    P, Kc = spd(), spd()
    b = 0.3 * scale
    cov = 1.5**2 * P + 0.5**2 * Kc + np.diag(b**2)
    e = np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, 6))) + 0.2 * scale
    feats = pd.DataFrame(index=range(n))
    iu = np.triu_indices(6)
    for block, C in (("parcov", P), ("intrcov", Kc)):
        for (a, bb) in zip(*iu, strict=True):
            feats[f"{block}_{a}{bb}"] = C[:, a, bb]
    err = pd.DataFrame(e, columns=metrics.error_columns())
    model = un.fit_error_model(feats[:2000], err[:2000])
    assert model["kind"] == "P"
    sc = un.score_error_model(model, feats[2000:].reset_index(drop=True), err[2000:].reset_index(drop=True))
    assert abs(sc["inside_68_all"] - 0.6827) < 0.03
    assert abs(sc["inside_95_all"] - 0.95) < 0.02
    assert abs(sc["nees_mean"] - 6.0) < 0.5
    for d in metrics.ERROR_DIMS:
        assert model[d]["c"] == pytest.approx(1.5, rel=0.15)


def _parameter_model_data(rng, n, c, k, b, nu):
    """Features and errors drawn from model (P) with Student-t errors of nu degrees of
    freedom (covariance c^2 P_i + k^2 K_i + diag(b^2), random per-frame P_i, K_i)."""
    scale = np.array([1e-3] * 3 + [3e-3] * 3)

    def spd():
        A = rng.normal(size=(n, 6, 6)) * scale[None, :, None] * np.exp(rng.normal(0, 0.7, (n, 1, 1)))
        return A @ np.swapaxes(A, 1, 2) / 6

    P, Kc = spd(), spd()
    cov = c**2 * P + k**2 * Kc + np.diag((b * scale) ** 2)
    w = np.sqrt((nu - 2) / rng.chisquare(nu, n))  # multivariate t with covariance cov
    e = np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=(n, 6))) * w[:, None]
    feats = pd.DataFrame(index=range(n))
    iu = np.triu_indices(6)
    for block, C in (("parcov", P), ("intrcov", Kc)):
        for (a, bb) in zip(*iu, strict=True):
            feats[f"{block}_{a}{bb}"] = C[:, a, bb]
    return feats, pd.DataFrame(e, columns=metrics.error_columns())


def test_parameter_model_heavy_tails_calibrated():
    """Errors of model (P) with Student-t tails (nu = 5): fitted on 3000 frames, on 3000
    others the 68 % and 95 % bands (t quantiles) hold 68 +- 2.5 % and 95 +- 1.5 % and NEES is
    6 +- 0.6, where normal bands of the same sigma would hold > 72 % at 68 %; c, k recovered
    within 15 %, nu within [3.5, 8]."""
    rng = np.random.default_rng(7)
    f, e = _parameter_model_data(rng, 6000, 1.5, 0.5, 0.3, 5.0)
    model = un.fit_error_model(f[:3000], e[:3000])
    assert 3.5 < model["nu"] < 8
    assert model["x_m"]["c"] == pytest.approx(1.5, rel=0.15)
    assert model["x_m"]["k"] == pytest.approx(0.5, rel=0.15)
    f2, e2 = f[3000:].reset_index(drop=True), e[3000:].reset_index(drop=True)
    sc = un.score_error_model(model, f2, e2)
    assert abs(sc["inside_68_all"] - 0.6827) < 0.025
    assert abs(sc["inside_95_all"] - 0.95) < 0.015
    assert abs(sc["nees_mean"] - 6.0) < 0.6
    sigma, mu = un.predict_error_sigma(model, f2)
    assert np.mean(np.abs(e2.to_numpy() - mu) <= sigma) > 0.72  # what a normal band would say


def test_parameter_covariance_of_a_fixed_intrinsic_matches_monte_carlo():
    """A fixed principal point (cx, cy std 3 px) moves the held-out PnP pose (re-solved by
    cv2.solvePnP with the perturbed cx, cy) and the fitted mountings (through a sensitivity S);
    the propagated error covariance matches the Monte-Carlo covariance of the composed errors
    (std within 10 %, correlations within 0.1), signs included."""
    rng = np.random.default_rng(8)
    p_B = board_object_points(BOARD)
    fit = _fit_with_std(fx=0.0)
    names = fit["correlation"]["names"]
    S = np.zeros((len(names), 2))
    S[names.index("T_Cm_C_ry_rad"), 0] = 1.0 / 700  # a cx shift is, to first order, a turn
    S[names.index("T_Cm_C_rx_rad"), 1] = -0.5 / 700
    S[names.index("T_Bm_B_x_m"), 0] = 2e-4
    fit["fixed_intrinsics"] = {"names": ["cx", "cy"], "std": [3.0, 3.0], "sensitivity": S.tolist()}
    rvec = np.array([[0.2, -0.3, 0.1], [-0.4, 0.2, 0.0]])
    tvec = np.array([[-0.2, 0.1, 2.0], [0.3, -0.1, 3.0]])
    T_ref = tf.T_from_rvec_tvec(rvec, tvec)
    q = np.array([tf.quat_from_R(T[:3, :3]) for T in T_ref]).reshape(-1, 4)
    frames = pd.DataFrame({"fold": 0, **{f"cvs_rvec_{j}": rvec[:, j] for j in range(3)},
                           "cvs_x_m": tvec[:, 0], "cvs_y_m": tvec[:, 1], "cvs_z_m": tvec[:, 2],
                           **{f"ref_q{a}": q[:, i] for i, a in enumerate("xyzw")},
                           "ref_x_m": tvec[:, 0], "ref_y_m": tvec[:, 1], "ref_z_m": tvec[:, 2]})  # fmt: skip
    cov, _ = un.parameter_covariance(frames, p_B, [fit])
    for i in range(len(frames)):
        uv, _ = cv2.projectPoints(p_B.reshape(-1, 1, 3), rvec[i], tvec[i], K, DIST)
        errs = []
        for _ in range(300):
            d = rng.normal(0, 3.0, 2)
            K1 = K.copy()
            K1[0, 2] += d[0]
            K1[1, 2] += d[1]
            _, r, t = cv2.solvePnP(p_B.reshape(-1, 1, 3), uv, K1, DIST, rvec[i][:, None].copy(),
                                   tvec[i][:, None].copy(), useExtrinsicGuess=True,
                                   flags=cv2.SOLVEPNP_ITERATIVE)  # fmt: skip
            x = S @ d
            p = dict(zip(names, x, strict=True))
            R_C = tf.R_from_rvec(np.array([p[f"T_Cm_C_r{a}_rad"] for a in "xyz"]))
            R_B = tf.R_from_rvec(np.array([p[f"T_Bm_B_r{a}_rad"] for a in "xyz"]))
            T_Cm_C = tf.make_T(R_C, np.array([p[f"T_Cm_C_{a}_m"] for a in "xyz"]))
            T_Bm_B = tf.make_T(R_B, np.array([p[f"T_Bm_B_{a}_m"] for a in "xyz"]))
            T_r = tf.invert_T(T_Cm_C) @ T_ref[i] @ T_Bm_B  # T_Cm_C0 = T_Bm_B0 = I
            T_c = tf.T_from_rvec_tvec(r.ravel()[None], t.ravel()[None])
            errs.append(metrics.pose_errors(T_r[None], T_c, frame="C")[metrics.error_columns()].to_numpy()[0])
        C_mc = np.cov(np.array(errs), rowvar=False)
        sd_mc, sd = np.sqrt(np.diag(C_mc)), np.sqrt(np.diag(cov[i]))
        np.testing.assert_allclose(sd, sd_mc, rtol=0.1)
        np.testing.assert_allclose(cov[i] / np.outer(sd, sd), C_mc / np.outer(sd_mc, sd_mc), atol=0.1)


# --------------------------------------------------------------------------- model (T)


@pytest.fixture(scope="module")
def truth_session():
    """A 10 s corner-level session scored against its own truth (the true K): CVS = PnP of the
    noisy corners, reference = the true pose, so the error is the corner noise alone."""
    s = simulate_session(21, duration_s=10.0, pixel_noise_px=0.4)
    tr = s["truth"]
    p_B = board_object_points(s["board"])
    frame, t, uv = corner_arrays(s["corners"], len(p_B))
    T_cvs, ok = solve_pnp_frames(uv, p_B, tr["K"], tr["dist"])
    rows = {"frame": frame[ok], "t_s": t[ok], "fold": 0}
    for pre, T in (("cvs_", T_cvs[ok]), ("ref_", tr["T_C_B"][ok])):
        q = tf.quat_from_R(T[:, :3, :3])
        for j, a in enumerate("xyz"):
            rows[f"{pre}{a}_m"] = T[:, j, 3]
        for j, a in enumerate(("qx", "qy", "qz", "qw")):
            rows[f"{pre}{a}"] = q[:, j]
    rv = tf.rvec_from_R(T_cvs[ok][:, :3, :3])
    for j in range(3):
        rows[f"cvs_rvec_{j}"] = rv[:, j]
    rows["reproj_rms_px"] = 0.4
    table = metrics.frame_errors(pd.DataFrame(rows))
    fits = [{"fold": 0, "K": tr["K"].tolist(), "dist": tr["dist"].tolist()}]
    return s, table, fits


def test_cramer_rao_sigma_is_the_pnp_scatter(truth_session):
    """With the true camera and iid 0.4 px corner noise, the CVS errors over the CRB of their
    frame have an RMS of 1 (within 10 %) on every axis: the bound is reached by PnP."""
    s, table, fits = truth_session
    feats = un.measurement_features(table, s["corners"], s["board"], fits=fits)
    crb = un.cramer_rao_sigma(feats, 0.4)
    E = table[[f"err_{d}" for d in metrics.ERROR_DIMS]].to_numpy()
    z = np.sqrt(np.mean((E / crb) ** 2, axis=0))
    np.testing.assert_allclose(z, 1.0, atol=0.1)
    assert (feats["n_corners"] == 20).all()
    assert feats["speed_px"].between(0.0, 50.0).all() and feats["speed_px"].median() > 0.1


def test_corner_velocities_next_to_gaps_and_lost_corners():
    """A board grid turning and drifting at a constant rate (so its velocity field is affine
    and every difference exact): frames next to a 0.3 s gap take the one-sided difference,
    corners neither neighbour saw take the affine field of the others, and the speed next to
    the gap is the one-sided travel, not 0. Before, a fast swing that lost corners in the
    track (a 1080p render with a 14 x 10 board) predicted no rolling-shutter shear for them,
    and its held-out fold scored NEES 31.6."""
    gx, gy = np.meshgrid(np.arange(6) * 40.0, np.arange(4) * 40.0)
    grid = np.c_[gx.ravel(), gy.ravel()] + [300.0, 200.0]
    omega, v0 = 0.5, np.array([120.0, -60.0])  # rad/s about the grid centre, px/s
    centre = grid.mean(axis=0)
    frames = np.r_[0:10, 19:30]  # frames 10-18 lost: a 0.3 s gap at 30 fps
    rows = []
    for f in frames:
        t = f / 30.0
        c, s_ = np.cos(omega * t), np.sin(omega * t)
        uv = (grid - centre) @ np.array([[c, s_], [-s_, c]]) + centre + v0 * t
        keep = np.ones(len(grid), bool)
        if f in (4, 6):
            keep[:12] = False  # the neighbours of frame 5 lost half the corners
        rows.append(pd.DataFrame({"frame": f, "t_s": t, "found": True, "corner": np.arange(24)[keep],
                                  "u_px": uv[keep, 0], "v_px": uv[keep, 1]}))
    corners = pd.concat(rows, ignore_index=True)
    uv, speed, vel = un.seen_corners(corners, frames, 24)

    def truth(f):
        t = f / 30.0
        c, s_ = np.cos(omega * t), np.sin(omega * t)
        d = (grid - centre) @ np.array([[c, s_], [-s_, c]])
        return v0 + omega * d @ np.array([[0.0, 1.0], [-1.0, 0.0]])

    i = {f: k for k, f in enumerate(frames)}
    # differences of a turning grid are exact to O(omega h): under 2 % here
    for f in (2, 9, 19, 5):  # central, before and after the gap, lost corners
        np.testing.assert_allclose(vel[i[f]], truth(f), rtol=0, atol=0.02 * np.abs(truth(f)).max())
    assert 0 not in speed
    assert speed[i[9]] == pytest.approx(np.linalg.norm(truth(9), axis=1).mean() / 30.0, rel=0.02)


def test_measurement_features_use_only_the_seen_corners(truth_session):
    """Hiding half of a frame's corners raises its unit covariance (fewer, closer corners)."""
    s, table, fits = truth_session
    c = s["corners"].copy()
    f0 = int(table["frame"].iloc[10])
    hide = (c["frame"] == f0) & (c["corner"] >= 10)
    c.loc[hide, ["u_px", "v_px"]] = np.nan
    full = un.measurement_features(table.iloc[[10]], s["corners"], s["board"], fits=fits)
    part = un.measurement_features(table.iloc[[10]], c, s["board"], fits=fits)
    assert int(part["n_corners"].iloc[0]) == 10 and part["spread_px"].iloc[0] < full["spread_px"].iloc[0]
    assert part["unitcov_00"].iloc[0] > 1.5 * full["unitcov_00"].iloc[0]
    with pytest.raises(OptimiseError, match="lacks columns"):
        un.measurement_features(table.drop(columns=["reproj_rms_px"]), s["corners"], s["board"],
                                fits=fits)  # fmt: skip


def test_transfer_model_recovers_its_parameters_and_is_calibrated():
    """Model (T) fitted on 6000 frames drawn from it recovers the corner-noise scale, the speed
    term and the floors; on 3000 new frames (another draw of the shared term) NEES ~ 6 and
    the bands hold per axis."""
    rng = np.random.default_rng(3)
    feats, E, _ = draw_transfer(rng, 4000, TRUTH_T, n_blocks=200)
    m = un.fit_transfer_model(feats, E)
    assert m["kind"] == "T"
    for name, rtol in (("s_speed", 0.15), ("b_pos_m", 0.2), ("b_rot_rad", 0.2), ("c_cal", 0.2)):
        assert abs(m[name] - TRUTH_T[name]) < rtol * TRUTH_T[name], (name, m[name])
    var_true = TRUTH_T["s0_px"] ** 2 + (TRUTH_T["s_reproj"] * 0.3) ** 2
    var_fit = m["s0_px"] ** 2 + (m["s_reproj"] * 0.3) ** 2
    assert abs(var_fit / var_true - 1) < 0.15  # s0 and s_reproj trade at fixed reproj spread
    assert m["nu"] > 4.0  # heavy tails seen (the shared Gaussian term lightens the total's)
    f2, E2, _ = draw_transfer(np.random.default_rng(4), 3000, TRUTH_T, n_blocks=100)
    sc = un.score_covariance(un.transfer_covariance(m, f2), E2, nu=m["nu"])
    assert 5.0 < sc["nees_mean"] < 7.0
    for d in metrics.ERROR_DIMS:
        assert 0.93 < sc["inside_95"][d] < 0.97 and 0.64 < sc["inside_68"][d] < 0.72, d


def test_transfer_fit_started_from_the_whole_fit_finds_the_folds_optimum():
    """A fold's fit started from the whole session's (the cross-fit's warm start) reaches the
    likelihood of the two fixed starts and the same determined parameters."""
    feats, E, _ = draw_transfer(np.random.default_rng(5), 1600, TRUTH_T, n_blocks=80)
    whole = un.fit_transfer_model(feats, E)
    # started at its own optimum, a fit stays there: the start is the model, entry by entry
    again = un.fit_transfer_model(feats, E, start=whole)
    for name in un.TRANSFER_PARAMS:
        assert again[name] == pytest.approx(whole[name], rel=1e-5, abs=1e-12), name
    fold = np.arange(len(E)) * 4 // len(E)
    for k in range(4):
        f, e = feats[fold != k].reset_index(drop=True), E[fold != k].reset_index(drop=True)
        cold, warm = un.fit_transfer_model(f, e), un.fit_transfer_model(f, e, start=whole)
        assert warm["nll"] <= cold["nll"] + 1e-6 * abs(cold["nll"]), k
        for name in ("s_speed", "b_pos_m", "b_rot_rad", "nu"):
            assert warm[name] == pytest.approx(cold[name], rel=0.02), (k, name)
    # the start is the whole fit only: a wrong one still ends at the fold's optimum
    bad = {**whole, "s_speed": 10 * whole["s_speed"], "nu": 30.0}
    f, e = feats[fold != 0].reset_index(drop=True), E[fold != 0].reset_index(drop=True)
    assert un.fit_transfer_model(f, e, start=bad)["s_speed"] == pytest.approx(
        un.fit_transfer_model(f, e)["s_speed"], rel=0.02)


def _draw_still(rng, n, s_still, inter_coded):
    """Frames of model (T) (no parameter covariance) whose nearly still, inter-coded ones err by
    the still board's pose-like codec term too: var_px (1 + s_still^2 (n_c / 3) g(v)) U."""
    from cvsflow.uncertainty import transfer as tr
    from cvsflow.uncertainty.features import STILL_SPEED_PX

    feats, _, _ = draw_transfer(rng, n, TRUTH_T)
    feats = feats.drop(columns=un.cov_columns("parcov"))
    feats["n_corners"] = 20
    feats["speed_px"] = np.where(rng.uniform(size=n) < 0.4, rng.uniform(0, 0.4, n),
                                 rng.uniform(1, 10, n))
    feats["inter_coded"] = float(inter_coded)
    U, _, _, speed, reproj, *_ = tr._transfer_terms(feats)
    var_px = TRUTH_T["s0_px"] ** 2 + (TRUTH_T["s_speed"] * speed) ** 2 + (TRUTH_T["s_reproj"] * reproj) ** 2
    still = (20 / 3) / (1.0 + (speed / STILL_SPEED_PX) ** 2)
    # U is in working units: back to SI
    cov = (var_px * (1.0 + s_still**2 * still))[:, None, None] * U
    cov = cov * np.outer(un.WORKING_UNITS, un.WORKING_UNITS)[None]
    floor = np.r_[[TRUTH_T["b_pos_m"]] * 3, [TRUTH_T["b_rot_rad"]] * 3] ** 2
    nu = TRUTH_T["nu"]
    w = np.sqrt((nu - 2) / rng.chisquare(nu, n))
    e = np.einsum("nij,nj->ni", np.linalg.cholesky(cov + np.diag(floor)), rng.normal(size=(n, 6)))
    return feats, pd.DataFrame(e * w[:, None], columns=[f"err_{d}" for d in metrics.ERROR_DIMS]), speed


def test_transfer_model_still_board_codec_term():
    """Frames whose still board a motion-compensated codec shows with a pose-like error (drawn
    with s_still = 0.6, as the rendered MPEG-4 video's): the fit recovers s_still, and the still frames' NEES is ~6 with the
    term and over 7.2 without it; an intra-coded video (inter_coded 0) gets no such term."""
    feats, E, speed = _draw_still(np.random.default_rng(5), 4000, 0.6, True)
    m = un.fit_transfer_model(feats, E)
    assert abs(m["s_still"] - 0.6) < 0.1, m["s_still"]
    plain = un.fit_transfer_model(feats, E, still=False)
    assert "s_still" not in plain
    f2, E2, v2 = _draw_still(np.random.default_rng(6), 3000, 0.6, True)
    slow = v2 < 0.4
    with_term = un.score_covariance(un.transfer_covariance(m, f2)[slow], E2[slow], nu=m["nu"])
    without = un.score_covariance(un.transfer_covariance(plain, f2)[slow], E2[slow],
                                  nu=plain["nu"])  # fmt: skip
    assert 5.5 < with_term["nees_mean"] < 6.5 and without["nees_mean"] > 7.2
    intra, E_intra, _ = _draw_still(np.random.default_rng(7), 2000, 0.0, False)
    assert "s_still" not in un.fit_transfer_model(intra, E_intra)


def test_transfer_nll_is_the_fitted_likelihood_and_scores_new_frames():
    """transfer_nll of a model on its own training frames is the mean NLL the fit reached; on
    new still-board frames of an inter-coded video the model with s_still scores better."""
    feats, E, _ = _draw_still(np.random.default_rng(8), 2000, 0.6, True)
    with_term = un.fit_transfer_model(feats, E)
    without = un.fit_transfer_model(feats, E, still=False)
    assert un.transfer_nll(with_term, feats, E) == pytest.approx(with_term["nll"], rel=1e-12)
    assert un.transfer_nll(without, feats, E) == pytest.approx(without["nll"], rel=1e-12)
    f2, E2, _ = _draw_still(np.random.default_rng(9), 2000, 0.6, True)
    assert un.transfer_nll(with_term, f2, E2) < un.transfer_nll(without, f2, E2) - 0.02


def test_transfer_model_bad_input():
    """Named errors: missing columns, too few rows."""
    feats, E, _ = draw_transfer(np.random.default_rng(0), 30, TRUTH_T)
    with pytest.raises(OptimiseError, match="missing columns"):
        un.fit_transfer_model(feats.drop(columns=["speed_px"]), E)
    with pytest.raises(OptimiseError, match=">= 20"):
        un.fit_transfer_model(feats.iloc[:10], E.iloc[:10])


def test_shrink_corner_noise_is_the_dof_weighted_mean_of_variances():
    """k = 0 keeps each frame's estimate, a huge k gives the pool, and in between the variance
    is the (2n - 6, k)-weighted mean of the frame's and the pool's; the pool is the median."""
    noise = np.array([0.1, 0.2, 0.4])
    n_c = np.array([20, 28, 30])
    np.testing.assert_allclose(un.shrink_corner_noise(noise, n_c, 0.25, 0.0), noise)
    np.testing.assert_allclose(un.shrink_corner_noise(noise, n_c, 0.25, 1e12), 0.25, rtol=1e-9)
    got = un.shrink_corner_noise(noise, n_c, 0.25, 30.0) ** 2
    dof = 2.0 * n_c - 6
    np.testing.assert_allclose(got, (dof * noise**2 + 30.0 * 0.0625) / (dof + 30.0))
    rms = noise * np.sqrt(2.0) / np.sqrt(2.0 * n_c / (2.0 * n_c - 6))
    assert un.corner_noise_pool(rms, n_c) == pytest.approx(0.2)


def test_transfer_model_shrinks_noisy_corner_noise_toward_the_pool():
    """Two sessions whose corner noise is one value each (0.15 and 0.45 px) and whose frames
    estimate it from 25 corners (44 dof, ~11 % scatter): the fitted prior strength k is more
    than twice a frame's dof (the session's pool is the better estimate; 1200 frames tell k
    only roughly), the likelihood is higher than without shrinkage, and k = 0 is the model
    without it."""
    rng = np.random.default_rng(5)
    n = 1200
    true = np.where(np.arange(n) < n // 2, 0.15, 0.45)
    truth = {**TRUTH_T, "s0_px": 1e-3, "s_speed": 1e-4, "s_reproj": 1.0}
    feats, E, _ = draw_transfer(rng, n, truth, n_blocks=100, reproj=true)
    dof = 2 * 25 - 6
    est = true * np.sqrt(rng.chisquare(dof, n) / dof)
    feats["n_corners"] = 25
    feats["reproj_rms_px"] = est * np.sqrt(2.0) / np.sqrt(50.0 / dof)
    np.testing.assert_allclose(un.corner_noise_from_reproj(feats["reproj_rms_px"], 25), est)
    half = np.arange(n) < n // 2
    feats[un.NOISE_POOL_COLUMN] = np.where(half, np.median(est[half]), np.median(est[~half]))
    m0 = un.fit_transfer_model(feats, E)
    m1 = un.fit_transfer_model(feats, E, shrink="fit")
    assert m1["k_shrink"] > 2 * dof, m1["k_shrink"]
    assert m1["nll"] < m0["nll"] - 0.005, (m1["nll"], m0["nll"])
    np.testing.assert_allclose(un.transfer_covariance({**m0, "k_shrink": 0.0}, feats),
                               un.transfer_covariance(m0, feats), rtol=1e-9)  # fmt: skip
    with pytest.raises(OptimiseError, match="shrink"):
        un.fit_transfer_model(feats, E, shrink="median")


def test_vicon_filled_marks_frames_near_a_gap_filled_board_sample():
    """A board sample with a filled marker at t = 1.0 s marks the frames whose Vicon time is
    within FILL_WINDOW_S of it, not the others nor the camera's fills."""
    t = np.arange(0.0, 2.0, 1.0 / 300)
    bodies = pd.DataFrame({"t_s": np.r_[t, t], "body": ["board"] * len(t) + ["camera"] * len(t),
                           "n_filled": 0})  # fmt: skip
    bodies.loc[(bodies["body"] == "board") & (np.abs(bodies["t_s"] - 1.0) < 1e-9), "n_filled"] = 1
    bodies.loc[(bodies["body"] == "camera") & (np.abs(bodies["t_s"] - 0.5) < 1e-9), "n_filled"] = 2
    tq = np.array([0.5, 0.985, 0.995, 1.0, 1.009, 1.02, 1.5])
    np.testing.assert_array_equal(un.vicon_filled(bodies, tq), [0, 0, 1, 1, 1, 0, 0])


def test_flight_reference_covariance_takes_the_shrinkage_option():
    """A flight's reference covariance under model (T) with ``k_shrink``: k = 0 is the model
    without it; a huge k pulls every frame to the flight's pooled noise, so frames whose
    residual is below the pool get a larger covariance and those above a smaller one."""
    from cvsflow import flight as F
    from cvsflow.board.model import board_object_points
    from cvsflow.synth.flight_demo import T_Q_B_DEFAULT, camera_pose, true_flight
    from cvsflow.synth.flight_reference import BOARD_DEFAULT, CAMERA_DEMO, measure_reference

    t = np.arange(60) / 30.0
    T_C_B = tf.invert_T(camera_pose()) @ true_flight(3, 20.0)(t) @ T_Q_B_DEFAULT
    _, valid, _, poses, corners = measure_reference(T_C_B, t, np.ones(len(t), bool),
                                                    np.random.default_rng(2), calib_std={})
    K = [[CAMERA_DEMO["fx_px"], 0, CAMERA_DEMO["cx_px"]],
         [0, CAMERA_DEMO["fy_px"], CAMERA_DEMO["cy_px"]], [0, 0, 1]]
    calib = {"K": K, "dist": CAMERA_DEMO["dist"], "std": {}}
    p_B = board_object_points(BOARD_DEFAULT)
    m = un.RENDERED_TRANSFER_MODEL

    def trace(model):
        S = F.reference_covariance_transfer(poses, corners, p_B, calib, model=model, flips=False)
        return np.einsum("nii->n", S[valid][:, :3, :3])

    base = trace(m)
    np.testing.assert_allclose(trace({**m, "k_shrink": 0.0}), base, rtol=1e-12)
    pooled = trace({**m, "k_shrink": 1e9})
    rows = poses[valid]
    n_seen = np.isfinite(un.seen_corners(corners, rows["frame"].to_numpy(), len(p_B))[0]).all(-1).sum(1)
    n_i = un.corner_noise_from_reproj(rows["reproj_rms_px"].to_numpy(float), n_seen)
    low = n_i < 0.95 * np.median(n_i)
    high = n_i > 1.05 * np.median(n_i)
    assert low.sum() >= 5 and high.sum() >= 5
    assert (pooled[low] > base[low]).all() and (pooled[high] < base[high]).all()


def test_correlated_noise_terms_limits_are_iid_noise_and_a_common_shift():
    """A correlation length far below the corner spacing gives the iid term (frame_noise_terms'
    unit covariance); an infinite one gives the covariance of the pose change that
    PnP makes when every corner shifts by the same unit (re-solved by cv2.solvePnP for a
    0.01 px shift along u and along v)."""
    p_B = board_object_points(BOARD)
    rvec, tvec = np.array([0.3, -0.4, 0.1]), np.array([-0.1, 0.05, 2.0])
    uv, _ = cv2.projectPoints(p_B.reshape(-1, 1, 3), rvec, tvec, K, DIST)
    uv = uv.reshape(1, -1, 2)
    uv[0, 3] = np.nan  # an unseen corner is left out
    unit, _ = un.frame_noise_terms(uv, np.zeros_like(uv), rvec[None], tvec[None], p_B, K, DIST)
    tiny = un.correlated_noise_terms(uv, rvec[None], tvec[None], p_B, K, DIST, 1e-3)
    np.testing.assert_allclose(tiny, unit, rtol=1e-9, atol=1e-9 * np.abs(unit).max())
    huge = un.correlated_noise_terms(uv, rvec[None], tvec[None], p_B, K, DIST, np.inf)[0]
    seen = np.isfinite(uv[0]).all(axis=1)
    T0 = tf.T_from_rvec_tvec(rvec[None], tvec[None])
    cols = [f"err_{d}" for d in metrics.ERROR_DIMS]
    eps, expect = 0.01, np.zeros((6, 6))
    for axis in range(2):
        shifted = uv[0, seen] + eps * np.eye(2)[axis]
        _, r, t = cv2.solvePnP(p_B[seen].reshape(-1, 1, 3), shifted.reshape(-1, 1, 2), K, DIST,
                               rvec.copy()[:, None], tvec.copy()[:, None],
                               useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)  # fmt: skip
        T1 = tf.T_from_rvec_tvec(r.reshape(1, 3), t.reshape(1, 3))
        e = metrics.pose_errors(T0, T1)[cols].to_numpy()[0] / eps
        expect += np.outer(e, e)
    np.testing.assert_allclose(huge, expect, rtol=0.02, atol=0.02 * np.abs(expect).max())
    with pytest.raises(OptimiseError, match="length_px"):
        un.correlated_noise_terms(uv, rvec[None], tvec[None], p_B, K, DIST, 0.0)


def test_transfer_model_fits_the_correlated_corner_term():
    """Errors of model (T) plus a correlated corner noise of 0.4 times the frame's corner noise
    (covariance per px^2 C_i in ``corrcov``): the fit recovers s_corr within 20 % and the band coverage holds on new
    frames; without ``corrcov`` columns the model has no such term, and a model with it
    refuses features without the columns."""
    rng = np.random.default_rng(7)

    def draw(rng, n):
        feats, E, _ = draw_transfer(rng, n, TRUTH_T, n_blocks=100)
        B = rng.normal(size=(n, 6, 2)) * np.r_[2e-3, 2e-3, 5e-3, 3e-3, 3e-3, 1e-3][None, :, None]
        C = B @ np.swapaxes(B, 1, 2) + np.eye(6) * 1e-10  # a shift-like term: rank 2 per frame
        iu = np.triu_indices(6)
        for c, name in enumerate(un.cov_columns("corrcov")):
            feats[name] = C[:, iu[0][c], iu[1][c]]
        var_px = (TRUTH_T["s0_px"] ** 2 + (TRUTH_T["s_speed"] * feats["speed_px"]) ** 2
                  + (TRUTH_T["s_reproj"] * feats["reproj_rms_px"] / np.sqrt(2.0)) ** 2)  # fmt: skip
        z = rng.normal(size=(n, 2)) * (0.4 * np.sqrt(var_px.to_numpy()))[:, None]
        return feats, E + np.einsum("nij,nj->ni", B, z)

    feats, E = draw(rng, 2000)
    m = un.fit_transfer_model(feats, E)
    assert m["s_corr"] == pytest.approx(0.4, rel=0.2)
    f2, E2 = draw(np.random.default_rng(8), 2000)
    sc = un.score_covariance(un.transfer_covariance(m, f2), E2, nu=m["nu"])
    assert 5.0 < sc["nees_mean"] < 7.0
    for d in metrics.ERROR_DIMS:
        assert 0.93 < sc["inside_95"][d] < 0.97, d
    plain = feats.drop(columns=un.cov_columns("corrcov"))
    assert "s_corr" not in un.fit_transfer_model(plain.iloc[:300], E.iloc[:300])
    with pytest.raises(OptimiseError, match="corrcov"):
        un.transfer_covariance(m, plain)


def test_transfer_model_fits_the_shears_relative_error():
    """Errors of model (T) around a rolling-shutter shear mu_i that is itself 20 % off (one
    factor per frame, the line delay's and the velocities' error: rank one along mu_i): the
    fit recovers r_rs within 25 %, and on new frames the frames with the largest shear are
    inside the 95 % band as often as the rest; without r_rs they are not. A session without
    shear has no such term."""
    rng = np.random.default_rng(21)

    def draw(rng, n):
        feats, E, _ = draw_transfer(rng, n, TRUTH_T, n_blocks=100)
        scale = np.r_[3e-3, 2e-3, 8e-3, 4e-3, 4e-3, 1e-3] * rng.lognormal(0.0, 1.0, n)[:, None]
        mu = rng.normal(size=(n, 6)) * scale * (rng.uniform(size=n) < 0.6)[:, None]
        for j, d in enumerate(metrics.ERROR_DIMS):
            feats[f"rs_err_{d}"] = mu[:, j]
        return feats, E + mu * (1.0 + 0.2 * rng.normal(size=n))[:, None], mu

    feats, E, _ = draw(rng, 3000)
    m = un.fit_transfer_model(feats, E)
    assert m["r_rs"] == pytest.approx(0.2, rel=0.25)
    f2, E2, mu2 = draw(np.random.default_rng(22), 3000)
    big = np.linalg.norm(mu2 / un.WORKING_UNITS, axis=1) > np.quantile(
        np.linalg.norm(mu2 / un.WORKING_UNITS, axis=1), 0.8)
    mean = un.transfer_mean(m, f2)
    nees = un.nees_values(un.transfer_covariance(m, f2), E2, mean=mean)
    inside = nees < 12.59  # chi2(6) 95 % (the errors are Student-t: ~92 % expected)
    assert inside[big].mean() > 0.88 and abs(inside[big].mean() - inside[~big].mean()) < 0.04
    assert 5.0 < nees.mean() < 7.0
    nees = un.nees_values(un.transfer_covariance({**m, "r_rs": 0.0}, f2), E2, mean=mean)
    assert (nees[big] < 12.59).mean() < 0.6  # 0.47: the shear's error is most of theirs
    plain = feats.drop(columns=[f"rs_err_{d}" for d in metrics.ERROR_DIMS])
    assert "r_rs" not in un.fit_transfer_model(plain.iloc[:300], E.iloc[:300])
    # the within-session cross-fit records each fold's r_rs (comparison.yaml error_model.folds)
    score, _, _ = un.crossfit_transfer(feats.iloc[:900], E.iloc[:900].assign(fold=np.arange(900) % 3))
    assert all(0.1 < f["params"]["r_rs"] < 0.3 for f in score["folds"])


def test_transfer_model_floors_follow_the_board_bodys_noise():
    """The floors are the mocap board body's own noise: a model fitted on frames whose board
    noise is n scores frames of a mocap three times noisier (errors drawn with floors 3x,
    board-noise columns 3 n) with its floors scaled by 3, and the bands hold; unscaled they
    do not. Frames of the fitted session itself keep the floors bit for bit."""
    from cvsflow.uncertainty import transfer as tr

    truth = {**TRUTH_T, "s0_px": 0.02, "s_reproj": 0.2, "b_pos_m": 1.5e-3, "b_rot_rad": 1.2e-3}
    feats, E, _ = draw_transfer(np.random.default_rng(31), 3000, truth, n_blocks=100)
    feats["board_noise_rot_rad"], feats["board_noise_pos_m"] = 1.3e-4, 8.5e-5
    m = un.fit_transfer_model(feats, E)
    assert m["board_noise"] == {"board_noise_rot_rad": 1.3e-4, "board_noise_pos_m": 8.5e-5}
    assert tr._floors_for(m, feats)["b_pos_m"] == m["b_pos_m"]
    noisy = {**truth, "b_pos_m": 4.5e-3, "b_rot_rad": 3.6e-3}
    f2, E2, _ = draw_transfer(np.random.default_rng(32), 3000, noisy, n_blocks=100)
    f2["board_noise_rot_rad"], f2["board_noise_pos_m"] = 3.9e-4, 2.55e-4
    scaled = un.score_covariance(un.transfer_covariance(m, f2), E2, nu=m["nu"])
    plain = un.score_covariance(un.transfer_covariance({**m, "board_noise": None}, f2), E2,
                                nu=m["nu"])  # fmt: skip
    assert 5.0 < scaled["nees_mean"] < 7.0 and plain["nees_mean"] > 9.0
    for d in metrics.ERROR_DIMS:
        assert 0.92 < scaled["inside_95"][d] < 0.98, d


def test_quantiles_without_scipy_stats_equal_scipy_stats_bit_for_bit():
    """chi2_quantile / student_t_quantile are chi2.ppf / t.ppf exactly (the demo's tables rely on
    it); chi2_pdf is chi2.pdf to rounding."""
    from scipy import stats

    from cvsflow.uncertainty.scoring import chi2_pdf, chi2_quantile, student_t_quantile

    p = np.r_[1e-6, np.linspace(0.001, 0.999, 97), 0.6826894921370859 / 2 + 0.5, 0.95, 0.975, 0.99]
    for df in (1, 2, 3, 6, 6.0, 9.5, 30):
        assert np.array_equal(chi2_quantile(p, df), stats.chi2.ppf(p, df))
        assert chi2_quantile(0.95, df) == stats.chi2.ppf(0.95, df)
    for nu in (2.05, 2.5, 3.0, 4.7, 13.44, 50.0, 1e3):
        assert np.array_equal(student_t_quantile(p, nu), stats.t.ppf(p, nu))
        assert student_t_quantile(0.975, nu) == stats.t.ppf(0.975, nu)
    x = np.linspace(-1.0, 40.0, 401)
    np.testing.assert_allclose(chi2_pdf(x, 6), stats.chi2.pdf(x, 6), rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("case", ["plain", "correlated", "shrunk", "shear", "reference", "flip",
                                  "still"])
def test_transfer_likelihood_gradient_matches_central_differences(case):
    """The analytic gradient of model (T)'s likelihood (what L-BFGS-B is given) equals central
    differences of the likelihood in every parameter, with a rolling-shutter mean, gap-filled
    frames, the correlated corner term, the shrinkage's k, the shear's relative error, a
    moving camera body's reference noise, the planar PnP's flip (whose weight moves with
    the corner variance) and a still board's codec term (which moves with it too)."""
    from cvsflow.uncertainty import transfer as tr

    rng = np.random.default_rng(11)
    feats, E, _ = draw_transfer(rng, 300, TRUTH_T, n_blocks=30)
    for j, d in enumerate(metrics.ERROR_DIMS):
        feats[f"rs_err_{d}"] = rng.normal(size=300) * 2e-4 * (j + 1)
    feats["vicon_filled"] = (rng.uniform(size=300) < 0.2).astype(float)
    feats["n_corners"] = rng.integers(8, 21, 300)
    # a random low-rank 6x6 block per frame: the correlated corners' or the camera body's
    block = {"correlated": ("corrcov", 2, 2e-3), "reference": ("refcov", 3, 1e-3)}.get(case)
    if block is not None:
        name, rank, scale = block
        B = rng.normal(size=(300, 6, rank)) * scale
        C = B @ np.swapaxes(B, 1, 2) + np.eye(6) * 1e-10
        iu = np.triu_indices(6)
        for c, col in enumerate(un.cov_columns(name)):
            feats[col] = C[:, iu[0][c], iu[1][c]]
    if case == "flip":
        # a fifth of the frames with a second solution that fits about as well as the first
        has = rng.uniform(size=300) < 0.2
        for j, d in enumerate(metrics.ERROR_DIMS):
            feats[f"flip_{d}"] = np.where(has, rng.normal(size=300) * 3.0 * un.WORKING_UNITS[j], 0.0)
        feats["flip_dssr_px2"] = np.where(has, rng.uniform(0.0, 1.0, 300), np.inf)
    if case == "still":
        # inter-coded frames, a third of them nearly still
        feats["inter_coded"] = (rng.uniform(size=300) < 0.7).astype(float)
        feats["speed_px"] = np.where(rng.uniform(size=300) < 0.3, rng.uniform(0, 0.6, 300),
                                     feats["speed_px"])
    terms = tr._transfer_terms(feats)
    if case == "still":
        assert (terms[-1][feats["inter_coded"] == 0] == 0).all() and terms[-1].max() > 1.0
    if case == "flip":
        w = un.flip_weight(feats["flip_dssr_px2"].to_numpy(), 0.3)
        assert (w[has] > 0.05).mean() > 0.9 and (w[~has] == 0).all()
    e = E.to_numpy(float) / un.WORKING_UNITS
    q = np.log([0.3, 0.05, 0.6, 0.8, 1.3, 3e-4, 6e-4, 1e-3, 3e-3, 4.0])
    shrink, s_corr = None, 0.3 if case == "correlated" else 0.0
    r_rs = 0.4 if case == "shear" else 0.0
    c_ref = 0.8 if case == "reference" else 0.0
    s_still = 0.6 if case == "still" else 0.0
    if case == "shrunk":
        q, shrink = np.r_[q, np.log(20.0)], tr._shrink_terms(feats)

    def f(q, s, r=r_rs, cr=c_ref, st=s_still):
        return tr._transfer_nll(q, s, e, terms, shrink, r, cr, st)[0]

    nll, grad, grad_corr, grad_rrs, grad_ref, grad_still = tr._transfer_nll(
        q, s_corr, e, terms, shrink, r_rs, c_ref, s_still)
    assert nll == pytest.approx(f(q, s_corr))
    if case == "still":
        h = 1e-5
        fd_st = (f(q, s_corr, st=s_still * np.exp(h)) - f(q, s_corr, st=s_still * np.exp(-h))) / (2 * h)
        assert abs(grad_still) > 1e-6 and grad_still == pytest.approx(fd_st, rel=1e-5)
    if case == "reference":
        h = 1e-5
        fd_ref = (f(q, s_corr, cr=c_ref * np.exp(h)) - f(q, s_corr, cr=c_ref * np.exp(-h))) / (2 * h)
        assert abs(grad_ref) > 1e-6 and grad_ref == pytest.approx(fd_ref, rel=1e-5)
    if case == "shear":
        fd_rrs = (f(q, s_corr, r_rs * np.exp(h := 1e-5)) - f(q, s_corr, r_rs * np.exp(-h))) / (2 * h)
        assert abs(grad_rrs) > 1e-6 and grad_rrs == pytest.approx(fd_rrs, rel=1e-5)
    h = 1e-5
    fd = np.array([(f(q + h * u, s_corr) - f(q - h * u, s_corr)) / (2 * h) for u in np.eye(len(q))])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-7)
    assert np.all(np.abs(grad) > 1e-6)  # every entry moves the likelihood: none tested as 0 = 0
    if case == "correlated":
        fd_corr = (f(q, s_corr * np.exp(h)) - f(q, s_corr * np.exp(-h))) / (2 * h)
        assert grad_corr == pytest.approx(fd_corr, rel=1e-5)


def test_unsheared_reproj_reads_the_corner_noise_not_the_shear():
    """Corners sheared by a rolling shutter (a board sweeping sideways at 600 px/s, 50 us per
    row) plus 0.1 px noise: PnP's residual of the sheared corners overstates the noise, the
    residual of the unsheared ones reads it (RMS length 0.1 sqrt(2) sqrt((2n - 6) / 2n)), and
    the unsheared pose is nearer the true one than the measured."""
    rng = np.random.default_rng(4)
    board = {"squares_x": 8, "squares_y": 6, "square_m": 0.06}
    p_B = board_object_points(board).astype(float)
    K = np.array([[640.0, 0, 320], [0, 640, 240], [0, 0, 1]])
    dist = np.zeros(5)
    n_fr, n = 40, len(p_B)
    rv_true = np.tile([0.25, -0.2, 0.05], (n_fr, 1)) + 0.02 * rng.standard_normal((n_fr, 3))
    tv_true = np.tile([-0.2, -0.15, 1.3], (n_fr, 1))
    vel = np.zeros((n_fr, n, 2))
    vel[..., 0] = 600.0
    uv = np.empty((n_fr, n, 2))
    rv, tv = np.empty((n_fr, 3)), np.empty((n_fr, 3))
    for i in range(n_fr):
        uv0 = cv2.projectPoints(p_B, rv_true[i], tv_true[i], K, dist)[0].reshape(-1, 2)
        uv[i] = uv0 + un.shear_displacement(uv0, vel[i], 5e-5) + 0.1 * rng.standard_normal((n, 2))
        _, r, t = cv2.solvePnP(p_B, uv[i], K, dist, rv_true[i].copy(), tv_true[i].copy(), True,
                               cv2.SOLVEPNP_ITERATIVE)
        rv[i], tv[i] = r.ravel(), t.ravel()
    raw = np.array([np.sqrt(np.mean(np.sum((cv2.projectPoints(p_B, rv[i], tv[i], K, dist)[0]
                                            .reshape(-1, 2) - uv[i]) ** 2, axis=1)))
                    for i in range(n_fr)])  # fmt: skip
    rv_c, tv_c, rms = un.unsheared_pnp(uv, vel, rv, tv, p_B, K, dist, 5e-5)
    expected = 0.1 * np.sqrt(2.0) * np.sqrt((2 * n - 6) / (2 * n))
    assert abs(np.sqrt(np.mean(rms**2)) / expected - 1.0) < 0.1
    assert np.sqrt(np.mean(raw**2)) > 1.5 * expected
    assert np.linalg.norm(rv_c - rv_true) < 0.5 * np.linalg.norm(rv - rv_true)
