"""The moving camera body's reference noise (cvsflow.uncertainty.reference_noise)."""

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from cvsflow.geometry import transforms as tf
from cvsflow.metrics.errors import ERROR_DIMS, pose_errors
from cvsflow.uncertainty.reference_noise import camera_body_error_cov, moving_body_noise


def _bodies(sigma_rot, sigma_pos, rate=300.0, duration_s=20.0, seed=0):
    """A camera body swaying at 0.3-0.7 Hz with white pose noise of known size per axis."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * rate)) / rate
    rv = np.c_[0.3 * np.sin(2 * np.pi * 0.3 * t), 0.2 * np.sin(2 * np.pi * 0.5 * t + 1), 0.1 * t]
    R = Rotation.from_rotvec(rv) * Rotation.from_rotvec(rng.normal(0, sigma_rot, (len(t), 3)))
    p = np.c_[0.5 * np.sin(2 * np.pi * 0.7 * t), 0.3 * np.cos(2 * np.pi * 0.4 * t), 1.0 + 0 * t]
    p = p + rng.normal(0, sigma_pos, p.shape)
    q = R.as_quat()
    return pd.DataFrame({"t_s": t, "body": "camera", "valid": True, "x_m": p[:, 0],
                         "y_m": p[:, 1], "z_m": p[:, 2], "qx": q[:, 0], "qy": q[:, 1],
                         "qz": q[:, 2], "qw": q[:, 3]})  # fmt: skip


def test_moving_body_noise_is_the_smoothed_tracks():
    """White noise of 2 mrad / 0.1 mm per axis at 300 Hz, smoothed by a 0.1 s local quadratic
    (31 samples, centre variance factor 0.0727): the estimate from the track alone is the
    smoothed noise, 0.54 mrad / 0.027 mm, within 10 %, whatever the slow sway."""
    s_r, s_p = moving_body_noise(_bodies(2e-3, 1e-4))
    g = 3 * (3 * 31**2 - 7) / (4 * 31 * (31**2 - 4))
    assert s_r == pytest.approx(2e-3 * np.sqrt(g), rel=0.1)
    assert s_p == pytest.approx(1e-4 * np.sqrt(g), rel=0.1)


@pytest.mark.parametrize("frame", ["C", "B"])
def test_camera_body_error_cov_against_monte_carlo(frame):
    """The camera-marker body's pose drawn with isotropic noise in its own frame, the optical
    centre 6 cm from its origin, the board 1.5 m away: the reference T_C_B recomputed from
    the noisy body has the stated error covariance to within 8 % of its largest entry (the
    6 cm lever is what the model leaves out), the rotation's lever included: the position
    errors across the line of sight are 1.5 mm for 1 mrad."""
    rng = np.random.default_rng(4)
    rvec, tvec = np.array([[2.9, 0.2, -0.3]]), np.array([[0.2, -0.1, 1.5]])
    T_C_B = tf.T_from_rvec_tvec(rvec, tvec)[0]
    T_Cm_C = tf.make_T(Rotation.from_rotvec([-1.2, 0.1, -1.5]).as_matrix(), [0.03, -0.02, 0.05])
    T_W_Cm = tf.make_T(Rotation.from_rotvec([0.1, 0.4, 2.0]).as_matrix(), [1.0, 2.0, 1.2])
    T_W_B = T_W_Cm @ T_Cm_C @ T_C_B
    s_r, s_p = 1e-3, 2e-4
    cov = camera_body_error_cov(rvec, tvec, s_r, s_p, frame=frame)[0]
    n = 20000
    noise = tf.make_T(Rotation.from_rotvec(rng.normal(0, s_r, (n, 3))).as_matrix(),
                      rng.normal(0, s_p, (n, 3)))  # fmt: skip
    ref = np.linalg.inv(T_W_Cm @ noise @ T_Cm_C) @ T_W_B
    E = pose_errors(ref, np.broadcast_to(T_C_B, (n, 4, 4)).copy(),
                    frame=frame)[[f"err_{d}" for d in ERROR_DIMS]].to_numpy()
    sd = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(np.cov(E.T), cov, atol=0.08 * sd.max() ** 2)
    if frame == "C":
        assert sd[3:] == pytest.approx([1e-3] * 3, rel=1e-4)
        assert 1.4e-3 < sd[0] < 1.6e-3 and 1.4e-3 < sd[1] < 1.6e-3


def test_model_T_adds_the_reference_noise_at_its_scale():
    """Features with ``refcov`` (a moving camera body): a model fitted without it, as
    RENDERED_TRANSFER_MODEL, adds it at the physical scale 1; a model that fitted c_ref adds
    c_ref^2 of it; without the columns nothing changes."""
    from cvsflow import uncertainty as un

    rng = np.random.default_rng(2)
    n = 40
    A = rng.normal(size=(n, 6, 6)) * 1e-3
    U = A @ np.swapaxes(A, 1, 2) + np.eye(6) * 1e-8
    feats = pd.DataFrame({"speed_px": rng.uniform(0, 5, n), "reproj_rms_px": 0.3, "n_corners": 30})
    iu = np.triu_indices(6)
    for c, name in enumerate(un.cov_columns("unitcov")):
        feats[name] = U[:, iu[0][c], iu[1][c]]
    base = un.transfer_covariance(un.RENDERED_TRANSFER_MODEL, feats)
    R = camera_body_error_cov(rng.normal(size=(n, 3)), np.c_[rng.normal(0, 0.3, (n, 2)),
                              rng.uniform(1, 3, n)], 5e-4, 7e-5)  # fmt: skip
    with_ref = feats.copy()
    for c, name in enumerate(un.cov_columns("refcov")):
        with_ref[name] = R[:, iu[0][c], iu[1][c]]
    np.testing.assert_allclose(un.transfer_covariance(un.RENDERED_TRANSFER_MODEL, with_ref),
                               base + R, rtol=1e-9, atol=1e-18)  # fmt: skip
    half = {**un.RENDERED_TRANSFER_MODEL, "c_ref": 0.5}
    np.testing.assert_allclose(un.transfer_covariance(half, with_ref), base + 0.25 * R,
                               rtol=1e-9, atol=1e-18)  # fmt: skip
    np.testing.assert_array_equal(un.transfer_covariance(half, feats), base)
