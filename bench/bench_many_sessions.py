"""Many sessions end to end: N rendered sessions locally and through SLURM, timings and tables.

Makes N sessions from the demo session of config/config.yaml (``s00`` .. ``s{N-1}``, synth seed =
the demo's seed + k, length ``--duration-s``; the flight demo left out: it is not a session),
renders each once into a cache folder (``--cache``; the workflow's ``synth`` rule, reused on a
rerun while the session's synth block is unchanged), then for each mode runs the whole DAG after
``synth`` on all N sessions in a fresh working directory:

* ``local``: ``snakemake --cores 2`` (the workstation profile);
* ``slurm``: ``snakemake --workflow-profile profiles/slurm`` on the single-node cluster of
  cluster/slurm-localhost.sh, started here if ``sinfo`` does not answer (``make slurm-up``); if it
  cannot be started the mode is skipped, with the reason.

Per mode it prints the total wall time and, per session, from Snakemake's benchmark files
(``benchmarks/<session>/<stage>.tsv``): the span from its first job's start to its last job's end
(a benchmark file is written when its job ends, so end = the file's mtime and start = end - s),
the sum of its jobs' wall seconds and their CPU seconds. A job's benchmark covers its script only:
through SLURM each job also starts its own Snakemake, which the span shows and the sums do not.
Then the sha256 of every table under results/ (``*.parquet``, ``*.csv``, ``*.yaml``, ``*.json``)
is compared between the modes: the count equal and different, and every different one listed.
Exits 1 if any table differs. Rendering is done first and is not in the timings.

    .venv/bin/python bench/bench_many_sessions.py                                  # 20 x 90 s
    .venv/bin/python bench/bench_many_sessions.py --n-sessions 20 --duration-s 20 --modes local,slurm
    .venv/bin/python bench/bench_many_sessions.py --n-sessions 2 --duration-s 20   # smoke run

A session must hold the held-out scoring's folds (evaluate.n_folds blocks of evaluate.block_s,
5 x 2 s in the demo config) and enough pairs per fold: 5 s is too short, 20 s (the demo's) works.

Both modes run with ``OPENCV_FOR_THREADS_NUM=1`` as tests/workflow/test_slurm.py does (OpenCV's
default thread pool sums in another order from run to run; the rules that use more threads set
them themselves).
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pandas as pd
import yaml
from job_times import read_job_times  # beside this script

REPO = Path(__file__).resolve().parents[1]
PROFILE = REPO / "profiles" / "slurm"
CLUSTER = REPO / "cluster" / "slurm-localhost.sh"
TABLE_SUFFIXES = (".parquet", ".csv", ".yaml", ".json")
MODES = ("local", "slurm")
ENV = {**os.environ, "OPENCV_FOR_THREADS_NUM": "1"}


def session_names(n_sessions: int) -> list[str]:
    """``s00`` .. ``s{N-1}`` (two digits at least, so that they sort)."""
    width = max(2, len(str(n_sessions - 1)))
    return [f"s{k:0{width}d}" for k in range(n_sessions)]


def sessions_config(n_sessions: int, duration_s: float) -> dict:
    """The demo config with N copies of the demo session, seeds base + k, without the flight."""
    config = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    config["flights"] = {}
    demo = config["sessions"]["demo"]
    base_seed = int(demo["synth"]["seed"])
    sessions = {}
    for k, name in enumerate(session_names(n_sessions)):
        s = copy.deepcopy(demo)
        s["synth"]["seed"] = base_seed + k
        s["synth"]["duration_s"] = float(duration_s)
        s["calib_dir"], s["video"] = f"data/{name}/calib", f"data/{name}/video.mp4"
        s["mocap"] = {"file": f"data/{name}/vicon.csv"}
        sessions[name] = s
    config["sessions"] = sessions
    return config


def write_config(workdir: Path, config: dict) -> None:
    (workdir / "config").mkdir(parents=True, exist_ok=True)
    (workdir / "config" / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))


def render(cache: Path, config: dict) -> None:
    """Render every session not yet in ``cache/data`` (or whose synth block changed), 2 cores."""
    stamps = cache / "stamps"
    stamps.mkdir(parents=True, exist_ok=True)
    missing = []
    for name, s in config["sessions"].items():
        stamp = yaml.safe_dump(s["synth"], sort_keys=True)
        done = (cache / "data" / name / "truth.yaml").exists()
        if done and (stamps / f"{name}.yaml").exists() and (stamps / f"{name}.yaml").read_text() == stamp:
            continue
        shutil.rmtree(cache / "data" / name, ignore_errors=True)
        missing.append(name)
    if not missing:
        print(f"all {len(config['sessions'])} sessions rendered already in {cache}", flush=True)
        return
    print(f"rendering {len(missing)} sessions into {cache} ...", flush=True)
    write_config(cache, config)
    t0 = time.perf_counter()
    snakemake(cache, "--cores", "2", *(f"data/{n}/truth.yaml" for n in missing))
    for name in missing:
        (stamps / f"{name}.yaml").write_text(yaml.safe_dump(config["sessions"][name]["synth"],
                                                            sort_keys=True))
    print(f"rendered in {time.perf_counter() - t0:.1f} s wall (not in the timings below)", flush=True)


def snakemake(workdir: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"),
           "--directory", str(workdir), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=ENV)
    if check and proc.returncode != 0:
        sys.exit(f"snakemake {' '.join(args)} failed in {workdir}:\n"
                 f"{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}")
    return proc


def sinfo_answers() -> bool:
    if not shutil.which("sinfo"):
        return False
    try:
        proc = subprocess.run(["sinfo", "-h", "-o", "%T"], capture_output=True, text=True, timeout=20)
    except subprocess.TimeoutExpired:
        return False
    return proc.returncode == 0 and bool(proc.stdout.strip())


def ensure_cluster() -> str | None:
    """None when the single-node cluster answers (started here if needed); else why it does not."""
    if importlib.util.find_spec("snakemake_executor_plugin_slurm") is None:
        return "snakemake-executor-plugin-slurm is not installed: .venv/bin/pip install -e '.[test,slurm]'"
    if sinfo_answers():
        return None
    print(f"starting the single-node SLURM cluster: {CLUSTER.relative_to(REPO)} start", flush=True)
    proc = subprocess.run([str(CLUSTER), "start"], capture_output=True, text=True)
    if proc.returncode != 0 or not sinfo_answers():
        return f"{CLUSTER.name} start failed (rc {proc.returncode}): {(proc.stderr or proc.stdout)[-1500:]}"
    return None


def run_mode(mode: str, cache: Path, config: dict, keep: Path | None) -> tuple[float, pd.DataFrame, dict]:
    """The whole DAG after synth on every session in a fresh working directory.

    Returns the wall time (s), one row per job (its benchmark file) and the sha256 of every table
    under results/ by path.
    """
    work = Path(tempfile.mkdtemp(prefix=f"cvsflow_many_{mode}_"))
    try:
        write_config(work, config)
        (work / "data").mkdir()
        for name in config["sessions"]:
            shutil.copytree(cache / "data" / name, work / "data" / name)
        # Mark the copied sessions as made by this workflow so that synth is not rerun.
        snakemake(work, "--cores", "2", "--touch",
                  *(f"data/{n}/truth.yaml" for n in config["sessions"]))
        args = (["--cores", "2"] if mode == "local"
                else ["--workflow-profile", str(PROFILE)])
        print(f"{mode}: running {len(config['sessions'])} sessions in {work} ...", flush=True)
        t0 = time.perf_counter()
        with LoadSampler() as load:
            proc = snakemake(work, *args)
        wall = time.perf_counter() - t0
        # on a shared machine the load says how much of the wall time was someone else's
        print(f"{mode}: 1-min load average during the run: mean {load.mean():.2f}, max {load.max():.2f} "
              f"({os.cpu_count()} CPUs)", flush=True)
        jobs = read_jobs(work / "benchmarks")
        if mode == "slurm":
            n_sub = (proc.stdout + proc.stderr).count("has been submitted with SLURM jobid")
            print(f"slurm: {n_sub} SLURM jobs submitted", flush=True)
        hashes = table_hashes(work / "results")
        if keep is not None:
            shutil.copytree(work / "results", keep / mode / "results", dirs_exist_ok=True)
            shutil.copytree(work / "benchmarks", keep / mode / "benchmarks", dirs_exist_ok=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return wall, jobs, hashes


class LoadSampler:
    """The 1-min load average every 5 s while the block runs (a background thread)."""

    def __init__(self, every_s: float = 5.0):
        self.every_s, self.samples = every_s, [os.getloadavg()[0]]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            self.samples.append(os.getloadavg()[0])

    def __enter__(self) -> LoadSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self.samples.append(os.getloadavg()[0])

    def mean(self) -> float:
        return sum(self.samples) / len(self.samples)

    def max(self) -> float:
        return max(self.samples)


def read_jobs(folder: Path) -> pd.DataFrame:
    """One row per job: session (``-`` for the jobs over all sessions), stage, s, cpu_s, start, end.

    ``end`` is the benchmark file's mtime (Snakemake writes it when the job ends), ``start`` is
    ``end - s``; both in seconds since the epoch.
    """
    rows = []
    for job in read_job_times(folder.parent).itertuples():
        if job.stage == "synth":
            continue
        parts = Path(job.job).parts
        end = (folder / f"{job.job}.tsv").stat().st_mtime
        rows.append({"session": parts[0] if len(parts) == 2 else "-", "stage": job.stage,
                     "s": job.s, "cpu_s": job.cpu_s, "start": end - job.s, "end": end})
    return pd.DataFrame(rows)


def per_session(jobs: pd.DataFrame) -> pd.DataFrame:
    g = jobs.groupby("session")
    table = pd.DataFrame({"jobs": g.size(), "span_s": g["end"].max() - g["start"].min(),
                          "wall_sum_s": g["s"].sum(), "cpu_s": g["cpu_s"].sum()})
    return table


def table_hashes(results: Path) -> dict[str, str]:
    return {str(p.relative_to(results)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(results.rglob("*"))
            if p.is_file() and p.suffix in TABLE_SUFFIXES and not p.name.startswith(".")}


def print_mode(mode: str, wall: float, jobs: pd.DataFrame, n_sessions: int, duration_s: float) -> None:
    table = per_session(jobs)
    print(f"\n== {mode}: {n_sessions} sessions x {duration_s:g} s, whole DAG after synth ==")
    print(f"total wall {wall:.1f} s; jobs {len(jobs)}; jobs' wall sum {jobs['s'].sum():.1f} s; "
          f"jobs' CPU {jobs['cpu_s'].sum():.1f} s")
    print("per session (span = first job's start to last job's end; '-' = jobs over all sessions):")
    print(table.to_string(float_format=lambda v: f"{v:.1f}"))
    sess = table.drop(index="-", errors="ignore")
    if len(sess):
        print(f"sessions: span {sess['span_s'].min():.1f} .. {sess['span_s'].max():.1f} s, "
              f"wall sum {sess['wall_sum_s'].min():.1f} .. {sess['wall_sum_s'].max():.1f} s, "
              f"CPU {sess['cpu_s'].min():.1f} .. {sess['cpu_s'].max():.1f} s "
              f"(median {sess['cpu_s'].median():.1f})", flush=True)


def compare(hashes: dict[str, dict[str, str]]) -> int:
    """Print equal/different counts between the first mode and each other; the number different."""
    modes = list(hashes)
    n_bad = 0
    ref = hashes[modes[0]]
    for other in modes[1:]:
        got = hashes[other]
        names = sorted(ref.keys() | got.keys())
        equal = [n for n in names if ref.get(n) is not None and ref.get(n) == got.get(n)]
        differ = [n for n in names if n not in equal]
        print(f"\n== tables under results/ ({', '.join(TABLE_SUFFIXES)}), sha256 {modes[0]} vs {other} ==")
        print(f"{len(equal)} equal, {len(differ)} different (of {len(names)})")
        for n in differ:
            where = ("only in " + (modes[0] if n in ref else other)) if (n in ref) != (n in got) else "differs"
            print(f"  {n}: {where}")
        n_bad += len(differ)
    return n_bad


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-sessions", type=int, default=20)
    parser.add_argument("--duration-s", type=float, default=90.0, help="length of each session (s)")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "cvsflow_many")
    parser.add_argument("--modes", default="local,slurm", help="comma-separated: local, slurm")
    parser.add_argument("--keep", type=Path, default=None,
                        help="copy each mode's results/ and benchmarks/ into this folder")
    parser.add_argument("--render-only", action="store_true")
    args = parser.parse_args()
    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    if not modes or set(modes) - set(MODES):
        sys.exit(f"--modes: a comma-separated list of {', '.join(MODES)}, got {args.modes!r}")
    if args.n_sessions < 1 or args.duration_s <= 0:
        sys.exit("--n-sessions must be >= 1 and --duration-s > 0")

    config = sessions_config(args.n_sessions, args.duration_s)
    cache = args.cache / f"d{args.duration_s:g}s"
    print(f"{args.n_sessions} sessions {', '.join(config['sessions'])[:60]}..., "
          f"{args.duration_s:g} s each, seeds {config['sessions'][session_names(1)[0]]['synth']['seed']}"
          f" + k; modes {', '.join(modes)}; {os.cpu_count()} CPUs", flush=True)
    render(cache, config)
    if args.render_only:
        return

    hashes = {}
    for mode in modes:
        if mode == "slurm":
            why = ensure_cluster()
            if why is not None:
                print(f"\n== slurm: SKIPPED, the single-node cluster cannot be started here ==\n{why}",
                      flush=True)
                continue
        wall, jobs, hashes[mode] = run_mode(mode, cache, config, args.keep)
        print_mode(mode, wall, jobs, args.n_sessions, args.duration_s)
    if len(hashes) < 2:
        print(f"\nonly {', '.join(hashes) or 'no'} mode ran: no tables compared "
              f"({len(next(iter(hashes.values()), {}))} tables)")
        return
    if compare(hashes):
        sys.exit(1)


if __name__ == "__main__":
    main()
