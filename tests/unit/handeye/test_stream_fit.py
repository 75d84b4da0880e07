"""Time offset and hand-eye from two pose streams: the model's Jacobian, the truth on simulated
streams with a known offset and correlated noise, what is not observable, coverage."""

from __future__ import annotations

import numpy as np
import pytest

from cvsflow.exceptions import OverlapError
from cvsflow.geometry import PoseCurve, R_from_rvec, interpolate_T, make_T, rvec_from_R
from cvsflow.handeye.stream_fit import StreamsOptions, estimate_streams, seconds_since
from cvsflow.handeye.stream_model import PARAM_NAMES, StreamProblem
from cvsflow.handeye.stream_offset import coarse_offset
from cvsflow.handeye.stream_report import split_half_check
from cvsflow.handeye.stream_sim import simulate_streams


def _errors(res, sim):
    """The fit's error per parameter in its own local coordinates (rad, m, s)."""
    e = {"dt_offset_s": res.estimate["dt_s"] - sim["dt_offset_s"]}
    for name in ("T_Cm_C", "T_W_B"):
        T_est, T_true = res.estimate[name], sim[name]
        dr = rvec_from_R(T_true[:3, :3].T @ T_est[:3, :3])
        for k, axis in enumerate("xyz"):
            e[f"{name}_r{axis}"], e[f"{name}_{axis}"] = dr[k], T_est[k, 3] - T_true[k, 3]
    return e


def _fit(sim, **options):
    return estimate_streams(sim["t_cam_ns"], sim["T_B_C"], sim["t_mocap_ns"], sim["T_W_Cm"], StreamsOptions(**options))


def test_analytic_jacobian_matches_finite_differences():
    """The 13 columns of the model's Jacobian against central differences (dt away from kinks)."""
    sim = simulate_streams(3, duration_s=5.0)
    t_ref = int(sim["t_cam_ns"][0])
    curve = PoseCurve(seconds_since(sim["t_mocap_ns"], t_ref), sim["T_W_Cm"])
    T = sim["T_B_C"]
    prob = StreamProblem(seconds_since(sim["t_cam_ns"], t_ref), T[:, :3, :3], T[:, :3, 3], curve,
                         sim["T_Cm_C"] @ make_T(R_from_rvec([0.01, -0.02, 0.01]), [0.003, 0, -0.002]),
                         sim["T_W_B"], sim["dt_offset_s"] + 0.002)  # fmt: skip
    x = np.array([0.0011, 0.01, -0.02, 0.005, 0.001, -0.002, 0.003, 0.004, 0.01, -0.01, 0.002, 0.001, -0.003])
    J = prob.jac(x)
    Jn = np.empty_like(J)
    for k in range(13):
        h = np.zeros(13)
        h[k] = 1e-7
        Jn[:, k] = (prob.fun(x + h) - prob.fun(x - h)) / 2e-7
    np.testing.assert_allclose(J[:, 1:], Jn[:, 1:], atol=2e-5 * np.abs(Jn[:, 1:]).max())
    good = np.abs(J[:, 0] - Jn[:, 0]) < 1e-3 * np.abs(Jn[:, 0]).max()  # SLERP is piecewise in time
    assert good.mean() > 0.97


def test_noise_free_streams_give_the_truth():
    """Exact streams with a 43.7 ms offset: dt within 0.2 ms, T_Cm_C within 0.2 mm / 0.01 deg."""
    sim = simulate_streams(5, duration_s=15.0, cam_rot_sigma_deg=(0, 0, 0), cam_trans_sigma_mm=(0, 0, 0),
                           mocap_rot_sigma_deg=0.0, mocap_trans_sigma_mm=0.0, dt_offset_s=0.0437)  # fmt: skip
    e = _errors(_fit(sim), sim)
    assert abs(e["dt_offset_s"]) < 2e-4
    assert max(abs(e[f"T_Cm_C_{a}"]) for a in "xyz") < 2e-4
    assert max(abs(e[f"T_Cm_C_r{a}"]) for a in "xyz") < 2e-4


def test_coarse_offset_finds_a_large_offset():
    """A 731 ms offset is found by the angular-speed correlation to 10 ms, with a clear peak."""
    sim = simulate_streams(7, duration_s=30.0, dt_offset_s=0.731)
    t_ref = int(sim["t_cam_ns"][0])
    curve = PoseCurve(seconds_since(sim["t_mocap_ns"], t_ref), sim["T_W_Cm"])
    c = coarse_offset(seconds_since(sim["t_cam_ns"], t_ref), sim["T_B_C"][:, :3, :3], curve)
    assert abs(c["dt_s"] - 0.731) < 0.01 and c["quality"] > 0.5


def test_one_noisy_draw_is_within_its_errors():
    """AR(1) detector noise: every parameter within 4.5 stated std, all frames used, >= 10 blocks."""
    sim = simulate_streams(11, duration_s=30.0)
    res = _fit(sim)
    assert res.dt_offset_s is not None and res.T_Cm_C is not None
    z = np.array([err / res.std[k] for k, err in _errors(res, sim).items()])
    assert np.all(np.abs(z) < 4.5)
    assert res.counts["n_used"] == res.counts["n_camera"] and res.counts["n_blocks"] >= 10
    assert all(res.std[k] >= res.std_gn[k] for k in PARAM_NAMES)


def test_coverage_fast_subset():
    """8 seeded draws of 25 s: |err| / std < 2 for most components, mean z^2 near 1 (the full
    study is bench/bench_streams_coverage.py)."""
    zs = []
    for seed in range(100, 108):
        sim = simulate_streams(seed, duration_s=25.0)
        res = _fit(sim)
        zs += [err / res.std[k] for k, err in _errors(res, sim).items()]
    zs = np.abs(np.array(zs))
    assert np.mean(zs < 2) > 0.85
    assert np.mean(zs**2) < 1.6


def test_frames_outside_the_mocap_or_in_its_gaps_are_counted():
    """A 1 s motion-capture dropout and a stream ending 2 s early: those frames are counted and
    left out; dt still within its errors."""
    sim = simulate_streams(13, duration_s=20.0, n_gaps=0)
    tm, Tm = sim["t_mocap_ns"], sim["T_W_Cm"]
    t_rel = (tm - sim["t_cam_ns"][0]) / 1e9
    keep = ~((t_rel > 8.0) & (t_rel < 9.0)) & (t_rel < 18.0)
    res = estimate_streams(sim["t_cam_ns"], sim["T_B_C"], tm[keep], Tm[keep])
    c = res.counts
    assert c["n_in_mocap_gap"] >= 25 and c["n_outside_mocap"] >= 55
    assert c["n_used"] + c["n_in_mocap_gap"] + c["n_outside_mocap"] == c["n_camera"]
    assert abs(res.dt_offset_s - sim["dt_offset_s"]) < 5 * res.dt_offset_std_s


def test_streams_that_do_not_overlap_name_both_spans():
    """A motion capture 100 s after the camera: OverlapError with both spans."""
    sim = simulate_streams(13, duration_s=15.0, n_gaps=0)
    with pytest.raises(OverlapError, match=r"0 of \d+ camera poses fall inside the motion capture .*camera "
                       r"\d+\.\d+-\d+\.\d+ s, motion capture \d+\.\d+-\d+\.\d+ s"):  # fmt: skip
        estimate_streams(sim["t_cam_ns"], sim["T_B_C"], sim["t_mocap_ns"] + 100 * 10**9, sim["T_W_Cm"],
                         StreamsOptions(dt_init_s=0.0))  # fmt: skip


def test_dt_not_observable_from_isolated_still_frames():
    """yac-like: 30 views seconds apart, the camera still at each: dt null with both reasons, held
    at 0, the hand-eye still fitted."""
    sim = simulate_streams(17, duration_s=60.0, still=True, n_gaps=0, dt_offset_s=0.0)
    t = (sim["t_cam_ns"] - sim["t_cam_ns"][0]) / 1e9
    pick = np.searchsorted(t, (np.arange(30) + 0.5) * 2.0)
    res = estimate_streams(sim["t_cam_ns"][pick], sim["T_B_C"][pick], sim["t_mocap_ns"], sim["T_W_Cm"])
    assert res.dt_offset_s is None and res.dt_offset_std_s is None and res.dt_used_s == 0.0
    reason = res.observability["dt"]["reason"]
    assert "gives no angular speed" in reason and "nearly still" in reason
    np.testing.assert_allclose(res.T_Cm_C[:3, 3], sim["T_Cm_C"][:3, 3], atol=0.01)


def test_hand_eye_not_observable_when_turning_about_one_axis():
    """A marker body turning about z only: T_Cm_C null with the axis spread in the reason."""
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, 0.01)
    ang = 0.6 * np.sin(2 * np.pi * t / 3.3) + 0.3 * np.sin(2 * np.pi * t / 1.1)
    T_W_Cm = make_T(R_from_rvec(np.outer(ang, [0, 0, 1.0])), np.column_stack([0.2 * np.sin(t), 0.1 * np.cos(t), 0 * t]))
    T_Cm_C = make_T(R_from_rvec([0.3, -0.2, 0.1]), [0.05, 0.02, 0.01])
    T_W_B = make_T(R_from_rvec([np.pi, 0, 0]), [0.0, 0.0, -1.0])
    tc = np.arange(0.5, 19.5, 1 / 30)
    T_at, _, _ = interpolate_T(t, T_W_Cm, np.ones(len(t), bool), tc)
    T_B_C = np.linalg.inv(T_W_B) @ T_at @ T_Cm_C
    T_B_C[:, :3, 3] += rng.normal(0, 1e-3, (len(tc), 3))
    res = estimate_streams((tc * 1e9).astype(np.int64), T_B_C, (t * 1e9).astype(np.int64), T_W_Cm)
    assert res.T_Cm_C is None and "rotation axes spread only" in res.observability["hand_eye"]["reason"]
    assert res.dt_offset_s is None


def test_split_half_rows():
    """The split-half check compares all 13 parameters; on a 40 s simulated stream most agree."""
    sim = simulate_streams(19, duration_s=40.0)
    split = split_half_check(sim["t_cam_ns"], sim["T_B_C"], sim["t_mocap_ns"], sim["T_W_Cm"])
    assert [r["name"] for r in split["rows"]] == list(PARAM_NAMES)
    assert all(r["std_diff"] > 0 for r in split["rows"]) and split["n_agree"] >= 10
    assert split["mean_z2_limit"] == pytest.approx(22.362 / 13, abs=1e-3)
