"""`cvsflow export trajectory --format`: a session's and a flight's trajectories in TUM, ASL and KITTI."""

import numpy as np
import pytest

from cvsflow import cli
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.trajectory import kitti_times_path, read_trajectory, table_ns, write_tum
from tests.unit.cli.test_cli import _pairs_from_truth

POSE = ["x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]


@pytest.mark.parametrize("fmt", ["asl", "kitti"])
def test_session_trajectories_in_each_format_equal_the_tum_ones(tmp_path, capsys, fmt):
    """The same poses and the same exact times in every format; evo's command for the format."""
    pairs, *_, se3 = _pairs_from_truth()
    write_parquet(pairs, tmp_path / "pairs.parquet")
    write_yaml(se3, tmp_path / "se3" / "calib" / "result.yaml")
    assert cli.main(["export", "trajectory", str(tmp_path), "--out-dir", str(tmp_path / "tum")]) == 0
    assert cli.main(["export", "trajectory", str(tmp_path), "--out-dir", str(tmp_path / fmt), "--format", fmt]) == 0
    out = capsys.readouterr().out
    assert {"asl": "evo_ape euroc", "kitti": "evo_ape kitti"}[fmt] in out
    suffix = {"asl": ".csv", "kitti": ".kitti"}[fmt]
    for name in ("cvs_T_C_B", "vicon_T_Cm_Bm", "vicon_T_C_B"):
        a = read_trajectory(tmp_path / "tum" / f"{name}.tum", "tum")
        b = read_trajectory(tmp_path / fmt / f"{name}{suffix}", fmt)
        assert np.array_equal(a["t_ns"], b["t_ns"])
        assert np.array_equal(a["t_ns"], table_ns(pairs))  # the video clock, to the nanosecond
        np.testing.assert_allclose(b[POSE[:3]], a[POSE[:3]], rtol=0, atol=0)
        np.testing.assert_allclose(np.abs(b[POSE[3:]].to_numpy()), np.abs(a[POSE[3:]].to_numpy()), atol=1e-15)
    if fmt == "kitti":
        assert kitti_times_path(tmp_path / fmt / "cvs_T_C_B.kitti").is_file()


def test_flight_trajectories_rewritten_exactly(tmp_path, capsys):
    """A flight's three TUM files (exact ns) come out in the format asked with the same times."""
    pairs, *_ = _pairs_from_truth(12)
    from cvsflow.cli.export import FLIGHT_TRAJECTORIES, _trajectory_table, session_trajectories

    flight = tmp_path / "results" / "flights" / "f1"
    T = session_trajectories(pairs)["cvs_T_C_B"]
    table = _trajectory_table(pairs["t_s"].to_numpy(), T)
    table["t_ns"] = 1_700_000_000_000_000_001 + np.arange(len(T), dtype=np.int64) * 33_333_333
    for name in FLIGHT_TRAJECTORIES:
        write_tum(table, flight / f"{name}.tum")
    assert cli.main(["export", "trajectory", str(flight), "--out-dir", str(tmp_path / "o"), "--format", "asl"]) == 0
    assert "evo_ape euroc" in capsys.readouterr().out
    for name in FLIGHT_TRAJECTORIES:
        back = read_trajectory(tmp_path / "o" / f"{name}.csv", "asl")
        assert np.array_equal(back["t_ns"], table["t_ns"])
        assert np.array_equal(back[POSE].to_numpy(), table[POSE].to_numpy())
