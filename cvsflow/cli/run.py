"""``cvsflow run``: the workflow that ships in the package, on a config file, from any folder."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

from cvsflow.exceptions import InputError
from cvsflow.io.files import read_yaml
from cvsflow.workflow.config import PROFILES, SNAKEFILE, require_sessions

log = logging.getLogger(__name__)


def _has_option(args: list[str], *names: str) -> bool:
    """Whether ``args`` holds one of the options ``names`` (``--opt value`` or ``--opt=value``)."""
    return any(a == n or a.startswith(n + "=") for a in args for n in names)


def _precheck(config: Path) -> None:
    """The config's named errors before snakemake starts: not a file, not YAML, no sessions.

    A YTE template (``__use_yte__: true``) is left to snakemake: reading it here would run its
    code twice.
    """
    if not config.is_file():
        raise InputError(
            f"{config}: config file not found (cvsflow run's first argument is the config; "
            "snakemake targets go after it)"
        )
    data = read_yaml(config)
    if not data.get("__use_yte__"):
        require_sessions(data, [config])


def run_command(config: Path | None, extra: list[str], cwd: Path) -> list[str]:
    """The snakemake command line ``cvsflow run`` executes.

    Parameters
    ----------
    config : Path or None
        The config file; None runs the Snakefile of ``cwd`` (the repository's).
    extra : list of str
        Snakemake's arguments (``--cores``, ``--directory``, targets ...), unchanged.
    cwd : Path
        The folder ``cvsflow run`` was started in.

    Returns
    -------
    list of str
        ``python -m snakemake`` with, for a config, the package's Snakefile and the config as
        an absolute path (``--directory`` may move the run); the package's workstation profile
        unless ``extra`` names a profile, or (without a config) ``cwd`` has ``profiles/default``,
        which snakemake applies itself.

    Raises
    ------
    InputError
        No config and no Snakefile in ``cwd``.
    """
    cmd = [sys.executable, "-m", "snakemake"]
    if config is not None:
        cmd += ["-s", str(SNAKEFILE), "--configfile", str(config.resolve())]
    elif not (cwd / "Snakefile").is_file() and not (cwd / "workflow" / "Snakefile").is_file():
        hint = ""
        if _has_option(extra, "--configfile", "--configfiles"):
            hint = " (the config goes first: `cvsflow run my.yaml`, not `--configfile my.yaml`)"
        raise InputError(
            f"{cwd}: no config file given and no Snakefile here{hint}; expected "
            "`cvsflow run CONFIG.yaml [--cores N] [snakemake options]` (`cvsflow init DIR` "
            "writes a session file, `cvsflow demo DIR` runs a complete example)"
        )
    own_profile = config is None and (cwd / "profiles" / "default").is_dir()
    if not own_profile and not _has_option(extra, "--profile", "--workflow-profile"):
        cmd += ["--workflow-profile", str(PROFILES / "default")]
    return cmd + list(extra)


def cmd_run(args, extra) -> int:
    """``cvsflow run [CONFIG] [snakemake options]``: run the workflow through snakemake.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``run`` command (only ``verbose``; nothing else is parsed).
    extra : list of str
        Every argument after ``run``. A first argument that is not an option is the config
        file: the package's workflow runs exactly its sessions and flights (no demo merged
        in), keys left out taking the schema's defaults, with ``results/``, ``logs/`` and
        ``benchmarks/`` under the current folder (or ``--directory``). Without one, the
        current folder's Snakefile runs (the repository's: the demo). The rest goes to
        snakemake unchanged; ``--workflow-profile slurm`` finds the package's SLURM profile.

    Returns
    -------
    int
        Snakemake's exit code.

    Raises
    ------
    InputError
        The config file does not exist or is not a YAML mapping, or no config and no
        Snakefile here.
    ConfigError
        The config has no sessions.
    """
    config = None
    if extra and not extra[0].startswith("-"):
        config, extra = Path(extra[0]), extra[1:]
        _precheck(config)
    cmd = run_command(config, extra, Path.cwd())
    log.info("running %s", " ".join(cmd))
    return subprocess.call(cmd)
