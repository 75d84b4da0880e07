"""Shared test fixtures: where the repository and the shared real data are."""

import os
from pathlib import Path

# One BLAS thread per test process, as Snakemake gives a job of one thread: pytest -n runs
# workers side by side, and OpenBLAS's threads spin waiting for the other worker's core.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import pytest  # noqa: E402

from tests.helpers.real_data import REAL_DATA  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def real_data():
    """The real sample files made by others (shared/data/real); skip when absent."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real data not found at {REAL_DATA}")
    return REAL_DATA
