"""The workflow through a real SLURM (snakemake-executor-plugin-slurm, profiles/slurm).

Opt-in: skipped unless CVSFLOW_SLURM=1 and `sinfo` answers. Start the single-node cluster on
this machine first:

    cluster/slurm-localhost.sh start
    CVSFLOW_SLURM=1 .venv/bin/python -m pytest tests/workflow/test_slurm.py

The working directories are pytest temp dirs on this machine's disk: the tests are for a
cluster whose node is this machine (cluster/slurm-localhost.sh), not for a remote cluster.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from .test_workflow import REPO, demo_config, write_config

PROFILE = REPO / "profiles" / "slurm"


def _sinfo_answers() -> bool:
    if not shutil.which("sinfo"):
        return False
    try:
        proc = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True,
                              timeout=20)
    except subprocess.TimeoutExpired:
        return False
    return proc.returncode == 0 and bool(proc.stdout.strip())


OPTED_IN = os.environ.get("CVSFLOW_SLURM") == "1"
START = "cluster/slurm-localhost.sh start"
pytestmark = [
    pytest.mark.skipif(not OPTED_IN, reason=f"opt-in: set CVSFLOW_SLURM=1 (and run {START})"),
    pytest.mark.skipif(OPTED_IN and not _sinfo_answers(),
                       reason=f"sinfo does not answer: no SLURM cluster (run {START})"),
]


@pytest.fixture(scope="module", autouse=True)
def slurm_plugin():
    try:
        import snakemake_executor_plugin_slurm  # noqa: F401
    except ImportError:
        pytest.fail("snakemake-executor-plugin-slurm is not installed (pip install -e '.[slurm]')")


# OpenCV's thread pool makes calibrateCamera differ by an ulp from run to run (sums in another
# order), which the optimisers downstream amplify; with one thread it is reproducible bit for bit.
# sbatch passes the environment on to the jobs.
ENV = {**os.environ, "OPENCV_FOR_THREADS_NUM": "1"}


def run(workdir: Path, *args: str, snakefile: Path = REPO / "Snakefile",
        timeout: int = 1800) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(snakefile), "--directory", str(workdir),
           *args]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=ENV)
    proc.seconds = time.monotonic() - t0
    return proc


def slurm_run(workdir: Path, *targets: str, snakefile: Path = REPO / "Snakefile"):
    """Through SLURM with the repository's profile; SLURM's job logs are kept as evidence."""
    proc = run(workdir, "--workflow-profile", str(PROFILE), "--slurm-keep-successful-logs", *targets,
               snakefile=snakefile)
    out = proc.stdout + proc.stderr
    if proc.returncode != 0:
        raise AssertionError(f"snakemake through SLURM failed:\n{out[-6000:]}")
    submitted = re.findall(r"has been submitted with SLURM jobid (\d+)", out)
    return proc, submitted


def rule_jobs(out: str) -> list[str]:
    """Rule names of the jobs Snakemake ran (the `rule x:` headers, local rules excluded)."""
    return re.findall(r"^rule (\w+):", out, flags=re.M)


def test_tiny_workflow_runs_as_slurm_jobs(tmp_path):
    """Two rules, each an sbatch job with the threads and memory the rule asks for."""
    # Each job writes its SLURM job id and what SLURM granted it (scontrol: CPUs, memory).
    show = ("echo $SLURM_JOB_ID $(scontrol show job -o $SLURM_JOB_ID "
            "| grep -oE 'NumCPUs=[0-9]+|MinMemoryNode=[0-9]+M' | sort | tr '\\n' ' ')")
    (tmp_path / "Snakefile").write_text(
        'rule all:\n    input: "b.txt"\n\n'
        'rule a:\n    output: "a.txt"\n    threads: 1\n    resources: mem_mb=200, runtime=5\n'
        f'    shell: "{show} > {{output}}"\n\n'
        'rule b:\n    input: "a.txt"\n    output: "b.txt"\n    threads: 2\n'
        '    resources: mem_mb=300, runtime=5\n'
        f'    shell: "cat {{input}} > {{output}}; {show} >> {{output}}"\n'
    )
    proc, submitted = slurm_run(tmp_path, snakefile=tmp_path / "Snakefile")
    assert len(submitted) == 2, proc.stdout + proc.stderr
    a, b = [line.split() for line in (tmp_path / "b.txt").read_text().splitlines()]
    assert [a[0], b[0]] == submitted                     # each rule ran in its own SLURM job
    assert a[1:] == ["MinMemoryNode=200M", "NumCPUs=1"], a
    assert b[1:] == ["MinMemoryNode=300M", "NumCPUs=2"], b


# Wall-clock durations recorded in the results (optimisers' time_s, timings_s): they differ
# from run to run.
TIMING_KEYS = {"time_s", "timings_s"}


def assert_values_equal(got, want, where: str) -> None:
    """Equal YAML/JSON values, timings left out; floats to 1e-9 relative."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and got.keys() == want.keys(), where
        for k in want.keys() - TIMING_KEYS:
            assert_values_equal(got[k], want[k], f"{where}: {k}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), where
        for i, (g, w) in enumerate(zip(got, want, strict=True)):
            assert_values_equal(g, w, f"{where}[{i}]")
    elif isinstance(want, float) and not isinstance(got, bool):
        assert isinstance(got, int | float), where
        assert math.isclose(got, want, rel_tol=1e-9, abs_tol=1e-12) or (
            math.isnan(got) and math.isnan(want)), f"{where}: {got} != {want}"
    else:
        assert got == want, f"{where}: {got!r} != {want!r}"


def compare_trees(local: Path, slurm: Path) -> list[str]:
    """Same files under results/ and data/, with equal contents. Returns the files compared.

    Tables (Parquet, CSV, TUM) equal by pandas testing / numpy (rtol 1e-5 / 1e-9); YAML and
    JSON values equal (assert_values_equal); the rendered inputs under data/ byte for byte;
    figures only non-empty. Snakemake's marker files (.snakemake_timestamp) are left out.
    """
    def files(root: Path) -> set[str]:
        return {str(p.relative_to(root)) for d in ("results", "data")
                for p in (root / d).rglob("*")
                if p.is_file() and not p.name.startswith(".")}

    names = files(local)
    assert files(slurm) == names
    for name in sorted(names):
        got, want = slurm / name, local / name
        if name.endswith(".parquet"):
            pd.testing.assert_frame_equal(pd.read_parquet(got), pd.read_parquet(want), obj=name)
        elif name.endswith((".yaml", ".yml")) and got.read_text().startswith("%YAML:"):
            # OpenCV FileStorage (camera_opencv.yaml): not YAML 1.1 that PyYAML reads
            assert got.read_bytes() == want.read_bytes(), name
        elif name.endswith((".yaml", ".yml")):
            assert_values_equal(yaml.safe_load(got.read_text()), yaml.safe_load(want.read_text()),
                                name)
        elif name.endswith(".json"):
            assert_values_equal(json.loads(got.read_text()), json.loads(want.read_text()), name)
        elif name.startswith("data/"):
            assert got.read_bytes() == want.read_bytes(), name
        elif name.endswith(".csv"):
            pd.testing.assert_frame_equal(pd.read_csv(got), pd.read_csv(want), obj=name)
        elif name.endswith(".tum"):
            np.testing.assert_allclose(np.loadtxt(got), np.loadtxt(want), rtol=1e-9, atol=1e-12,
                                       err_msg=name)
        else:
            assert got.stat().st_size > 0, name
    return sorted(names)


# Stages that must exist for the comparison to mean anything. The demo DAG is compared as far as
# the local run gets: every file the local run writes must come out equal through SLURM.
REQUIRED = ["results/demo/camera.yaml", "results/demo/poses_raw.parquet"]


def test_demo_through_slurm_equals_local_run(tmp_path):
    """The demo session through SLURM gives the same tables and YAML values as a local run."""
    local, slurm = tmp_path / "local", tmp_path / "slurm"
    for d in (local, slurm):
        write_config(d, demo_config())

    # Local run of the whole DAG; --keep-going so that, while a stage is still being written,
    # everything that does not depend on it is compared.
    loc = run(local, "--cores", "2", "--keep-going")
    produced = sorted(str(p.relative_to(local)) for p in (local / "results").rglob("*")
                      if p.is_file() and not p.name.startswith("."))
    for name in REQUIRED:
        assert name in produced, f"local run did not produce {name}:\n{loc.stderr[-4000:]}"
    targets = [] if loc.returncode == 0 else produced   # [] = the default target, rule all

    proc, submitted = slurm_run(slurm, *targets)
    out = proc.stdout + proc.stderr
    jobs = [r for r in rule_jobs(out) if r != "all"]
    assert jobs and len(submitted) == len(jobs), out[-4000:]
    for rule in set(jobs):                                # SLURM's own log of every job
        assert list((slurm / ".snakemake" / "slurm_logs" / f"rule_{rule}").rglob("*.log")), rule

    compared = compare_trees(local, slurm)
    print(f"local {loc.seconds:.0f} s (rc {loc.returncode}), SLURM {proc.seconds:.0f} s, "
          f"{len(submitted)} SLURM jobs, {len(compared)} files compared"
          + ("" if loc.returncode == 0 else f"; targets limited to {targets}"))
