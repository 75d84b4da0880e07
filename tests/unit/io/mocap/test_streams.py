"""Pose streams: exact times, the stream table's checks and policies, the export of one body."""

import logging

import numpy as np
import pytest

from cvsflow.exceptions import PoseFormatError, PoseStreamError, QuaternionNormError, TimestampOrderError
from cvsflow.io.mocap.formats import read_mocap, read_pose_stream
from cvsflow.io.mocap.streams import STREAM_COLUMNS, stream_T, time_to_ns
from tests.helpers.real_data import need_real_file

PRIME = "ethz-hand-eye/prime_sense_color_w_vicon_1/prime_sense_1/2017-04-09-18-13-10_"


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    ("text", "unit", "ns"),
    [
        ("1491754391.84618", "s", 1491754391846180000),
        ("1606153863362296104", "ns", 1606153863362296104),
        ("1311868164.363181", "s", 1311868164363181000),
        ("0.0000000015", "s", 2),  # half to even: 1.5 ns -> 2
        ("0.0000000025", "s", 2),  # 2.5 ns -> 2
        ("1.4917543918461800e+09", "s", 1491754391846180000),
        ("-1.5", "s", -1500000000),
        ("1500", "us", 1500000),
    ],
)
def test_time_to_ns_is_exact(text, unit, ns):
    """Decimal times become integer nanoseconds exactly (half to even below 1 ns)."""
    assert time_to_ns(text, unit) == ns


def test_time_to_ns_beats_float():
    """A float round trip loses the last digits of Unix seconds; the decimal parse does not."""
    text = "1491561400.9530976"
    assert time_to_ns(text, "s") == 1491561400953097600
    assert int(round(float(text) * 1e9)) != 1491561400953097600


def test_quaternion_norm_names_the_row(tmp_path):
    """A quaternion off unit norm names its line and the count; a zero one too."""
    p = _write(tmp_path, "q.txt", "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0.0 1.01\n3.0 0 0 0 0 0 0 0.9\n")
    with pytest.raises(QuaternionNormError, match=r"q\.txt, line 2: .* norm 1\.01.*\(2 rows so"):
        read_pose_stream(p)
    p = _write(tmp_path, "z.txt", "1.0 0 0 0 0 0 0 0\n")
    with pytest.raises(QuaternionNormError, match=r"z\.txt, line 1"):
        read_pose_stream(p)


def test_small_norm_error_is_renormalised(tmp_path):
    """Rows within the tolerance (4-digit files) are renormalised and counted."""
    p = _write(tmp_path, "q.txt", "1.0 0 0 0 0.6 0 0 0.8002\n2.0 0 0 0 0 0 0 1\n")
    s = read_pose_stream(p)
    np.testing.assert_allclose(np.linalg.norm(s[["qx", "qy", "qz", "qw"]], axis=1), 1.0)
    assert s.attrs["n_quats_renormalised"] == 1


def test_backward_time_is_an_error_naming_both_lines(tmp_path):
    """A time earlier than the row before it: both lines and the count named."""
    p = _write(tmp_path, "o.txt", "2.0 0 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n3.0 2 0 0 0 0 0 1\n")
    with pytest.raises(TimestampOrderError, match=r"line 2: time 1\.000000000 s is earlier than "
                       r"line 1's 2\.000000000 s \(1 such steps\)"):  # fmt: skip
        read_pose_stream(p)


def test_repeated_stamp_keeps_the_first_with_a_warning(tmp_path, caplog):
    """Rows repeating the timestamp before them are dropped (first kept), warned and counted."""
    p = _write(tmp_path, "d.txt", "1.0 0 0 0 0 0 0 1\n1.0 0.002 0 0 0 0 0 1\n1.0 0.001 0 0 0 0 0 1\n"
                                  "2.0 1 0 0 0 0 0 1\n")  # fmt: skip
    with caplog.at_level(logging.WARNING):
        s = read_pose_stream(p)
    assert s["x_m"].tolist() == [0.0, 1.0] and s["line"].tolist() == [1, 4]
    assert s.attrs["n_duplicates_dropped"] == 2
    assert "lines 1 and 2: both at time 1.000000000 s; 2 rows" in caplog.text
    assert "up to 2 mm" in caplog.text


def test_pose_list_keeps_file_order_and_every_row(tmp_path):
    """in_time_order=False (a pose list paired by position): file order, duplicates kept."""
    p = _write(tmp_path, "o.txt", "2.0 0 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n1.0 2 0 0 0 0 0 1\n")
    s = read_pose_stream(p, in_time_order=False)
    assert s["x_m"].tolist() == [0.0, 1.0, 2.0]


def test_sign_flipped_quaternions_are_kept_and_make_the_same_rotation(tmp_path):
    """The file's quaternion sign is kept; q and -q give one rotation."""
    p = _write(tmp_path, "f.txt", "1.0 0 0 0 0 0 0.1 0.99498743710662\n2.0 0 0 0 0 0 -0.1 -0.99498743710662\n")
    s = read_pose_stream(p)
    assert s["qw"].iloc[1] < 0
    T = stream_T(s)
    np.testing.assert_allclose(T[0], T[1], atol=1e-12)


def test_position_not_finite_is_named(tmp_path):
    """A NaN position names its line."""
    p = _write(tmp_path, "n.txt", "1.0 0 0 0 0 0 0 1\n2.0 nan 0 0 0 0 0 1\n")
    with pytest.raises(PoseStreamError, match=r"n\.txt, line 2: position"):
        read_pose_stream(p)


@pytest.mark.parametrize("rel", ["yac-mocap-aprilgrid/body0/data.csv", "tum-fr2-desk/fr2_desk_groundtruth.txt"],
                         ids=["asl", "tum"])
def test_a_stream_cut_inside_its_last_row_is_read_as_far_as_it_goes(tmp_path, caplog, rel):
    """A real pose stream cut in the middle of a row (a copy interrupted): before, 'line N: 4 fields;
    expected 8', an error; now, as a motion-capture take cut short, the rows before it are read
    with a WARNING naming the line. A short row that ends its line stays an error."""
    text = need_real_file(rel).read_text()
    whole = read_pose_stream(need_real_file(rel))
    cut = text[: text.index("\n", len(text) // 2) + 9]  # 8 characters into a row
    p = _write(tmp_path, "cut" + rel[-4:], cut)
    with caplog.at_level(logging.WARNING):
        s = read_pose_stream(p)
    n_line = cut.count("\n") + 1
    assert f"line {n_line}: the file ends inside this row" in caplog.text
    np.testing.assert_array_equal(s["t_ns"].to_numpy(), whole["t_ns"].to_numpy()[: len(s)])
    assert len(s) == len(whole[whole["t_ns"] <= s["t_ns"].iloc[-1]])
    p.write_text(cut + "\n")
    with pytest.raises(PoseFormatError, match=rf"line {n_line}: \d fields; expected 8"):
        read_pose_stream(p)


def test_export_of_a_stream_is_one_body_with_exact_times(tmp_path):
    """read_mocap of a pose stream: one body named by the file stem, t_ns beside t_s."""
    p = _write(tmp_path, "body0.csv", "timestamp [ns],x,y,z,qx,qy,qz,qw\n"
                                      "1606153863362296104,1,2,3,0,0,0,1\n1606153863412387371,1,2,3,0,0,0,1\n")  # fmt: skip
    export = read_mocap(p)
    assert export.format == "asl" and export.body_names == ["body0"]
    assert export.bodies["t_ns"].tolist() == [1606153863362296104, 1606153863412387371]
    assert list(export.stream.columns) == STREAM_COLUMNS
    assert export.rate_hz == pytest.approx(1e9 / 50091267)


def test_a_marker_export_is_not_a_pose_stream(tmp_path):
    """read_pose_stream of a Nexus CSV names it a marker export."""
    p = _write(tmp_path, "v.csv", "Trajectories\n100\n,,a,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n1,0,1,2,3\n")
    with pytest.raises(PoseFormatError, match="Vicon Nexus Trajectories CSV .*a marker export, not a pose stream"):
        read_pose_stream(p)


def test_prime_sense_vicon_repeats_five_stamps():
    """ETH's prime_sense Vicon (10 ms stamps with jitter) repeats 5 stamps, the first at lines 1161/1162."""
    s = read_pose_stream(need_real_file(PRIME + "vicon_prime_sense.csv"))
    assert s.attrs["format"] == "eth" and s.attrs["n_duplicates_dropped"] == 5
    assert len(s) == 7093 - 5 and np.all(np.diff(s["t_ns"]) > 0)
    assert 1161 in s["line"].to_numpy() and 1162 not in s["line"].to_numpy()


def test_falcon_imu_odom_out_of_order_is_named():
    """The falcon's merged imu_odom stream goes back in time: an error naming the lines."""
    p = need_real_file("ethz-hand-eye/5_falcon/5_falcon_merged-2017-04-07-12-36-38_imu_odom.csv")
    with pytest.raises(TimestampOrderError, match=r"line 2: time 1491561398\.460000000 s is earlier than line 1"):
        read_pose_stream(p)
