"""ETH hand_eye_calibration CSVs: the real sets, contradictions, nanoseconds named."""

import glob

import numpy as np
import pytest

from cvsflow.exceptions import PoseFormatError
from cvsflow.io.mocap.formats import detect_format, read_pose_stream
from tests.helpers.real_data import REAL_DATA, need_real_file

PRIME = "ethz-hand-eye/prime_sense_color_w_vicon_1/prime_sense_1/2017-04-09-18-13-10_"
EUROC = ("#timestamp,p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n"
         "1403636580838555648,4.6,-1.7,0.7,0.5341,-0.1530,-0.8273,-0.0821\n")  # fmt: skip


def test_eth_camera_stream():
    """prime_sense_1's camera stream: 1533 poses, exact first time, the file's values."""
    p = need_real_file(PRIME + "W_camera_rgb_image_raw.csv")
    assert detect_format(p) == "eth"
    s = read_pose_stream(p)
    assert len(s) == 1533 and s["t_ns"].iloc[0] == 1491754391846180000
    np.testing.assert_allclose(s[["x_m", "qw"]].iloc[0], [0.14845810661944808, 0.21647370716671938])


def test_every_eth_file_is_recognised():
    """Every CSV of the ETH sets is detected as eth."""
    files = glob.glob(str(REAL_DATA / "ethz-hand-eye/**/*.csv"), recursive=True)
    if not files:
        pytest.skip("real data not available")
    assert {detect_format(f) for f in files} == {"eth"}


def test_space_separated_eth_when_named(tmp_path):
    """White-space rows are TUM under auto and read as ETH when the format says eth."""
    p = tmp_path / "s.txt"
    p.write_text("1.5 0 0 0 0 0 0 1\n1.6 0 0 0 0 0 0 1\n")
    assert detect_format(p) == "tum"
    assert read_pose_stream(p, "eth").attrs["format"] == "eth"


def test_eth_given_for_an_euroc_file_says_asl(tmp_path):
    """--pose-format eth or tum on a EuRoC file: the message names ASL/EuRoC."""
    p = tmp_path / "g.csv"
    p.write_text(EUROC)
    for fmt in ("eth", "tum"):
        with pytest.raises(PoseFormatError, match="but the file is an ASL/EuRoC pose CSV"):
            read_pose_stream(p, fmt)


def test_nanoseconds_in_a_seconds_format(tmp_path):
    """Headerless rows with ns integers: eth names the ns; auto says an ASL CSV needs a header."""
    p = tmp_path / "ns.csv"
    p.write_text("1606153863362296104,0,0,0,0,0,0,1\n1606153863412387371,0,0,0,0,0,0,1\n")
    with pytest.raises(PoseFormatError, match="nanoseconds; ETH times are in seconds"):
        read_pose_stream(p, "eth")
    with pytest.raises(PoseFormatError, match="an ASL CSV needs one"):
        read_pose_stream(p)
