"""The hand-eye from pose streams on ETH's real sets (skipped without the shared real data)."""

from __future__ import annotations

import glob

import numpy as np
import pytest

from cvsflow.handeye.stream_fit import estimate_streams
from cvsflow.handeye.stream_report import split_half_check
from cvsflow.io.mocap.formats import read_pose_stream
from cvsflow.io.mocap.streams import stream_T
from tests.helpers.real_data import REAL_DATA

ETH = REAL_DATA / "ethz-hand-eye"
SETS = {
    "prime_sense_1": ("prime_sense_color_w_vicon_1/prime_sense_1/*_W_camera_rgb_image_raw.csv",
                      "prime_sense_color_w_vicon_1/prime_sense_1/*_vicon_prime_sense.csv"),
    "5_falcon": ("5_falcon/*_W_d.csv", "5_falcon/*_vicon_falcon-*.csv"),
}  # fmt: skip


def _streams(name):
    paths = [glob.glob(str(ETH / pattern)) for pattern in SETS[name]]
    if not all(paths):
        pytest.skip(f"real data not available ({ETH})")
    cam, moc = read_pose_stream(paths[0][0]), read_pose_stream(paths[1][0])
    return cam["t_ns"].to_numpy(), stream_T(cam), moc["t_ns"].to_numpy(), stream_T(moc)


@pytest.mark.parametrize(("name", "dt_ms", "t_mm", "tol_mm"), [
    ("prime_sense_1", (10, 30), (72, 40, 26), 10),  # t_vicon = t_camera + ~19 ms
    ("5_falcon", (400, 440), (36, 41, -47), 25),  # the W_d camera, a 25 Hz Vicon
])  # fmt: skip
def test_eth_offset_and_mountings(name, dt_ms, t_mm, tol_mm):
    """ETH's sets: the offset (its sign: t_vicon = t_camera + dt) and T_Cm_C where ETH's own
    files put them, every camera pose used, errors several times the independent-residual ones."""
    res = estimate_streams(*_streams(name))
    assert dt_ms[0] < 1e3 * res.dt_offset_s < dt_ms[1] and res.dt_offset_std_s < 0.006
    np.testing.assert_allclose(1e3 * res.T_Cm_C[:3, 3], t_mm, atol=tol_mm)
    assert res.counts["n_used"] == res.counts["n_camera"]
    assert res.std["dt_offset_s"] > 3 * res.std_gn["dt_offset_s"]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SETS))
def test_eth_split_half_is_reported(name):
    """The split-half check runs on both sets and reports its z per parameter (prime_sense_1's
    halves disagree beyond their errors, 5_falcon's agree: docs in the issue note)."""
    split = split_half_check(*_streams(name))
    assert split["n"] == 13 and np.isfinite(split["mean_z2"])
