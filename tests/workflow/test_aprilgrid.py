"""An AprilGrid session end to end: config/aprilgrid.yaml's rendered session, its grid given as a
Kalibr target file (target:), through calibrate, corners, poses, sync, se3 and the held-out
evaluation; and the config's board and target checked at parse time."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from tests.workflow.test_workflow import REPO, dry_run_jobs, snakemake, write_config

KALIBR_TARGET = "target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0.055\ntagSpacing: 0.3\n"


def aprilgrid_config(workdir, duration_s=6.0) -> dict:
    """The AprilGrid session alone (the demo's other sections), shortened: 6 s, 10 stills, 3 folds;
    its board given by a Kalibr target file in the working directory."""
    config = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    session = yaml.safe_load((REPO / "config" / "aprilgrid.yaml").read_text())["sessions"]["aprilgrid"]
    session["synth"].update(duration_s=duration_s, n_stills=10)
    (workdir / "targets").mkdir(parents=True, exist_ok=True)
    (workdir / "targets" / "aprilgrid.yaml").write_text(KALIBR_TARGET)
    board = session.pop("board")
    assert yaml.safe_load(KALIBR_TARGET)["tagSize"] == board["tag_size_m"]
    session["target"] = "targets/aprilgrid.yaml"
    config["sessions"] = {"aprilgrid": session}
    config["flights"] = {}
    config.setdefault("evaluate", {}).update(n_folds=3, n_boot=200)
    return config


@pytest.fixture(scope="module")
def aprilgrid_run(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("aprilgrid")
    write_config(workdir, aprilgrid_config(workdir))
    snakemake(workdir, "results/aprilgrid/comparison.yaml")
    return workdir


def read(workdir, rel):
    return yaml.safe_load((workdir / rel).read_text())


def test_rendered_aprilgrid_session_recovers_the_truth(aprilgrid_run):
    """From rendered AprilGrid stills and video: the intrinsics, the mountings in Kalibr's target
    frame and the time offset against the renderer's truth; the corners summary and camera.yaml
    name the detector; the held-out evaluation ran."""
    truth = read(aprilgrid_run, "data/aprilgrid/truth.yaml")
    camera = read(aprilgrid_run, "results/aprilgrid/camera.yaml")
    assert camera["board"] == {"type": "aprilgrid", "tag_cols": 6, "tag_rows": 6, "tag_size_m": 0.055,
                               "tag_spacing": 0.3}
    np.testing.assert_allclose(np.diag(camera["K"])[:2], np.diag(truth["camera"]["K"])[:2], rtol=3e-3)
    summary = read(aprilgrid_run, "results/aprilgrid/corners_summary.yaml")
    assert summary["detector"].startswith("apriltag3") and camera["detector"] == summary["detector"]
    assert summary["frames_by_method"]["aprilgrid"] >= 0.5 * summary["n_frames_decoded"]
    se3 = read(aprilgrid_run, "results/aprilgrid/se3/calib/result.yaml")
    for name in ("T_Bm_B", "T_Cm_C"):
        T, T_true = np.asarray(se3[name]), np.asarray(truth[name])
        assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 2e-3, name
        cos = (np.trace(T[:3, :3].T @ T_true[:3, :3]) - 1) / 2
        assert np.degrees(np.arccos(min(cos, 1.0))) < 0.3, name
    assert abs(se3["dt_offset_s"] - truth["dt_offset_s"]) < 1e-3
    assert (aprilgrid_run / "results/aprilgrid/comparison.yaml").is_file()


def test_board_and_target_together_are_refused(tmp_path):
    """A session naming both a board and a target fails at parse time, naming the session."""
    config = aprilgrid_config(tmp_path)
    config["sessions"]["aprilgrid"]["board"] = {"type": "aprilgrid", "tag_cols": 6, "tag_rows": 6,
                                                "tag_size_m": 0.055, "tag_spacing": 0.3}
    write_config(tmp_path, config)
    proc = snakemake(tmp_path, "-n", check=False)
    assert proc.returncode != 0 and "aprilgrid" in proc.stdout + proc.stderr
    assert not (tmp_path / "results").exists()


def test_unsupported_target_file_is_a_named_error(tmp_path):
    """A Kalibr circle grid as the session's target: the run stops before any job, naming the
    session, the file and the target type."""
    config = aprilgrid_config(tmp_path)
    (tmp_path / "targets" / "aprilgrid.yaml").write_text(
        "target_type: circlegrid\ntargetCols: 6\ntargetRows: 7\nspacingMeters: 0.02\n")
    write_config(tmp_path, config)
    proc = snakemake(tmp_path, "-n", check=False)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert "sessions.aprilgrid.target" in out and "targets/aprilgrid.yaml" in out and "circlegrid" in out
    assert not (tmp_path / "results").exists() and not (tmp_path / "data").exists()


def test_aprilgrid_board_block_needs_its_keys(tmp_path):
    """type: aprilgrid without tag_size_m is refused by the schema, naming the key."""
    config = aprilgrid_config(tmp_path)
    session = config["sessions"]["aprilgrid"]
    session.pop("target")
    session["board"] = {"type": "aprilgrid", "tag_cols": 6, "tag_rows": 6, "tag_spacing": 0.3}
    write_config(tmp_path, config)
    proc = snakemake(tmp_path, "-n", check=False)
    assert proc.returncode != 0 and "tag_size_m" in proc.stdout + proc.stderr


def test_config_file_as_shipped_parses(tmp_path):
    """config/aprilgrid.yaml over config/config.yaml: the session's jobs are planned, se3 alone."""
    for name in ("config.yaml", "aprilgrid.yaml"):
        (tmp_path / "config").mkdir(exist_ok=True)
        (tmp_path / "config" / name).write_text((REPO / "config" / name).read_text())
    jobs = dry_run_jobs(tmp_path, "results/aprilgrid/comparison.yaml", "--configfile",
                        str(tmp_path / "config" / "config.yaml"), str(tmp_path / "config" / "aprilgrid.yaml"))
    assert {"synth", "calibrate", "corners", "optimise_se3", "heldout_se3", "compare"} <= jobs
    assert "optimise_seed" not in jobs
