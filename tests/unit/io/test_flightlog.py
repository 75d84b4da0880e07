"""Tests of cvsflow.io.flightlog: PX4 ULog, generic CSV and TUM readers, TUM writer."""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd
import pytest

from cvsflow.exceptions import InputError
from cvsflow.geometry.transforms import R_from_euler, R_from_quat, quat_from_R
from cvsflow.io.flightlog import read_csv_log, read_tum, read_ulog, read_ulog_topic, write_tum
from tests.helpers.real_data import REAL_DATA

REAL = REAL_DATA
PX4 = REAL / "px4"
TUM = REAL / "tum-fr2-desk"


@pytest.fixture(scope="module")
def px4():
    """The two real PX4 logs (pyulog's test files); skip when absent."""
    if not PX4.is_dir():
        pytest.skip(f"real data not found at {PX4}")
    return PX4


def test_ulog_small_counts_spans_and_flags(px4, caplog):
    """sample_log_small.ulg: 1298 attitude / 636 position samples, spans of SOURCES.md §4,
    effective span 6.496 s (not the 1174 s header), xy invalid -> x, y NaN, warned."""
    with caplog.at_level(logging.WARNING, logger="cvsflow.io.flightlog"):
        df = read_ulog(px4 / "sample_log_small.ulg")
    a = df.attrs
    assert a["topics"]["vehicle_attitude"]["n"] == 1298
    assert a["topics"]["vehicle_attitude"]["t_first_us"] == 20326716
    assert a["topics"]["vehicle_attitude"]["t_last_us"] == 26822868
    assert a["topics"]["vehicle_local_position"]["n"] == 636
    assert a["topics"]["vehicle_local_position"]["t_first_us"] == 20321827
    assert a["topics"]["vehicle_local_position"]["t_last_us"] == 26817979
    assert len(df) == 1298
    assert a["span_s"] == pytest.approx(6.496, abs=1e-3)
    assert a["header_duration_s"] == pytest.approx(1174.058, abs=1e-3)
    assert a["xy_valid_fraction"] == 0.0 and a["z_valid_fraction"] == 1.0
    assert df["x_m"].isna().all() and df["y_m"].isna().all() and not df["pos_valid"].any()
    assert df["rot_valid"].all() and df["z_valid"].sum() > 1290
    z = df["z_m"].dropna()
    assert z.min() >= -1.1832 and z.max() <= -0.1325  # SOURCES.md: z from -1.183 to -0.133 m
    assert "xy_valid = 0 in 636 of 636" in caplog.text
    assert "header spans 1174.058 s" in caplog.text
    np.testing.assert_allclose(np.linalg.norm(df[["qx", "qy", "qz", "qw"]], axis=1), 1.0, atol=1e-9)


def test_ulog_quaternion_is_reordered_to_scalar_last(px4):
    """PX4 q[0..3] = (w, x, y, z) becomes (qx, qy, qz, qw): qw equals q[0] of the raw topic."""
    raw = read_ulog_topic(px4 / "sample_log_small.ulg", "vehicle_attitude")
    df = read_ulog(px4 / "sample_log_small.ulg")
    q_raw = raw[["q[0]", "q[1]", "q[2]", "q[3]"]].to_numpy(float)
    q_raw = q_raw / np.linalg.norm(q_raw, axis=1, keepdims=True)
    q_raw *= np.sign(q_raw[:, :1])
    np.testing.assert_allclose(df["qw"], q_raw[:, 0], atol=1e-7)
    np.testing.assert_allclose(df[["qx", "qy", "qz"]], q_raw[:, 1:], atol=1e-7)
    # the vehicle sits near level before take-off: roll and pitch within 10 deg
    R = R_from_quat(df[["qx", "qy", "qz", "qw"]].to_numpy()[:1])[0]
    assert np.rad2deg(np.arccos(np.clip(R[2, 2], -1, 1))) < 10.0


def test_ulog_appended_multiple(px4):
    """sample_appended_multiple.ulg: 306 attitude, 95 position samples, 9.780 s, xy invalid."""
    df = read_ulog(px4 / "sample_appended_multiple.ulg")
    a = df.attrs
    assert a["topics"]["vehicle_attitude"]["n"] == 306
    assert (
        a["topics"]["vehicle_attitude"]["t_first_us"],
        a["topics"]["vehicle_attitude"]["t_last_us"],
    ) == (12263164, 21872804)
    assert a["topics"]["vehicle_local_position"]["n"] == 95
    assert (
        a["topics"]["vehicle_local_position"]["t_first_us"],
        a["topics"]["vehicle_local_position"]["t_last_us"],
    ) == (12263164, 21803961)
    assert a["header_duration_s"] == pytest.approx(9.780, abs=1e-3)
    assert not df["pos_valid"].any() and df["x_m"].isna().all()
    z = df["z_m"].dropna()
    assert z.min() >= -0.4747 and z.max() <= -0.2321


def test_ulog_bad_inputs(px4, tmp_path):
    """A non-ULog file, a missing topic and an unknown source are InputErrors naming the file."""
    bad = tmp_path / "bad.ulg"
    bad.write_bytes(b"not a ulog at all")
    with pytest.raises(InputError, match="bad.ulg: not a readable PX4 ULog"):
        read_ulog(bad)
    with pytest.raises(InputError, match="topic vehicle_odometry.*not in the log"):
        read_ulog(px4 / "sample_log_small.ulg", source="odometry")
    with pytest.raises(InputError, match="source="):
        read_ulog(px4 / "sample_log_small.ulg", source="gps")
    with pytest.raises(InputError, match="file not found"):
        read_ulog(tmp_path / "none.ulg")


def test_tum_read_groundtruth(tmp_path):
    """fr2_desk_groundtruth.txt: 3 comment lines skipped, 20957 poses of which one repeats the
    stamp before it (dropped, counted), first and last stamps exact."""
    if not TUM.is_dir():
        pytest.skip(f"real data not found at {TUM}")
    df = read_tum(TUM / "fr2_desk_groundtruth.txt")
    assert len(df) == 20956 and df.attrs["n_duplicates_dropped"] == 1
    assert df["t_ns"].iloc[0] == 1311868163869700000 and df["t_ns"].iloc[-1] == 1311868263234200000
    assert df["t_s"].iloc[0] == pytest.approx(1311868163.8697, abs=1e-6)
    assert df["t_s"].iloc[-1] == pytest.approx(1311868263.2342, abs=1e-6)
    assert df["x_m"].iloc[0] == -0.1357 and df["z_m"].iloc[0] == 1.4764
    # the file's first quaternion has qw < 0; stored sign-normalised (same rotation)
    q0 = np.array([0.6453, -0.5498, 0.3363, -0.4101])
    q0 /= np.linalg.norm(q0)
    np.testing.assert_allclose(df[["qx", "qy", "qz", "qw"]].iloc[0], -q0, atol=1e-12)
    assert len(read_tum(TUM / "fr2_desk_ORB.txt")) == 2893
    assert len(read_tum(TUM / "fr2_desk_ORB_kf_mono.txt")) == 157


def test_tum_round_trip(tmp_path):
    """write_tum then read_tum gives the same poses (1e-8), drops invalid rows, atomic write."""
    rng = np.random.default_rng(11)
    q = quat_from_R(R_from_euler(rng.normal(size=(20, 3))))
    df = pd.DataFrame(
        {
            "t_s": 1e9 + np.arange(20) * 0.033,
            "x_m": rng.normal(size=20),
            "y_m": rng.normal(size=20),
            "z_m": rng.normal(size=20),
            "qx": q[:, 0],
            "qy": q[:, 1],
            "qz": q[:, 2],
            "qw": q[:, 3],
            "pos_valid": True,
            "rot_valid": True,
        }
    )
    df.loc[3, "pos_valid"] = False
    path = tmp_path / "out" / "est.txt"
    write_tum(df, path)
    back = read_tum(path)
    assert len(back) == 19
    keep = df.drop(index=3).reset_index(drop=True)
    np.testing.assert_allclose(
        back[["t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]],
        keep[["t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]],
        atol=1e-8,
    )
    assert [p.name for p in path.parent.iterdir()] == ["est.txt"]


def test_tum_bad_line(tmp_path):
    """A TUM line with 7 fields is an InputError naming the file and line number."""
    p = tmp_path / "t.txt"
    p.write_text("# c\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n")
    with pytest.raises(InputError, match=r"t.txt, line 3: 7 fields; expected 8"):
        read_tum(p)
    p.write_text("1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 x\n")
    with pytest.raises(InputError, match="line 2: not a number"):
        read_tum(p)


def test_csv_units_and_rotation_conventions(tmp_path):
    """CSV in ms, mm and degrees (Euler rpy) and quat_wxyz give the same SI poses (1e-12)."""
    rng = np.random.default_rng(12)
    n = 15
    t = np.arange(n) * 0.01
    p = rng.normal(size=(n, 3))
    rpy = rng.uniform(-1.0, 1.0, size=(n, 3))
    q = quat_from_R(R_from_euler(rpy))
    pd.DataFrame(
        {
            "time": t * 1e3,
            "px": p[:, 0] * 1e3,
            "py": p[:, 1] * 1e3,
            "pz": p[:, 2] * 1e3,
            "r": np.rad2deg(rpy[:, 0]),
            "pi": np.rad2deg(rpy[:, 1]),
            "ya": np.rad2deg(rpy[:, 2]),
        }
    ).to_csv(tmp_path / "e.csv", index=False)
    a = read_csv_log(
        tmp_path / "e.csv",
        {
            "time_col": "time",
            "time_unit": "ms",
            "pos_cols": ["px", "py", "pz"],
            "pos_unit": "mm",
            "rot": "euler_rpy",
            "rot_cols": ["r", "pi", "ya"],
            "angle_unit": "deg",
        },
    )
    np.testing.assert_allclose(a["t_s"], t, atol=1e-12)
    np.testing.assert_allclose(a[["x_m", "y_m", "z_m"]], p, atol=1e-12)
    np.testing.assert_allclose(a[["qx", "qy", "qz", "qw"]], q, atol=1e-12)
    pd.DataFrame(
        {
            "t": t * 1e6,
            "x": p[:, 0],
            "y": p[:, 1],
            "z": p[:, 2],
            "w": q[:, 3],
            "i": q[:, 0],
            "j": q[:, 1],
            "k": q[:, 2],
        }
    ).to_csv(tmp_path / "q.csv", index=False)
    b = read_csv_log(
        tmp_path / "q.csv",
        {"time_unit": "us", "rot": "quat_wxyz", "rot_cols": ["w", "i", "j", "k"]},
    )
    np.testing.assert_allclose(b[["qx", "qy", "qz", "qw"]], q, atol=1e-12)
    assert b.attrs["source"] == "csv" and b["pos_valid"].all()


def test_csv_bad_inputs(tmp_path, caplog):
    """Missing column, non-numeric cell (row named), bad unit are InputErrors; empty cells warn."""
    p = tmp_path / "c.csv"
    p.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.1,1,,0,0,0,0,1\n0.2,abc,0,0,0,0,0,1\n")
    with pytest.raises(InputError, match=r"c.csv, row 4, column x: 'abc' is not a number"):
        read_csv_log(p)
    p.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n0.1,1,,0,0,0,0,1\n")
    with caplog.at_level(logging.WARNING, logger="cvsflow.io.flightlog"):
        df = read_csv_log(p)
    assert list(df["pos_valid"]) == [True, False] and "1 of 2 rows" in caplog.text
    with pytest.raises(InputError, match=r"header lacks column\(s\) \['roll'\]"):
        read_csv_log(p, {"rot": "euler_rpy", "rot_cols": ["roll", "qx", "qy"]})
    with pytest.raises(InputError, match="pos_unit='ft'"):
        read_csv_log(p, {"pos_unit": "ft"})
