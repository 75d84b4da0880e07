"""The workflow's own style checks: snakefmt's formatting and Snakemake's linter."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
WORKFLOW = REPO / "cvsflow" / "workflow"
#: The one lint tolerated: rules run in the package's own environment, not per-rule conda/containers.
TOLERATED = {"Specify a conda environment or container for each rule."}


def test_snakefiles_are_snakefmt_formatted():
    """`snakefmt --check` finds nothing to change in the Snakefiles and rule files."""
    proc = subprocess.run([sys.executable, "-m", "snakefmt", "--check", str(REPO / "Snakefile"), str(WORKFLOW)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_snakemake_lint_finds_only_the_tolerated_lint():
    """`snakemake --lint` on the shipped workflow with the demo config reports no lint but the
    per-rule environment one (e.g. no rules and functions mixed in one file, no params read from
    the config inside a script)."""
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--lint", "-s", str(WORKFLOW / "Snakefile"),
                           "--configfile", str(REPO / "config" / "config.yaml"), "--directory", str(REPO)],
                          capture_output=True, text=True)
    titles = set(re.findall(r"^\s*\* (.+?):\s*$", proc.stdout + proc.stderr, flags=re.M))
    assert titles, "no lint output parsed: " + (proc.stdout + proc.stderr)[-2000:]
    assert titles <= TOLERATED, titles - TOLERATED
