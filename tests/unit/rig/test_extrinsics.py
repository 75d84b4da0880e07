"""Relative camera poses from shared views: recovered against the truth they were made from."""

import copy
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from cvsflow.board.model import board_object_points
from cvsflow.exceptions import CalibrationError, InputError
from cvsflow.geometry.camera import project_points
from cvsflow.geometry.transforms import R_from_euler, invert_T, make_T, pose_error_left, rvec_from_R
from cvsflow.rig.extrinsics import calibrate_rig, stereo_extrinsics
from cvsflow.rig.fusion import fused_board_pose, rig_calibration_covariance
from cvsflow.synth.stereo import render_shared_stills

REPO = Path(__file__).resolve().parents[3]

BOARD = {"squares_x": 9, "squares_y": 7, "square_m": 0.04}
CAM0 = {"K": [[700.0, 0, 322.0], [0, 698.0, 241.0], [0, 0, 1]], "dist": [-0.28, 0.09, 0.001, -0.0005, 0.0],
        "width": 640, "height": 480}
CAM1 = {"K": [[910.0, 0, 630.0], [0, 912.0, 362.0], [0, 0, 1]], "dist": [0.05, -0.1, 0.0, 0.0, 0.0],
        "width": 1280, "height": 720}
# camera 1 sits 1 m to the right of camera 0, turned 20 deg towards it
T_C0_C1 = make_T(R_from_euler([0.02, -np.deg2rad(20.0), 0.01]), [1.0, 0.03, 0.1])
T_C1_C0 = invert_T(T_C0_C1)


def _views(rng, n_views, sigma_px, rig=((CAM0, np.eye(4)), (CAM1, T_C1_C0)), hide=0):
    """Corner tables of each (camera, T_Ci_C0) of the rig for n_views board poses in front of all."""
    p_B = board_object_points(BOARD)
    centre_B = p_B.mean(axis=0)
    tables = [[] for _ in rig]
    for v in range(n_views):
        target_C0 = np.array([rng.uniform(0.25, 0.5), rng.uniform(-0.15, 0.15), rng.uniform(1.8, 2.4)])
        R = R_from_euler(np.deg2rad([rng.uniform(-25, 25), rng.uniform(-10, 30), rng.uniform(-30, 30)]))
        T_C0_B = make_T(R, target_C0 - R @ centre_B)
        for c, (cam, T) in enumerate(rig):
            p_C = (T @ T_C0_B)[:3, :3] @ p_B.T
            p_C = p_C.T + (T @ T_C0_B)[:3, 3]
            uv = project_points(p_C, np.array(cam["K"]), np.array(cam["dist"]))
            uv = uv + rng.normal(0.0, sigma_px, uv.shape)
            keep = np.ones(len(p_B), bool)
            if hide:
                keep[rng.choice(len(p_B), hide, replace=False)] = False
            tables[c].append(pd.DataFrame({
                "image": f"pair_{v:03d}.png", "corner": np.flatnonzero(keep),
                "u_px": uv[keep, 0], "v_px": uv[keep, 1], "X_m": p_B[keep, 0], "Y_m": p_B[keep, 1]}))
    return [pd.concat(t, ignore_index=True) for t in tables]


def _pose_error(T_est, T_true):
    """[rotation error (rad, on the left: R_est = exp([r]x) R_true), t error (m)], as ``std``."""
    return np.concatenate([rvec_from_R(T_est[:3, :3] @ T_true[:3, :3].T), T_est[:3, 3] - T_true[:3, 3]])


def test_relative_pose_is_recovered_within_its_standard_errors():
    z = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        out = stereo_extrinsics(_views(rng, 12, 0.2), [CAM0, CAM1])
        cam = out["cameras"][0]
        err = _pose_error(np.array(cam["T_Ci_C0"]), T_C1_C0)
        std = np.array(list(cam["std"].values()))
        z.append(err / std)
        assert abs(cam["baseline_m"] - np.linalg.norm(T_C0_C1[:3, 3])) < 5 * cam["baseline_std_m"]
        assert out["sigma_px"] == pytest.approx(0.2, rel=0.1)
    z = np.array(z)
    # if the standard errors are right, z is unit normal: pooled over the 240 values the RMS
    # lies in [0.85, 1.15] (chi-square, beyond 3 sigma otherwise), per parameter over 40 draws
    # in [0.7, 1.35] (p < 0.003 each)
    pooled = np.sqrt(np.mean(z ** 2))
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    assert 0.85 < pooled < 1.15, pooled
    assert np.all((rms > 0.7) & (rms < 1.35)), rms


def test_joint_fit_uses_the_corners_only_one_camera_saw():
    # each camera misses a different 15 of the 48 corners per view (a hand, a ChArUco board):
    # stereoCalibrate (the start) sees only the corners both saw, the joint fit all of them
    sq_start, sq_joint = np.zeros(6), np.zeros(6)
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        out = stereo_extrinsics(_views(rng, 10, 0.3, hide=15), [CAM0, CAM1])
        cam = out["cameras"][0]
        assert out["n_views"] == 10 and cam["n_shared_views"] == 10
        assert all(r == pytest.approx(0.3 * np.sqrt(2), rel=0.15) for r in out["rms_px"])
        err = _pose_error(np.array(cam["T_Ci_C0"]), T_C1_C0)
        assert np.all(np.abs(err) < 4.5 * np.array(list(cam["std"].values()))), err
        sq_joint += err ** 2
        sq_start += _pose_error(np.array(cam["start_T_Ci_C0"]), T_C1_C0) ** 2
    assert np.sum(sq_joint / sq_start) < 6 * 0.9, sq_joint / sq_start


def test_intrinsics_uncertainty_widens_the_errors():
    rng = np.random.default_rng(3)
    cams = [dict(CAM0, std={"fx": 1.0, "fy": 1.0, "cx": 0.8, "cy": 0.8}), dict(CAM1, std={"fx": 1.5, "fy": 1.5})]
    cam = stereo_extrinsics(_views(rng, 12, 0.2), cams)["cameras"][0]
    data, both = np.array(list(cam["std_data_only"].values())), np.array(list(cam["std"].values()))
    assert np.all(both >= data) and np.any(both > 1.5 * data)


def test_three_cameras_in_one_fit():
    rng = np.random.default_rng(11)
    # a third camera: camera 1's intrinsics, 0.5 m left of camera 0
    T_C2_C0 = invert_T(make_T(R_from_euler([0.0, np.deg2rad(8.0), 0.0]), [-0.5, 0.0, 0.0]))
    tables = _views(rng, 8, 0.2, rig=((CAM0, np.eye(4)), (CAM1, T_C1_C0), (CAM1, T_C2_C0)))
    out = stereo_extrinsics(tables, [CAM0, CAM1, CAM1])
    for cam, T_true in zip(out["cameras"], [T_C1_C0, T_C2_C0], strict=True):
        err = _pose_error(np.array(cam["T_Ci_C0"]), T_true)
        assert np.all(np.abs(err) < 5 * np.array(list(cam["std"].values()))), (cam["camera"], err)


def test_a_camera_without_shared_views_is_named():
    rng = np.random.default_rng(0)
    t0, t1 = _views(rng, 4, 0.2)
    t1 = t1.assign(image="other_" + t1["image"])
    with pytest.raises(CalibrationError, match="camera 1 shares 0 views"):
        stereo_extrinsics([t0, t1], [CAM0, CAM1])


def test_bad_rows_are_named():
    rng = np.random.default_rng(0)
    t0, t1 = _views(rng, 4, 0.2)
    t1.loc[5, "u_px"] = np.nan
    with pytest.raises(InputError, match="camera 1: corner table row 5"):
        stereo_extrinsics([t0, t1], [CAM0, CAM1])
    with pytest.raises(InputError, match="two or more cameras"):
        stereo_extrinsics([t0], [CAM0])


def test_rendered_stereo_stills_calibrate_to_the_true_rig():
    # two cameras 0.6 m apart, each calibrated from its own copy of 15 shared stills
    cfg0 = yaml.safe_load((REPO / "config" / "config.yaml").read_text())["sessions"]["demo"]
    cfg1 = copy.deepcopy(cfg0)
    cfg1["synth"]["camera"].update(fx_px=760.0, fy_px=757.0, cx_px=318.0, cy_px=236.0,
                                   dist=[-0.2, 0.05, 0.0, 0.0, 0.0])
    T_C1_C0_true = invert_T(make_T(R_from_euler([0.0, -np.deg2rad(12.0), 0.0]), [0.6, 0.0, 0.05]))
    stills, T_C0_B = render_shared_stills([cfg0, cfg1], [np.eye(4), T_C1_C0_true], 15, seed=0)
    assert len(T_C0_B) == 15 and [len(s) for s in stills] == [15, 15]
    # camera 1 has two stills of its own: they help its intrinsics, not the rig
    extra, _ = render_shared_stills([cfg0, cfg1], [np.eye(4), T_C1_C0_true], 2, seed=1)
    stills[1] = stills[1] + [("own_" + name, img) for name, img in extra[1]]
    cams, out, _ = calibrate_rig(stills, cfg0["board"])
    assert [c["n_used"] for c in cams] == [15, 17]
    assert out["n_views"] == 15
    cam = out["cameras"][0]
    err = _pose_error(np.array(cam["T_Ci_C0"]), T_C1_C0_true)
    z = err / np.array(list(cam["std"].values()))
    assert np.all(np.abs(z) < 4), z
    assert abs(cam["baseline_m"] - np.linalg.norm(T_C1_C0_true[:3, 3])) < 4 * cam["baseline_std_m"]
    assert np.all(np.abs(err[3:]) < 3e-3) and np.all(np.abs(err[:3]) < 2e-3)  # mm, mrad
    # sharp stills: the views alone would claim far more than they know
    z_data = err / np.array(list(cam["std_data_only"].values()))
    assert np.max(np.abs(z_data)) > 5


def _rig_views(T_C0_B, rig, rng=None, sigma_px=0.3):
    p_B = board_object_points(BOARD)
    uv = np.zeros((len(T_C0_B), len(rig), len(p_B), 2))
    for c, (cam, T) in enumerate(rig):
        T_C_B = T @ T_C0_B
        p_C = np.einsum("fij,nj->fni", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
        uv[:, c] = project_points(p_C, np.array(cam["K"]), np.array(cam["dist"]))
    if rng is not None:
        uv += sigma_px * rng.standard_normal(uv.shape)
    return uv, np.ones(uv.shape[:3], bool), p_B


def _board_poses(rng, n, depth_m):
    p_B = board_object_points(BOARD)
    R = R_from_euler(np.deg2rad(rng.uniform(-20, 20, (n, 3))))
    t = np.column_stack([rng.uniform(0.3, 0.5, n), rng.uniform(-0.1, 0.1, n), rng.uniform(*depth_m, n)])
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = t - np.einsum("fij,j->fi", R, p_B.mean(axis=0))
    return T


def test_fused_board_pose_is_pnp_for_one_camera():
    rng = np.random.default_rng(5)
    T_true = _board_poses(rng, 20, (1.5, 2.5))
    uv, seen, p_B = _rig_views(T_true, [(CAM0, np.eye(4))], rng)
    K, dist = np.array(CAM0["K"]), np.array(CAM0["dist"])
    T_hat, Sigma, n_seen = fused_board_pose(uv, seen, p_B, [(K, dist)], [np.eye(4)], T_true)
    assert np.all(n_seen == len(p_B))
    for f in range(len(T_true)):
        ok, rvec, tvec = cv2.solvePnP(p_B, uv[f, 0], K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
        assert np.allclose(T_hat[f, :3, 3], tvec.ravel(), atol=1e-6)
        assert np.allclose(T_hat[f, :3, :3], cv2.Rodrigues(rvec)[0], atol=1e-7)
    # without sigma_px the noise comes from each frame's residual: 0.3 px on average
    _, Sigma_03, _ = fused_board_pose(uv, seen, p_B, [(K, dist)], [np.eye(4)], T_true, sigma_px=0.3)
    assert np.mean(Sigma[:, 2, 2] / Sigma_03[:, 2, 2]) == pytest.approx(1.0, abs=0.12)


def test_fused_board_pose_errors_match_its_covariance():
    # a stereo rig, 1 m baseline; Monte Carlo over frames: NEES mean 6 (chi-square, 6 dof)
    rng = np.random.default_rng(9)
    T_true = _board_poses(rng, 400, (1.8, 2.4))
    rig = [(CAM0, np.eye(4)), (CAM1, T_C1_C0)]
    uv, seen, p_B = _rig_views(T_true, rig, rng)
    cams = [(np.array(c["K"]), np.array(c["dist"])) for c, _ in rig]
    T_hat, Sigma, _ = fused_board_pose(uv, seen, p_B, cams, [T for _, T in rig], T_true, sigma_px=0.3)
    e = pose_error_left(T_hat, T_true)
    nees = np.einsum("fi,fij,fj->f", e, np.linalg.inv(Sigma), e)
    # 400 draws of chi-square(6): mean 6 +- 0.17 (1 sigma)
    assert 5.4 < nees.mean() < 6.6, nees.mean()
    # the second camera is what measures depth: the single camera's depth sigma is larger
    _, Sigma_mono, _ = fused_board_pose(uv[:, :1], seen[:, :1], p_B, cams[:1], [np.eye(4)], T_true, sigma_px=0.3)
    assert np.median(np.sqrt(Sigma_mono[:, 2, 2] / Sigma[:, 2, 2])) > 1.5


def test_fused_board_pose_keeps_frames_one_camera_saw():
    rng = np.random.default_rng(2)
    T_true = _board_poses(rng, 6, (1.8, 2.4))
    rig = [(CAM0, np.eye(4)), (CAM1, T_C1_C0)]
    uv, seen, p_B = _rig_views(T_true, rig, rng)
    seen[:3, 1] = False       # camera 1 misses frames 0-2
    seen[3, :, :] = False     # nobody sees frame 3
    seen[4, 0, 10:] = False   # camera 0 sees part of the board on frame 4
    cams = [(np.array(c["K"]), np.array(c["dist"])) for c, _ in rig]
    T_hat, Sigma, n_seen = fused_board_pose(uv, seen, p_B, cams, [T for _, T in rig], T_true, sigma_px=0.3)
    assert n_seen.tolist()[:5] == [[48, 0], [48, 0], [48, 0], [0, 0], [10, 48]]
    assert np.isnan(T_hat[3]).all() and np.isnan(Sigma[3]).all()
    ok = [0, 1, 2, 4, 5]
    err = np.linalg.norm(T_hat[ok, :3, 3] - T_true[ok, :3, 3], axis=1)
    assert np.all(err < 5 * np.sqrt(np.trace(Sigma[ok, :3, :3], axis1=1, axis2=2)))


def test_rig_calibration_covariance_matches_resolves_at_sampled_calibrations():
    """The fused pose's spread over calibrations drawn from the intrinsics' std and the rig's
    extrinsic covariance equals the propagated covariance; an exact calibration adds nothing."""
    rng = np.random.default_rng(4)
    T_true = _board_poses(rng, 12, (1.8, 2.4))
    rig = [(CAM0, np.eye(4)), (CAM1, T_C1_C0)]
    uv, seen, p_B = _rig_views(T_true, rig, rng)
    seen[:4, 1] = False  # camera 0 alone on four frames
    cams = [(np.array(c["K"]), np.array(c["dist"])) for c, _ in rig]
    T_Ci_C0 = [T for _, T in rig]
    T_hat = fused_board_pose(uv, seen, p_B, cams, T_Ci_C0, T_true, sigma_px=0.3)[0]
    std = [{"fx": 1.5, "fy": 1.5, "cx": 1.0, "cy": 1.0, "k1": 0.004},
           {"fx": 2.0, "fy": 2.0, "cx": 1.5, "cy": 1.5, "k2": 0.01}]
    A = rng.normal(size=(6, 6))
    C_ext = np.diag([3e-4, 3e-4, 2e-4, 1e-3, 1e-3, 2e-3]) ** 2 + 1e-9 * (A @ A.T)  # rad, m
    S = rig_calibration_covariance(uv, seen, p_B, cams, T_Ci_C0, T_hat, 0.3, std, [C_ext])
    names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
    d = []
    for _ in range(150):
        cams_s = []
        for (K, dist), sd in zip(cams, std, strict=True):
            x = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist] + [sd.get(n, 0.0) * rng.standard_normal()
                                                                  for n in names]
            cams_s.append((np.array([[x[0], 0, x[2]], [0, x[1], x[3]], [0, 0, 1.0]]), x[4:]))
        e = rng.multivariate_normal(np.zeros(6), C_ext)
        T1 = T_C1_C0.copy()
        T1[:3, :3] = cv2.Rodrigues(e[:3])[0] @ T1[:3, :3]
        T1[:3, 3] += e[3:]
        T = fused_board_pose(uv, seen, p_B, cams_s, [np.eye(4), T1], T_hat, sigma_px=0.3)[0]
        d.append(pose_error_left(T, T_hat))
    sd = np.sqrt(np.diagonal(S, axis1=1, axis2=2))
    ratio = np.sqrt(np.mean(np.array(d) ** 2, axis=0)) / sd
    # 150 draws: the ratio's own spread is about 6 %. Components the calibration barely
    # moves (a lone camera's roll about its axis: 1e-5 rad against 3e-3) are second order.
    big = np.concatenate([sd[:, :3] > 0.1 * sd[:, :3].max(axis=1, keepdims=True),
                          sd[:, 3:] > 0.1 * sd[:, 3:].max(axis=1, keepdims=True)], axis=1)
    assert big.sum() >= 60
    assert np.all((ratio[big] > 0.75) & (ratio[big] < 1.3)), ratio
    # frames camera 0 saw alone do not depend on the rig's extrinsics
    S_int = rig_calibration_covariance(uv, seen, p_B, cams, T_Ci_C0, T_hat, 0.3, std, [0 * C_ext])
    np.testing.assert_allclose(S[:4], S_int[:4], rtol=1e-6, atol=1e-16)
    # on the frames both cameras saw the extrinsics add a positive semi-definite term
    extra = S[4:] - S_int[4:]
    assert np.all(np.linalg.eigvalsh(extra).min(axis=1) > -1e-9 * np.abs(S[4:]).max())
    assert np.all(extra[:, 2, 2] > 0.02 * S_int[4:, 2, 2])
    zero = rig_calibration_covariance(uv, seen, p_B, cams, T_Ci_C0, T_hat, 0.3, [{}, {}], [0 * C_ext])
    assert zero.shape == (12, 6, 6) and not zero.any()
    with pytest.raises(InputError, match="2 cameras"):
        rig_calibration_covariance(uv, seen, p_B, cams, T_Ci_C0, T_hat, 0.3, std, [])


def test_intrinsics_sensitivity_matches_refits():
    """``intrinsics_sensitivity`` predicts how the fitted pose moves when an intrinsic does:
    a camera's principal point off by 0.5 px is mostly taken up by a turn of camera 1."""
    rng = np.random.default_rng(21)
    tables = _views(rng, 12, 0.05)
    out = stereo_extrinsics(tables, [CAM0, CAM1])
    S = np.array(out["cameras"][0]["intrinsics_sensitivity"])
    assert S.shape == (6, 18)
    T0 = np.array(out["cameras"][0]["T_Ci_C0"])
    for col, key, h in ((2, "cx", 0.5), (0, "fx", 1.0), (9 + 3, "cy", 0.5), (4, "k1", 0.005)):
        cams = copy.deepcopy([CAM0, CAM1])
        c, r, k = divmod(col, 9)[0], *{"fx": (0, 0), "cx": (0, 2), "cy": (1, 2), "k1": (None, 0)}[key]
        if r is None:
            cams[c]["dist"][k] += h
        else:
            cams[c]["K"][r][k] += h
        T1 = np.array(stereo_extrinsics(tables, cams)["cameras"][0]["T_Ci_C0"])
        moved = _pose_error(T1, T0)
        np.testing.assert_allclose(moved, S[:, col] * h, atol=0.05 * np.abs(S[:, col] * h).max() + 1e-9)


def test_fused_board_pose_best_escapes_the_mirrored_start():
    """A small board 8-12 m from a 1 m rig: started from the mirrored IPPE pose, one solve stays there; from all
    candidates the fused pose is the true one, and the flip term is in its covariance."""
    from cvsflow.rig.fusion import board_pose_starts, fused_board_pose_best

    rng = np.random.default_rng(3)
    board = {"squares_x": 6, "squares_y": 5, "square_m": 0.125}
    p_B = board_object_points(board)
    R = R_from_euler(np.deg2rad([15.0, 25.0, 5.0]))
    T_true = np.array([make_T(R, [0.3 + 0.1 * i, 0.2, 8.0 + 0.5 * i] - R @ p_B.mean(axis=0)) for i in range(8)])
    K = np.array(CAM0["K"])
    cams = [(K, np.zeros(5)), (K, np.zeros(5))]
    T_C0_C1 = make_T(R_from_euler([0.0, -np.arctan2(1.0, 10.0), 0.0]), [1.0, 0.0, 0.0])
    T_Ci_C0 = [np.eye(4), invert_T(T_C0_C1)]
    uv = np.stack([project_points(np.einsum("ij,fnj->fni", T[:3, :3], np.einsum("fij,nj->fni", T_true[:, :3, :3], p_B)
                   + T_true[:, None, :3, 3]) + T[:3, 3], K, np.zeros(5)) for T in T_Ci_C0], axis=1)  # fmt: skip
    uv += rng.normal(0.0, 0.3, uv.shape)
    seen = np.ones(uv.shape[:3], bool)
    starts = board_pose_starts(uv, seen, p_B, cams, T_Ci_C0)
    assert starts.shape == (4, 8, 4, 4)

    def tilt_err(T):
        return np.degrees(np.linalg.norm(pose_error_left(T, T_true)[:, 3:], axis=1))

    # the mirrored candidate of camera 0: the one farther from the truth
    far = np.where(tilt_err(starts[0]) > tilt_err(starts[1]), 0, 1)
    mirrored = starts[far, np.arange(8)]
    assert np.all(tilt_err(mirrored) > 10.0)
    T_one = fused_board_pose(uv, seen, p_B, cams, T_Ci_C0, mirrored, sigma_px=0.3)[0]
    T_best, S_best, _ = fused_board_pose_best(uv, seen, p_B, cams, T_Ci_C0, starts, sigma_px=0.3)
    _, S_flip, _ = fused_board_pose_best(uv, seen, p_B, cams, T_Ci_C0, starts, sigma_px=0.3, flip_term=True)
    assert np.median(tilt_err(T_one)) > 10.0  # a single solve stays mirrored
    assert np.all(tilt_err(T_best) < 5.0)
    # the flip term only adds: positive semi-definite, and it widens the rotation
    extra = S_flip - S_best
    assert np.all(np.linalg.eigvalsh(extra).min(axis=1) > -1e-12)
    assert np.all(np.trace(extra[:, 3:, 3:], axis1=1, axis2=2) >= 0.0)
