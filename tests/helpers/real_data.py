"""Where the shared real data made by others lives, and skipping a test without it."""

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def _find_real_data() -> Path:
    """$CVSFLOW_REAL_DATA, else shared/data/real beside the repository or beside any folder above it
    (a git worktree sits deeper than the clone); the path beside the repository when none exists."""
    if os.environ.get("CVSFLOW_REAL_DATA"):
        return Path(os.environ["CVSFLOW_REAL_DATA"])
    for up in REPO.parents:
        if (up / "shared" / "data" / "real").is_dir():
            return up / "shared" / "data" / "real"
    return REPO.parent / "shared" / "data" / "real"


REAL_DATA = _find_real_data()


def need_real_file(path) -> Path:
    """``path`` (under REAL_DATA, or relative to it), or skip the test when that file is absent."""
    path = REAL_DATA / path
    if not path.is_file():
        pytest.skip(f"real data not available ({path})")
    return path
