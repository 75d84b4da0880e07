"""How the pipeline's cost grows with session length and image size, per stage.

Renders the demo session (config/config.yaml's ``demo``, fast preset) at several lengths and
resolutions into a cache folder (``--cache``; each case once, reruns reuse it), runs the whole
workflow after ``synth`` on each case in a fresh working directory, and reads every job's
Snakemake benchmark file (``benchmarks/<session>/<stage>.tsv``: wall seconds and peak resident
memory) and its log (CPU seconds: bench/job_times.py). Then, per stage, it fits
``cost = a * duration**b`` by least squares in log-log over the 640x480 cases and prints the
exponent b of CPU time, wall time and peak memory (b = 1: linear; b = 0: flat).

    .venv/bin/python bench/bench_scaling.py --cores 2                       # every case
    .venv/bin/python bench/bench_scaling.py --cases 90x480 --keep-tables DIR # one case, keep its tables
    .venv/bin/python bench/bench_scaling.py --render-only                   # only fill the cache
    .venv/bin/python bench/bench_scaling.py --plot-only                     # redraw from --out

A case is ``<duration_s>x<height>``: 640x480, 1280x720 or 1920x1080. At the higher resolutions
the intrinsics (fx, fy, cx, cy) scale with the height so the vertical field of view stays the
demo's (16:9 images see more at the sides).
The flight demo is left out (its length does not follow the session's). CPU seconds are the
primary number on a shared machine; wall seconds are printed beside them.
Writes ``--out`` (CSV, one row per case, stage set and stage; a rerun replaces the earlier rows
of the same case and stage set) and the log-log figure ``--figure`` (cvsflow.plots.timing.plot_stage_scaling).
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml
from job_times import read_job_times  # beside this script

from cvsflow.plots.timing import prefer_whole_runs, stage_exponents

REPO = Path(__file__).resolve().parents[1]
SIZES = {480: (640, 480), 720: (1280, 720), 1080: (1920, 1080)}
DEFAULT_CASES = ["30x480", "90x480", "300x480", "30x720", "90x720", "30x1080", "90x1080"]
TABLE_SUFFIXES = (".parquet", ".csv", ".yaml", ".json", ".tum")


def parse_case(case: str) -> tuple[float, int]:
    """``"90x480"`` -> (90.0, 480); stops with a message naming the case otherwise."""
    try:
        duration, height = case.split("x")
        duration_s, height_px = float(duration), int(height)
    except ValueError:
        sys.exit(f"--cases: expected <duration_s>x<height> such as 90x480, got {case!r}")
    if height_px not in SIZES or duration_s <= 0:
        sys.exit(f"--cases {case!r}: height must be one of {sorted(SIZES)} and duration > 0")
    return duration_s, height_px


def case_config(duration_s: float, height_px: int) -> dict:
    """The demo config at this length and resolution, without the flight demo."""
    config = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    config["flights"] = {}
    demo = config["sessions"]["demo"]
    synth = demo["synth"]
    synth["duration_s"] = duration_s
    width, height = SIZES[height_px]
    if height_px != 480:
        synth["image_size"] = [width, height]
        # scaled with the height: the vertical field of view stays the demo's (its 15 stills
        # must hold the whole board), the wider 16:9 images see more at the sides
        scale = height / 480.0
        cam = synth["camera"]
        cam["fx_px"] *= scale
        cam["fy_px"] *= scale
        # Principal point at the same place relative to the image centre.
        cam["cx_px"] = width / 2 + (cam["cx_px"] - 320.0) * scale
        cam["cy_px"] = height / 2 + (cam["cy_px"] - 240.0) * scale
        # The subpixel window follows the square size in px (config corners.subpix_window_px).
        config["corners"]["subpix_window_px"] = int(round(config["corners"]["subpix_window_px"] * scale)) | 1
    config["sessions"] = {"demo": copy.deepcopy(demo)}
    return config


def render(cache: Path, config: dict, cores: int) -> Path:
    """Render the case once into ``cache`` (its ``data/``); return the cache folder."""
    if not (cache / "data" / "demo" / "truth.yaml").exists():
        print(f"rendering into {cache} ...", flush=True)
        (cache / "config").mkdir(parents=True, exist_ok=True)
        (cache / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
        t0 = time.perf_counter()
        run(cache, cores, "data/demo/truth.yaml")
        print(f"rendered in {time.perf_counter() - t0:.1f} s wall", flush=True)
    return cache


#: ``--stages front``: the stages before the optimisers (every stage that reads frames).
FRONT_TARGETS = ("results/demo/pairs.parquet", "results/demo/figures/poses_raw.png")


def run_case(case: str, cache_root: Path, cores: int, keep_tables: Path | None,
             stages: str = "all", code: str = "") -> pd.DataFrame:
    """Run the workflow (rendering excluded) on one case; one row per stage."""
    duration_s, height_px = parse_case(case)
    config = case_config(duration_s, height_px)
    cache = render(cache_root / case, config, cores)
    work = Path(tempfile.mkdtemp(prefix=f"cvsflow_scaling_{case}_"))
    try:
        (work / "config").mkdir()
        (work / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
        shutil.copytree(cache / "data", work / "data")
        # Mark the copied session as made by this workflow so that synth is not rerun.
        run(work, cores, "--touch", "data/demo/truth.yaml")
        t0 = time.perf_counter()
        run(work, cores, *(FRONT_TARGETS if stages == "front" else ()))
        wall = time.perf_counter() - t0
        rows = read_benchmarks(work / "benchmarks")
        if keep_tables is not None:
            write_table_hashes(work / "results", keep_tables / f"{case}.sha256")
    finally:
        shutil.rmtree(work)
    width, height = SIZES[height_px]
    rows.insert(0, "case", case)
    rows.insert(1, "duration_s", duration_s)
    rows.insert(2, "width_px", width)
    rows.insert(3, "height_px", height)
    rows["pipeline_wall_s"] = wall
    rows["stages"] = stages
    rows["code"] = code
    print(f"{case}: pipeline wall {wall:.1f} s on {cores} cores, jobs' CPU {rows['cpu_s'].sum():.1f} s",
          flush=True)
    return rows


def read_benchmarks(folder: Path) -> pd.DataFrame:
    """One row per job: stage (the benchmark file's name without the session), s, cpu_s, max_rss_MB."""
    jobs = read_job_times(folder.parent)
    in_synth = jobs["job"].map(lambda job: "synth" in Path(job).parts[:-1])
    jobs = jobs[(jobs["stage"] != "synth") & ~in_synth]
    return jobs[["stage", "s", "cpu_s", "max_rss_MB"]].reset_index(drop=True)


def write_table_hashes(results: Path, out: Path) -> None:
    """sha256 of every table under ``results`` (not the figures), one ``<hash>  <path>`` a line."""
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"{hashlib.sha256(p.read_bytes()).hexdigest()}  {p.relative_to(results)}"
             for p in sorted(results.rglob("*")) if p.is_file() and p.suffix in TABLE_SUFFIXES]
    out.write_text("\n".join(lines) + "\n")
    print(f"sha256 of {len(lines)} tables: {out}", flush=True)


def print_tables(raw: pd.DataFrame) -> None:
    table = prefer_whole_runs(raw)
    order = table.groupby("stage")["cpu_s"].max().sort_values(ascending=False).index
    cases = sorted(table["case"].unique(), key=lambda c: (parse_case(c)[1], parse_case(c)[0]))
    for col, title in (("cpu_s", "CPU s per stage"), ("s", "wall s per stage"),
                       ("max_rss_MB", "peak RSS (MB) per stage")):
        wide = table.pivot_table(index="stage", columns="case", values=col).reindex(order)[cases]
        print(f"\n{title}")
        digits = 0 if col == "max_rss_MB" else 1
        print(wide.to_string(float_format=lambda v, d=digits: f"{v:.{d}f}"))
    whole = raw[raw["stages"] == "all"] if "stages" in raw else raw
    totals = whole.groupby("case").agg(cpu_s=("cpu_s", "sum"), pipeline_wall_s=("pipeline_wall_s", "first"),
                                       peak_rss_MB=("max_rss_MB", "max")).dropna()
    print("\ntotals (rendering excluded)")
    print(totals.to_string(float_format=lambda v: f"{v:.1f}"))
    fits = stage_exponents(table)
    if len(fits):
        print("\nexponent b of cost = a * duration**b (640x480 cases, log-log least squares)")
        print(fits.to_string(index=False, float_format=lambda v: f"{v:.2f}"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=DEFAULT_CASES,
                        help="<duration_s>x<height>, e.g. 30x480 1200x480 90x1080")
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "cvsflow_scaling")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "benchmarks" / "scaling.csv")
    parser.add_argument("--figure", type=Path, default=None, help="draw the log-log figure here")
    parser.add_argument("--keep-tables", type=Path, default=None,
                        help="write the sha256 of each case's result tables into this folder")
    parser.add_argument("--stages", choices=("all", "front"), default="all",
                        help="front: only the stages up to pairs (calibrate, corners, poses, vicon, sync)")
    parser.add_argument("--render-only", action="store_true")
    parser.add_argument("--plot-only", action="store_true")
    args = parser.parse_args()

    if args.render_only:
        for case in args.cases:
            render(args.cache / case, case_config(*parse_case(case)), args.cores)
        return
    if not args.plot_only:
        code = code_version()
        new = pd.concat([run_case(c, args.cache, args.cores, args.keep_tables, args.stages, code)
                         for c in args.cases], ignore_index=True)
        if args.out.exists():
            old = pd.read_csv(args.out)
            if "stages" not in old:
                old["stages"] = "all"
            # a rerun of a case with the same stage set replaces its rows
            same = old.set_index(["case", "stages"]).index.isin(new.set_index(["case", "stages"]).index)
            new = pd.concat([old[~same], new], ignore_index=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        new.to_csv(args.out, index=False, float_format="%.3f")
        print(f"\nwrote {args.out}")
    raw = pd.read_csv(args.out)
    print_tables(raw)
    if args.figure is None:
        return
    from cvsflow.plots.timing import plot_stage_scaling

    fig = plot_stage_scaling(prefer_whole_runs(raw))
    args.figure.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.figure, dpi=110)
    print(f"wrote {args.figure}")


def code_version() -> str:
    """The checkout's short commit, with ``+dirty`` when tracked files differ from it."""
    git = ["git", "-C", str(REPO)]
    rev = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    if rev.returncode != 0:
        return "unknown"
    dirty = subprocess.run([*git, "diff", "--quiet", "HEAD"]).returncode != 0
    return rev.stdout.strip() + ("+dirty" if dirty else "")


def run(workdir: Path, cores: int, *targets: str) -> None:
    # quiet, but not "all": that also silences the error a failed run should show
    cmd = [sys.executable, "-m", "snakemake", *targets, "-s", str(REPO / "Snakefile"),
           "--directory", str(workdir), "--cores", str(cores),
           "--quiet", "progress", "rules", "host", "reason"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"snakemake failed in {workdir}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")


if __name__ == "__main__":
    main()
