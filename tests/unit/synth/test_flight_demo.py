"""Tests of cvsflow.synth.flight_demo (the rendered flight demo) and cvsflow.plots.flight."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest

from cvsflow import flight as F
from cvsflow.exceptions import ConfigError, SyncError
from cvsflow.geometry.transforms import invert_T
from cvsflow.synth.flight_demo import T_Q_B_DEFAULT, camera_pose, render_flight
from cvsflow.synth.flight_reference import CALIB_STD_DEFAULT, corner_noise


@pytest.fixture(scope="module")
def demo():
    """A rendered 40 s flight (seed 3)."""
    return render_flight(seed=3, duration_s=40.0)


def test_render_is_seeded():
    """Same seed, same flight (bit for bit); another seed, another flight."""
    a = render_flight(seed=5, duration_s=5.0)
    b = render_flight(seed=5, duration_s=5.0)
    c = render_flight(seed=6, duration_s=5.0)
    np.testing.assert_array_equal(a.onboard[["x_m", "qw"]], b.onboard[["x_m", "qw"]])
    np.testing.assert_array_equal(a.reference[["x_m"]].fillna(0), b.reference[["x_m"]].fillna(0))
    assert not np.allclose(a.onboard["x_m"], c.onboard["x_m"])


def test_geometry_range_and_board_faces_camera(demo):
    """The body stays 3..20 m from the camera, and the board's z axis points away from it."""
    T_C_Q = invert_T(demo.T_L_C) @ F.T_from_traj(demo.truth)
    dq = np.linalg.norm(T_C_Q[:, :3, 3], axis=1)
    assert dq.min() >= 3.0 - 1e-9 and dq.max() <= 20.0 + 1e-9
    assert dq.max() - dq.min() > 10.0
    assert demo.truth["z_m"].max() <= -0.5 + 1e-9  # NED: at least 0.5 m above the ground
    T_C_B = T_C_Q @ T_Q_B_DEFAULT
    d = np.linalg.norm(T_C_B[:, :3, 3], axis=1)
    cos_view = np.einsum("ni,ni->n", T_C_B[:, :3, 2], T_C_B[:, :3, 3] / d[:, None])
    assert np.all(cos_view > np.cos(np.deg2rad(60)))
    # and the board stays inside the 640x480 field of view of f = 700 px
    u = 700 * T_C_B[:, 0, 3] / T_C_B[:, 2, 3]
    v = 700 * T_C_B[:, 1, 3] / T_C_B[:, 2, 3]
    assert np.all(np.abs(u) < 320) and np.all(np.abs(v) < 240)


def test_clock_and_injected_error_are_as_declared(demo):
    """Log times map onto the true clock with the declared offset/skew; the injected error equals
    the log minus the truth, and its mean holds the declared biases plus drift."""
    t_ref = demo.clock.to_ref(demo.onboard["t_s"].to_numpy())
    assert t_ref[0] <= -4.99 and t_ref[-1] >= 44.99
    np.testing.assert_allclose(np.diff(demo.onboard["t_s"]), 0.01, atol=1e-9)
    inj = demo.injected[F.ERR_COLS].to_numpy()
    # the white noise alone (0.01 m, 0.003 rad) bounds the frame-to-frame change of the error
    step = np.diff(inj, axis=0).std(0)
    assert np.all(step[:3] < 0.03) and np.all(step[3:] < 0.01)
    # the random walk after 45 s is ~0.01*sqrt(45) = 0.07 m: the bias of 0.08 m in z shows
    assert inj[:, 2].mean() == pytest.approx(0.08, abs=0.15)


def _reference_z(demo, Sigma=None):
    """Reference minus truth ([dt, dtheta] in C) over the stated sigma, valid frames."""
    from scipy.spatial.transform import Rotation

    ok = demo.reference["pos_valid"].to_numpy()
    T_true = invert_T(demo.T_L_C) @ F.T_from_traj(demo.truth) @ demo.T_Q_B
    T_meas = F.T_from_traj(demo.reference)
    dt = T_meas[ok, :3, 3] - T_true[ok, :3, 3]
    dth = Rotation.from_matrix(
        T_meas[ok, :3, :3] @ np.swapaxes(T_true[ok, :3, :3], 1, 2)
    ).as_rotvec()
    S = demo.Sigma_ref if Sigma is None else Sigma
    return np.column_stack([dt, dth]) / np.sqrt(np.diagonal(S[ok], axis1=1, axis2=2)), ok


def test_reference_noise_follows_its_covariance(demo):
    """Reference minus truth, whitened by Sigma_ref, has unit variance per component (±10 %)."""
    z, ok = _reference_z(demo)
    np.testing.assert_allclose(z.std(0), 1.0, atol=0.1)
    assert 0.95 < ok.mean() < 1.0  # ~2 % of the frames are missed


#: The calibration error of the PnP flights below, principal point exact: its error turns C
#: about its origin, which a flight's alignment absorbs and model (T) leaves out.
_NO_PP = {k: v for k, v in CALIB_STD_DEFAULT.items() if k not in ("cx", "cy")}
_TELE = {"fx_px": 910.0, "fy_px": 905.0, "cx_px": 329.0, "cy_px": 251.0,
         "dist": [-0.05, 0.02, 0.0, 0.0, 0.0], "width_px": 640, "height_px": 480}  # fmt: skip


@pytest.fixture(scope="module", params=["demo", "tele"])
def pnp_flight(request):
    """A 20 s flight (3-20 m) whose reference is the CVS's PnP of noisy corners, on the demo's
    camera and on a 910 px lens."""
    camera = None if request.param == "demo" else _TELE
    return render_flight(seed=7, duration_s=20.0, reference="pnp", camera=camera,
                         calib_std=_NO_PP)  # fmt: skip


def test_pnp_reference_states_model_T_covariance_truth_check(pnp_flight):
    """Reference measured from noisy corners (not drawn from its covariance): the truth check
    through the flight evaluation (true clock, fitted SE(3) alignment) gives z RMS 0.85-1.1 on
    position and 0.7-1.1 on attitude: never overconfident by more than 10 %; conservative on
    iid corner noise as expected (model (T)'s s_reproj 1.13, fitted on rendered corners whose
    errors are partly shared, makes ~0.89); the raw reference error in C over its stated sigma
    0.8-1.1. The flip term carried exactly into the Euler angles (flip_ref): every axis
    0.82-1.1 (0.86-0.96 measured); linearised, roll's sigma is overstated (0.73-0.74)."""
    d = pnp_flight
    assert np.isnan(d.Sigma_ref[~d.reference["pos_valid"].to_numpy()]).all()
    z, ok = _reference_z(d)
    assert ok.mean() > 0.9
    zr = np.sqrt(np.mean(z**2, axis=0))
    assert np.all((zr > 0.8) & (zr < 1.1)), zr
    zc = {}
    for exact in (True, False):
        r = F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref, clock=d.clock,
                              flip_ref=d.flip_ref if exact else None)  # fmt: skip
        c = F.check_against_truth(r, d.onboard, d.truth, d.T_L_C, d.clock)
        zc[exact] = np.array(list(c["z_rms"].values()))
    assert np.all((zc[True] > 0.82) & (zc[True] < 1.1)), zc[True]
    assert zc[True][3] > zc[False][3] + 0.08, zc


def test_pnp_reference_estimated_clock_and_weighted_alignment(pnp_flight):
    """The clock from a PnP reference: frame-to-frame angular speeds fail (far-board tilt noise
    and planar flips: SyncError), the coarse step falls back to a longer baseline, and the
    recovered log time at the reference's centre is within 3 stated sigma of the injected one
    (0.9 and 0.3 measured, std 2.7 and 3.5 ms; dt_offset_s, extrapolated over 27 s with the
    skew from only ten 2 s blocks, within 4: 0.9 and 1.0). The alignment weighted by the reference covariance is not
    moved by the far frames' depth noise: with a truth-fitted alignment x and z z RMS drop
    from > 1.5 (2.0-2.3 measured) to < 1.25 (0.98-1.16)."""
    d = pnp_flight
    with pytest.raises(SyncError, match="below min_quality"):
        F.estimate_clock(d.reference, d.onboard, R_Q_B=d.T_Q_B[:3, :3],
                         speed_baselines_s=(None,))  # fmt: skip
    res = {}
    for weighted in (False, True):
        r = F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref,
                              weighted_alignment=weighted)  # fmt: skip
        res[weighted] = F.check_against_truth(r, d.onboard, d.truth, d.T_L_C, d.clock)
    k = r.clock
    assert k.details["xcorr_baseline_s"] is not None
    t_c = k.details["t_centre_s"]
    e_c = k.to_log(t_c) - d.clock.to_log(t_c)
    assert 0 < k.details["dt_centre_std_s"] < 5e-3
    assert abs(e_c) < 3 * k.details["dt_centre_std_s"]
    assert abs(k.dt_offset_s - d.clock.dt_offset_s) < 4 * k.details["dt_offset_std_s"]
    assert r.alignment.method == "se3w"
    for axis in ("x_m", "z_m"):
        assert res[False]["z_rms_truth_alignment"][axis] > 1.5, res[False]
        assert res[True]["z_rms_truth_alignment"][axis] < 1.25, res[True]


def test_flip_term_holds_the_planar_ambiguity():
    """Far, small boards flip (IPPE's other solution, tens of degrees off): without the flip
    term the stated rotation sigma is too small (z RMS > 1.5 on some axis), with it not."""
    from scipy.spatial.transform import Rotation

    from cvsflow.board.model import board_object_points
    from cvsflow.synth.flight_demo import true_flight
    from cvsflow.synth.flight_reference import BOARD_DEFAULT, CAMERA_DEMO, measure_reference

    t = np.arange(601) / 30.0
    T_C_B = invert_T(camera_pose()) @ true_flight(3, 20.0)(t) @ T_Q_B_DEFAULT
    T_meas, valid, Sig, poses, corners = measure_reference(
        T_C_B, t, np.ones(len(t), bool), np.random.default_rng(11), calib_std={})
    K = [[CAMERA_DEMO["fx_px"], 0, CAMERA_DEMO["cx_px"]], [0, CAMERA_DEMO["fy_px"],
                                                           CAMERA_DEMO["cy_px"]], [0, 0, 1]]
    Sig0 = F.reference_covariance_transfer(poses, corners, board_object_points(BOARD_DEFAULT),
                                           {"K": K, "dist": CAMERA_DEMO["dist"], "std": {}},
                                           flips=False)  # fmt: skip
    dth = Rotation.from_matrix(T_meas[valid, :3, :3]
                               @ np.swapaxes(T_C_B[valid, :3, :3], 1, 2)).as_rotvec()
    assert (np.linalg.norm(dth, axis=1) > np.deg2rad(5)).sum() >= 5  # the ambiguity is real
    z1 = dth / np.sqrt(np.einsum("nii->ni", Sig[valid][:, 3:, 3:]))
    z0 = dth / np.sqrt(np.einsum("nii->ni", Sig0[valid][:, 3:, 3:]))
    assert np.sqrt(np.mean(z0**2, axis=0)).max() > 1.5
    assert np.sqrt(np.mean(z1**2, axis=0)).max() < 1.15


def test_corner_noise_shared_part():
    """corner_noise: iid part uncorrelated between corners; the shared part correlates
    neighbours (1 square apart) by exp(-1/2) of its variance; total variance as declared."""
    board = {"squares_x": 6, "squares_y": 5, "square_m": 0.1}
    e = corner_noise(np.random.default_rng(0), 20000, board, 0.1, 0.2, 1.0)
    assert e.shape == (20000, 20, 2)
    assert e[..., 0].var() == pytest.approx(0.01 + 0.04, rel=0.03)
    c01 = np.mean(e[:, 0, 0] * e[:, 1, 0])  # corners 0 and 1: one square apart
    assert c01 == pytest.approx(0.04 * np.exp(-0.5), abs=0.003)
    e0 = corner_noise(np.random.default_rng(0), 20000, board, 0.1)
    assert abs(np.mean(e0[:, 0, 0] * e0[:, 1, 0])) < 3e-4


def test_given_covariance_is_used():
    """A Sigma_ref array given to the renderer is the one returned and drawn from."""
    n = 5 * 30 + 1
    S = np.tile(np.diag([1e-6] * 3 + [1e-8] * 3), (n, 1, 1))
    demo = render_flight(seed=2, duration_s=5.0, Sigma_ref=S, missed_frame_rate=0.0)
    np.testing.assert_array_equal(demo.Sigma_ref, S)
    T_true = invert_T(demo.T_L_C) @ F.T_from_traj(demo.truth) @ demo.T_Q_B
    dt = F.T_from_traj(demo.reference)[:, :3, 3] - T_true[:, :3, 3]
    assert dt.std() == pytest.approx(1e-3, rel=0.15)
    with pytest.raises(ConfigError, match="Sigma_ref shape"):
        render_flight(seed=2, duration_s=5.0, Sigma_ref=S[:3])


def test_bad_parameters():
    """Non-positive duration, inverted range and a 1 % skew are ConfigErrors naming the key."""
    with pytest.raises(ConfigError, match="duration_s"):
        render_flight(duration_s=0.0)
    with pytest.raises(ConfigError, match="range_m"):
        render_flight(range_m=(20.0, 3.0))
    with pytest.raises(ConfigError, match="skew"):
        render_flight(skew=0.01)


def test_camera_pose_looks_north_tilted_up():
    """The demo camera's optical axis points north and 8 deg up (NED: negative z)."""
    z_C = camera_pose()[:3, 2]
    assert z_C[0] == pytest.approx(np.cos(np.deg2rad(8)), abs=1e-12)
    assert z_C[2] == pytest.approx(-np.sin(np.deg2rad(8)), abs=1e-12)


def test_figures(demo, tmp_path):
    """The three flight figures build with labelled axes in mm/deg; the error panel draws a band."""
    from cvsflow.io.files import save_figure
    from cvsflow.plots.flight import plot_ape, plot_flight_errors, plot_flight_trajectories

    r = F.evaluate_flight(
        demo.reference, demo.onboard, demo.T_Q_B, demo.Sigma_ref, clock=demo.clock
    )
    fig = plot_flight_errors(r.errors, injected=demo.injected)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels == [
        "x error (mm)",
        "y error (mm)",
        "z error (mm)",
        "roll error (deg)",
        "pitch error (deg)",
        "yaw error (deg)",
    ]
    assert len(fig.axes[0].collections) == 1  # the ±kσ band
    ymax = np.max(np.abs(fig.axes[0].lines[0].get_ydata()))
    assert ymax == pytest.approx(1e3 * np.abs(r.errors["err_x_m"]).max(), rel=1e-9)
    save_figure(fig, tmp_path / "err.png")
    for f in (plot_flight_trajectories(r.ref_aligned, r.est_aligned), plot_ape(r.errors, r.stats)):
        assert all(ax.get_xlabel() and ax.get_ylabel() for ax in f.axes)
        save_figure(f, tmp_path / "f.png")
    assert (tmp_path / "err.png").stat().st_size > 10_000


def test_stereo_reference_states_its_error():
    """A two-camera reference (1 m baseline, the rig calibrated on shared views with the
    drawn lens) states a covariance its errors match: pooled over six calibration draws,
    the z RMS per axis of camera 0's board pose is near 1. Without the intrinsics' cross-
    covariance with the fitted rig the depth term would be several times too large."""
    from cvsflow.geometry.transforms import pose_error_left
    from cvsflow.synth.flight_reference import measure_reference_rig, stereo_rig

    base = render_flight(seed=1, duration_s=60.0)
    T_C0_B = (invert_T(base.T_L_C) @ F.T_from_traj(base.truth) @ base.T_Q_B)[::30]
    z, sd_depth = [], []
    for seed in range(6):
        T, valid, S, rig = measure_reference_rig(T_C0_B, np.ones(len(T_C0_B), bool), np.random.default_rng(seed),
                                                 stereo_rig(1.0))  # fmt: skip
        assert valid.mean() > 0.9 and rig["n_views"] == 20
        e = pose_error_left(T[valid], T_C0_B[valid])
        z.append(e / np.sqrt(np.diagonal(S[valid], axis1=1, axis2=2)))
        sd_depth.append(np.sqrt(S[valid, 2, 2]))
    rms = np.sqrt(np.mean(np.concatenate(z) ** 2, axis=0))
    # the calibration error is one draw per seed: six draws scatter the RMS by about 30 %
    assert np.all((rms > 0.55) & (rms < 1.6)), rms
    # the rig measures depth: its stated depth sigma at 3-20 m is a few cm, not the 0.1 m an
    # independent principal-point error would give
    assert np.median(np.concatenate(sd_depth)) < 0.05


def test_render_flight_stereo_reference():
    """``reference="stereo"`` gives the flight stage a reference with a finite covariance;
    a rig without it, or unknown rig keys, are refused."""
    d = render_flight(seed=4, duration_s=6.0, reference="stereo", rig={"baseline_m": 1.0})
    valid = d.reference["pos_valid"].to_numpy(bool)
    assert valid.mean() > 0.9
    assert np.all(np.isfinite(d.Sigma_ref[valid])) and np.all(np.isnan(d.Sigma_ref[~valid]))
    assert np.all(np.linalg.eigvalsh(d.Sigma_ref[valid]).min(axis=1) > 0)
    r = F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref, clock=d.clock)
    assert r.stats["n_pairs"] > 150
    with pytest.raises(ConfigError, match="rig"):
        render_flight(seed=4, duration_s=2.0, reference="pnp", rig={"baseline_m": 1.0})
    with pytest.raises(ConfigError, match="unknown rig keys"):
        render_flight(seed=4, duration_s=2.0, reference="stereo", rig={"base_m": 1.0})
    with pytest.raises(ConfigError, match="baseline_m"):
        render_flight(seed=4, duration_s=2.0, reference="stereo", rig={"baseline_m": 0.0})


def test_pnp_flight_files_keep_the_flip_and_calibration_terms(tmp_path):
    """A rendered PnP flight written as files (write_flight_demo) and read back as the flight
    stage reads it: the covariance, the flip term and the calibration factor come back equal,
    and the evaluation from the files states the same sigma as from memory."""
    from cvsflow.io.files import read_parquet
    from cvsflow.io.flightlog import write_flight_demo

    d = render_flight(seed=3, duration_s=6.0, reference="pnp")
    write_flight_demo(d, tmp_path)
    table = read_parquet(tmp_path / "reference.parquet")
    np.testing.assert_array_equal(F.sigma_from_columns(table), d.Sigma_ref)
    np.testing.assert_array_equal(F.flip_from_columns(table), d.flip_ref)
    G = F.factor_from_columns(table)
    assert G.shape == d.cal_factor.shape == (len(table), 6, 9)
    np.testing.assert_array_equal(G, d.cal_factor)
    kw = {"clock": d.clock}
    a = F.evaluate_flight(table, d.onboard, d.T_Q_B, F.sigma_from_columns(table),
                          flip_ref=F.flip_from_columns(table), cal_factor=G, **kw)  # fmt: skip
    b = F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref, flip_ref=d.flip_ref,
                          cal_factor=d.cal_factor, **kw)  # fmt: skip
    np.testing.assert_allclose(a.errors[F.SIG_COLS], b.errors[F.SIG_COLS], rtol=1e-12)
    # a model-reference flight has neither
    m = render_flight(seed=3, duration_s=6.0)
    assert m.flip_ref is None and m.cal_factor is None
    assert F.factor_from_columns(m.reference) is None and F.flip_from_columns(m.reference) is None
