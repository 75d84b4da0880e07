"""Logging set-up for workflow scripts: one log file per job, plus stderr."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import time
from pathlib import Path

from cvsflow.exceptions import CvsflowError
from cvsflow.io.progress import console_handler

#: Set (to anything but 0 or empty) to print a failed stage's traceback on the console too.
DEBUG_ENV = "CVSFLOW_DEBUG"


def _quiet_hook(exc: BaseException, log_path: Path, stage: str):
    """An excepthook that ends the process on ``exc`` with the log's path instead of a traceback."""
    previous = sys.excepthook

    def hook(kind, value, tb):
        if value is not exc:
            return previous(kind, value, tb)
        sys.stderr.write(f"cvsflow: stage {stage} failed; its log: {log_path} (the traceback is "
                         f"left out: {DEBUG_ENV}=1 prints it)\n")

    return hook


def process_cpu_s() -> float:
    """User + system CPU seconds of this process and its finished children so far.

    Returns
    -------
    float
        Seconds, interpreter start-up included.
    """
    cpu = os.times()
    return cpu.user + cpu.system + cpu.children_user + cpu.children_system


@contextlib.contextmanager
def cpu_section(log: logging.Logger, name: str):
    """Log the process CPU seconds a block of a stage takes, as ``section NAME: CPU X s``.

    bench/job_times.py reads these lines (an analyse job's numbers and figures, for instance).

    Parameters
    ----------
    log : logging.Logger
        The stage's logger.
    name : str
        The block's name, one word.

    Returns
    -------
    contextmanager of None
        Used as ``with cpu_section(log, "figures"):``; the line is logged when the block ends
        without an exception.
    """
    cpu0 = process_cpu_s()
    yield
    log.info("section %s: CPU %.2f s", name, process_cpu_s() - cpu0)


@contextlib.contextmanager
def stage_logging(log_path, stage: str):
    """Send cvsflow's log records to ``log_path`` and stderr for one stage; log a failure's reason.

    A ``CvsflowError`` is logged as one line naming its class (its message already says where
    and what) and re-raised so that Snakemake marks the job failed and removes its outputs.
    If it ends the process (a workflow script run by Snakemake) the console gets that line and
    the log's path, not the traceback, unless the environment sets ``CVSFLOW_DEBUG``. Any
    other exception is a bug: logged with its traceback, which the console shows too.

    Parameters
    ----------
    log_path : str or Path
        The stage's log file; its parent directory is created, the file overwritten.
    stage : str
        Stage name, used in the logger name ``cvsflow.stage.{stage}`` and the messages.

    Returns
    -------
    contextmanager of logging.Logger
        Used as ``with stage_logging(path, "sync") as log:``; yields the stage's logger. The
        first line gives the process's CPU time so far (start-up: interpreter, Snakemake's
        preamble, the script's imports). On exit the handlers are removed and the elapsed wall
        time and the process's CPU time (start-up included) are logged (on success).
    """
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    fmt = "%(asctime)s %(levelname)s %(name)s: %(message)s"
    handlers = [logging.FileHandler(log_path, mode="w"), console_handler(sys.stderr, fmt)]
    handlers[0].setFormatter(logging.Formatter(fmt))
    root = logging.getLogger()
    for h in handlers:
        root.addHandler(h)
    root.setLevel(logging.INFO)
    log = logging.getLogger(f"cvsflow.stage.{stage}")
    t0 = time.perf_counter()
    log.info("stage %s started (start-up CPU %.2f s)", stage, process_cpu_s())
    try:
        yield log
    except CvsflowError as exc:
        log.error("stage %s failed (%s): %s", stage, type(exc).__name__, exc)
        if os.environ.get(DEBUG_ENV, "0") in ("", "0"):
            sys.excepthook = _quiet_hook(exc, log_path, stage)
        raise
    except Exception:
        log.exception("stage %s failed with an unexpected error", stage)
        raise
    else:
        # The job's own CPU, start-up included: Snakemake's benchmark samples it, and misses
        # whatever a job spends after its last sample (a 34 s job was reported as 15 s).
        log.info("stage %s done in %.2f s (process CPU %.2f s)", stage, time.perf_counter() - t0,
                 process_cpu_s())
    finally:
        for h in handlers:
            root.removeHandler(h)
            h.close()
