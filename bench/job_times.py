"""Each job's wall time, CPU time and peak memory from a workflow run's benchmark files and logs.

Snakemake's benchmark file gives the wall seconds (``s``) and peak memory (``max_rss``) of a
job, but its ``cpu_time`` is sampled (every 0.5 s for the first 30 samples, then every 30 s)
and keeps the last sample: a job of 20-45 s is reported at about 15 s (the 90 s demo's
heldout_seed, 35 CPU s, as 15.0). The CPU seconds here come from the job's log line ``stage
... done in ... s (process CPU ... s)`` (:func:`cvsflow.io.logs.stage_logging`: the process's
user + system time, start-up included); Snakemake's value stays as ``cpu_s_snakemake`` and
stands in for jobs whose log has no such line (the line is written on success only).

``startup_s`` is the process CPU at the log's first line (``stage ... started (start-up CPU
... s)``: interpreter, Snakemake's preamble and the script's imports), ``figures_s`` the CPU of
a ``section figures`` block (:func:`cvsflow.io.logs.cpu_section`); NaN where a log has none.
"""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

DONE = re.compile(r"stage \S+ done in [0-9.]+ s \(process CPU ([0-9.]+) s\)")
STARTED = re.compile(r"stage \S+ started \(start-up CPU ([0-9.]+) s\)")
FIGURES = re.compile(r"section figures: CPU ([0-9.]+) s")


def log_cpu_s(log: Path, pattern: re.Pattern = DONE) -> float | None:
    """The CPU seconds of a job's last line matching ``pattern`` (default: ``done``), or None."""
    if not log.is_file():
        return None
    found = pattern.findall(log.read_text(errors="replace"))
    return float(found[-1]) if found else None


def read_job_times(workdir: Path) -> pd.DataFrame:
    """One row per job of ``workdir/benchmarks``: ``job`` (its path there without .tsv),
    ``stage`` (the file name's stem), ``s``, ``cpu_s``, ``cpu_s_snakemake``, ``startup_s``,
    ``figures_s``, ``max_rss_MB``."""
    rows = []
    for tsv in sorted((workdir / "benchmarks").rglob("*.tsv")):
        job = str(tsv.relative_to(workdir / "benchmarks"))[:-4]
        b = pd.read_csv(tsv, sep="\t")
        cpu_sm = float(b["cpu_time"].iloc[0])
        log = workdir / "logs" / f"{job}.log"
        cpu = log_cpu_s(log)
        startup, figures = log_cpu_s(log, STARTED), log_cpu_s(log, FIGURES)
        rows.append({"job": job, "stage": tsv.stem, "s": float(b["s"].iloc[0]),
                     "cpu_s": cpu_sm if cpu is None else cpu, "cpu_s_snakemake": cpu_sm,
                     "startup_s": float("nan") if startup is None else startup,
                     "figures_s": float("nan") if figures is None else figures,
                     "max_rss_MB": float(b["max_rss"].iloc[0])})
    return pd.DataFrame(rows)
