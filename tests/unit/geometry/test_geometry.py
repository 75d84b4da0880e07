"""cvsflow.geometry against independent references: scipy's Rotation and Slerp, OpenCV's
projectPoints, finite differences and known transforms."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from cvsflow import geometry as geo
from cvsflow.exceptions import MocapError

K = np.array([[701.0, 0.0, 322.0], [0.0, 697.0, 243.0], [0.0, 0.0, 1.0]])
DIST = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02])
LAYOUT_M = np.array([[0.0, 0.0, 0.0], [0.76, 0.0, 0.0], [0.0, 0.52, 0.0], [0.58, 0.5, 0.1]])


def _random_T(rng, n):
    return geo.make_T(Rotation.random(n, random_state=rng).as_matrix(), rng.normal(0.0, 1.0, (n, 3)))


# ------------------------------------------------------------------ SO(3) / SE(3)


def test_euler_convention_is_rz_ry_rx():
    """R_from_euler([r, p, y]) = Rz(y) Ry(p) Rx(r), and euler_from_R inverts it."""
    r, p, y = 0.3, -0.4, 2.0
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(r), -s(r)], [0, s(r), c(r)]])
    Ry = np.array([[c(p), 0, s(p)], [0, 1, 0], [-s(p), 0, c(p)]])
    Rz = np.array([[c(y), -s(y), 0], [s(y), c(y), 0], [0, 0, 1]])
    np.testing.assert_allclose(geo.R_from_euler([r, p, y]), Rz @ Ry @ Rx, atol=1e-15)
    np.testing.assert_allclose(geo.euler_from_R(Rz @ Ry @ Rx), [r, p, y], atol=1e-14)


def test_invert_compose_exp_log_skew():
    """invert_T is the matrix inverse; exp(log R) = R; skew(v) w = v x w."""
    rng = np.random.default_rng(1)
    T = _random_T(rng, 5)
    np.testing.assert_allclose(geo.invert_T(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-14)
    np.testing.assert_allclose(geo.invert_T(T), np.linalg.inv(T), atol=1e-13)
    rvec = geo.rvec_from_R(T[:, :3, :3])
    np.testing.assert_allclose(geo.R_from_rvec(rvec), T[:, :3, :3], atol=1e-14)
    v, w = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    np.testing.assert_allclose((geo.skew(v) @ w[..., None])[..., 0], np.cross(v, w), atol=1e-15)
    np.testing.assert_allclose(geo.pose_difference(T, T), np.broadcast_to(np.eye(4), T.shape), atol=1e-14)


def test_rotation_means_agree_and_ignore_quaternion_sign():
    """The chordal mean (scipy) and the quaternion block mean agree on a small spread, and the
    block mean does not care whether a sample comes as q or -q."""
    rng = np.random.default_rng(2)
    centre = Rotation.from_rotvec([0.4, -1.0, 2.5])
    R = (centre * Rotation.from_rotvec(rng.normal(0.0, 0.02, (10, 3)))).as_matrix()
    q = Rotation.from_matrix(R).as_quat()
    q[::3] *= -1.0
    q_mean = geo.block_mean_quats(q[None])[0]
    R_chordal = geo.mean_rotation(R)
    assert geo.rotation_angle(Rotation.from_quat(q_mean).as_matrix().T @ R_chordal) < 1e-6
    assert geo.rotation_angle(centre.as_matrix().T @ R_chordal) < 0.02


# ------------------------------------------------------------------ rigid fit


def test_fit_rigid_recovers_a_known_transform_per_frame():
    """Noise-free markers give back T_W_body to 1e-12, with a hidden marker, and rms ~ 0."""
    rng = np.random.default_rng(3)
    T_true = _random_T(rng, 6)
    Q = geo.transform_points(T_true[:, None], LAYOUT_M[None])
    Q[2, 1] = np.nan  # one marker unseen: three are left
    T, rms, n_used = geo.fit_rigid(LAYOUT_M, Q)
    np.testing.assert_allclose(T, T_true, atol=1e-12)
    assert np.all(rms < 1e-12) and list(n_used) == [4, 4, 3, 4, 4, 4]


def test_fit_rigid_refuses_degenerate_and_umeyama_agrees_with_it():
    """Collinear markers give NaN; Umeyama's single-set form agrees with the batched fit (not
    bitwise: another summation order) and both are proper rotations on noisy data."""
    rng = np.random.default_rng(4)
    line = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.3, 0.0, 0.0]])
    T_line, rms, _ = geo.fit_rigid(line, geo.transform_points(_random_T(rng, 1)[:, None], line[None]))
    assert np.isnan(T_line).all() and np.isnan(rms).all()
    T_true = _random_T(rng, 1)[0]
    Q = geo.transform_points(T_true, LAYOUT_M) + rng.normal(0.0, 1e-3, LAYOUT_M.shape)
    T_pair, s = geo.umeyama(LAYOUT_M, Q)
    T_batch = geo.fit_rigid(LAYOUT_M, Q[None])[0][0]
    np.testing.assert_allclose(T_pair, T_batch, atol=1e-13)
    assert s == 1.0 and np.linalg.det(T_pair[:3, :3]) == pytest.approx(1.0)
    assert np.linalg.norm(T_pair[:3, 3] - T_true[:3, 3]) < 3e-3


def test_umeyama_with_scale_and_its_refusals():
    """Sim(3): a known similarity is recovered exactly; a mirrored set still gives a rotation;
    points on one spot are refused."""
    rng = np.random.default_rng(9)
    T_true = _random_T(rng, 1)[0]
    p = rng.normal(size=(20, 3))
    q = 2.5 * p @ T_true[:3, :3].T + T_true[:3, 3]
    T, s = geo.umeyama(p, q, with_scale=True)
    assert s == pytest.approx(2.5, rel=1e-12)
    np.testing.assert_allclose(T, T_true, atol=1e-12)
    T_m, _ = geo.umeyama(p, p * [1.0, 1.0, -1.0])
    assert np.linalg.det(T_m[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(Exception, match="coincide"):
        geo.umeyama(np.ones((4, 3)), p[:4])
    M = rng.normal(size=(5, 3, 3))
    np.testing.assert_array_equal(geo.project_SO3(M)[2], geo.project_SO3(M[2]))


# ------------------------------------------------------------------ interpolation


def test_interpolate_T_equals_scipy_slerp_and_linear_translation():
    """Rotations equal scipy's Slerp, translations the linear blend; outside the samples and
    next to an invalid sample the result is NaN and not ok."""
    rng = np.random.default_rng(5)
    t = np.arange(6) * 0.1
    T = _random_T(rng, 6)
    valid = np.array([True, True, True, True, False, True])
    tq = np.array([0.0, 0.03, 0.17, 0.25, 0.28, 0.35, 0.6, 0.61, -0.01])
    T_at, ok, near = geo.interpolate_T(t, T, valid, tq)
    assert list(ok) == [True, True, True, True, True, False, False, False, False]
    ref = Slerp(t[:4], Rotation.from_matrix(T[:4, :3, :3]))(tq[:5]).as_matrix()
    np.testing.assert_allclose(T_at[:5, :3, :3], ref, atol=1e-12)
    f = (tq[2] - t[1]) / (t[2] - t[1])
    np.testing.assert_allclose(T_at[2, :3, 3], (1 - f) * T[1, :3, 3] + f * T[2, :3, 3], atol=1e-15)
    assert np.isnan(T_at[~ok]).all()
    assert list(near[:4]) == [0, 0, 2, 2]
    with pytest.raises(MocapError, match="at least 2 samples"):
        geo.interpolate_T(t[:1], T[:1], valid[:1], tq)


def test_interpolate_quats_equals_scipy_slerp():
    """The quaternion form gives the rotations of scipy's Slerp (up to the sign of q)."""
    rng = np.random.default_rng(6)
    t = np.array([0.0, 0.5, 1.0, 2.0])
    rots = Rotation.random(4, random_state=rng)
    tq = np.linspace(0.0, 2.0, 9)
    q, ok = geo.interpolate_quats(t, rots.as_quat(), np.ones(4, bool), tq)
    assert ok.all()
    ref = Slerp(t, rots)(tq)
    assert np.all((Rotation.from_quat(q) * ref.inv()).magnitude() < 1e-12)


def test_sample_period_is_the_median_spacing():
    """30 fps frames with two dropped and one late stamp keep their 1/30 s period; unsorted
    times are sorted first; fewer than two samples give the default."""
    rng = np.random.default_rng(8)
    t = np.delete(np.arange(100) / 30.0, [10, 11])
    t[40] += 0.004
    assert geo.sample_period(t) == pytest.approx(1 / 30.0, abs=1e-12)
    assert geo.sample_period(rng.permutation(t)) == geo.sample_period(t)
    assert np.isnan(geo.sample_period([1.0])) and geo.sample_period([], default=1.0) == 1.0


# ------------------------------------------------------------------ camera model


def _points_C(rng, n=40):
    return np.column_stack([rng.uniform(-0.6, 0.6, (n, 2)), rng.uniform(0.8, 3.0, n)])


def test_projection_equals_opencv_project_points():
    """project_points and project_points_jac's pixels equal cv2.projectPoints to 1e-9 px."""
    rng = np.random.default_rng(7)
    p_C = _points_C(rng)
    uv_cv, _ = cv2.projectPoints(p_C.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, DIST)
    np.testing.assert_allclose(geo.project_points(p_C, K, DIST), uv_cv[:, 0], atol=1e-9)
    np.testing.assert_allclose(geo.project_points_jac(p_C, K, DIST)[0], uv_cv[:, 0], atol=1e-9)


def test_projection_jacobian_matches_opencv_and_finite_differences():
    """d(uv)/dp equals OpenCV's d(uv)/d(tvec) (p = R p_B + t) and central differences; the
    intrinsics' columns equal OpenCV's f, c and distortion columns."""
    rng = np.random.default_rng(8)
    p_B = _points_C(rng, 12) - [0.0, 0.0, 1.5]
    rvec, tvec = np.array([0.2, -0.3, 0.1]), np.array([0.05, -0.02, 1.6])
    p_C = geo.transform_points(geo.T_from_rvec_tvec(rvec, tvec), p_B)
    _, J_p, J_i = geo.project_points_jac(p_C, K, DIST)
    _, jac = cv2.projectPoints(p_B.reshape(-1, 1, 3), rvec, tvec, K, DIST)
    jac = jac.reshape(-1, 2, jac.shape[1])
    np.testing.assert_allclose(J_p, jac[:, :, 3:6], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(J_i, jac[:, :, 6:15], rtol=1e-6, atol=1e-6)
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        fd = (geo.project_points(p_C + d, K, DIST) - geo.project_points(p_C - d, K, DIST)) / (2 * h)
        np.testing.assert_allclose(J_p[:, :, k], fd, rtol=1e-6, atol=1e-4)


@pytest.mark.parametrize("side", ["right", "left"])
def test_euler_jacobian_against_finite_differences(side):
    rng = np.random.default_rng(11)
    R = Rotation.random(6, random_state=rng).as_matrix()
    R[0] = geo.R_from_euler(np.array([-1.5708, 0.1, -1.5708]))  # the demo's mounting, roll -90
    J = geo.euler_jacobian(R, side=side)
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        Rp, Rm = Rotation.from_rotvec(d).as_matrix(), Rotation.from_rotvec(-d).as_matrix()
        if side == "right":
            plus, minus = R @ Rp, R @ Rm
        else:
            plus, minus = Rp @ R, Rm @ R
        fd = geo.wrap_angle(geo.euler_from_R(plus) - geo.euler_from_R(minus)) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], fd, atol=1e-6)
    np.testing.assert_allclose(geo.euler_jacobian(R[0], side=side), J[0])
    with pytest.raises(ValueError, match="side"):
        geo.euler_jacobian(R, side="middle")


def test_pose_curve_is_interpolate_T_and_ignores_sign_flips():
    """PoseCurve's poses are interpolate_T's (SLERP through rotation matrices: no quaternion
    signs), its rates the segment's, and outside / gap queries are told apart."""
    from cvsflow.geometry import PoseCurve, R_from_rvec, interpolate_T, make_T

    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.008, 0.012, 50))
    T = make_T(R_from_rvec(np.cumsum(rng.normal(0, 0.05, (50, 3)), axis=0)), rng.normal(0, 1, (50, 3)))
    tq = np.sort(rng.uniform(t[0] - 0.05, t[-1] + 0.05, 200))
    R, p, _, _, status = PoseCurve(t, T, max_gap_s=1.0).at(tq)
    T_ref, ok, _ = interpolate_T(t, T, np.ones(50, bool), tq)
    assert np.array_equal(status == 0, ok) and set(np.unique(status[~ok])) == {1}
    np.testing.assert_allclose(R[ok], T_ref[ok, :3, :3], atol=1e-12)
    np.testing.assert_allclose(p[ok], T_ref[ok, :3, 3], atol=1e-12)
    t2 = np.array([0.0, 0.01, 0.02, 0.5, 0.51])
    T2 = make_T(R_from_rvec(np.outer(t2, [0, 0, 1.0])), np.outer(t2, [2.0, 0, 0]))
    _, _, omega, v, status = PoseCurve(t2, T2).at(np.array([0.005, 0.2, 0.505, 0.6]))
    assert status.tolist() == [0, 2, 0, 1]
    np.testing.assert_allclose(omega[0], [0, 0, 1.0], atol=1e-12)
    np.testing.assert_allclose(v[0], [2.0, 0, 0], atol=1e-12)


def test_right_jacobian_inverse_inverts_the_right_jacobian():
    """Jr^-1(w) Jr(w) = I for rotations up to 3 rad and below the series threshold."""
    from cvsflow.geometry import right_jacobian_inv_SO3, right_jacobian_SO3

    rng = np.random.default_rng(2)
    for w in [*rng.normal(0, 1.0, (5, 3)), np.array([1e-8, 0, 0]), np.array([0, 3.0, 0])]:
        np.testing.assert_allclose(right_jacobian_inv_SO3(w) @ right_jacobian_SO3(w), np.eye(3), atol=1e-8)
