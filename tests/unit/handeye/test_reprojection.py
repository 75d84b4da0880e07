"""Hand-eye refinement: the analytic Jacobian, z-scores, carrier-pose sigmas, intrinsics."""

from __future__ import annotations

import numpy as np
import pytest

from cvsflow.handeye import closed_form as hm
from cvsflow.handeye import reprojection as hr
from tests.helpers.handeye_sim import CAMERA, K, pose_errors, simulate


@pytest.mark.parametrize("mode", hm.MODES)
def test_jacobian_matches_finite_differences(mode):
    """The analytic Jacobian (poses, intrinsics, carrier-pose errors) equals central differences."""
    s = simulate(mode, n=4, seed=1)
    m = hr._Model(s["T_W_X"], mode, s["uv"], s["p_B"], s["T_H"], s["T_G"],
                  hr._intrinsics_vector({"K": K, "dist": [0.01, -0.02, 1e-3, 1e-3, 0.0]}),
                  ("fx", "cy", "k1", "p2"), True, (0.5, 1e-3, 1e-3))  # fmt: skip
    x = m.x0() + np.random.default_rng(2).normal(0.0, 1e-3, len(m.x0()))
    J = m.jacobian(x)
    J_fd = np.zeros_like(J)
    for j in range(len(x)):
        h = 1e-6 * max(1.0, abs(x[j]))
        e = np.zeros(len(x))
        e[j] = h
        J_fd[:, j] = (m.residuals(x + e) - m.residuals(x - e)) / (2 * h)
    assert np.abs(J - J_fd).max() < 1e-5 * np.abs(J_fd).max()


@pytest.mark.parametrize("mode", hm.MODES)
def test_refined_recovers_truth_corner_noise_only(mode):
    """With exact carrier poses and 0.3 px corner noise the plain refinement's z-scores are
    standard normal: RMS over 12 parameters x 12 sessions near 1, none beyond 4.5."""
    z = []
    for seed in range(12):
        s = simulate(mode, n=10, seed=100 + seed, sigma_px=0.3)
        T0_H, T0_G = hm.closed_form_hand_eye(s["T_W_X"], s["T_C_B"], mode, "park")
        fit = hr.refine_hand_eye(s["uv"], s["p_B"], s["T_W_X"], CAMERA, T0_H, T0_G, mode,
                                 pose_noise=False)  # fmt: skip
        err = np.concatenate([pose_errors(s["T_H"], fit["T_H"]), pose_errors(s["T_G"], fit["T_G"])])
        z.append(err / np.sqrt(np.diag(fit["cov"])))
        assert abs(fit["sigma_px"] - 0.3) < 0.03
    z = np.asarray(z)
    assert 0.75 < np.sqrt(np.mean(z**2)) < 1.3
    assert np.abs(z).max() < 4.5


@pytest.mark.parametrize("mode", hm.MODES)
def test_pose_noise_model_recovers_truth_and_sigmas(mode):
    """With 2 mm / 0.1 deg carrier-pose errors the errors-in-variables fit estimates both
    sigmas, its z-scores stay sane (RMS 0.6-1.5), and the plain fit's do not (it ignores the
    pose errors, so its Gauss-Newton standard errors are far too small)."""
    z_eiv, z_plain, sig_pos, sig_rot = [], [], [], []
    for seed in range(6):
        s = simulate(mode, n=12, seed=200 + seed, sigma_px=0.3, sigma_pos_m=0.002,
                     sigma_rot_rad=np.radians(0.1))  # fmt: skip
        T0_H, T0_G = hm.closed_form_hand_eye(s["T_W_X"], s["T_C_B"], mode, "park")
        for noise, z in ((True, z_eiv), (False, z_plain)):
            fit = hr.refine_hand_eye(s["uv"], s["p_B"], s["T_W_X"], CAMERA, T0_H, T0_G, mode,
                                     pose_noise=noise)  # fmt: skip
            err = np.concatenate([pose_errors(s["T_H"], fit["T_H"]), pose_errors(s["T_G"], fit["T_G"])])
            z.append(err / np.sqrt(np.diag(fit["cov"])))
            if noise:
                sig_pos.append(fit["sigma_pos_m"])
                sig_rot.append(fit["sigma_rot_rad"])
    rms_eiv = np.sqrt(np.mean(np.square(z_eiv)))
    assert 0.6 < rms_eiv < 1.5
    assert np.sqrt(np.mean(np.square(z_plain))) > 2.0 * rms_eiv
    assert 0.0014 < np.median(sig_pos) < 0.0026
    assert np.radians(0.05) < np.median(sig_rot) < np.radians(0.15)


def test_intrinsics_refined_when_freed():
    """Started from fx, fy 2 % off, the fit with fx, fy, cx, cy free lands near the truth."""
    s = simulate("eye_in_hand", n=12, seed=7, sigma_px=0.2)
    cam = {"K": K * np.array([[1.02, 1, 1], [1, 0.98, 1], [1, 1, 1]]), "dist": np.zeros(5)}
    T0_H, T0_G = hm.closed_form_hand_eye(s["T_W_X"], s["T_C_B"], "eye_in_hand", "park")
    fit = hr.refine_hand_eye(s["uv"], s["p_B"], s["T_W_X"], cam, T0_H, T0_G, "eye_in_hand",
                             ("fx", "fy", "cx", "cy"), pose_noise=False)  # fmt: skip
    sd = np.sqrt(np.diag(fit["cov"]))[12:]
    err = fit["intrinsics"][:4] - np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    assert np.all(np.abs(err) < 4 * sd)
    assert np.all(sd < 3.0)


def test_fixed_intrinsic_std_propagates_as_the_refit_shift():
    """camera["std"] of a fixed fx adds S sd^2 S^T: the added variance of each parameter equals
    the square of its shift when fx is moved by one sd and the fit redone (linearity)."""
    s = simulate("eye_in_hand", n=10, seed=41, sigma_px=0.2)
    T0_H, T0_G = hm.closed_form_hand_eye(s["T_W_X"], s["T_C_B"], "eye_in_hand", "park")
    args = (s["uv"], s["p_B"], s["T_W_X"])
    base = hr.refine_hand_eye(*args, {"K": K, "dist": np.zeros(5)}, T0_H, T0_G, pose_noise=False)
    with_sd = hr.refine_hand_eye(*args, {"K": K, "dist": np.zeros(5), "std": {"fx": 3.0}},
                                 T0_H, T0_G, pose_noise=False)  # fmt: skip
    K_moved = K.copy()
    K_moved[0, 0] += 3.0
    moved = hr.refine_hand_eye(*args, {"K": K_moved, "dist": np.zeros(5)}, T0_H, T0_G,
                               pose_noise=False)  # fmt: skip
    assert with_sd["intrinsic_std_propagated"] == ["fx"]
    added = np.diag(with_sd["cov"]) - np.diag(base["cov"])
    shift = np.concatenate([hr._deviation(base["T_H"], moved["T_H"]),
                            hr._deviation(base["T_G"], moved["T_G"])])  # fmt: skip
    big = shift**2 > 0.05 * added.max()
    np.testing.assert_allclose(added[big], shift[big] ** 2, rtol=0.1)
