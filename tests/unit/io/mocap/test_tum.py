"""TUM trajectories: exact times, the fr2_desk files, contradictions named."""

import pytest

from cvsflow.exceptions import PoseFormatError
from cvsflow.io.mocap.formats import detect_format, read_pose_stream
from tests.helpers.real_data import need_real_file


def test_tum_real_file_exact_times():
    """fr2_desk_ORB.txt: TUM, the first time exact to the ns."""
    p = need_real_file("tum-fr2-desk/fr2_desk_ORB.txt")
    s = read_pose_stream(p)
    assert s.attrs["format"] == "tum" and s["t_ns"].iloc[0] == 1311868164363181000


def test_tum_ground_truth_duplicate_is_dropped():
    """fr2_desk_groundtruth.txt repeats one stamp (lines 10862/10863): the first kept."""
    s = read_pose_stream(need_real_file("tum-fr2-desk/fr2_desk_groundtruth.txt"))
    assert s.attrs["n_duplicates_dropped"] == 1 and len(s) == 20957 - 1


def test_tum_given_for_an_eth_file_says_eth(tmp_path):
    """--pose-format tum on comma-separated rows: the message names ETH."""
    p = tmp_path / "e.csv"
    p.write_text("1.0, 0, 0, 0, 0, 0, 0, 1\n1.1, 0, 0, 0, 0, 0, 0, 1\n")
    assert detect_format(p) == "eth"
    with pytest.raises(PoseFormatError, match=r"says TUM trajectory.*but the file is an ETH hand_eye_calibration CSV"):
        read_pose_stream(p, "tum")


def test_wrong_field_count_names_the_line(tmp_path):
    """A row of 7 numbers names its line."""
    p = tmp_path / "t.txt"
    p.write_text("1.0 0 0 0 0 0 0 1\n1.1 0 0 0 0 0 1\n")
    with pytest.raises(PoseFormatError, match=r"t\.txt, line 2: 7 fields; expected 8"):
        read_pose_stream(p)
