"""Trajectory files (TUM, EuRoC/ASL, KITTI + times): exact ns round trips, what evo reads, bad input."""

import numpy as np
import pandas as pd
import pytest

from cvsflow.exceptions import InputError, PoseFormatError, TimestampOrderError
from cvsflow.geometry import R_from_euler, R_from_quat, quat_from_R
from cvsflow.io import trajectory as tj

POSE = ["x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]


def table(n=50, seed=3, t0_ns=1_606_153_863_362_296_104):
    """A trajectory at Unix-epoch nanoseconds (no float holds them), random poses and signs."""
    rng = np.random.default_rng(seed)
    q = quat_from_R(R_from_euler(rng.normal(size=(n, 3))))
    q *= rng.choice([-1.0, 1.0], size=(n, 1))  # streams flip sign: kept as written
    t_ns = t0_ns + np.cumsum(rng.integers(1, 40_000_000, size=n)).astype(np.int64)
    p = rng.normal(scale=3.0, size=(n, 3))
    return pd.DataFrame({"t_ns": t_ns, "x_m": p[:, 0], "y_m": p[:, 1], "z_m": p[:, 2], "qx": q[:, 0],
                         "qy": q[:, 1], "qz": q[:, 2], "qw": q[:, 3]})


def test_seconds_text_is_exact_from_the_integer():
    """9 decimals from the integer, negative times included; a float could not hold these."""
    assert tj.seconds_text(1_606_153_863_000_000_001) == "1606153863.000000001"
    assert tj.seconds_text(-1) == "-0.000000001" and tj.seconds_text(0) == "0.000000000"
    assert tj.seconds_text(-1_500_000_000) == "-1.500000000"
    assert f"{1_606_153_863_000_000_001 / 1e9:.9f}" != "1606153863.000000001"


def test_times_from_float_seconds_are_the_nearest_nanosecond():
    """A table with only t_s writes the nearest ns of each float's exact value (what %.9f prints)."""
    t_s = np.array([0.0, 0.1, 1e9 + 0.033, 1311868163.8697, -1.5, 2.5e-9])
    got = tj.table_ns(pd.DataFrame({"t_s": t_s}))
    assert [tj.seconds_text(n) for n in got] == [f"{x:.9f}" for x in t_s]
    with pytest.raises(ValueError, match="integer nanoseconds"):
        tj.table_ns(pd.DataFrame({"t_ns": [1.5]}))


@pytest.mark.parametrize("fmt", ["tum", "asl"])
def test_tum_and_asl_round_trip_bit_exact(tmp_path, fmt):
    """Written then read (by the pose-stream reader of the format): every t_ns equal, every value
    bit-identical, the quaternion's sign as written."""
    df = table()
    path = tmp_path / f"traj{tj.SUFFIX[fmt]}"
    tj.write_trajectory(df, path, fmt)
    back = tj.read_trajectory(path, fmt)
    assert back["t_ns"].dtype == np.int64 and np.array_equal(back["t_ns"], df["t_ns"])
    assert np.array_equal(back[POSE].to_numpy(), df[POSE].to_numpy())
    assert back["t_s"].tolist() == [float(tj.seconds_text(n)) for n in df["t_ns"]]


def test_kitti_round_trip(tmp_path):
    """KITTI: times exact, positions bit-identical, rotations within 1e-15 (a matrix, not a
    quaternion, is stored); the times file sits beside the poses file."""
    df = table()
    path = tmp_path / "traj.kitti"
    tj.write_trajectory(df, path, "kitti")
    assert tj.kitti_times_path(path).name == "traj.times.txt" and tj.kitti_times_path(path).is_file()
    back = tj.read_trajectory(path, "kitti")
    assert np.array_equal(back["t_ns"], df["t_ns"])
    assert np.array_equal(back[POSE[:3]].to_numpy(), df[POSE[:3]].to_numpy())
    R0 = R_from_quat(df[POSE[3:]].to_numpy())
    assert np.abs(R_from_quat(back[POSE[3:]].to_numpy()) - R0).max() < 1e-15
    # the file holds exactly the matrices written
    M = np.loadtxt(path).reshape(-1, 3, 4)
    assert np.array_equal(M[:, :, :3], R0) and np.array_equal(M[:, :, 3], df[POSE[:3]].to_numpy())


def test_files_read_as_evo_documents_its_readers(tmp_path):
    """What evo's file_interface does (TUM: split on ' ', '#' skipped; EuRoC: '#' header skipped,
    stamps = ns / 1e9, quaternion w x y z; KITTI: 12 numbers per line) gives back our poses and
    times: single spaces, EuRoC's column order, one line per pose."""
    df = table(n=20)
    t_s = np.array([float(tj.seconds_text(n)) for n in df["t_ns"]])
    tj.write_tum(df, tmp_path / "a.tum")
    rows = [line.split(" ") for line in (tmp_path / "a.tum").read_text().splitlines() if not line.startswith("#")]
    m = np.array(rows, dtype=float)
    assert np.array_equal(m[:, 0], t_s) and np.array_equal(m[:, 1:], df[POSE].to_numpy())
    tj.write_asl(df, tmp_path / "a.csv")
    rows = [line.split(",") for line in (tmp_path / "a.csv").read_text().splitlines() if not line.startswith("#")]
    assert [int(r[0]) for r in rows] == df["t_ns"].tolist()
    m = np.array(rows, dtype=float)
    assert np.abs(m[:, 0] / 1e9 - t_s).max() < 1e-6  # evo's stamps: a float of ns over 1e9
    assert np.array_equal(m[:, 1:4], df[POSE[:3]].to_numpy())
    assert np.array_equal(m[:, 4:8], df[["qw", "qx", "qy", "qz"]].to_numpy())
    tj.write_kitti(df, tmp_path / "a.kitti")
    rows = [line.split(" ") for line in (tmp_path / "a.kitti").read_text().splitlines()]
    assert np.array(rows, dtype=float).shape == (20, 12)


def test_evo_reads_what_cvsflow_writes(tmp_path):
    """evo itself (a test-only check: evo is GPL-3.0 and never a dependency) reads the three files
    to the same poses and times."""
    fi = pytest.importorskip("evo.tools.file_interface")
    df = table(n=20)
    t_s = np.array([float(tj.seconds_text(n)) for n in df["t_ns"]])
    tj.write_tum(df, tmp_path / "a.tum")
    tj.write_asl(df, tmp_path / "a.csv")
    tj.write_kitti(df, tmp_path / "a.kitti")
    traj = fi.read_tum_trajectory_file(str(tmp_path / "a.tum"))
    assert np.array_equal(traj.timestamps, t_s)
    assert np.array_equal(traj.positions_xyz, df[POSE[:3]].to_numpy())
    assert np.array_equal(traj.orientations_quat_wxyz, df[["qw", "qx", "qy", "qz"]].to_numpy())
    euroc = fi.read_euroc_csv_trajectory(str(tmp_path / "a.csv"))
    assert np.abs(euroc.timestamps - t_s).max() < 1e-6  # evo divides a float by 1e9
    assert np.array_equal(euroc.positions_xyz, df[POSE[:3]].to_numpy())
    kitti = fi.read_kitti_poses_file(str(tmp_path / "a.kitti"))
    assert np.abs(kitti.positions_xyz - df[POSE[:3]].to_numpy()).max() == 0.0


def test_invalid_rows_are_left_out_and_nan_rows_refused(tmp_path):
    """Rows flagged not valid are not written; a NaN pose in a valid row is refused with no file."""
    df = table(n=10)
    df["pos_valid"] = True
    df["rot_valid"] = True
    df.loc[4, "rot_valid"] = False
    tj.write_tum(df, tmp_path / "a.tum")
    assert len(tj.read_trajectory(tmp_path / "a.tum", "tum")) == 9
    df.loc[6, "x_m"] = np.nan
    with pytest.raises(ValueError, match="row 6"):
        tj.write_asl(df, tmp_path / "b.csv")
    assert not (tmp_path / "b.csv").exists()


def test_kitti_bad_input_is_named(tmp_path):
    """No times file, a short line, a count mismatch, a matrix that is not a rotation, times
    going back: each a named error with the file and line."""
    df = table(n=5)
    path = tmp_path / "k.kitti"
    tj.write_kitti(df, path)
    times = tj.kitti_times_path(path)
    good = times.read_text()
    times.unlink()
    with pytest.raises(InputError, match="KITTI poses carry no times"):
        tj.read_kitti(path)
    times.write_text(good.splitlines()[0] + "\n")
    with pytest.raises(PoseFormatError, match="1 times for the 5 poses"):
        tj.read_kitti(path)
    times.write_text("\n".join(reversed(good.splitlines())) + "\n")
    with pytest.raises(TimestampOrderError, match="line 2"):
        tj.read_kitti(path)
    times.write_text(good)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], "1 0 0 0 0 1 0 0 0 0 1", *lines[2:]]) + "\n")
    with pytest.raises(PoseFormatError, match="line 2: 11 fields; expected 12"):
        tj.read_kitti(path)
    path.write_text("\n".join([lines[0], "2 0 0 0 0 1 0 0 0 0 1 0", *lines[2:]]) + "\n")
    with pytest.raises(PoseFormatError, match="line 2: the 3x3 part is not a rotation"):
        tj.read_kitti(path)
    with pytest.raises(InputError, match="expected one of"):
        tj.read_trajectory(path, "euroc")
