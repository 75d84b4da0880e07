"""bodies_from_streams: two pose streams (own times) as one bodies table on the camera's times."""

import numpy as np
import pytest

from cvsflow.exceptions import MocapError
from cvsflow.geometry import R_from_rvec, make_T
from cvsflow.mocap import bodies_from_streams, body_poses


def rot_z(a):
    return R_from_rvec(np.array([0.0, 0.0, a]))


def _line(t_ns, v_m_s, yaw_rad_s):
    """Poses moving along x at v and turning about z at yaw_rad_s, at times t_ns (from 0)."""
    t = (np.asarray(t_ns) - t_ns[0]) / 1e9
    return np.stack([make_T(rot_z(yaw_rad_s * s), [v_m_s * s, 0.0, 1.0]) for s in t])


def test_board_interpolated_at_the_camera_times():
    """The camera's samples are kept as recorded (exact t_ns); the board's pose, sampled at other
    times, is interpolated at them (exact for uniform motion) and invalid outside its stream."""
    t0 = 1_606_153_863_362_296_104
    t_cam = t0 + np.arange(0, 2_000_000_000, 50_000_000, dtype=np.int64)  # 20 Hz over 2 s
    t_brd = t0 + 12_345_678 + np.arange(0, 1_500_000_000, 10_000_000, dtype=np.int64)  # 100 Hz, later start
    T_cam = _line(t_cam, 0.2, 0.1)
    T_brd = _line(t_brd, 0.5, -0.3)
    bodies = bodies_from_streams(t_cam, T_cam, t_brd, T_brd)
    assert bodies["t_ns"].dtype == np.int64
    np.testing.assert_array_equal(bodies.loc[bodies["body"] == "camera", "t_ns"], t_cam)
    t_s, T_c, ok_c = body_poses(bodies, "camera")
    np.testing.assert_allclose(T_c, T_cam, atol=1e-12)
    assert ok_c.all()
    _, T_b, ok_b = body_poses(bodies, "board")
    inside = (t_cam >= t_brd[0]) & (t_cam <= t_brd[-1])
    np.testing.assert_array_equal(ok_b, inside)
    s = (t_cam[inside] - t_brd[0]) / 1e9
    expected = np.stack([make_T(rot_z(-0.3 * x), [0.5 * x, 0.0, 1.0]) for x in s])
    np.testing.assert_allclose(T_b[inside], expected, atol=1e-9)
    assert bodies.attrs["rate_hz"] == pytest.approx(20.0)


def test_static_board_of_one_sample_and_streams_that_miss_each_other():
    """A board stream of one sample holds the board there; streams without common times are an
    error naming both spans."""
    t_cam = np.array([10, 20, 30], dtype=np.int64) * 1_000_000_000
    T = _line(t_cam, 0.1, 0.0)
    bodies = bodies_from_streams(t_cam, T, t_cam[:1], T[:1])
    _, T_b, ok = body_poses(bodies, "board")
    assert ok.all() and np.allclose(T_b, T[0])
    spans = r"\(40000000000 to 50000000000 ns\) covers none .* \(10000000000 to 30000000000 ns\)"
    with pytest.raises(MocapError, match=spans):
        bodies_from_streams(t_cam, T, t_cam[:2] + 30_000_000_000, T[:2])
