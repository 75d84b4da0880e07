"""ASL / EuRoC pose CSVs: columns by name in any order, units from the header, named errors."""

import numpy as np
import pytest

from cvsflow.exceptions import InputError, MissingColumnError, PoseFormatError
from cvsflow.io.mocap.asl import read_stream
from cvsflow.io.mocap.formats import detect_format, read_pose_stream
from tests.helpers.real_data import need_real_file

EUROC_HEADER = ("#timestamp,p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],"
                "q_RS_z [],v_RS_R_x [m s^-1],v_RS_R_y [m s^-1],v_RS_R_z [m s^-1],b_w_RS_S_x [rad s^-1],"
                "b_w_RS_S_y [rad s^-1],b_w_RS_S_z [rad s^-1],b_a_RS_S_x [m s^-2],b_a_RS_S_y [m s^-2],"
                "b_a_RS_S_z [m s^-2]")  # fmt: skip
EUROC_ROW = "1403636580838555648,4.688319,-1.786938,0.783338,0.534108,-0.153029,-0.827383,-0.082152," + ",".join(["0.1"] * 9)


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_euroc_header_any_order_and_extra_columns(tmp_path):
    """EuRoC's ground truth: q_RS_w before q_RS_x, velocities and biases after; found by name."""
    p = _write(tmp_path, "data.csv", EUROC_HEADER + "\n" + EUROC_ROW + "\n")
    assert detect_format(p) == "asl"
    s = read_pose_stream(p)
    assert s["t_ns"].iloc[0] == 1403636580838555648
    q = np.array([-0.153029, -0.827383, -0.082152, 0.534108])
    np.testing.assert_allclose(s[["qx", "qy", "qz", "qw"]].iloc[0], q / np.linalg.norm(q))
    assert s.attrs["columns"]["qw"] == "q_RS_w []" and "v_RS_R_x [m s^-1]" in s.attrs["ignored_columns"]


@pytest.mark.parametrize("order", [
    ["timestamp [ns]", "x", "y", "z", "qx", "qy", "qz", "qw"],
    ["timestamp [ns]", "qw", "qx", "qy", "qz", "x", "y", "z"],
    ["x", "y", "z", "qx", "qy", "qz", "qw", "timestamp [ns]"],
    ["tx", "qz", "timestamp [ns]", "ty", "qy", "tz", "qx", "qw", "note"],
])  # fmt: skip
def test_header_orders_give_one_table(tmp_path, order):
    """The same two poses written in any column order (and with an extra column) read the same."""
    rows = [{"timestamp [ns]": "1606153863362296104", "x": "1", "tx": "1", "y": "-2", "ty": "-2",
             "z": "0.5", "tz": "0.5", "qx": "0", "qy": "0.6", "qz": "0", "qw": "0.8", "note": "7"},
            {"timestamp [ns]": "1606153863412387371", "x": "1.1", "tx": "1.1", "y": "-2", "ty": "-2",
             "z": "0.5", "tz": "0.5", "qx": "0", "qy": "0", "qz": "0", "qw": "1", "note": "8"}]  # fmt: skip
    text = ",".join(order) + "\n" + "".join(",".join(r[c] for c in order) + "\n" for r in rows)
    s = read_pose_stream(_write(tmp_path, "p.csv", text))
    assert s.attrs["format"] == "asl"
    assert s["t_ns"].tolist() == [1606153863362296104, 1606153863412387371]
    np.testing.assert_allclose(s[["x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]].to_numpy(),
                               [[1, -2, 0.5, 0, 0.6, 0, 0.8], [1.1, -2, 0.5, 0, 0, 0, 1]])  # fmt: skip


def test_units_from_the_header(tmp_path):
    """[s] times and [mm] positions are converted (exactly, for the times)."""
    p = _write(tmp_path, "mm.csv", "timestamp [s],x [mm],y [mm],z [mm],qx,qy,qz,qw\n"
                                   "12.5,1000,-500,250,0,0,0,1\n12.75,1001,-500,250,0,0,0,1\n")  # fmt: skip
    s = read_pose_stream(p, "asl")
    assert s["t_ns"].tolist() == [12_500_000_000, 12_750_000_000]
    np.testing.assert_allclose(s[["x_m", "y_m", "z_m"]].iloc[0], [1.0, -0.5, 0.25])


def test_missing_and_ambiguous_columns_are_named(tmp_path):
    """A header without qw names it (auto and asl alike); two columns for x name both."""
    p = _write(tmp_path, "m.csv", "#timestamp [ns],x,y,z,qx,qy,qz\n1,0,0,0,0,0,0\n")
    with pytest.raises(MissingColumnError, match=r"m\.csv, line 1: no column for \['qw'\]"):
        read_pose_stream(p)
    p = _write(tmp_path, "m2.csv", "#timestamp [ns],x,y,z,qx,qy,qz,w_unknown\n1,0,0,0,0,0,0,1\n")
    with pytest.raises(MissingColumnError, match=r"no column for \['qw'\]"):
        read_pose_stream(p, "asl")
    p = _write(tmp_path, "eth_hdr.csv", "timestamp, x [m], y[m], z[m], x, y, z, w\n1.5, 0, 0, 0, 0, 0, 0, 1\n")
    with pytest.raises(MissingColumnError, match="several columns"):
        read_stream(p)
    s = read_pose_stream(p)  # the ETH extractor's header: positional
    assert s.attrs["format"] == "eth" and s["t_ns"].iloc[0] == 1_500_000_000


def test_time_not_integer_ns_is_named(tmp_path):
    """A header saying ns over a decimal time names the line and what to write."""
    p = _write(tmp_path, "t.csv", "timestamp [ns],x,y,z,qx,qy,qz,qw\n1.5,0,0,0,0,0,0,1\n")
    with pytest.raises(PoseFormatError, match=r"line 2: time '1\.5' is not an integer of ns"):
        read_pose_stream(p)


def test_asl_given_for_a_tum_file_says_tum(tmp_path):
    """--pose-format asl on a TUM file: the message says it is a TUM trajectory."""
    p = _write(tmp_path, "t.txt", "# t x y z qx qy qz qw\n1.0 0 0 0 0 0 0 1\n1.1 0 0 0 0 0 0 1\n")
    with pytest.raises(PoseFormatError, match=r"says ASL/EuRoC.*but the file is a TUM trajectory"):
        read_pose_stream(p, "asl")


def test_yac_body_is_exact_ns():
    """yac's body0 (timestamp [ns],x,y,z,qx,qy,qz,qw): 19-digit times kept exactly."""
    s = read_pose_stream(need_real_file("yac-mocap-aprilgrid/body0/data.csv"))
    assert s.attrs["format"] == "asl" and s.attrs["time_unit"] == "ns"
    assert s["t_ns"].iloc[0] == 1606153863362296104 and len(s) == 6128
    np.testing.assert_allclose(np.linalg.norm(s[["qx", "qy", "qz", "qw"]], axis=1), 1.0, atol=1e-12)


def test_yac_frame_list_is_not_a_pose_stream():
    """yac's cam0/data.csv (timestamp, filename) is no pose stream: named as such."""
    with pytest.raises(InputError, match=r"cam0/data\.csv: a frame list .*not motion capture"):
        read_pose_stream(need_real_file("yac-mocap-aprilgrid/cam0/data.csv"))
