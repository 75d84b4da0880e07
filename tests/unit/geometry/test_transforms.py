"""Property tests of cvsflow.geometry.transforms: inverses, round trips, composition, conventions."""

from __future__ import annotations

import numpy as np
import pytest

from cvsflow.geometry import transforms as tf


def _Rx(a):
    """Rotation about x by a (rad), written out by hand."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _Ry(a):
    """Rotation about y by a (rad), written out by hand."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _Rz(a):
    """Rotation about z by a (rad), written out by hand."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _random_rpy(rng, n):
    """Roll, yaw uniform in (-pi, pi), pitch uniform in (-pi/2, pi/2)."""
    return np.column_stack(
        [rng.uniform(-np.pi, np.pi, n), rng.uniform(-np.pi / 2, np.pi / 2, n),
         rng.uniform(-np.pi, np.pi, n)]
    )


def _random_T(rng, n):
    """Random rigid transforms, shape (n, 4, 4), translations within +-2 m."""
    return tf.T_from_pose6(np.column_stack([rng.uniform(-2, 2, (n, 3)), _random_rpy(rng, n)]))


def test_euler_convention_is_Rz_Ry_Rx_built_by_hand():
    """R_from_euler([roll, pitch, yaw]) equals Rz(yaw) @ Ry(pitch) @ Rx(roll) to 1e-12."""
    rng = np.random.default_rng(0)
    rpy = _random_rpy(rng, 50)
    R = tf.R_from_euler(rpy)
    for (roll, pitch, yaw), R_i in zip(rpy, R, strict=True):
        np.testing.assert_allclose(R_i, _Rz(yaw) @ _Ry(pitch) @ _Rx(roll), atol=1e-12)


def test_single_axis_euler_angles():
    """A pure roll/pitch/yaw of 0.3 rad gives the hand-built rotation about x/y/z and back."""
    for axis, R_hand in enumerate([_Rx(0.3), _Ry(0.3), _Rz(0.3)]):
        rpy = np.zeros(3)
        rpy[axis] = 0.3
        np.testing.assert_allclose(tf.R_from_euler(rpy), R_hand, atol=1e-12)
        np.testing.assert_allclose(tf.euler_from_R(R_hand), rpy, atol=1e-12)


def test_euler_round_trip_away_from_gimbal_lock():
    """euler_from_R(R_from_euler(rpy)) returns rpy (1e-9 rad) for |pitch| < pi/2 - 1e-3."""
    rng = np.random.default_rng(1)
    rpy = _random_rpy(rng, 500)
    rpy[:, 1] = np.clip(rpy[:, 1], -np.pi / 2 + 1e-3, np.pi / 2 - 1e-3)
    np.testing.assert_allclose(tf.euler_from_R(tf.R_from_euler(rpy)), rpy, atol=1e-9)


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2, np.pi / 2 - 1e-7, -np.pi / 2 + 1e-9])
def test_euler_round_trip_near_gimbal_lock_preserves_the_rotation(pitch):
    """At and near |pitch| = pi/2, roll and yaw are not separable, but the angles returned
    rebuild the same rotation matrix (1e-6) and pitch itself is recovered (1e-6 rad)."""
    rng = np.random.default_rng(2)
    for roll, yaw in rng.uniform(-np.pi, np.pi, (20, 2)):
        R = tf.R_from_euler([roll, pitch, yaw])
        rpy = tf.euler_from_R(R)
        np.testing.assert_allclose(tf.R_from_euler(rpy), R, atol=1e-6)
        assert rpy[1] == pytest.approx(pitch, abs=1e-6)


def test_euler_ranges():
    """Returned roll and yaw lie in [-pi, pi], pitch in [-pi/2, pi/2]."""
    rng = np.random.default_rng(3)
    R = tf.R_from_rvec(rng.normal(size=(1000, 3)) * 2.0)
    rpy = tf.euler_from_R(R)
    assert np.all(np.abs(rpy[:, [0, 2]]) <= np.pi + 1e-12)
    assert np.all(np.abs(rpy[:, 1]) <= np.pi / 2 + 1e-12)


def test_invert_T_gives_identity_both_ways():
    """invert_T(T) @ T and T @ invert_T(T) are the identity (1e-12), for stacks and singles."""
    rng = np.random.default_rng(4)
    T = _random_T(rng, 100)
    eye = np.broadcast_to(np.eye(4), T.shape)
    np.testing.assert_allclose(tf.invert_T(T) @ T, eye, atol=1e-12)
    np.testing.assert_allclose(T @ tf.invert_T(T), eye, atol=1e-12)
    np.testing.assert_allclose(tf.invert_T(T[0]), np.linalg.inv(T[0]), atol=1e-12)
    np.testing.assert_allclose(tf.invert_T(tf.invert_T(T)), T, atol=1e-12)


def test_transform_points_and_composition_order():
    """T_A_C = T_A_B @ T_B_C maps points as T_A_B(T_B_C p), and T_B_A = inv(T_A_B) maps back."""
    rng = np.random.default_rng(5)
    T_A_B, T_B_C = _random_T(rng, 2)
    p_C = rng.normal(size=(30, 3))
    p_B = tf.transform_points(T_B_C, p_C)
    p_A = tf.transform_points(T_A_B, p_B)
    np.testing.assert_allclose(tf.transform_points(T_A_B @ T_B_C, p_C), p_A, atol=1e-12)
    np.testing.assert_allclose(tf.transform_points(tf.invert_T(T_A_B), p_A), p_B, atol=1e-12)
    # the other order is a different map (no accidental commutation)
    assert not np.allclose(tf.transform_points(T_B_C @ T_A_B, p_C), p_A, atol=1e-3)
    # translation of T_A_B is the origin of B seen in A
    np.testing.assert_allclose(tf.transform_points(T_A_B, np.zeros(3)), T_A_B[:3, 3])


def test_make_T_layout():
    """make_T puts R in the top-left block, t in the last column, [0 0 0 1] as last row."""
    R, t = _Rz(0.4) @ _Rx(-0.2), np.array([0.1, -2.0, 3.0])
    T = tf.make_T(R, t)
    np.testing.assert_array_equal(T[:3, :3], R)
    np.testing.assert_array_equal(T[:3, 3], t)
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])


def test_rvec_round_trip_and_rodrigues_convention():
    """R_from_rvec(rvec_from_R(R)) == R; rvec = angle * axis as in OpenCV's Rodrigues."""
    import cv2

    rng = np.random.default_rng(6)
    R = tf.R_from_euler(_random_rpy(rng, 200))
    np.testing.assert_allclose(tf.R_from_rvec(tf.rvec_from_R(R)), R, atol=1e-12)
    rvec = np.array([0.3, -0.5, 1.1])
    R_cv, _ = cv2.Rodrigues(rvec)
    np.testing.assert_allclose(tf.R_from_rvec(rvec), R_cv, atol=1e-12)
    np.testing.assert_allclose(tf.R_from_rvec(rvec) @ [0, 0, 1.0], R_cv[:, 2], atol=1e-12)


def test_T_from_rvec_tvec_round_trip():
    """rvec_tvec_from_T inverts T_from_rvec_tvec for stacks (1e-12)."""
    rng = np.random.default_rng(7)
    T = _random_T(rng, 50)
    rvec, tvec = tf.rvec_tvec_from_T(T)
    np.testing.assert_allclose(tf.T_from_rvec_tvec(rvec, tvec), T, atol=1e-12)
    T1 = tf.T_from_rvec_tvec(rvec[0], tvec[0])
    assert T1.shape == (4, 4)


def test_pose6_round_trip():
    """T_from_pose6(pose6_from_T(T)) == T for random transforms (1e-12)."""
    rng = np.random.default_rng(8)
    T = _random_T(rng, 100)
    np.testing.assert_allclose(tf.T_from_pose6(tf.pose6_from_T(T)), T, atol=1e-12)


def test_quaternion_round_trip_and_scalar_last_sign():
    """R_from_quat(quat_from_R(R)) == R, qw >= 0, and a rotation by a about z is
    (0, 0, sin(a/2), cos(a/2)) (scalar last)."""
    rng = np.random.default_rng(9)
    R = tf.R_from_euler(_random_rpy(rng, 200))
    q = tf.quat_from_R(R)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(tf.R_from_quat(q), R, atol=1e-12)
    np.testing.assert_allclose(tf.quat_from_R(_Rz(0.5)), [0, 0, np.sin(0.25), np.cos(0.25)],
                               atol=1e-12)


def test_wrap_angle_range_and_equivalence():
    """wrap_angle maps into (-pi, pi], keeps values already inside, sends -pi to pi, and
    differs from the input by a whole number of turns."""
    rng = np.random.default_rng(10)
    a = rng.uniform(-50, 50, 10000)
    w = tf.wrap_angle(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    turns = (a - w) / (2 * np.pi)
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-9)
    inside = rng.uniform(-np.pi + 1e-9, np.pi, 100)
    np.testing.assert_allclose(tf.wrap_angle(inside), inside, atol=1e-12)
    assert tf.wrap_angle(-np.pi) == pytest.approx(np.pi)
    assert tf.wrap_angle(np.pi) == pytest.approx(np.pi)
    assert tf.wrap_angle(3 * np.pi) == pytest.approx(np.pi)
    assert isinstance(tf.wrap_angle(0.5), float)


def test_rotation_angle_and_pose_difference():
    """rotation_angle(Rz(a)) == |a| for a in [-pi, pi]; pose_difference(T, T) is identity and
    pose_difference(T_ref, T_ref @ D) == D (error in the reference's own frame)."""
    for a in np.linspace(-np.pi, np.pi, 13):
        assert tf.rotation_angle(_Rz(a)) == pytest.approx(abs(a), abs=1e-9)
    rng = np.random.default_rng(11)
    T_ref, D = _random_T(rng, 2)
    np.testing.assert_allclose(tf.pose_difference(T_ref, T_ref), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(tf.pose_difference(T_ref, T_ref @ D), D, atol=1e-12)


def test_mean_rotation_of_symmetric_spread_is_the_centre():
    """The mean of R0 Rz(+a) and R0 Rz(-a) is R0 (1e-9)."""
    R0 = tf.R_from_euler([0.3, -0.2, 1.0])
    R = np.stack([R0 @ _Rz(0.2), R0 @ _Rz(-0.2)])
    np.testing.assert_allclose(tf.mean_rotation(R), R0, atol=1e-9)


def test_R_from_rvec_accepts_read_only_arrays():
    """R_from_rvec (and T_from_rvec_tvec) work on read-only arrays, as pandas returns them."""
    rvec = np.array([0.1, 0.2, 0.3])
    rvec.setflags(write=False)
    np.testing.assert_allclose(tf.R_from_rvec(rvec), tf.R_from_rvec(rvec.copy()), atol=0)


def test_pose_error_left_inverts_a_left_perturbation():
    rng = np.random.default_rng(8)
    R = tf.R_from_rvec(rng.normal(size=(5, 3)))
    T_ref = tf.make_T(R, rng.normal(size=(5, 3)))
    w, dt = 0.05 * rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    T_est = tf.make_T(tf.R_from_rvec(w) @ R, T_ref[:, :3, 3] + dt)
    np.testing.assert_allclose(tf.pose_error_left(T_est, T_ref), np.concatenate([dt, w], axis=1), atol=1e-12)
    assert tf.pose_error_left(T_est[0], T_ref[0]).shape == (6,)
    np.testing.assert_allclose(tf.pose_error_left(T_ref, T_ref), 0.0, atol=1e-15)
