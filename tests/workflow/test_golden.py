"""The demo, rendered and run as `make demo` runs it, against the last release's tables.

The tolerances and how to move the golden files are in tests/workflow/golden.py.
"""

from __future__ import annotations

import copy
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from tests.workflow.golden import (
    GOLDEN,
    TABLES,
    bootstrap_tolerance,
    compare_frames,
    compare_results,
    compare_values,
    read_table,
)

REPO = Path(__file__).resolve().parents[2]


def test_demo_tables_match_the_last_release(tmp_path):
    """Every table of the demo (config/config.yaml) is within the golden tolerances of the last release."""
    shutil.copytree(REPO / "config", tmp_path / "config")
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory", str(tmp_path),
           "--cores", "2", "--quiet", "all"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    n_boot = yaml.safe_load((REPO / "config" / "config.yaml").read_text())["evaluate"]["n_boot"]
    diffs = compare_results(GOLDEN / "demo", tmp_path / "results", n_boot=n_boot)
    assert not diffs, "demo tables moved beyond the golden tolerances:\n" + "\n".join(diffs[:40])


def test_golden_files_are_complete():
    """The golden folder holds every table the comparison reads."""
    missing = [rel for rel in TABLES if not (GOLDEN / "demo" / rel).is_file()]
    assert not missing


def test_a_float_moved_by_more_than_its_tolerance_is_reported():
    """1e-9 relative passes, 1e-8 fails; a tiny mean is held to its siblings' scale, not its own."""
    camera = read_table(GOLDEN / "demo" / "demo/camera.yaml")
    moved = copy.deepcopy(camera)
    moved["K"][0][0] *= 1 + 5e-10
    assert compare_values("camera", camera, moved) == []
    moved["K"][0][0] *= 1 + 1e-8
    assert any("K[0][0]" in d for d in compare_values("camera", camera, moved))
    stats = {"mean": -9e-15, "rmse": 0.05}
    assert compare_values("s", stats, {"mean": 4e-11, "rmse": 0.05}) == []
    assert compare_values("s", stats, {"mean": 1e-9, "rmse": 0.05})


def test_counts_flags_and_text_are_exact():
    """An integer count, a flag or a word that changes is a difference; a number in text to its digits."""
    assert compare_values("x", {"n": 600}, {"n": 601})
    assert compare_values("x", {"diverged": True}, {"diverged": False})
    assert compare_values("x", {"method": "se3"}, {"method": "seed"})
    reason = "fy = 4985.8 px within a grid step"
    assert compare_values("x", reason, "fy = 4985.9 px within a grid step") == []
    assert compare_values("x", reason, "fy = 4986.1 px within a grid step")


def test_bootstrap_interval_ends_get_their_monte_carlo_error():
    """At 1000 resamples and 95 %, an interval end may move by ~6 % of the interval's width."""
    tol = bootstrap_tolerance(-1.0, 1.0, 1000, 0.95)
    assert 0.09 < tol < 0.16
    golden = {"mean": 0.1, "mean_lo": -1.0, "mean_hi": 1.0}
    assert compare_values("m", golden, {"mean": 0.1, "mean_lo": -1.0 + 0.5 * tol, "mean_hi": 1.0}) == []
    assert compare_values("m", golden, {"mean": 0.1, "mean_lo": -1.0 - 2 * tol, "mean_hi": 1.0})


def test_a_table_with_a_moved_row_is_reported():
    """One corner moved by 1e-6 px in the golden corners table is found, with its row."""
    corners = pd.read_parquet(GOLDEN / "demo" / "demo/corners.parquet")
    col = next(c for c in corners.columns if pd.api.types.is_float_dtype(corners[c]) and corners[c].notna().any())
    moved = corners.copy()
    row = int(moved[col].notna().to_numpy().nonzero()[0][3])
    moved.loc[row, col] += 1e-3
    diffs = compare_frames("corners", corners, moved)
    assert diffs and f"first row {row}" in diffs[0]
    assert compare_frames("corners", corners, corners.copy()) == []


@pytest.mark.parametrize("rel", ["headline.csv", "demo/sync.yaml"])
def test_golden_tables_parse(rel):
    """The golden tables are readable as the comparison reads them."""
    assert read_table(GOLDEN / "demo" / rel) is not None
