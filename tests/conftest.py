"""Shared test fixtures: where the repository and the shared real data are."""

import os
from pathlib import Path

# One BLAS thread per test process, as Snakemake gives a job of one thread: pytest -n runs
# workers side by side, and OpenBLAS's threads spin waiting for the other worker's core.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


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


@pytest.fixture(scope="session")
def real_data():
    """The real sample files made by others (shared/data/real); skip when absent."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real data not found at {REAL_DATA}")
    return REAL_DATA
