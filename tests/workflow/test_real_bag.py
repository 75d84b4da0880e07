"""A ROS bag as a workflow session: yac's frames (its JPEG files' bytes as CompressedImage) and its
two mocap bodies (PoseStamped) written by rosbags to an MCAP bag give, stage by stage, the tables
the same recording gives as a frame folder and two pose files. Skips without the shared real data."""

from __future__ import annotations

import pandas as pd
import pytest
import yaml

from tests.helpers.bags import JPEG_TOPIC, write_bag, yac_messages
from tests.helpers.real_data import need_real_file
from tests.workflow.test_real_streams import YAC, yac_session
from tests.workflow.test_workflow import snakemake, write_config


@pytest.mark.slow
def test_yac_bag_session_gives_the_files_results(tmp_path):
    """corners (exact t_ns), poses, bodies, pairs and the se3 fit of the bag session equal the
    frame folder + pose files session's; the bag's camera uses the files session's calibration."""
    root = need_real_file(f"{YAC}/cam0/data.csv").parents[1]
    bag = write_bag(tmp_path / "yac_mcap", "mcap", yac_messages(root, raw=False, tf=False))
    files = yac_session(root)
    body = {"camera_body": {"topic": "/mocap/body0/pose", "parent": "world"},
            "board_body": {"topic": "/mocap/target0/pose", "parent": "world"}}  # fmt: skip
    from_bag = {"target": files["target"], "camera": "files", "dt_offset_s": 0.0, "methods": ["se3"],
                "bag": {"path": str(bag), "image_topic": JPEG_TOPIC, **body}}  # fmt: skip
    write_config(tmp_path, {"sessions": {"files": files, "bag": from_bag}, "evaluate": {"n_boot": 200}})
    snakemake(tmp_path, *(f"results/{s}/{f}" for s in ("files", "bag") for f in ("comparison.yaml", "pairs.parquet")))
    res = tmp_path / "results"
    for table in ("corners", "poses_raw", "bodies", "bodies_30hz", "pairs"):
        a, b = (pd.read_parquet(res / s / f"{table}.parquet") for s in ("files", "bag"))
        pd.testing.assert_frame_equal(a, b, check_exact=True, obj=table)
    fits = [yaml.safe_load((res / s / "se3" / "calib" / "result.yaml").read_text()) for s in ("files", "bag")]
    for key in ("T_Cm_C", "T_Bm_B", "rms_px", "dt_offset_s"):
        assert fits[0][key] == fits[1][key], key
    summary = yaml.safe_load((res / "bag" / "corners_summary.yaml").read_text())
    assert summary["inter_coded"] is False and summary["n_found"] >= 29
    assert "bag" in (tmp_path / "logs" / "bag" / "corners.log").read_text()
