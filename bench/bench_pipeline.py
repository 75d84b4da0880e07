"""End-to-end time of the pipeline on the demo session, rendering excluded.

Renders the demo at the given length once into a cache folder (``--cache``), then runs the
whole workflow (every stage after ``synth``: calibration, corners, poses, Vicon, sync, pairs,
both optimisers, held-out scoring, analysis, figures, summary, flight demo) in a fresh working
directory and prints the wall time, each rule's time from Snakemake's benchmark files, and
the peak memory of the slowest job. CPU seconds (``cpu_s``, from each job's log:
bench/job_times.py says why not Snakemake's sampled ``cpu_time``, printed as ``cpu_s_snakemake``)
are printed beside wall seconds: on a shared machine they are the steadier number.

    .venv/bin/python bench/bench_pipeline.py --duration 90 --cores 2
    .venv/bin/python bench/bench_pipeline.py --imports      # start-up cost of each workflow script
    .venv/bin/python bench/bench_pipeline.py --duration 20 --methods se3 --no-figures  # the fast path

Before and after a change, on the same machine, with the spread over repeats: run the other
checkout's workflow and package (``--repo``, put first on PYTHONPATH) and save its table, then
print this checkout's beside it (the median of each job's CPU over the repeats and, per job,
their range):

    .venv/bin/python bench/bench_pipeline.py --duration 20 --repeat 2 --repo ../before --out before.csv
    .venv/bin/python bench/bench_pipeline.py --duration 20 --repeat 2 --before before.csv

The table's ``startup_s`` is each job's CPU before its stage began (interpreter, Snakemake's
preamble, imports) and ``figures_s`` the CPU its figures took, where its log states them
(bench/job_times.py).

``--imports`` times, in fresh interpreters (best of 3), the import lines of every script in
cvsflow/workflow/scripts/ and of the heavy libraries they pull in: the fixed cost each job pays
before it reads its first input (bench/bench_startup.py, which also runs on its own).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml
from job_times import read_job_times  # beside this script

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=90.0, help="demo length (s)")
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "cvsflow_bench")
    parser.add_argument("--keep", action="store_true", help="keep the working directory")
    parser.add_argument("--repeat", type=int, default=1, help="pipeline runs (medians and ranges)")
    parser.add_argument("--repo", type=Path, default=REPO,
                        help="checkout whose workflow and package to run (default: this one)")
    parser.add_argument("--out", type=Path, help="write every run's per-job table here (CSV)")
    parser.add_argument("--before", type=Path, help="an --out table to print beside this run's")
    parser.add_argument("--no-figures", action="store_true",
                        help="run with `figures: false` (a sweep's setting; rendering unchanged)")
    parser.add_argument("--methods", nargs="+", choices=("seed", "se3"),
                        help="optimise.methods (default: the config's, seed and se3)")
    parser.add_argument("--imports", action="store_true",
                        help="only time each workflow script's imports")
    args = parser.parse_args()
    if args.imports:
        from bench_startup import import_times  # beside this script

        import_times(REPO)
        return

    repo = args.repo.resolve()
    config = yaml.safe_load((repo / "config" / "config.yaml").read_text())
    config["sessions"]["demo"]["synth"]["duration_s"] = args.duration
    cache = args.cache / f"demo_{args.duration:g}s"
    if not (cache / "data" / "demo" / "truth.yaml").exists():
        print(f"rendering the {args.duration:g} s demo into {cache} (once) ...", flush=True)
        (cache / "config").mkdir(parents=True, exist_ok=True)
        (cache / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
        t0 = time.perf_counter()
        run(repo, cache, args.cores, "data/demo/truth.yaml")
        print(f"rendered in {time.perf_counter() - t0:.1f} s")

    if args.no_figures:
        config["figures"] = False
    if args.methods:
        config.setdefault("optimise", {})["methods"] = args.methods
    tables = []
    for k in range(args.repeat):
        table, wall = run_once(repo, config, cache, args.cores, args.keep)
        print(table.drop(columns="stage").sort_values("s", ascending=False)
              .to_string(index=False, float_format=lambda v: f"{v:.1f}"))
        print(f"\nrun {k + 1}: demo {args.duration:g} s, {args.cores} cores: pipeline wall time "
              f"{wall:.1f} s (rendering excluded); jobs' CPU {table['cpu_s'].sum():.1f} s; peak RSS "
              f"of one job {table['max_rss_MB'].max():.0f} MB; load average {os.getloadavg()[0]:.1f}\n",
              flush=True)
        tables.append(table.assign(run=k, wall_s=wall))
    runs = pd.concat(tables, ignore_index=True)
    if args.out:
        runs.to_csv(args.out, index=False)
    if args.before:
        print(before_after(pd.read_csv(args.before), runs))


def run_once(repo: Path, config: dict, cache: Path, cores: int, keep: bool):
    """One pipeline run from the rendered inputs in a fresh folder: its job table and wall s."""
    work = Path(tempfile.mkdtemp(prefix="cvsflow_bench_run_"))
    (work / "config").mkdir()
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    shutil.copytree(cache / "data", work / "data")
    # Mark the copied session as made by this workflow so that synth is not rerun.
    run(repo, work, cores, "--touch", "data/demo/truth.yaml")
    t0 = time.perf_counter()
    run(repo, work, cores)
    wall = time.perf_counter() - t0
    table = read_job_times(work)
    if keep:
        print(f"working directory kept: {work}")
    else:
        shutil.rmtree(work)
    return table, wall


def before_after(before: pd.DataFrame, after: pd.DataFrame) -> str:
    """Per job, the median CPU seconds (total, start-up, figures) over the runs of each table,
    and the range of the total; then the sums per run (median and range)."""

    def per_job(runs):
        g = runs.groupby("job")
        return pd.DataFrame({"cpu": g["cpu_s"].median(),
                             "range": g["cpu_s"].agg(lambda v: f"{v.min():.1f}-{v.max():.1f}"),
                             "startup": g["startup_s"].median(), "figures": g["figures_s"].median()})

    table = per_job(before).join(per_job(after), how="outer", lsuffix="_before", rsuffix="_after")
    table = table.sort_values("cpu_before", ascending=False)
    sums = []
    for name, runs in (("before", before), ("after", after)):
        per_run = runs.groupby("run").agg(cpu=("cpu_s", "sum"), wall=("wall_s", "first"))
        sums.append(f"{name}: jobs' CPU {per_run['cpu'].median():.1f} s "
                    f"({per_run['cpu'].min():.1f}-{per_run['cpu'].max():.1f}), wall "
                    f"{per_run['wall'].median():.1f} s ({per_run['wall'].min():.1f}-"
                    f"{per_run['wall'].max():.1f}) over {len(per_run)} runs")
    return (table.to_string(float_format=lambda v: f"{v:.2f}", na_rep="-") + "\n\n"
            + "\n".join(sums))


def run(repo: Path, workdir: Path, cores: int, *targets: str) -> None:
    """Snakemake on ``repo``'s Snakefile in ``workdir``, ``repo``'s package first on the path."""
    cmd = [sys.executable, "-m", "snakemake", *targets, "-s", str(repo / "Snakefile"),
           "--directory", str(workdir), "--cores", str(cores), "--quiet", "all"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(repo)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))}
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        sys.exit(f"snakemake failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")


if __name__ == "__main__":
    main()
