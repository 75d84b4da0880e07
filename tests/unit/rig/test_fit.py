"""Tests of the N-camera se3 fit and its fused poses (optimise.se3_rig, se3_rig_poses) on
corner-level simulated rigs.
"""

from __future__ import annotations

import numpy as np
import pytest

from cvsflow.board.model import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import transforms as tf
from cvsflow.geometry.camera import INTRINSIC_NAMES
from cvsflow.optimise import se3
from cvsflow.optimise.body_tracks import BodyTrack
from cvsflow.optimise.se3_model import Se3Model
from cvsflow.optimise.se3_sim import simulate_rig_session
from cvsflow.optimise.se3_start import corner_arrays
from cvsflow.rig.fit import RigModel, cross_validate_se3_rig, optimise_se3_rig
from cvsflow.rig.fusion import fused_board_pose
from cvsflow.rig.instants import corners_at_instants, interpolation_error_ms
from cvsflow.rig.poses import (
    calibration_covariance,
    fused_pose_calibration_covariance,
    fused_rig_poses,
    rig_geometry,
)

#: Intrinsics fitted in these tests; the others are held at the truth with std 0, so that
#: the standard errors are the data's alone and a z-score tests them.
FREE = ("fx", "fy", "k1", "k2")
HELD_STD = {n: 0.0 for n in INTRINSIC_NAMES if n not in FREE}


def _entries(session, df_px=(6.0, -5.0), ddt_s=0.01):
    """Camera entries from a simulated rig: fx, fy off by df_px, dt by ddt_s."""
    out = []
    for c, t in zip(session["cameras"], session["truth"]["cameras"], strict=True):
        K0 = t["K"] + np.diag([df_px[0], df_px[1], 0.0])
        camera = {"K": K0.tolist(), "dist": t["dist"].tolist(), "std": HELD_STD}
        out.append({"corners": c["corners"], "camera": camera, "dt_offset_s": t["dt_offset_s"] + ddt_s})
    return out


def _truth_vector(result, truth):
    """The true parameters in the fit's parametrisation (rotations as perturbations of the start)."""
    out = {}
    T_Bm_B0 = np.asarray(result["init_T_Bm_B"])
    w_B = tf.rvec_from_R(T_Bm_B0[:3, :3].T @ truth["T_Bm_B"][:3, :3])
    for name in result["estimates"]:
        if name.startswith("T_Bm_B_"):
            s = name[len("T_Bm_B_") :]
            out[name] = w_B["xyz".index(s[1])] if s[0] == "r" else truth["T_Bm_B"]["xyz".index(s[0]), 3]
            continue
        i = int(name[3 : name.index("_")])
        s = name[name.index("_") + 1 :]
        tc = truth["cameras"][i]
        if s == "dt_offset_s":
            out[name] = tc["dt_offset_s"]
        elif s.startswith("T_Cm_C_"):
            s = s[len("T_Cm_C_") :]
            R0 = np.asarray(result["cameras"][i]["init"]["T_Cm_C"])[:3, :3]
            w = tf.rvec_from_R(R0.T @ tc["T_Cm_C"][:3, :3])
            out[name] = w["xyz".index(s[1])] if s[0] == "r" else tc["T_Cm_C"]["xyz".index(s[0]), 3]
        else:
            intr = [tc["K"][0, 0], tc["K"][1, 1], tc["K"][0, 2], tc["K"][1, 2], *tc["dist"]]
            out[name] = intr[INTRINSIC_NAMES.index(s)]
    return out


def _z(result, truth):
    tv = _truth_vector(result, truth)
    return {n: (result["estimates"][n] - tv[n]) / result["std_errors"][n] for n in tv}


@pytest.fixture(scope="module")
def rig():
    """Two cameras (30 fps each, genlocked, own clocks), 6 s, 15 % hidden from each."""
    return simulate_rig_session(3, n_cameras=2, duration_s=6.0)


@pytest.fixture(scope="module")
def fitted(rig):
    return optimise_se3_rig(_entries(rig), rig["bodies"], rig["board"], free=FREE)


def test_rig_jacobian_matches_finite_differences(rig):
    """RigModel's stacked analytic Jacobian equals central differences (shared T_Bm_B columns too)."""
    p_B = board_object_points(rig["board"])
    cam = BodyTrack.from_bodies(rig["bodies"], "camera")
    brd = BodyTrack.from_bodies(rig["bodies"], "board", smooth_s=0.01)
    models, per_cam = [], []
    tb = rig["truth"]
    for c, t in zip(rig["cameras"], tb["cameras"], strict=True):
        _, tv, uv = corner_arrays(c["corners"], len(p_B))
        intr = np.array([t["K"][0, 0], t["K"][1, 1], t["K"][0, 2], t["K"][1, 2], *t["dist"]])
        models.append(Se3Model(intr, set(FREE), t["T_Cm_C"][:3, :3], tb["T_Bm_B"][:3, :3], True,
                               t["dt_offset_s"], tv[::10], uv[::10], p_B, cam, brd))  # fmt: skip
        per_cam.append((intr, t["T_Cm_C"][:3, 3], t["dt_offset_s"] + 0.003, 0.0))
    model = RigModel(models)
    x = model.pack(per_cam, tb["T_Bm_B"][:3, 3])
    x[model.b_cols[:3]] += [0.002, -0.001, 0.003]
    J = model.jacobian(x)
    J_fd = model.jacobian_fd(x)
    scale = np.abs(J_fd).max(axis=0)
    assert np.max(np.abs(J - J_fd) / scale) < 1e-5
    # camera 0's rows do not depend on camera 1's own parameters, and the reverse
    assert not J[model.rows[0]][:, model.index[1][:10]].any()
    assert not J[model.rows[1]][:, model.index[0][:10]].any()
    assert J[model.rows[1]][:, model.b_cols].any() and J[model.rows[0]][:, model.b_cols].any()


def test_rig_recovers_every_parameter(fitted, rig):
    """Every parameter of both cameras and the shared T_Bm_B within 4 of its standard errors."""
    z = _z(fitted.result, rig["truth"])
    assert len(z) == 2 * (4 + 6 + 1) + 6
    worst = max(z, key=lambda n: abs(z[n]))
    assert abs(z[worst]) < 4.0, (worst, z[worst])
    assert fitted.result["status"] == 1
    # rig frames seen by one camera and by both, each counted once
    by = fitted.result["n_rig_frames_by_cameras"]
    assert by.get(1, 0) > 10 and by.get(2, 0) > 10


def test_rig_fused_pose_against_truth(fitted, rig):
    """Fused T_C0_B is near the truth; NEES of its covariance near 6; two cameras tighten depth."""
    e = fitted.errors
    dt0 = rig["truth"]["cameras"][0]["dt_offset_s"]
    T_true = rig["truth"]["T_C0_B_at"](e["t_vicon_s"].to_numpy() - dt0)
    q = e[["cvs_qx", "cvs_qy", "cvs_qz", "cvs_qw"]].to_numpy()
    T_est = tf.make_T(tf.R_from_quat(q), e[["cvs_x_m", "cvs_y_m", "cvs_z_m"]].to_numpy())
    d = tf.pose_error_left(T_est, T_true)
    S = e[[f"S{a}{b}" for a in range(6) for b in range(6)]].to_numpy().reshape(-1, 6, 6)
    nees = np.einsum("fi,fij,fj->f", d, np.linalg.inv(S), d)
    two = e["n_cameras"].to_numpy() == 2
    # with the calibration's uncertainty in: 5.9 (one camera), 7.3 (two); 6.2, 10.4 without
    # it; over seeds 0-7 of this session, two-camera frames 5.6-7.3 with it
    assert 4.0 < nees[~two].mean() < 8.5
    assert 4.0 < nees[two].mean() < 8.5
    depth_sd = np.sqrt(S[:, 2, 2])
    assert np.median(depth_sd[two]) < 0.8 * np.median(depth_sd[~two])


def test_rig_fused_calibration_covariance_monte_carlo(fitted, rig):
    """The fused pose's calibration covariance matches re-solves at sampled calibrations."""
    p_B = board_object_points(rig["board"])
    res = fitted.result
    # the frames as they are (not moved to one instant), so that uv below is what was fused
    e = fused_rig_poses(res, [c["corners"] for c in rig["cameras"]], rig["bodies"], rig["board"],
                        instant="nearest")  # fmt: skip
    rows = np.flatnonzero(e["n_cameras"].to_numpy() == 2)[::20]
    rows = np.concatenate([rows, np.flatnonzero(e["n_cameras"].to_numpy() == 1)[::20]])
    uv = np.full((len(rows), 2, len(p_B), 2), np.nan)
    for i, c in enumerate(rig["cameras"]):
        fr, _, uv_i = corner_arrays(c["corners"], len(p_B))
        for k, f in enumerate(e[f"frame_cam{i}"].to_numpy()[rows]):
            if f >= 0:
                uv[k, i] = uv_i[np.flatnonzero(fr == f)[0]]
    seen = np.isfinite(uv).all(axis=-1)
    q = e[["cvs_qx", "cvs_qy", "cvs_qz", "cvs_qw"]].to_numpy()[rows]
    T0 = tf.make_T(tf.R_from_quat(q), e[["cvs_x_m", "cvs_y_m", "cvs_z_m"]].to_numpy()[rows])
    S_cal = fused_pose_calibration_covariance(res, uv, seen, p_B, T0, res["sigma_px"])
    names, values, cov = calibration_covariance(res)
    assert len(names) == 2 * (len(FREE) + 6)  # the held intrinsics have std 0: left out
    rng = np.random.default_rng(0)
    d = []
    for v in rng.multivariate_normal(values, cov, size=100):
        cameras, T_Ci_C0 = rig_geometry(res, names, v)
        T = fused_board_pose(uv, seen, p_B, cameras, T_Ci_C0, T0)[0]
        d.append(tf.pose_error_left(T, T0))
    d = np.array(d)
    # per frame and axis, the sampled spread over the propagated one (camera 0's frames alone
    # have a singular S_cal: four intrinsics move six pose components)
    ratio = np.sqrt(np.mean(d**2, axis=0) / np.diagonal(S_cal, axis1=1, axis2=2))
    assert np.all((ratio > 0.75) & (ratio < 1.3)), ratio
    # the second camera's mounting adds depth uncertainty to the frames camera 1 saw alone
    only1 = e["frame_cam0"].to_numpy()[rows] < 0
    assert only1.any() and np.all(np.sqrt(S_cal[only1, 2, 2]) > 1e-4)


def test_rig_standard_errors_monte_carlo():
    """Over 6 simulated rigs, the z-scores of all 28 parameters have an RMS near 1."""
    zs = []
    for seed in range(6):
        s = simulate_rig_session(100 + seed, n_cameras=2, duration_s=4.0, hidden_share=0.1)
        fit = optimise_se3_rig(_entries(s), s["bodies"], s["board"], free=FREE)
        zs.append(list(_z(fit.result, s["truth"]).values()))
    z = np.array(zs)
    rms = float(np.sqrt(np.mean(z**2)))
    assert 0.6 < rms < 1.4, rms
    assert np.abs(z).max() < 4.5


def test_two_cameras_beat_one_on_T_Bm_B(fitted, rig):
    """Adding the second camera shrinks every T_Bm_B standard error, and the truth stays inside."""
    one = optimise_se3_rig(_entries(rig)[:1], rig["bodies"], rig["board"], free=FREE).result
    two = fitted.result
    names = [n for n in two["std_errors"] if n.startswith("T_Bm_B_")]
    ratio = np.array([two["std_errors"][n] / one["std_errors"][n] for n in names])
    assert (ratio < 0.95).all(), dict(zip(names, ratio, strict=True))
    z_two = _z(two, rig["truth"])
    assert max(abs(z_two[n]) for n in names) < 4.0


def test_one_camera_rig_equals_mono(rig):
    """A one-camera rig is the mono solve: estimates and standard errors to 1e-9."""
    e = _entries(rig)[0]
    e["camera"]["std"] = {"cx": 0.5}  # others defaulted: the fixed-intrinsics path of both
    mono = se3.optimise_se3(e["corners"], rig["bodies"], e["camera"], rig["board"], e["dt_offset_s"],
                            free=FREE).result  # fmt: skip
    one = optimise_se3_rig([e], rig["bodies"], rig["board"], free=FREE).result
    assert list(one["estimates"]) == [f"cam0_{n}" if not n.startswith("T_Bm_B") else n
                                      for n in mono["estimates"]]  # fmt: skip
    for key in ("estimates", "std_errors", "std_errors_data", "std_errors_fixed"):
        a = np.array(list(mono[key].values()))
        b = np.array(list(one[key].values()))
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12, err_msg=key)
    assert one["sigma_px"] == pytest.approx(mono["sigma_px"], rel=1e-9)


def test_rig_cross_validation(rig):
    """Held-out fused poses: every rig frame scored once, by a fit that did not see its block."""
    held, fits = cross_validate_se3_rig(_entries(rig), rig["bodies"], rig["board"], n_folds=2,
                                        block_s=1.5, free=FREE)  # fmt: skip
    assert len(fits) == 2 and set(held["fold"]) == {0, 1}
    assert held["t_vicon_s"].is_unique
    assert held["err_dist_m"].quantile(0.9) < 0.01
    assert set(held["n_cameras"]) == {1, 2}


def test_rig_three_cameras_own_rates(rig):
    """Three cameras, the third at 25 fps on its own clock: its dt and mounting recovered."""
    s = simulate_rig_session(5, n_cameras=3, duration_s=4.0)
    fit = optimise_se3_rig(_entries(s), s["bodies"], s["board"], free=FREE).result
    z = _z(fit, s["truth"])
    assert max(abs(v) for v in z.values()) < 4.5
    assert set(fit["n_rig_frames_by_cameras"]) >= {1, 2, 3}
    T_C0_C2 = np.asarray(fit["cameras"][2]["T_C0_C"])
    assert np.linalg.norm(T_C0_C2[:3, 3] - s["truth"]["cameras"][2]["T_C0_C"][:3, 3]) < 0.003


def _fused_nees(poses, truth):
    dt0 = truth["cameras"][0]["dt_offset_s"]
    T_true = truth["T_C0_B_at"](poses["t_vicon_s"].to_numpy() - dt0)
    q = poses[["cvs_qx", "cvs_qy", "cvs_qz", "cvs_qw"]].to_numpy()
    T_est = tf.make_T(tf.R_from_quat(q), poses[["cvs_x_m", "cvs_y_m", "cvs_z_m"]].to_numpy())
    d = tf.pose_error_left(T_est, T_true)
    S = poses[[f"S{a}{b}" for a in range(6) for b in range(6)]].to_numpy().reshape(-1, 6, 6)
    return np.einsum("fi,fij,fj->f", d, np.linalg.inv(S), d)


def testcorners_at_instants_interpolates_and_extrapolates():
    """Corners moving linearly are moved to the instant exactly; across a gap the neighbour
    before serves (at most half an interval), and with neither the frame is left out."""
    t = np.array([0.0, 0.04, 0.08, 0.20, 0.24])
    v = np.array([[30.0, -12.0], [5.0, 40.0]])  # px/s of two corners
    uv = 100.0 + t[:, None, None] * v[None]
    target = t + np.array([0.01, -0.03, 0.015, 0.02, 0.005])
    uv_at, noise, moved, usable = corners_at_instants(uv, t, target, max_gap_s=0.06,
                                                       quadratic=False)
    assert moved.all()
    # frame 2's next frame is 0.12 s away: extrapolated from frame 1 (w = -0.375);
    # frame 4 has no next frame: extrapolated from frame 3 (w = -0.125)
    np.testing.assert_array_equal(usable, [True, True, True, True, True])
    np.testing.assert_allclose(uv_at, 100.0 + target[:, None, None] * v[None], atol=1e-9)
    w = np.array([0.25, 0.75, -0.375, 0.5, -0.125])
    np.testing.assert_allclose(noise, np.sqrt((1 - w) ** 2 + w**2))
    # more than half an interval past the last frame of a run: nothing to move it with
    target2 = t + np.array([0.0, 0.0, 0.03, 0.0, 0.0])
    uv_at2, noise2, moved2, usable2 = corners_at_instants(uv, t, target2, max_gap_s=0.06,
                                                           quadratic=False)
    np.testing.assert_array_equal(moved2, [False, False, True, False, False])
    assert not usable2[2] and np.isnan(uv_at2[2]).all()
    np.testing.assert_array_equal(uv_at2[[0, 1, 3, 4]], uv[[0, 1, 3, 4]])
    assert np.all(noise2[[0, 1, 3, 4]] == 1.0)
    # a corner missing from the neighbour is missing from the moved frame, the other kept
    uv3 = uv.copy()
    uv3[1, 0] = np.nan
    uv_at3 = corners_at_instants(uv3, t, target, max_gap_s=0.06, quadratic=False)[0]
    assert np.isnan(uv_at3[0, 0]).all() and np.isfinite(uv_at3[0, 1]).all()


def testcorners_at_instants_quadratic_follows_an_accelerating_corner():
    """A corner on a parabola in time is moved to the instant exactly through three frames;
    linear interpolation misses it by a tau (1 - tau) dt^2 / 2. Where the third frame is
    farther than max_gap_s, or lacks the corner, the linear value is kept."""
    t = np.arange(6) * 0.04
    a = np.array([[900.0, -400.0], [250.0, 600.0]])  # px/s^2 of two corners
    def at(tt):
        return 100.0 + 20.0 * tt[..., None, None] + 0.5 * tt[..., None, None] ** 2 * a
    uv = at(t)
    tau = np.array([0.0, 0.25, 0.5, 0.0, 0.75, 0.0])
    target = t + tau * 0.04
    lin, noise_lin, _, _ = corners_at_instants(uv, t, target, 0.06, quadratic=False)
    quad, noise_q, moved, usable = corners_at_instants(uv, t, target, 0.06)
    np.testing.assert_array_equal(moved, tau > 0)
    np.testing.assert_allclose(quad[moved], at(target)[moved], atol=1e-9)
    miss = (at(target) - lin)[moved]
    expect = -(0.5 * tau * (1 - tau) * 0.04**2)[moved][:, None, None] * a
    np.testing.assert_allclose(miss, expect, atol=1e-9)
    # the weights' root sum of squares: e.g. tau = 0.5 with nodes at 0, 1, -1 intervals
    np.testing.assert_allclose(noise_q[2], np.sqrt(0.75**2 + 0.375**2 + 0.125**2))
    assert np.all(noise_q[moved] > noise_lin[moved])
    # a third frame missing one corner: that corner linear, the other quadratic
    uv2 = uv.copy()
    uv2[0, 0] = np.nan  # frame 1's third node is frame 0
    q2 = corners_at_instants(uv2, t, target, 0.06)[0]
    np.testing.assert_allclose(q2[1, 0], lin[1, 0], atol=1e-9)
    np.testing.assert_allclose(q2[1, 1], at(target)[1, 1], atol=1e-9)
    # a third frame beyond max_gap_s: linear
    t_gap = t.copy()
    t_gap[0] = -0.1  # 0.14 s before frame 1
    target_gap = t_gap + tau * 0.04
    q3 = corners_at_instants(at(t_gap), t_gap, target_gap, 0.06)[0]
    l3 = corners_at_instants(at(t_gap), t_gap, target_gap, 0.06, quadratic=False)[0]
    np.testing.assert_array_equal(q3[1], l3[1])
    assert np.abs(q3[1] - at(target_gap)[1]).max() > 1e-4


def test_fused_board_pose_per_camera_noise(rig):
    """A per-camera noise array equal everywhere gives the scalar's solve; a camera given a
    huge noise drops out, leaving the other camera's own PnP and covariance."""
    p_B = board_object_points(rig["board"])
    tr = rig["truth"]["cameras"]
    rng = np.random.default_rng(2)
    T_C0_B = rig["truth"]["T_C0_B_at"](np.linspace(0.5, 5.0, 12))
    T_Ci_C0 = [np.linalg.inv(c["T_C0_C"]) for c in tr]
    cameras = [(c["K"], c["dist"]) for c in tr]
    from cvsflow.geometry.camera import project_points

    uv = np.stack([project_points(np.einsum("ij,fnj->fni", T[:3, :3], np.einsum("fij,nj->fni",
                   T_C0_B[:, :3, :3], p_B) + T_C0_B[:, None, :3, 3]) + T[:3, 3], K, d)
                   for T, (K, d) in zip(T_Ci_C0, cameras, strict=True)], axis=1)  # fmt: skip
    uv = uv + rng.normal(0, 0.3, uv.shape)
    seen = np.isfinite(uv).all(axis=-1)
    T_s, S_s, _ = fused_board_pose(uv, seen, p_B, cameras, T_Ci_C0, T_C0_B, sigma_px=0.3)
    T_a, S_a, _ = fused_board_pose(uv, seen, p_B, cameras, T_Ci_C0, T_C0_B, sigma_px=np.full((12, 2), 0.3))
    np.testing.assert_allclose(T_a, T_s, atol=1e-12)
    np.testing.assert_allclose(S_a, S_s, rtol=1e-9)
    T_1, S_1, _ = fused_board_pose(uv, seen, p_B, cameras, T_Ci_C0, T_C0_B,
                                   sigma_px=np.tile([0.3, 1e4], (12, 1)))  # fmt: skip
    T_m, S_m, _ = fused_board_pose(uv[:, :1], seen[:, :1], p_B, cameras[:1], T_Ci_C0[:1], T_C0_B, sigma_px=0.3)
    np.testing.assert_allclose(T_1[:, :3, 3], T_m[:, :3, 3], atol=1e-7)
    np.testing.assert_allclose(S_1, S_m, rtol=1e-4, atol=1e-14)
    with pytest.raises(ValueError, match="positive"):
        fused_board_pose(uv, seen, p_B, cameras, T_Ci_C0, T_C0_B, sigma_px=np.zeros((12, 2)))


def _tremor_track(t, n_corners, rng, f_hz, amplitude_px):
    """Corners (T, n, 2) px of a board swaying at ``f_hz`` (low, high): three sinusoids per
    axis shared by all corners (a rigid board's corners move nearly together) plus a slow
    spread."""
    f = rng.uniform(*f_hz, size=(3, 2))
    phase = rng.uniform(0, 2 * np.pi, size=(3, 2))
    shake = (amplitude_px * np.sin(2 * np.pi * f[None] * t[:, None, None] + phase[None])).sum(axis=1)
    base = rng.uniform(100, 400, size=(n_corners, 2))
    return base[None] + shake[:, None, :] + 5.0 * t[:, None, None] * rng.normal(size=(n_corners, 2))[None]


def _interpolation_mc(f_hz, amplitude_px, seed=11, sigma=0.05, dt_frame=0.04, drop=0.0,
                      only_gap_neighbours=False):
    """Moved corners' mean square error against the truth over their stated variance: with
    the interpolation term, and with the corner noise's propagation only. ``drop``: share of
    the frames dropped (their neighbours are moved linearly, by extrapolation or without the
    fourth frame); ``only_gap_neighbours``: score only the frames next to a dropped one."""
    rng = np.random.default_rng(seed)
    err2, stated, noise_only = [], [], []
    for _ in range(40):
        t = np.arange(60) * dt_frame
        if drop:
            t = t[rng.random(len(t)) >= drop]
        tau = rng.uniform(-0.21, 0.21, size=len(t))  # a quarter of a 30 fps frame
        tau[rng.random(len(t)) < 0.3] = 0.0
        truth_at = _tremor_track(np.concatenate([t, t + tau * dt_frame]), 20, rng, f_hz, amplitude_px)
        uv = truth_at[: len(t)] + rng.normal(0, sigma, truth_at[: len(t)].shape)
        uv_at, f, moved, usable = corners_at_instants(uv, t, t + tau * dt_frame, 1.5 * dt_frame)
        s2 = interpolation_error_ms(uv, t, t + tau * dt_frame, 1.5 * dt_frame, sigma)
        m = moved & usable & (s2 > 0)
        if only_gap_neighbours:  # all of them, a term or not
            m = moved & usable
            step = np.diff(t) > 1.5 * dt_frame  # a dropped frame between i and i + 1
            near = np.zeros(len(t), bool)
            for lag in (0, 1):  # the frames either side of a gap and the next ones out
                near[: len(step) - lag] |= step[lag:]
                near[1 + lag :] |= step[: len(step) - lag]
            m &= near
        err2.append(((uv_at - truth_at[len(t):]) ** 2)[m].mean(axis=(1, 2)))
        stated.append((sigma * f[m]) ** 2 + s2[m])
        noise_only.append((sigma * f[m]) ** 2)
    err2, stated, noise_only = (np.concatenate(x) for x in (err2, stated, noise_only))
    assert len(err2) > (300 if only_gap_neighbours else 1000)
    return err2.sum() / stated.sum(), err2.sum() / noise_only.sum()


def test_interpolation_variance_matches_the_interpolation_error(monkeypatch):
    """Monte Carlo: corners of a swaying board plus 0.05 px noise, at 25 fps, moved a fraction
    of a frame through three frames. The stated variance (the noise's propagation plus the
    interpolation term) matches the mean square error against the true corners at the
    instant within 20 %, both for a 3-4 Hz sway (w about 0.9 rad per frame; seed 11: error
    over stated 1.00, 3.7 without the term; 1.06 without the frequency factor) and for 7-9 Hz
    tremor near the Nyquist frequency (w about 2.0: 1.01, 5.2 without the term), where the
    third difference alone falls short (1.63 without its frequency factor)."""
    from cvsflow.rig import instants as rig_instants

    for f_hz, amplitude_px, lo_noise in (((3.0, 4.0), 4.0, 2.0), ((7.0, 9.0), 0.6, 3.0)):
        ratio, ratio_noise = _interpolation_mc(f_hz, amplitude_px)
        assert 0.8 < ratio < 1.2, (f_hz, ratio)
        assert ratio_noise > lo_noise, (f_hz, ratio_noise)
    monkeypatch.setattr(rig_instants, "_nyquist_factor", lambda uv, tau, *a: np.ones(len(uv)))
    ratio, _ = _interpolation_mc((7.0, 9.0), 0.6)
    assert ratio > 1.4, ratio
    # frames not moved carry no term
    t = np.arange(10) * 0.04
    uv = np.random.default_rng(0).normal(size=(10, 4, 2))
    assert np.all(interpolation_error_ms(uv, t, t, 0.06, 0.05) == 0.0)

def test_interpolation_variance_holds_next_to_dropped_frames():
    """Frames next to a dropped one are moved linearly, by extrapolation, or through three
    frames without a fourth beyond: their term is the next Newton term of the interpolant
    they had, the divided difference taken with the frame beyond its nodes, times the
    frequency factor for those nodes. Monte Carlo as above (0.05 px, 25 fps) with 15 % of the
    frames dropped, scored on the two frames either side of each gap, every one of them:
    error over stated at seed 11 1.13 for a 3-4 Hz sway (9.8 when most of them had no term,
    15.8 with the noise's share only) and 0.98 for 7-9 Hz tremor near the Nyquist frequency
    (1.49 without the factor; 0.65 with it but the frequency read across the gaps)."""
    from cvsflow.rig import instants as rig_instants

    ratio, ratio_noise = _interpolation_mc((3.0, 4.0), 4.0, drop=0.15, only_gap_neighbours=True)
    assert 0.8 < ratio < 1.25, ratio
    assert ratio_noise > 5.0, ratio_noise
    ratio, _ = _interpolation_mc((7.0, 9.0), 0.6, drop=0.15, only_gap_neighbours=True)
    assert 0.8 < ratio < 1.2, ratio
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(rig_instants, "_nyquist_factor_nodes", lambda w, *a: np.ones(len(w)))
        ratio_without, _ = _interpolation_mc((7.0, 9.0), 0.6, drop=0.15, only_gap_neighbours=True)
    assert ratio_without > 1.3, ratio_without


def test_rig_fuses_unsynchronised_cameras_at_one_instant():
    """A 25 fps camera on its own clock shares rig frames with a 30 fps pair: moved to the
    pair's instant its corners fuse consistently (NEES near 6), where fusing the frames as
    if simultaneous (``instant="nearest"``) is 3-4 times overconfident."""
    s = simulate_rig_session(3, n_cameras=3, duration_s=6.0)
    fit = optimise_se3_rig(_entries(s), s["bodies"], s["board"], free=FREE)
    entries = [e["corners"] for e in _entries(s)]
    out = {}
    for instant in ("interpolate", "nearest"):
        poses = fused_rig_poses(fit.result, entries, s["bodies"], s["board"], instant=instant)
        shared = (poses["frame_cam2"].to_numpy() >= 0) & (poses["n_cameras"].to_numpy() >= 2)
        out[instant] = _fused_nees(poses, s["truth"])[shared]
        assert shared.sum() > 60
    # seed 3: 5.8 moved to one instant, 21.2 as if simultaneous (seeds 0-2: 5.9-7.6, 29-60)
    assert 4.0 < out["interpolate"].mean() < 8.5
    assert out["nearest"].mean() > 2.0 * out["interpolate"].mean()
    with pytest.raises(OptimiseError, match="instant"):
        fused_rig_poses(fit.result, entries, s["bodies"], s["board"], instant="mean")


def test_rig_named_errors(rig):
    """A camera with no corners, all frames lost, a frame with two times, unordered times, or
    a fit that explains nothing."""
    good = _entries(rig)
    bad = [dict(good[0]), dict(good[1], corners=good[1]["corners"].iloc[:0])]
    with pytest.raises(OptimiseError, match="camera 1: corners table is empty"):
        optimise_se3_rig(bad, rig["bodies"], rig["board"])
    lost = good[1]["corners"].assign(found=False)
    with pytest.raises(OptimiseError, match="camera 1: .*no found frame"):
        optimise_se3_rig([good[0], dict(good[1], corners=lost)], rig["bodies"], rig["board"])
    c = good[1]["corners"].copy()
    f = c.loc[c["found"], "frame"].iloc[5]
    c.loc[(c["frame"] == f) & (c["corner"] == 3), "t_s"] += 0.5
    with pytest.raises(OptimiseError, match=f"camera 1: frame {f} has rows with different t_s"):
        optimise_se3_rig([good[0], dict(good[1], corners=c)], rig["bodies"], rig["board"])
    c = good[0]["corners"].copy()
    c.loc[c["frame"] == 40, "t_s"] = 0.0
    with pytest.raises(OptimiseError, match="camera 0: t_s does not increase with frame"):
        optimise_se3_rig([dict(good[0], corners=c), good[1]], rig["bodies"], rig["board"])
    with pytest.raises(OptimiseError, match="camera 1: entry lacks"):
        optimise_se3_rig([good[0], {"corners": good[1]["corners"]}], rig["bodies"], rig["board"])
    with pytest.raises(OptimiseError, match="camera 1: 0 frames"):
        optimise_se3_rig([good[0], dict(good[1], dt_offset_s=500.0)], rig["bodies"], rig["board"])
    # camera 1's corners read with the wrong clock (3 s off): the fit cannot explain them
    with pytest.raises(OptimiseError, match="se3 rig: camera 1: .*do not agree: check the board"):
        optimise_se3_rig([good[0], dict(good[1], dt_offset_s=good[1]["dt_offset_s"] + 3.0)],
                         rig["bodies"], rig["board"], free=FREE)
    with pytest.raises(OptimiseError, match="3 corner tables for 2 cameras"):
        fused_rig_poses({"cameras": [{}, {}]}, [good[0]["corners"]] * 3, rig["bodies"], rig["board"])
