"""A real recording as a workflow session: yac's timestamped frame folder (ASL cam0) and its two
mocap pose streams (ASL CSVs: the camera's body, the target's), one clock (dt_offset_s: 0), the
grid from yac's Kalibr target file; calibrate, corners, poses, the bodies from the streams, pairs,
se3 and the held-out evaluation. Skips without the shared real data."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml

from cvsflow.geometry import rotation_angle
from tests.helpers.real_data import need_real_file
from tests.workflow.test_workflow import snakemake, write_config

YAC = "yac-mocap-aprilgrid"


def yac_session(root) -> dict:
    """The session block `cvsflow init` would write for yac, with its real paths."""
    return {"target": str(root / "calib_mocap-intel_d435i.yaml"), "calib_dir": str(root / "cam0" / "data"),
            "frames": str(root / "cam0"),
            "pose_streams": {"camera": str(root / "body0" / "data.csv"), "board": str(root / "target0" / "data.csv")},
            "dt_offset_s": 0.0, "methods": ["se3"]}  # fmt: skip


@pytest.mark.slow
def test_yac_frames_and_pose_streams_end_to_end(tmp_path):
    """Every frame paired with the mocap at its exact time; the offset held at the stated 0; a
    corner fit under 1 px; the grid's axes within 2 deg of the target body's (it was mounted
    square on it); per-frame uncertainty stated and judged on held-out frames."""
    root = need_real_file(f"{YAC}/cam0/data.csv").parents[1]
    write_config(tmp_path, {"sessions": {"yac": yac_session(root)}, "evaluate": {"n_boot": 200}})
    snakemake(tmp_path, "results/yac/comparison.yaml", "results/yac/pairs.parquet", "results/headline.csv")
    res = tmp_path / "results" / "yac"
    corners = pd.read_parquet(res / "corners.parquet")
    names = sorted(int(p.stem) for p in (root / "cam0" / "data").iterdir())
    assert sorted(corners["t_ns"].unique()) == names  # exact ns, not a float's rounding
    summary = yaml.safe_load((res / "corners_summary.yaml").read_text())
    assert summary["inter_coded"] is False and summary["n_found"] >= 29
    sync = yaml.safe_load((res / "sync.yaml").read_text())
    assert sync["method"] == "given" and sync["dt_offset_s"] == 0.0
    pairs = pd.read_parquet(res / "pairs.parquet")
    assert len(pairs) >= 29
    se3 = yaml.safe_load((res / "se3" / "calib" / "result.yaml").read_text())
    assert se3["dt_offset_s"] == 0.0 and se3["rms_px"] < 1.0
    assert np.degrees(rotation_angle(np.asarray(se3["T_Bm_B"])[:3, :3])) < 2.0
    comparison = yaml.safe_load((res.parent / "yac" / "comparison.yaml").read_text())
    assert np.isfinite(comparison["error_model"]["nees_mean"])
    headline = pd.read_csv(tmp_path / "results" / "headline.csv")
    assert "T_Cm_C z" in set(headline["quantity"])
