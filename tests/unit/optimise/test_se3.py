"""Tests of the se3 joint calibration (cvsflow.optimise.se3) on corner-level synthetic data."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from cvsflow.board.model import board_object_points
from cvsflow.exceptions import MocapError, OptimiseError
from cvsflow.geometry import transforms as tf
from cvsflow.geometry.camera import project_points
from cvsflow.geometry.interpolate import interpolate_T
from cvsflow.geometry.transforms import project_SO3
from cvsflow.mocap import body_poses
from cvsflow.optimise import DEFAULT_FREE, se3
from cvsflow.optimise.body_tracks import (
    CAMERA_MOVING_SMOOTH_S,
    BodyTrack,
    is_static,
    smooth_track,
    smooth_track_local,
)
from cvsflow.optimise.se3_cov import DEFAULT_INTRINSIC_STD
from cvsflow.optimise.se3_model import Se3Model
from cvsflow.optimise.se3_sim import simulate_session
from cvsflow.optimise.se3_start import corner_arrays, solve_hand_eye


@pytest.fixture(scope="module")
def session():
    """A 20 s synthetic session (600 frames, 20 corners, 0.3 px, 0.3 mm marker noise)."""
    return simulate_session(11, duration_s=20.0)


@pytest.fixture(scope="module")
def fitted(session):
    """se3 fitted from a perturbed start (fx +8 px, fy -6 px, cx +4 px, dist x0.9, dt +20 ms)."""
    tr = session["truth"]
    K0 = tr["K"] + np.diag([8.0, -6.0, 0.0])
    K0[0, 2] += 4.0
    cam = {"K": K0.tolist(), "dist": (0.9 * tr["dist"]).tolist()}
    return se3.optimise_se3(
        session["corners"], session["bodies"], cam, session["board"], tr["dt_offset_s"] + 0.02
    )


def _pose_err(T_true, T_est):
    """(translation error m, rotation error rad) of an estimate."""
    d = tf.invert_T(T_true) @ T_est
    return float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])), float(tf.rotation_angle(d[:3, :3]))


def test_project_points_equals_opencv():
    """The vectorised projection equals cv2.projectPoints (5-term distortion) to 1e-9 px."""
    rng = np.random.default_rng(0)
    K = np.array([[701.0, 0, 322.0], [0, 697.0, 243.0], [0, 0, 1]])
    dist = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02])
    p_B = rng.uniform(-0.4, 0.4, (50, 3)) * [1, 1, 0]
    rvec = np.array([0.3, -0.2, 0.1])
    tvec = np.array([0.1, -0.05, 1.5])
    ref, _ = cv2.projectPoints(p_B.reshape(-1, 1, 3), rvec, tvec, K, dist)
    p_C = tf.transform_points(tf.T_from_rvec_tvec(rvec, tvec), p_B)
    uv = project_points(p_C, K, dist)
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-9)


def test_projection_and_model_jacobians_equal_finite_differences():
    """The analytic Jacobian of the residuals (intrinsics, both transforms, dt) equals central
    differences to 1e-5 relative, with a moving camera and nonzero rotation perturbations."""
    s = simulate_session(3, duration_s=3.0, camera_motion_m=0.02)
    tr = s["truth"]
    p_B = board_object_points(s["board"])
    _, t, uv = corner_arrays(s["corners"], len(p_B))
    cam = BodyTrack.from_bodies(s["bodies"], "camera")
    brd = BodyTrack.from_bodies(s["bodies"], "board")
    intr = np.r_[tr["K"][0, 0], tr["K"][1, 1], tr["K"][0, 2], tr["K"][1, 2], tr["dist"]]
    model = Se3Model(
        intr, set(DEFAULT_FREE), tr["T_Cm_C"][:3, :3], tr["T_Bm_B"][:3, :3], True,
        tr["dt_offset_s"], t, uv, p_B, cam, brd,
    )  # fmt: skip
    x = model.pack(intr, tr["T_Cm_C"][:3, 3], tr["T_Bm_B"][:3, 3], tr["dt_offset_s"] + 0.00123)
    x[9:12] = [0.1, -0.2, 0.3]
    x[15:18] = [-0.2, 0.1, 0.05]
    J = model.jacobian(x)
    J_fd = model.jacobian_fd(x)
    rel = np.abs(J - J_fd).max(axis=0) / np.abs(J_fd).max(axis=0)
    assert rel.max() < 1e-5, dict(zip(model.names, rel, strict=True))


def test_body_track_linear_and_slerp():
    """Midway between two samples the pose is the mean position and the half-angle rotation."""
    R1 = tf.R_from_euler([0.0, 0.0, 0.4])
    q = np.array([[0, 0, 0, 1.0], tf.quat_from_R(R1)])
    bodies = pd.DataFrame(
        {"frame": [0, 1], "t_s": [0.0, 0.1], "body": "board", "valid": True,
         "x_m": [0.0, 1.0], "y_m": [0.0, 2.0], "z_m": [0.0, -1.0],
         "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2], "qw": q[:, 3]}
    )  # fmt: skip
    track = BodyTrack.from_bodies(bodies, "board")
    tq = np.array([0.05, 0.2])
    assert track.ok(tq).tolist() == [True, False]
    T = track(tq)
    np.testing.assert_allclose(T[0, :3, 3], [0.5, 1.0, -0.5], atol=1e-12)
    np.testing.assert_allclose(T[0, :3, :3], tf.R_from_euler([0.0, 0.0, 0.2]), atol=1e-12)


def test_body_track_is_geometry_interpolate_T():
    """The solver's interpolant is geometry's (the one SLERP): every bit of interpolate_T on a
    swaying camera, same validity."""
    s = simulate_session(3, duration_s=3.0, camera_motion_m=0.02)
    t, T, valid = body_poses(s["bodies"], "camera", invalid="identity", min_valid=2, track=True)
    valid[40:45] = False
    tq = np.linspace(t[0] - 0.1, t[-1] + 0.1, 400)
    track = BodyTrack(t, T, valid)
    T_geo, ok, _ = interpolate_T(t, T, valid, tq)
    assert np.array_equal(track.ok(tq), ok) and 0 < ok.sum() < len(tq)
    np.testing.assert_array_equal(track(tq)[ok], T_geo[ok])


def _hand_eye_pairs(rng, n, noise_rad=0.0, noise_m=0.0):
    """Random pairs A_i = Z B_i X^-1 with optional noise on B_i; returns A, B, Z, X."""
    Z = tf.T_from_pose6([0.03, -0.02, 0.05, -1.5, 0.1, -1.6])  # T_Cm_C
    X = tf.T_from_pose6([0.1, 0.07, -0.004, 3.1, 0.05, 0.02])  # T_Bm_B
    B = tf.T_from_pose6(
        np.c_[rng.uniform(-0.5, 0.5, (n, 2)), rng.uniform(1.0, 4.0, n), rng.uniform(-0.6, 0.6, (n, 3))]
    )
    A = Z @ B @ tf.invert_T(X)
    Bn = B.copy()
    Bn[:, :3, :3] = Bn[:, :3, :3] @ tf.R_from_rvec(rng.normal(0, noise_rad, (n, 3)))
    Bn[:, :3, 3] += rng.normal(0, noise_m, (n, 3))
    return A, Bn, Z, X


def test_hand_eye_exact_on_noise_free_pairs():
    """Noise-free pairs give T_Cm_C and T_Bm_B to 1e-9 m and 1e-9 rad."""
    A, B, Z, X = _hand_eye_pairs(np.random.default_rng(1), 30)
    Z_est, X_est = solve_hand_eye(A, B)
    for T_true, T_est in ((Z, Z_est), (X, X_est)):
        dt_m, dr_rad = _pose_err(T_true, T_est)
        assert dt_m < 1e-9 and dr_rad < 1e-9


def test_hand_eye_noisy_agrees_with_truth_and_opencv():
    """With PnP-like noise (0.5 deg, 5 mm) on 300 pairs, the closed form is within 10 mm and
    0.5 deg of truth and within 10 mm / 0.5 deg of cv2.calibrateRobotWorldHandEye (with the
    argument mapping A = cTw, X = wTb, Z = cTg, B = gTb)."""
    A, B, Z, X = _hand_eye_pairs(np.random.default_rng(2), 300, np.radians(0.5), 0.005)
    Z_est, X_est = solve_hand_eye(A, B)
    R_b2w, t_b2w, R_g2c, t_g2c = cv2.calibrateRobotWorldHandEye(
        list(A[:, :3, :3]), list(A[:, :3, 3]), list(B[:, :3, :3]), list(B[:, :3, 3])
    )
    X_cv = tf.make_T(R_b2w, t_b2w.ravel())
    Z_cv = tf.make_T(R_g2c, t_g2c.ravel())
    for T_true, T_est, T_cv in ((Z, Z_est, Z_cv), (X, X_est, X_cv)):
        dt_m, dr_rad = _pose_err(T_true, T_est)
        assert dt_m < 0.010 and dr_rad < np.radians(0.5)
        dt_m, dr_rad = _pose_err(T_cv, T_est)
        assert dt_m < 0.010 and dr_rad < np.radians(0.5)


def test_hand_eye_leaves_out_gross_pnp_errors(caplog):
    """300 noisy pairs of which 12 carry a gross PnP error (a pose 50 km away as a garbled
    board gives, or a board flipped by 40 deg): the start is as close to the truth as without
    them (10 mm, 0.5 deg), the pairs are named in a warning; without them left out the
    translation would be off by kilometres."""
    rng = np.random.default_rng(5)
    A, B, Z, X = _hand_eye_pairs(rng, 300, np.radians(0.5), 0.005)
    bad = rng.choice(300, 12, replace=False)
    B[bad[:6], :3, 3] *= 2e4
    B[bad[6:], :3, :3] = B[bad[6:], :3, :3] @ tf.R_from_euler([np.radians(40), 0.0, 0.0])
    with caplog.at_level("WARNING"):
        Z_est, X_est = solve_hand_eye(A, B)
    assert "pose pairs left out of the start" in caplog.text
    for T_true, T_est in ((Z, Z_est), (X, X_est)):
        dt_m, dr_rad = _pose_err(T_true, T_est)
        assert dt_m < 0.010 and dr_rad < np.radians(0.5), (dt_m, np.degrees(dr_rad))
    # the plain least squares on every pair, as before
    RA = A[:, :3, :3]
    lhs = np.concatenate([RA, -np.broadcast_to(np.eye(3), RA.shape)], axis=2).reshape(-1, 6)
    rhs = (np.einsum("ij,nj->ni", Z_est[:3, :3], B[:, :3, 3]) - A[:, :3, 3]).ravel()
    assert np.linalg.norm(np.linalg.lstsq(lhs, rhs, rcond=None)[0][3:] - Z[:3, 3]) > 100.0


def test_hand_eye_keeps_every_consistent_pair(caplog):
    """Without gross errors no pair is left out and the start is the plain closed form."""
    A, B, _, _ = _hand_eye_pairs(np.random.default_rng(2), 300, np.radians(0.5), 0.005)
    with caplog.at_level("WARNING"):
        solve_hand_eye(A, B)
    assert "left out" not in caplog.text


@pytest.mark.parametrize("mistake", ["bodies swapped", "clock 3 s off", "board transposed"])
def test_se3_refuses_a_fit_that_explains_nothing(mistake):
    """A user's mistake the corners cannot fit (the camera's and the board's Vicon bodies
    swapped, a sync offset 3 s off, squares_x and squares_y swapped) is an OptimiseError that
    says what to check, where the fit used to return fx of -264 px, 22 px or a 14 px median
    residual as a result."""
    s = simulate_session(0, duration_s=12.0)
    bodies, board, dt = s["bodies"], s["board"], s["truth"]["dt_offset_s"]
    if mistake == "bodies swapped":
        bodies = bodies.assign(body=bodies["body"].map({"camera": "board", "board": "camera"}))
    elif mistake == "clock 3 s off":
        dt += 3.0
    else:
        board = {**board, "squares_x": board["squares_y"], "squares_y": board["squares_x"]}
    with pytest.raises(OptimiseError, match="do not agree: check the board"):
        se3.optimise_se3(s["corners"], bodies, s["camera"], board, dt)


def test_hand_eye_rejects_single_axis_rotation():
    """Board rotations about one axis only cannot separate X from Z: OptimiseError."""
    rng = np.random.default_rng(4)
    n = 20
    B = tf.T_from_pose6(np.c_[rng.uniform(-0.5, 0.5, (n, 3)), np.zeros((n, 2)), rng.uniform(-1, 1, n)])
    with pytest.raises(OptimiseError, match="rotations are too alike"):
        solve_hand_eye(B, B)


def test_se3_recovers_truth_within_tolerance_and_3_sigma(session, fitted):
    """fx, fy within 0.2 %; T_Cm_C, T_Bm_B within 2 mm and 0.2 deg; dt within 2 ms; and each
    error within 3 reported standard errors (the rotation per axis of its local perturbation)."""
    tr = session["truth"]
    res = fitted.result
    se = res["std_errors"]
    K = np.array(res["K"])
    for i, name in ((0, "fx"), (1, "fy")):
        err = K[i, i] - tr["K"][i, i]
        assert abs(err) / tr["K"][i, i] < 0.002
        assert abs(err) < 3 * se[name], (name, err, se[name])
    for name in ("T_Cm_C", "T_Bm_B"):
        T_est = np.array(res[name])
        dt_m, dr_rad = _pose_err(tr[name], T_est)
        assert dt_m < 0.002 and dr_rad < np.radians(0.2), (name, dt_m, dr_rad)
        terr = T_est[:3, 3] - tr[name][:3, 3]
        rerr = tf.rvec_from_R(T_est[:3, :3].T @ tr[name][:3, :3])  # about the axes of C / B
        for j, ax in enumerate("xyz"):
            assert abs(terr[j]) < 3 * se[f"{name}_{ax}_m"], (name, ax, terr[j])
            assert abs(rerr[j]) < 3 * se[f"{name}_r{ax}_rad"], (name, ax, rerr[j])
    dt_err = res["dt_offset_s"] - tr["dt_offset_s"]
    assert abs(dt_err) < 0.002 and abs(dt_err) < 3 * se["dt_offset_s"]
    assert res["rms_px"] == pytest.approx(0.3, rel=0.15)
    assert res["n_frames"] == 600


def test_se3_result_is_complete_and_plain(fitted):
    """result.yaml content has every documented key, plain Python types, a symmetric
    correlation with unit diagonal, and iterations whose cost does not increase."""
    res = fitted.result
    for key in (
        "K", "dist", "T_Cm_C", "T_Bm_B", "dt_offset_s", "estimates", "std_errors", "correlation",
        "n_frames", "rms_px", "cost", "n_iterations", "time_s", "warnings",
    ):  # fmt: skip
        assert key in res
    C = np.array(res["correlation"]["matrix"])
    np.testing.assert_allclose(C, C.T, atol=1e-6)
    np.testing.assert_allclose(np.diag(C), 1.0, atol=1e-6)
    assert isinstance(res["warnings"], list) and all(isinstance(w, str) for w in res["warnings"])
    assert set(res["estimates"]) == set(res["std_errors"]) == set(res["correlation"]["names"])
    cost = fitted.iterations["cost"].to_numpy()
    assert cost[-1] <= cost[0]
    assert {"frame", "t_s", "cvs_x_m", "ref_x_m", "rms_px"} <= set(fitted.errors.columns)


def test_se3_carries_the_uncertainty_of_a_fixed_principal_point(session):
    """cx held fixed 2 px off truth with a stated std of 1.5 px (cy, k3 fixed at truth, std
    0.3 px and 0.02): a principal-point shift is, to first order, a turn of the camera about
    its y axis by 2 / fx rad, so the mounting rotation T_Cm_C absorbs ~2.9 mrad (measured as
    the change from the same fit with cx at truth). The data-only standard errors (~0.01 mrad)
    miss it by hundreds of sigma; the total ones (which carry the fixed parameters' std through
    the sensitivity S) cover it and the whole error within 3 sigma, and S predicts the change
    of each mounting rotation to within 3 data-only sigma.

    (The fit with cx at truth is itself off by ~5 data-only sigma about x: the static camera's
    mean Vicon pose, one pose for the whole take, carries its marker noise into T_Cm_C as a
    constant that no per-frame or per-cluster error model sees.)"""
    tr = session["truth"]
    std = {"fx": 0.3, "fy": 0.3, "cx": 1.5, "cy": 0.3, "k1": 0.003, "k2": 0.03, "p1": 2e-4,
           "p2": 2e-4, "k3": 0.02}  # fmt: skip
    delta_cx = 2.0
    names = [f"T_Cm_C_r{ax}_rad" for ax in "xyz"]
    fits, rerrs = [], []
    for d in (0.0, delta_cx):
        K0 = tr["K"].copy()
        K0[0, 2] += d
        cam = {"K": K0.tolist(), "dist": tr["dist"].tolist(), "std": std}
        res = se3.optimise_se3(
            session["corners"], session["bodies"], cam, session["board"], tr["dt_offset_s"],
            free=["fx", "fy", "k1", "k2", "p1", "p2"],
        ).result
        fits.append(res)
        # the error of the mounting rotation, about the axes of C
        rerrs.append(tf.rvec_from_R(tr["T_Cm_C"][:3, :3].T @ np.array(res["T_Cm_C"])[:3, :3]))
    res, rerr = fits[1], rerrs[1]
    induced = rerrs[1] - rerrs[0]
    se, se_data = res["std_errors"], res["std_errors_data"]
    fixed = res["fixed_intrinsics"]
    assert fixed["names"] == ["cx", "cy", "k3"] and fixed["std_defaulted"] == []
    assert fixed["std"] == pytest.approx([1.5, 0.3, 0.02])
    assert not any("no std" in w for w in res["warnings"])
    assert induced[1] == pytest.approx(delta_cx / tr["K"][0, 0], rel=0.1)
    z_data = np.array([induced[j] / se_data[n] for j, n in enumerate(names)])
    z_total = np.array([rerr[j] / se[n] for j, n in enumerate(names)])
    assert np.max(np.abs(z_data)) > 100.0, z_data
    assert np.all(np.abs(z_total) < 3.0), z_total
    assert abs(induced[1]) < 3.0 * se["T_Cm_C_ry_rad"]
    # total^2 = data^2 + fixed^2, and the fixed part is ~ std_cx / fx about the y axis of C
    for n in res["std_errors"]:
        assert se[n] ** 2 == pytest.approx(se_data[n] ** 2 + res["std_errors_fixed"][n] ** 2,
                                           rel=1e-9)
    assert res["std_errors_fixed"]["T_Cm_C_ry_rad"] == pytest.approx(1.5 / tr["K"][0, 0], rel=0.2)
    # the linear sensitivity predicts the change of the mounting rotation caused by the offset
    S = np.array(fixed["sensitivity"])
    all_names = res["correlation"]["names"]
    for j, n in enumerate(names):
        shift = S[all_names.index(n), 0] * delta_cx
        assert abs(induced[j] - shift) < 3.0 * se_data[n], (n, induced[j], shift)
    # correlations: data-only and total, both symmetric with a unit diagonal
    for key in ("correlation", "correlation_total"):
        C = np.array(res[key]["matrix"])
        np.testing.assert_allclose(C, C.T, atol=1e-6)
        np.testing.assert_allclose(np.diag(C), 1.0, atol=1e-6)


def test_se3_without_camera_std_uses_the_documented_default(session):
    """With no ``std`` in the camera dict, the fixed intrinsics take DEFAULT_INTRINSIC_STD and
    the result says so; with every intrinsic free, nothing is propagated."""
    tr = session["truth"]
    cam = {"K": tr["K"].tolist(), "dist": tr["dist"].tolist()}
    kw = dict(max_nfev=20, frames=np.arange(0, 600, 3))
    res = se3.optimise_se3(session["corners"], session["bodies"], cam, session["board"],
                           tr["dt_offset_s"], free=["fx", "fy"], **kw).result
    fixed = res["fixed_intrinsics"]
    assert fixed["std_defaulted"] == fixed["names"] == ["cx", "cy", "k1", "k2", "p1", "p2", "k3"]
    assert fixed["std"] == [DEFAULT_INTRINSIC_STD[n] for n in fixed["names"]]
    assert any("DEFAULT_INTRINSIC_STD" in w for w in res["warnings"])
    assert res["std_errors_fixed"]["T_Cm_C_ry_rad"] > 0.0
    res_all = se3.optimise_se3(session["corners"], session["bodies"], cam, session["board"],
                               tr["dt_offset_s"], **kw).result
    assert res_all["fixed_intrinsics"]["names"] == []
    assert all(v == 0.0 for v in res_all["std_errors_fixed"].values())
    assert res_all["std_errors"] == pytest.approx(res_all["std_errors_data"], rel=1e-12)


def test_se3_with_moving_camera_and_outliers():
    """A swaying camera (2 cm, 2 deg; not detected as static) and 2 % of corners displaced by
    15 px: the robust fit still recovers fx within 0.2 %, T_Bm_B within 2 mm / 0.2 deg and
    T_Cm_C within 5 mm / 0.5 deg (the camera's own mrad-level orientation noise, smoothed
    over 1 s only, limits T_Cm_C when the camera moves)."""
    s = simulate_session(5, duration_s=15.0, camera_motion_m=0.02)
    rng = np.random.default_rng(5)
    corners = s["corners"].copy()
    bad = rng.random(len(corners)) < 0.02
    corners.loc[bad, "u_px"] += rng.choice([-15.0, 15.0], bad.sum())
    tr = s["truth"]
    res = se3.optimise_se3(corners, s["bodies"], s["camera"], s["board"], tr["dt_offset_s"]).result
    assert not res["camera_static"]
    assert abs(res["K"][0][0] - tr["K"][0, 0]) / tr["K"][0, 0] < 0.002
    for name, tol_m, tol_deg in (("T_Cm_C", 0.005, 0.5), ("T_Bm_B", 0.002, 0.2)):
        dt_m, dr_rad = _pose_err(tr[name], np.array(res[name]))
        assert dt_m < tol_m and dr_rad < np.radians(tol_deg), (name, dt_m, dr_rad)


def test_se3_warns_when_board_never_tilts():
    """A board kept nearly face-on (tilt <= 1 deg) cannot separate the translations of T_Cm_C
    and T_Bm_B (a board that does not turn shows no lever arm): the result carries warnings
    naming such a pair, also logged."""
    s = simulate_session(6, duration_s=8.0, max_tilt_rad=np.radians(1.0))
    tr = s["truth"]
    # hand-eye needs turns: start from the truth, fit intrinsics and transforms
    res = se3.optimise_se3(
        s["corners"], s["bodies"], s["camera"], s["board"], tr["dt_offset_s"],
        free=("fx", "fy"), init={"T_Cm_C": tr["T_Cm_C"], "T_Bm_B": tr["T_Bm_B"]},
    ).result  # fmt: skip
    pairs = [w for w in res["warnings"] if "T_Cm_C_" in w and "T_Bm_B_" in w and "_m and" in w]
    assert pairs, res["warnings"]


def test_se3_bad_input_named_errors(session):
    """Missing columns, unknown body (MocapError: the bodies table), unknown loss, too few frames
    (OptimiseError): a named error naming it."""
    tr = session["truth"]
    args = (session["corners"], session["bodies"], session["camera"], session["board"], 2.37)
    with pytest.raises(MocapError, match="bodies table lacks columns"):
        se3.optimise_se3(args[0], args[1].drop(columns=["qw"]), *args[2:])
    with pytest.raises(MocapError, match="no body 'camera'"):
        se3.optimise_se3(args[0], args[1][args[1]["body"] == "board"], *args[2:])
    with pytest.raises(OptimiseError, match="corners table lacks columns"):
        se3.optimise_se3(args[0].drop(columns=["u_px"]), *args[1:])
    with pytest.raises(OptimiseError, match="loss"):
        se3.optimise_se3(*args, loss="cauchy")
    with pytest.raises(OptimiseError, match="need at least"):
        se3.optimise_se3(*args, frames=[0, 1, 2])
    with pytest.raises(OptimiseError, match="free"):
        se3.optimise_se3(*args, free=("fz",))
    assert tr["dt_offset_s"] == 2.37


def test_se3_uses_partly_hidden_boards(session):
    """Frames that hold only part of the corners (a hand or the image border hides the rest)
    enter the fit with the corners they have: with 40 % of the frames keeping 6 to 14 of their
    20 corners (the rest dropped from the table), and 30 frames keeping only 5 (fewer than
    MIN_FRAME_CORNERS, left out), se3 still recovers fx, fy within 0.2 % and both transforms
    within 2 mm / 0.2 deg, counts the frames it used, and each used frame's residual RMS stays at
    the corner noise."""
    tr = session["truth"]
    rng = np.random.default_rng(21)
    corners = session["corners"]
    frames = corners["frame"].unique()
    partial = rng.choice(frames, int(0.4 * len(frames)), replace=False)
    few = rng.choice(np.setdiff1d(frames, partial), 30, replace=False)
    keep_n = {f: int(rng.integers(6, 15)) for f in partial} | {f: 5 for f in few}
    drop = np.zeros(len(corners), bool)
    for f, n in keep_n.items():
        idx = np.flatnonzero(corners["frame"].to_numpy() == f)
        drop[rng.choice(idx, len(idx) - n, replace=False)] = True
    cut = corners[~drop].reset_index(drop=True)
    frame_ids, _, uv = corner_arrays(cut, 20)
    assert len(frame_ids) == len(frames) - 30 and not np.isin(few, frame_ids).any()
    n_seen = np.isfinite(uv[..., 0]).sum(axis=1)
    assert n_seen.min() == 6 and (n_seen < 20).sum() == len(partial)
    fit = se3.optimise_se3(cut, session["bodies"], session["camera"], session["board"],
                           tr["dt_offset_s"])
    res = fit.result
    assert res["n_frames"] == len(frames) - 30
    assert res["n_residuals"] == 2 * int(n_seen.sum())
    for i in (0, 1):
        assert abs(res["K"][i][i] - tr["K"][i, i]) / tr["K"][i, i] < 0.002
    for name in ("T_Cm_C", "T_Bm_B"):
        dt_m, dr_rad = _pose_err(tr[name], np.array(res[name]))
        assert dt_m < 0.002 and dr_rad < np.radians(0.2), (name, dt_m, dr_rad)
    errs = fit.errors.set_index("frame")
    assert np.isfinite(errs.loc[partial, "rms_px"]).all()
    assert errs.loc[partial, "rms_px"].median() < 0.5


# --------------------------------------------------------------------------- rolling shutter

RS_FREE = ["fx", "fy", "k1", "k2", "p1", "p2"]
RS_LINE_DELAY_S = 5e-5  # 480 rows in 24 ms: a typical webcam readout


@pytest.fixture(scope="module")
def rs_session():
    """A 12 s session with a rolling shutter, the hand moving twice as fast as the default."""
    return simulate_session(5, duration_s=12.0, line_delay_s=RS_LINE_DELAY_S, speed=2.0)


@pytest.mark.parametrize("motion", [{"camera_motion_m": 0.02}, {"handheld_camera": True}],
                         ids=["sway", "handheld"])  # fmt: skip
def test_rolling_shutter_jacobian_equals_finite_differences(rs_session, motion):
    """With per-corner times the analytic Jacobian (dt and the line delay included) equals
    central differences to 1e-5 relative, moving camera and rotation perturbations too; with
    a hand-held camera (a still board) d / d dt and d / d line delay come from the camera
    body's velocity alone."""
    s = simulate_session(3, duration_s=3.0, line_delay_s=4e-5, **motion)
    tr = s["truth"]
    p_B = board_object_points(s["board"])
    _, t, uv = corner_arrays(s["corners"], len(p_B))
    cam = BodyTrack.from_bodies(s["bodies"], "camera")
    brd = BodyTrack.from_bodies(s["bodies"], "board")
    intr = np.r_[tr["K"][0, 0], tr["K"][1, 1], tr["K"][0, 2], tr["K"][1, 2], tr["dist"]]
    model = Se3Model(
        intr, set(DEFAULT_FREE), tr["T_Cm_C"][:3, :3], tr["T_Bm_B"][:3, :3], True,
        tr["dt_offset_s"], t, uv, p_B, cam, brd, fit_ld=True, ld0=3e-5,
    )  # fmt: skip
    assert model.names[-2:] == ["dt_offset_s", "line_delay_s"]
    x = model.pack(intr, tr["T_Cm_C"][:3, 3], tr["T_Bm_B"][:3, 3], tr["dt_offset_s"] + 0.00123,
                   3.3e-5)  # fmt: skip
    x[9:12] = [0.1, -0.2, 0.3]
    x[15:18] = [-0.2, 0.1, 0.05]
    J = model.jacobian(x)
    J_fd = model.jacobian_fd(x, h=1e-6)
    h_ld = 1e-10  # s per row: moves a corner at row 480 by 5e-8 s
    xp, xm = x.copy(), x.copy()
    xp[-1] += h_ld
    xm[-1] -= h_ld
    J_fd[:, -1] = (model.residuals(xp) - model.residuals(xm)) / (2 * h_ld)
    # the Vicon interpolant is piecewise linear: leave out corners whose time is within the
    # differencing step of a Vicon sample (a kink, where only one-sided slopes exist)
    t_vicon = np.sort(s["bodies"]["t_s"].unique())
    tq = (t[:, None] + x[-2] + x[-1] * model.row)[model.seen]
    near = np.abs(t_vicon[np.clip(np.searchsorted(t_vicon, tq), 1, len(t_vicon) - 1)] - tq)
    near = np.minimum(near, np.abs(tq - t_vicon[np.clip(np.searchsorted(t_vicon, tq) - 1, 0, None)]))
    smooth = np.repeat(near > 1e-5, 2)
    rel = np.abs(J - J_fd)[smooth].max(axis=0) / np.abs(J_fd[smooth]).max(axis=0)
    assert rel.max() < 1e-5, dict(zip(model.names, rel, strict=True))
    assert smooth.mean() > 0.9


def _reference_error_vs_speed(session, per_frame):
    """RMS (m) of the Vicon reference position minus the truth at the frame's mean corner time,
    and its correlation with the board's speed (m/s)."""
    tr = session["truth"]
    idx = np.searchsorted(tr["frame"], per_frame["frame"].to_numpy())
    p_true = tr["T_C_B"][:, :3, 3]
    v_true = np.gradient(p_true, tr["t_s"][1] - tr["t_s"][0], axis=0)
    dt_row = tr["t_corner_s"][idx].mean(axis=1) - tr["t_s"][idx]  # ~ms: first order suffices
    p_at = p_true[idx] + v_true[idx] * dt_row[:, None]
    err = np.linalg.norm(per_frame[["ref_x_m", "ref_y_m", "ref_z_m"]].to_numpy() - p_at, axis=1)
    speed = np.linalg.norm(v_true[idx], axis=1)
    return float(np.sqrt(np.mean(err**2))), float(np.corrcoef(err, speed)[0, 1])


def test_se3_recovers_the_line_delay_and_removes_the_speed_error(rs_session):
    """A rolling-shutter session: the fitted line delay is within 10 % of the truth (and within
    4 of its standard errors), dt and fx are unbiased, the corner RMS is the pixel noise, and
    the Vicon reference (at the frame's mean corner row) matches the truth with no trace of the
    board's speed; a global-shutter fit of the same data has dt biased by the mean row's delay,
    fx biased, and a reference error that grows with the speed."""
    s = rs_session
    tr = s["truth"]
    args = (s["corners"], s["bodies"], s["camera"], s["board"], tr["dt_offset_s"] + 0.004)
    rs = se3.optimise_se3(*args, free=RS_FREE, fit_line_delay=True)
    gs = se3.optimise_se3(*args, free=RS_FREE)
    ld, ld_se = rs.result["line_delay_s"], rs.result["std_errors"]["line_delay_s"]
    assert abs(ld - RS_LINE_DELAY_S) < 0.1 * RS_LINE_DELAY_S
    assert abs(ld - RS_LINE_DELAY_S) < 4 * ld_se
    assert abs(rs.result["dt_offset_s"] - tr["dt_offset_s"]) < 1e-3
    assert abs(gs.result["dt_offset_s"] - tr["dt_offset_s"]) > 5e-3  # ~ ld x the mean row
    fx_true = tr["K"][0, 0]
    assert abs(rs.result["K"][0][0] - fx_true) < 4 * rs.result["std_errors"]["fx"]
    assert abs(gs.result["K"][0][0] - fx_true) > 4 * abs(rs.result["K"][0][0] - fx_true)
    assert rs.result["rms_px"] < 0.35  # the 0.3 px corner noise
    assert gs.result["rms_px"] > 2 * rs.result["rms_px"]
    rms_rs, corr_rs = _reference_error_vs_speed(s, rs.errors)
    rms_gs, corr_gs = _reference_error_vs_speed(s, gs.errors)
    assert rms_rs < 0.002 and abs(corr_rs) < 0.15, (rms_rs, corr_rs)
    assert rms_gs > 3 * rms_rs and corr_gs > 0.25, (rms_gs, corr_gs)


def test_se3_finds_no_line_delay_on_a_global_shutter():
    """A global-shutter session fitted with the line delay free: it is within 3 of its standard
    errors of zero, and the other estimates equal the global-shutter fit's to well within
    their standard errors (dt along the line delay's correlation)."""
    s = simulate_session(5, duration_s=12.0, speed=2.0)
    tr = s["truth"]
    args = (s["corners"], s["bodies"], s["camera"], s["board"], tr["dt_offset_s"] + 0.004)
    rs = se3.optimise_se3(*args, free=RS_FREE, fit_line_delay=True).result
    gs = se3.optimise_se3(*args, free=RS_FREE).result
    assert abs(rs["line_delay_s"]) < 3 * rs["std_errors"]["line_delay_s"]
    assert rs["std_errors"]["line_delay_s"] < 0.05 * RS_LINE_DELAY_S  # it could see one
    for name in ("fx", "fy", "T_Cm_C_rx_rad", "T_Bm_B_z_m"):
        assert abs(rs["estimates"][name] - gs["estimates"][name]) < 0.5 * gs["std_errors"][name]
    # dt and the line delay trade along the mean row (~240 px): their sum there is unchanged
    shift = rs["dt_offset_s"] + 240.0 * rs["line_delay_s"] - gs["dt_offset_s"]
    assert abs(shift) < 0.5 * gs["std_errors"]["dt_offset_s"]


def test_se3_global_shutter_default_is_unchanged(session):
    """Without the line delay the model has one Vicon time per frame (no corner axis), the
    result says so, and a known line delay of 0 gives the same numbers bit for bit."""
    tr = session["truth"]
    args = (session["corners"], session["bodies"], session["camera"], session["board"],
            tr["dt_offset_s"])  # fmt: skip
    a = se3.optimise_se3(*args, frames=np.arange(300)).result
    b = se3.optimise_se3(*args, frames=np.arange(300), line_delay_s=0.0).result
    assert a["line_delay_s"] == 0.0 and a["fit_line_delay"] is False
    assert "line_delay_s" not in a["estimates"]
    assert a["estimates"] == b["estimates"]
    with pytest.raises(OptimiseError, match="line_delay_s"):
        se3.optimise_se3(*args, line_delay_s=-1e-5)


def test_is_static_ignores_a_short_bump_but_not_a_moving_camera():
    """A static camera track with a 2.5 mrad bump over 3 % of the take (a bridged marker
    dropout after smoothing) counts as static; a camera turning by 5 mrad over half the take
    does not; with quantile 1 (the old test) the bump makes it moving."""
    n = 3000
    T = np.repeat(np.eye(4)[None], n, axis=0)
    rv = np.zeros((n, 3))
    rv[1500:1590, 0] = 0.0025
    T[:, :3, :3] = tf.R_from_rvec(rv)
    assert is_static(T, 0.002, 0.002)
    assert not is_static(T, 0.002, 0.002, quantile=1.0)
    rv_move = np.zeros((n, 3))
    rv_move[:, 1] = np.linspace(-0.005, 0.005, n)
    T[:, :3, :3] = tf.R_from_rvec(rv_move)
    assert not is_static(T, 0.002, 0.002)


# --------------------------------------------------------------------------- moving camera


def _z_scores(tr, res):
    """Error / reported standard error of fx, fy, dt and each axis of T_Cm_C and T_Bm_B."""
    se = res["std_errors"]
    K = np.array(res["K"])
    z = {n: (K[i, i] - tr["K"][i, i]) / se[n] for i, n in ((0, "fx"), (1, "fy"))}
    for name in ("T_Cm_C", "T_Bm_B"):
        T = np.array(res[name])
        terr = T[:3, 3] - tr[name][:3, 3]
        rerr = tf.rvec_from_R(T[:3, :3].T @ tr[name][:3, :3])
        for j, ax in enumerate("xyz"):
            z[f"{name}_{ax}_m"] = terr[j] / se[f"{name}_{ax}_m"]
            z[f"{name}_r{ax}_rad"] = rerr[j] / se[f"{name}_r{ax}_rad"]
    z["dt_offset_s"] = (res["dt_offset_s"] - tr["dt_offset_s"]) / se["dt_offset_s"]
    return z


@pytest.fixture(scope="module")
def handheld():
    """10 s with the camera hand-held around a fixed board (the whole relative motion is the
    camera's: metres and tens of degrees), 0.3 mm marker noise on both bodies."""
    return simulate_session(3, duration_s=10.0, handheld_camera=True)


def test_handheld_camera_simulation_moves_the_camera_not_the_board(handheld):
    """The simulator's hand-held camera: the board body stands still in W (marker noise only)
    while the camera body travels metres and turns by tens of degrees."""
    b = handheld["bodies"]
    brd = b[b["body"] == "board"][["x_m", "y_m", "z_m"]].to_numpy()
    cam = b[b["body"] == "camera"][["x_m", "y_m", "z_m"]].to_numpy()
    assert brd.std(axis=0).max() < 0.001
    assert np.ptp(cam, axis=0).max() > 1.0
    T = handheld["truth"]["T_W_Cm"]
    assert np.degrees(tf.rotation_angle(T[0, :3, :3].T @ T[:, :3, :3]).max()) > 20.0


def test_se3_recovers_a_handheld_camera_where_the_old_smoothing_fails(handheld):
    """A hand-held camera: the fit sees it moving and recovers fx, fy, every axis of T_Cm_C
    and T_Bm_B and dt within 3 reported standard errors (dt within 0.5 ms). Today's
    approximation for a moving camera, its track through the 1 s box of the static test
    (``camera_static_tol=None``: the same track the old code used), bends the reference by
    centimetres: a median corner residual over 10 px (T_Cm_C metres off), which se3 refuses
    as a fit that explains nothing."""
    tr = handheld["truth"]
    args = (handheld["corners"], handheld["bodies"], handheld["camera"], handheld["board"],
            tr["dt_offset_s"] + 0.01)  # fmt: skip
    res = se3.optimise_se3(*args).result
    assert not res["camera_static"]
    assert res["camera_moving_smooth_s"] == CAMERA_MOVING_SMOOTH_S
    z = _z_scores(tr, res)
    assert max(abs(v) for v in z.values()) < 3.0, z
    assert abs(res["dt_offset_s"] - tr["dt_offset_s"]) < 5e-4
    assert res["rms_px"] < 0.7  # 0.3 px corners plus the camera body's noise at the board
    # the old track's fit (corner RMS over 5 px, T_Cm_C metres off) is now refused
    with pytest.raises(OptimiseError, match="median corner residual is"):
        se3.optimise_se3(*args, camera_static_tol=None)


def test_se3_static_camera_ignores_the_moving_camera_window(session):
    """A static camera goes through the path it always did: its result has no
    ``camera_moving_smooth_s`` key and any moving-camera window gives the same numbers."""
    tr = session["truth"]
    args = (session["corners"], session["bodies"], session["camera"], session["board"],
            tr["dt_offset_s"])  # fmt: skip
    a = se3.optimise_se3(*args, frames=np.arange(200)).result
    b = se3.optimise_se3(*args, frames=np.arange(200), camera_moving_smooth_s=0.5).result
    assert a["camera_static"] and "camera_moving_smooth_s" not in a
    assert a["estimates"] == b["estimates"] and a["std_errors"] == b["std_errors"]


def test_smooth_track_local_keeps_a_moving_path_the_box_bends():
    """A 0.5 Hz sway (0.3 m, 0.5 rad): the 0.1 s local quadratic stays within 0.1 mm and
    0.1 mrad of it, also across invalid samples; the 1 s box misses by centimetres; on noise
    the local quadratic divides the per-sample scatter by more than 2."""
    rate = 300.0
    t = np.arange(0, 6.0, 1.0 / rate)
    s = np.sin(2 * np.pi * 0.5 * t)
    R = tf.R_from_rvec(np.stack([0.5 * s, 0.2 * s, 0.1 + 0 * s], axis=1))
    T = tf.make_T(R, np.stack([0.3 * s, 0.1 * s, 1.0 + 0 * s], axis=1))
    valid = np.ones(len(t), bool)
    valid[600:612] = False
    inner = slice(60, -60)
    for fn, window, bound_m in ((smooth_track_local, 0.1, 1e-4), (smooth_track, 1.0, None)):
        Ts = fn(t, T, valid, window)
        dp = np.linalg.norm(Ts[:, :3, 3] - T[:, :3, 3], axis=1)[inner]
        dr = tf.rotation_angle(np.swapaxes(T[:, :3, :3], 1, 2) @ Ts[:, :3, :3])[inner]
        if bound_m is not None:
            assert dp.max() < bound_m and dr.max() < 1e-4
        else:
            assert dp.max() > 0.02
    rng = np.random.default_rng(0)
    Tn = T.copy()
    Tn[:, :3, 3] += rng.normal(0, 1e-3, (len(t), 3))
    Ts = smooth_track_local(t, Tn, np.ones(len(t), bool), 0.1)
    scatter = (Ts[:, :3, 3] - T[:, :3, 3])[inner].std()
    assert scatter < 0.5e-3


def test_smooth_track_local_follows_a_body_turning_without_bound():
    """A body circling twice (4 pi about z in 4 s, tilted 0.3 rad) with noise-free samples:
    the local quadratic stays within 0.05 mrad of it (each piece has its own reference
    rotation, so no rotation vector wraps at pi)."""
    t = np.arange(0, 4.0, 1.0 / 300.0)
    ang = np.pi * t
    R = tf.R_from_euler(np.stack([0.3 + 0 * t, 0 * t, ang], axis=1))
    T = tf.make_T(R, np.stack([np.cos(ang), np.sin(ang), 1.0 + 0 * t], axis=1))
    Ts = smooth_track_local(t, T, np.ones(len(t), bool), 0.1)
    dr = tf.rotation_angle(np.swapaxes(T[:, :3, :3], 1, 2) @ Ts[:, :3, :3])[30:-30]
    assert dr.max() < 5e-5
    assert np.linalg.norm(Ts[:, :3, 3] - T[:, :3, 3], axis=1)[30:-30].max() < 1e-4


def test_project_SO3_is_the_nearest_rotation():
    """geometry.project_SO3 (the hand-eye start's projection) equals scipy's nearest rotation
    (Bar-Itzhack) on perturbed rotations, and turns a reflection into a rotation."""
    rng = np.random.default_rng(4)
    for _ in range(5):
        M = Rotation.random(random_state=rng).as_matrix() + rng.normal(0, 0.05, (3, 3))
        R = project_SO3(M)
        np.testing.assert_allclose(R, Rotation.from_matrix(M).as_matrix(), atol=1e-9)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(project_SO3(np.diag([1.0, 1.0, -1.0]))) > 0
