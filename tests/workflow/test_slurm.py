"""The workflow through a real SLURM (snakemake-executor-plugin-slurm, workflow/profiles/slurm).

Opt-in: skipped unless CVSFLOW_SLURM=1 and `sinfo` answers. Start the single-node cluster on
this machine first:

    cluster/slurm-localhost.sh start
    CVSFLOW_SLURM=1 .venv/bin/python -m pytest tests/workflow/test_slurm.py

The working directories are pytest temp dirs on this machine's disk: the tests are for a
cluster whose node is this machine (cluster/slurm-localhost.sh), not for a remote cluster.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml

from .test_workflow import REPO, demo_config, write_config

PROFILE = REPO / "workflow" / "profiles" / "slurm"


def _sinfo_answers() -> bool:
    if not shutil.which("sinfo"):
        return False
    try:
        proc = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True,
                              timeout=20)
    except subprocess.TimeoutExpired:
        return False
    return proc.returncode == 0 and bool(proc.stdout.strip())


pytestmark = [
    pytest.mark.skipif(os.environ.get("CVSFLOW_SLURM") != "1",
                       reason="opt-in: set CVSFLOW_SLURM=1 (and start cluster/slurm-localhost.sh)"),
    pytest.mark.skipif(os.environ.get("CVSFLOW_SLURM") == "1" and not _sinfo_answers(),
                       reason="sinfo does not answer: no SLURM cluster (cluster/slurm-localhost.sh start)"),
]


@pytest.fixture(scope="module", autouse=True)
def slurm_plugin():
    try:
        import snakemake_executor_plugin_slurm  # noqa: F401
    except ImportError:
        pytest.fail("snakemake-executor-plugin-slurm is not installed (pip install -e '.[slurm]')")


def run(workdir: Path, *args: str, snakefile: Path = REPO / "Snakefile",
        timeout: int = 1800) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(snakefile), "--directory", str(workdir),
           *args]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    proc.seconds = time.monotonic() - t0
    return proc


def slurm_run(workdir: Path, *targets: str, snakefile: Path = REPO / "Snakefile"):
    """Through SLURM with the repository's profile; SLURM's job logs are kept as evidence."""
    proc = run(workdir, "--profile", str(PROFILE), "--slurm-keep-successful-logs", *targets,
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


def compare_trees(local: Path, slurm: Path) -> list[str]:
    """Same files; tables equal (pandas testing), YAML values equal. Returns the files compared.

    Snakemake's own marker files (.snakemake_timestamp) are left out; figures and videos only
    have to exist and be non-empty.
    """
    def files(root: Path) -> set[str]:
        return {str(p.relative_to(root)) for d in ("results", "data")
                for p in (root / d).rglob("*")
                if p.is_file() and not p.name.startswith(".")}

    names = files(local)
    assert files(slurm) == names
    for name in sorted(names):
        if name.endswith(".parquet"):
            pd.testing.assert_frame_equal(pd.read_parquet(slurm / name),
                                          pd.read_parquet(local / name), obj=name)
        elif name.endswith(".csv"):
            pd.testing.assert_frame_equal(pd.read_csv(slurm / name), pd.read_csv(local / name),
                                          obj=name)
        elif name.endswith((".yaml", ".yml")):
            assert yaml.safe_load((slurm / name).read_text()) == \
                yaml.safe_load((local / name).read_text()), name
        else:
            assert (slurm / name).stat().st_size > 0, name
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
                      if p.is_file())
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
