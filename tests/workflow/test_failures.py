"""Workflow-side failures: each asks for something the run cannot give, and the run says so.

One test per row of docs/failures.md (workflow side): the message, and that the failed stage leaves no
result behind. The workstation profile is checked to apply to a plain `snakemake`.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from .test_workflow import REPO, demo_config, dry_run_jobs, snakemake, write_config

BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
MARKERS = {
    "camera": {"names": ["cam:C1", "cam:C2", "cam:C3", "cam:C4"]},
    "board": {"names": ["board:B1", "board:B2", "board:B3", "board:B4"]},
}


def plain_snakemake(workdir: Path, *args: str) -> subprocess.CompletedProcess:
    """`snakemake` with no --cores and no profile named, from the working directory."""
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), *args]
    return subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=1200)


def demo_stills(n: int = 6) -> list:
    """The demo session's first n rendered stills, (name, gray)."""
    from cvsflow.synth.render import render_stills

    session = demo_config()["sessions"]["demo"]
    session["synth"]["n_stills"] = n
    return [(name, gray) for name, gray, _ in render_stills(session)]


def results_of(workdir: Path) -> list[str]:
    res = workdir / "results"
    return sorted(str(p.relative_to(res)) for p in res.rglob("*") if p.is_file()) if res.is_dir() else []


def test_plain_snakemake_applies_the_workstation_profile(tmp_path):
    """A plain `snakemake -n` (no --cores, no --profile) picks up profiles/default: it names the
    profile and runs, where without a profile Snakemake 9 refuses to run without --cores."""
    write_config(tmp_path, demo_config())
    proc = plain_snakemake(tmp_path, "-n")
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "workflow specific profile" in out and str(REPO / "profiles" / "default") in out
    settings = yaml.safe_load((REPO / "profiles" / "default" / "config.yaml").read_text())
    assert settings["rerun-incomplete"] is True and settings["cores"] == 2
    # the SLURM profile is where README and docs/cluster.md say, and the old place is gone; the
    # profiles ship in the package (one copy: the repository's profiles/ links there)
    assert (REPO / "profiles" / "slurm" / "config.yaml").is_file()
    assert (REPO / "profiles").resolve() == REPO / "cvsflow" / "workflow" / "profiles"
    assert not (REPO / "workflow" / "profiles").exists()
    for doc in ("README.md", "docs/cluster.md", "Makefile", ".ci/run"):
        assert re.search(r"(?<!cvsflow/)workflow/profiles", (REPO / doc).read_text()) is None, doc


@pytest.mark.parametrize("inputs", [{"video": "v.mp4", "mocap": "x.csv"}, {"video": "v.mp4"}],
                         ids=["video+mocap", "video-only"])
def test_video_without_stills_stops_before_any_job(tmp_path, inputs):
    """A session with a video but no calib_dir (with or without Vicon) is refused at parse
    time, saying what is missing and how to give another session's camera; nothing runs."""
    for name in inputs.values():
        (tmp_path / name).write_bytes(b"x")
    session = {"video": str(tmp_path / inputs["video"]), "board": BOARD, "markers": MARKERS}
    if "mocap" in inputs:
        session["mocap"] = {"file": str(tmp_path / inputs["mocap"])}
    write_config(tmp_path, {"sessions": {"lab": session}})
    proc = snakemake(tmp_path, check=False)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert "sessions.lab: names a video" in out and "no calib_dir" in out
    assert "camera: <session>" in out
    assert results_of(tmp_path) == []


def test_camera_key_reuses_another_sessions_calibration(tmp_path):
    """`camera: lab1` gives a session with a video and no stills lab1's camera.yaml: its poses
    (and nothing calibrating it) are in the DAG, their camera input is lab1's."""
    (tmp_path / "calib").mkdir()
    (tmp_path / "v.mp4").write_bytes(b"x")
    write_config(tmp_path, {"sessions": {
        "lab1": {"calib_dir": str(tmp_path / "calib"), "board": BOARD},
        "lab2": {"camera": "lab1", "video": str(tmp_path / "v.mp4"), "board": BOARD},
    }})
    proc = snakemake(tmp_path, "-n", "--printshellcmds", "--forceall", check=False)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out
    assert "results/lab2/poses_raw.parquet" in out
    assert "results/lab2/camera.yaml" not in out
    poses_block = out.split("rule poses:", 1)[1].split("\n\n", 1)[0]
    assert "results/lab1/camera.yaml" in poses_block
    assert dry_run_jobs(tmp_path, "--forceall") == {"all", "calibrate", "corners", "poses", "headline"}


@pytest.mark.parametrize("camera, message", [
    ("nobody", "names session 'nobody', which is not in sessions"),
    ("lab2", "session 'lab2' has no stills of its own"),
])
def test_bad_camera_key_is_a_config_error(tmp_path, camera, message):
    """`camera:` naming an unknown session, or one without stills, stops the run saying so."""
    (tmp_path / "v.mp4").write_bytes(b"x")
    write_config(tmp_path, {"sessions": {
        "lab2": {"camera": camera, "video": str(tmp_path / "v.mp4"), "board": BOARD},
    }})
    proc = snakemake(tmp_path, "-n", check=False)
    assert proc.returncode != 0
    assert f"sessions.lab2.camera: {message}" in proc.stdout + proc.stderr


def test_a_real_sessions_inputs_under_data_of_another_name_need_no_synth_rule(tmp_path, real_data):
    """A real session whose inputs live under data/<name>/, <name> not a session: before, the
    synth rule claimed data/<name>/... ('InputFunctionException in rule synth ... KeyError');
    now the whole DAG is planned without it, and calibrate runs on the files where they are."""
    rec = tmp_path / "data" / "recordings"
    (rec / "calib").mkdir(parents=True)
    for p in sorted((real_data / "opencv-chessboard").glob("left*.jpg"))[:6]:
        (rec / "calib" / p.name).write_bytes(p.read_bytes())
    (rec / "video.mp4").write_bytes(b"x")
    (rec / "take.csv").write_bytes(b"x")
    session = {"calib_dir": "data/recordings/calib", "video": "data/recordings/video.mp4",
               "mocap": {"file": "data/recordings/take.csv"}, "markers": MARKERS,
               "board": {"squares_x": 10, "squares_y": 7, "square_m": 0.025}}
    write_config(tmp_path, {"sessions": {"lab": session}})
    jobs = dry_run_jobs(tmp_path)
    assert "synth" not in jobs
    assert {"calibrate", "corners", "mocap_import", "sync", "pairs"} <= jobs
    proc = snakemake(tmp_path, "results/lab/camera.yaml")
    assert proc.returncode == 0 and (tmp_path / "results/lab/camera.yaml").is_file()
    assert not (tmp_path / "data" / "lab").exists()


def test_calib_dir_that_is_a_file_says_so(tmp_path):
    """calib_dir pointing at a file: 'is a file, expected a folder of stills'; no camera.yaml."""
    still = tmp_path / "still.png"
    cv2.imwrite(str(still), demo_stills(1)[0][1])
    write_config(tmp_path, {"sessions": {"s": {"calib_dir": str(still), "board": BOARD}}})
    proc = snakemake(tmp_path, check=False)
    assert proc.returncode != 0
    log = (tmp_path / "logs/s/calibrate.log").read_text()
    assert f"{still}: is a file, expected a folder of stills" in log
    assert results_of(tmp_path) == []


@pytest.mark.parametrize("debug", ["", "1"], ids=["default", "CVSFLOW_DEBUG"])
def test_a_failed_stage_shows_its_named_error_and_log_not_a_traceback(tmp_path, monkeypatch, debug):
    """Any stage failing in a plain `snakemake` run (the workstation profile): the console shows
    the one-line named error and the log's path; the script's Python traceback only with
    CVSFLOW_DEBUG=1 (before, every failure printed it)."""
    still = tmp_path / "still.png"
    still.write_bytes(b"")
    write_config(tmp_path, {"sessions": {"s": {"calib_dir": str(still), "board": BOARD}}})
    monkeypatch.setenv("CVSFLOW_DEBUG", debug)
    proc = plain_snakemake(tmp_path)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert f"stage calibrate failed (InputError): {still}: is a file, expected a folder" in out
    assert "logs/s/calibrate.log" in out
    assert ("Traceback (most recent call last)" in out) == bool(debug)
    assert results_of(tmp_path) == []


def test_video_that_is_a_folder_says_so(tmp_path):
    """video pointing at a folder without frames: a folder is read as a frame folder, and one
    without images or data.csv says what it expected; no corners table."""
    (tmp_path / "calib").mkdir()
    folder = tmp_path / "recordings"
    folder.mkdir()
    write_config(tmp_path, {"sessions": {"s": {"calib_dir": str(tmp_path / "calib"),
                                                "video": str(folder), "board": BOARD}}})
    proc = snakemake(tmp_path, "results/s/corners.parquet", check=False)
    assert proc.returncode != 0
    log = (tmp_path / "logs/s/corners.log").read_text()
    assert f"{folder}: no images (" in log and "expected frames named by their time in ns, or an ASL camera folder" in log
    assert results_of(tmp_path) == []


def test_five_copies_of_one_still_stop_the_calibration(tmp_path):
    """Five copies of one still (one distinct view) stop the calibrate rule with the copies
    named, where they used to give fx 645 for a true 702 without a warning; no camera.yaml."""
    name, gray = demo_stills(1)[0]
    stills = tmp_path / "calib"
    stills.mkdir()
    for i in range(5):
        cv2.imwrite(str(stills / f"copy{i}.png"), gray)
    write_config(tmp_path, {"sessions": {"s": {"calib_dir": str(stills), "board": BOARD}}})
    proc = snakemake(tmp_path, check=False)
    assert proc.returncode != 0
    log = (tmp_path / "logs/s/calibrate.log").read_text()
    assert "1 of 5 stills have a usable and distinct" in log
    assert "copy4.png (of copy0.png)" in log
    assert results_of(tmp_path) == []


def test_every_schema_description_is_text():
    """Every `description` in the config schema parses as a string (the calib_dir one used to be
    a broken YAML flow mapping), and calib_dir's names the image types."""
    schema = yaml.safe_load((REPO / "cvsflow/workflow/schemas/config.schema.yaml").read_text())
    bad = []

    def walk(node, where):
        if isinstance(node, dict):
            if "description" in node and not isinstance(node["description"], str):
                bad.append(where)
            for key, value in node.items():
                walk(value, f"{where}.{key}")
        elif isinstance(node, list):
            for i, value in enumerate(node):
                walk(value, f"{where}[{i}]")

    walk(schema, "schema")
    assert bad == []
    props = schema["properties"]["sessions"]["additionalProperties"]["properties"]
    assert "png, jpg" in props["calib_dir"]["description"]
    assert set(props["calib_dir"]) == {"type", "description"}


# --------------------------------------------------------------------------------------------
# Interrupted runs resume with a plain rerun, to the same bytes

TABLE_SUFFIXES = {".parquet", ".csv", ".yaml", ".json", ".tum"}
FAULT_ENV = {**__import__("os").environ, "OPENCV_FOR_THREADS_NUM": "1"}


def fault_config() -> dict:
    config = demo_config(duration_s=6.0)
    del config["sessions"]["stills"]
    return config


def tables(workdir: Path) -> dict[str, bytes]:
    """Every table and YAML/JSON result under results/ and data/, by relative path."""
    return {
        str(p.relative_to(workdir)): p.read_bytes()
        for top in ("results", "data")
        for p in sorted((workdir / top).rglob("*"))
        if p.suffix in TABLE_SUFFIXES
    }


def run_and_interrupt(workdir: Path, sig: int, at_job: int) -> int:
    """Start a plain `snakemake`; when job number `at_job` starts, send `sig` to its process
    group (as Ctrl-C or a kill would). Returns the number of jobs started."""
    import os
    import re
    import time

    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile")]
    proc = subprocess.Popen(cmd, cwd=workdir, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env=FAULT_ENV, start_new_session=True)
    started = 0
    for line in proc.stderr:
        if re.match(r"^(local)?rule \w+:", line):
            started += 1
            if started == at_job:
                time.sleep(0.5)  # inside the job, not between jobs
                os.killpg(proc.pid, sig)
                break
    proc.stderr.close()
    proc.wait(timeout=120)
    return started


@pytest.fixture(scope="module")
def reference_run(tmp_path_factory):
    """One uninterrupted plain run of a short rendered session, and its job count."""
    workdir = tmp_path_factory.mktemp("reference")
    write_config(workdir, fault_config())
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile")]
    proc = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, env=FAULT_ENV,
                          timeout=1200)
    assert proc.returncode == 0, proc.stderr[-4000:]
    n_jobs = len([ln for ln in proc.stderr.splitlines() if ln.startswith(("rule ", "localrule "))])
    return workdir, n_jobs


@pytest.mark.slow
@pytest.mark.parametrize("sig_name, seed", [("SIGINT", 21), ("SIGKILL", 22)])
def test_interrupted_run_resumes_with_a_plain_rerun_to_the_same_bytes(
        tmp_path, reference_run, sig_name, seed):
    """Interrupt a plain run at a seeded random job (Ctrl-C's SIGINT, or SIGKILL of the whole
    process group), rerun with a plain `snakemake` (after a kill, should it refuse for the
    stale lock, `snakemake --unlock` first, as its message says): it finishes, and every table and YAML/JSON result equals the uninterrupted
    run's byte for byte."""
    import signal

    reference, n_jobs = reference_run
    rng = np.random.default_rng(seed)
    at_job = int(rng.integers(2, n_jobs - 1))
    write_config(tmp_path, fault_config())
    started = run_and_interrupt(tmp_path, getattr(signal, sig_name), at_job)
    assert started == at_job
    rerun = plain_snakemake(tmp_path)
    if sig_name == "SIGKILL" and rerun.returncode != 0:
        # A killed Snakemake cannot remove its lock; should the rerun refuse for it, it says to
        # unlock (docs/sessions.md), and after --unlock a plain rerun works.
        out = rerun.stdout + rerun.stderr
        assert "cannot be locked" in out and "--unlock" in out, out[-4000:]
        assert plain_snakemake(tmp_path, "--unlock").returncode == 0
        rerun = plain_snakemake(tmp_path)
    assert rerun.returncode == 0, rerun.stderr[-4000:]
    want, got = tables(reference), tables(tmp_path)
    assert sorted(got) == sorted(want)
    differ = [name for name in want if got[name] != want[name]]
    assert differ == []
