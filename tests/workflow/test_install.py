"""What a user does: build the wheel, install it into a fresh venv, run cvsflow outside any clone.

The wheel is built (`pip wheel --no-deps`) from a copy of the repository's tracked files (an
in-tree build reuses `build/lib`, where a deleted module would survive), installed with its
declared dependencies into a new venv, and run in empty temporary folders outside the
repository with a clean environment (no PYTHONPATH): `cvsflow demo` renders and runs the demo
there, then `cvsflow run` runs a session file of the user's own on the demo's rendered inputs
in another folder. Slow (a few minutes on 2 cores): `.ci/run` runs it on its own.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pandas as pd
import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
#: Folders of a working copy that are not the source.
NOT_SOURCE = (".git", ".venv", "build", "results", "data", "logs", "benchmarks", ".snakemake",
              "__pycache__", ".pytest_cache", "cvsflow.egg-info")


def source_files() -> list[str]:
    """The repository's files as a clean clone has them (tracked and new, not ignored)."""
    proc = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                          cwd=REPO, capture_output=True, text=True)
    if proc.returncode == 0:
        return [f for f in proc.stdout.split("\0") if f and os.path.lexists(REPO / f)]
    return [str(p.relative_to(REPO)) for p in REPO.rglob("*")
            if (p.is_file() or p.is_symlink()) and not set(p.relative_to(REPO).parts) & set(NOT_SOURCE)]


def copy_source(dest: Path) -> list[str]:
    files = source_files()
    for name in files:
        target = dest / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, target, follow_symlinks=False)
    return files


def run(cmd: list, cwd: Path, env: dict, timeout: float = 1800) -> subprocess.CompletedProcess:
    proc = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, f"{cmd} failed:\n{proc.stdout[-4000:]}\n{proc.stderr[-4000:]}"
    return proc


@pytest.mark.slow
def test_wheel_installs_and_runs_the_demo_and_a_session_outside_the_repository(tmp_path):
    """The wheel holds the whole workflow; in a fresh venv, `cvsflow demo` and `cvsflow run` work
    from empty folders outside the repository, each run writing only under its own folder and
    `cvsflow run` running exactly the file's session with the schema's defaults."""
    times = {}
    src, wheels, venv = tmp_path / "src", tmp_path / "wheels", tmp_path / "venv"
    files = copy_source(src)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}

    t0 = time.perf_counter()
    run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "-w", wheels, src], tmp_path, env)
    (wheel,) = wheels.glob("cvsflow-*.whl")
    times["wheel_s"] = time.perf_counter() - t0
    names = set(zipfile.ZipFile(wheel).namelist())
    package = {f for f in files if f.startswith("cvsflow/") and "/__pycache__/" not in f}
    assert package - names == set(), "package files missing from the wheel"
    assert {"cvsflow/workflow/Snakefile", "cvsflow/workflow/demo.yaml",
            "cvsflow/workflow/profiles/default/config.yaml", "cvsflow/workflow/profiles/slurm/config.yaml",
            "cvsflow/workflow/schemas/config.schema.yaml", "cvsflow/workflow/report/workflow.rst"} <= names
    assert not [n for n in names if n.startswith(("tests/", "bench/", "config/"))]

    t0 = time.perf_counter()
    run([sys.executable, "-m", "venv", venv], tmp_path, env)
    run([venv / "bin" / "python", "-m", "pip", "install", "--quiet", wheel], tmp_path, env)
    times["install_s"] = time.perf_counter() - t0
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    where = run([venv / "bin" / "python", "-c", "import cvsflow; print(cvsflow.__file__)"], tmp_path, env)
    assert Path(where.stdout.strip()).is_relative_to(venv)
    cvsflow = venv / "bin" / "cvsflow"

    home = tmp_path / "user"
    home.mkdir()
    t0 = time.perf_counter()
    run([cvsflow, "demo", "demo", "--duration-s", "10"], home, env)
    times["demo_s"] = time.perf_counter() - t0
    demo = home / "demo"
    assert sorted(p.name for p in home.iterdir()) == ["demo"]
    assert (demo / "session.yaml").is_file() and (demo / "data" / "demo" / "video.mp4").is_file()
    assert yaml.safe_load((demo / "session.yaml").read_text())["sessions"]["demo"]["synth"]["duration_s"] == 10.0
    comparison = yaml.safe_load((demo / "results" / "demo" / "comparison.yaml").read_text())
    assert comparison["se3"]["per_dim"]["x_m"]["rmse"] < 0.01  # metres: a working fit, not a number to hold
    headline = pd.read_csv(demo / "results" / "headline.csv")
    assert {"demo", "flight flight_demo"} <= set(headline["session"])
    assert (demo / "logs" / "demo" / "corners.log").is_file()
    assert (demo / "benchmarks" / "demo" / "corners.tsv").is_file()

    # a session of the user's own (the demo's recording, given as files; only se3), elsewhere
    lab = home / "lab"
    lab.mkdir()
    session = yaml.safe_load((demo / "session.yaml").read_text())["sessions"]["demo"]
    mine = {k: session[k] for k in ("board", "markers")}
    mine.update({k: str(demo / session[k]) for k in ("calib_dir", "video")}, methods=["se3"])
    mine["mocap"] = {**session["mocap"], "file": str(demo / session["mocap"]["file"])}
    (home / "lab1.yaml").write_text(yaml.safe_dump({"sessions": {"lab1": mine}}))
    t0 = time.perf_counter()
    run([cvsflow, "run", "../lab1.yaml"], lab, env)
    times["run_s"] = time.perf_counter() - t0
    assert sorted(p.name for p in (lab / "results").iterdir() if p.is_dir()) == ["figures", "lab1"]
    assert not (lab / "data").exists()
    fit = yaml.safe_load((lab / "results" / "lab1" / "se3" / "calib" / "result.yaml").read_text())
    demo_fit = yaml.safe_load((demo / "results" / "demo" / "se3" / "calib" / "result.yaml").read_text())
    # the demo's config states every key at its schema default: the defaults give the same fit
    for key in ("fx_px", "fy_px", "dt_offset_s"):
        assert fit[key] == pytest.approx(demo_fit[key], rel=1e-9), key
    assert (lab / "results" / "lab1" / "comparison.yaml").is_file()
    print("install test timings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in times.items())
          + f"; wheel {wheel.stat().st_size} bytes")
