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

``--imports`` times, in fresh interpreters (best of 3), the import lines of every script in
cvsflow/workflow/scripts/ and of the heavy libraries they pull in: the fixed cost each job pays
before it reads its first input (bench/bench_startup.py, which also runs on its own).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from job_times import read_job_times  # beside this script

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=90.0, help="demo length (s)")
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "cvsflow_bench")
    parser.add_argument("--keep", action="store_true", help="keep the working directory")
    parser.add_argument("--imports", action="store_true",
                        help="only time each workflow script's imports")
    args = parser.parse_args()
    if args.imports:
        from bench_startup import import_times  # beside this script

        import_times(REPO)
        return

    config = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    config["sessions"]["demo"]["synth"]["duration_s"] = args.duration
    cache = args.cache / f"demo_{args.duration:g}s"
    if not (cache / "data" / "demo" / "truth.yaml").exists():
        print(f"rendering the {args.duration:g} s demo into {cache} (once) ...", flush=True)
        (cache / "config").mkdir(parents=True, exist_ok=True)
        (cache / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
        t0 = time.perf_counter()
        run(cache, args.cores, "data/demo/truth.yaml")
        print(f"rendered in {time.perf_counter() - t0:.1f} s")

    work = Path(tempfile.mkdtemp(prefix="cvsflow_bench_run_"))
    (work / "config").mkdir()
    (work / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    shutil.copytree(cache / "data", work / "data")
    # Mark the copied session as made by this workflow so that synth is not rerun.
    run(work, args.cores, "--touch", "data/demo/truth.yaml")
    t0 = time.perf_counter()
    run(work, args.cores)
    wall = time.perf_counter() - t0

    table = read_job_times(work).drop(columns="stage").sort_values("s", ascending=False)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.1f}"))
    print(f"\ndemo {args.duration:g} s, {args.cores} cores: pipeline wall time {wall:.1f} s "
          f"(rendering excluded); jobs' CPU {table['cpu_s'].sum():.1f} s; "
          f"peak RSS of one job {table['max_rss_MB'].max():.0f} MB")
    if args.keep:
        print(f"working directory kept: {work}")
    else:
        shutil.rmtree(work)


def run(workdir: Path, cores: int, *targets: str) -> None:
    cmd = [sys.executable, "-m", "snakemake", *targets, "-s", str(REPO / "Snakefile"),
           "--directory", str(workdir), "--cores", str(cores), "--quiet", "all"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"snakemake failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")


if __name__ == "__main__":
    main()
