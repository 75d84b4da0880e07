"""Tests of cvsflow.flight_synth (the rendered flight demo) and cvsflow.plots.flight."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest

from cvsflow import flight as F
from cvsflow.errors import ConfigError
from cvsflow.flight_synth import T_Q_B_DEFAULT, camera_pose, render_flight
from cvsflow.transforms import invert_T


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


def test_reference_noise_follows_its_covariance(demo):
    """Reference minus truth, whitened by Sigma_ref, has unit variance per component (±10 %)."""
    from scipy.spatial.transform import Rotation

    ok = demo.reference["pos_valid"].to_numpy()
    T_true = invert_T(demo.T_L_C) @ F.T_from_traj(demo.truth) @ demo.T_Q_B
    T_meas = F.T_from_traj(demo.reference)
    dt = T_meas[ok, :3, 3] - T_true[ok, :3, 3]
    dth = Rotation.from_matrix(
        T_meas[ok, :3, :3] @ np.swapaxes(T_true[ok, :3, :3], 1, 2)
    ).as_rotvec()
    d = np.column_stack([dt, dth])
    sig = np.sqrt(np.diagonal(demo.Sigma_ref[ok], axis1=1, axis2=2))
    np.testing.assert_allclose((d / sig).std(0), 1.0, atol=0.1)
    assert 0.95 < ok.mean() < 1.0  # ~2 % of the frames are missed


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
    assert ymax == pytest.approx(1e3 * np.abs(r.errors["ex_m"]).max(), rel=1e-9)
    save_figure(fig, tmp_path / "err.png")
    for f in (plot_flight_trajectories(r.ref_aligned, r.est_aligned), plot_ape(r.errors, r.stats)):
        assert all(ax.get_xlabel() and ax.get_ylabel() for ax in f.axes)
        save_figure(f, tmp_path / "f.png")
    assert (tmp_path / "err.png").stat().st_size > 10_000
