"""``cvsflow run``: the workflow through snakemake with the workstation profile."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

from cvsflow.exceptions import InputError

log = logging.getLogger(__name__)


def profile_dir(root: Path) -> Path:
    """``profiles/default`` at the repository root if present, else ``workflow/profiles/default``.

    Parameters
    ----------
    root : Path
        The repository root (the folder ``cvsflow run`` is run from).

    Returns
    -------
    Path
        The Snakemake profile folder (not checked to exist in the fallback case).
    """
    top = root / "profiles" / "default"
    return top if top.is_dir() else root / "workflow" / "profiles" / "default"


def cmd_run(args, extra) -> int:
    """``cvsflow run``: run ``python -m snakemake`` with the workstation profile.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``run`` command (only ``verbose``; nothing else is parsed).
    extra : list of str
        Every argument after ``run``, passed to snakemake unchanged; ``--profile
        <profile_dir>`` is added unless it has ``--profile`` or ``--workflow-profile``.

    Returns
    -------
    int
        Snakemake's exit code.

    Raises
    ------
    InputError
        No Snakefile in the current folder or its ``workflow/``.
    """
    root = Path.cwd()
    if not (root / "Snakefile").is_file() and not (root / "workflow" / "Snakefile").is_file():
        raise InputError(f"{root}: no Snakefile here (run `cvsflow run` from the cvsflow repository)")
    cmd = [sys.executable, "-m", "snakemake"]
    if "--profile" not in extra and "--workflow-profile" not in extra:
        cmd += ["--profile", str(profile_dir(root).relative_to(root))]
    cmd += list(extra)
    log.info("running %s", " ".join(cmd))
    return subprocess.call(cmd)
