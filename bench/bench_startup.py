"""Start-up cost of each workflow script: the CPU seconds of its import lines.

Every job is a fresh interpreter that imports its script's modules before it reads its first
input; with ~20 jobs per session that fixed cost adds up. Times, in fresh interpreters (best
of ``--repeat``), the import lines of every script in cvsflow/workflow/scripts/ and of the heavy
libraries they pull in, prints CPU and wall seconds and whether ``scipy.stats`` got loaded
(about 0.3 s of its own), and the sum over the scripts.

    .venv/bin/python bench/bench_startup.py
    .venv/bin/python bench/bench_startup.py --repo /path/to/other/checkout   # its scripts and package
"""

from __future__ import annotations

import argparse
import ast
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LIBRARIES = [("python (bare)", "pass"), ("numpy", "import numpy"), ("pandas", "import pandas"),
             ("scipy", "import scipy.optimize, scipy.spatial.transform"),
             ("scipy.stats", "import scipy.stats"), ("cv2", "import cv2"),
             ("matplotlib.pyplot", "import matplotlib.pyplot"),
             ("snakemake.script", "import snakemake.script")]
PROBE = "\nimport sys, time\nprint(int('scipy.stats' in sys.modules), time.process_time())"


def script_imports(repo: Path) -> list[tuple[str, str]]:
    """(name, import lines) of every workflow script of ``repo``."""
    cases = []
    for script in sorted((repo / "cvsflow" / "workflow" / "scripts").glob("*.py")):
        source = script.read_text()
        lines = [ast.get_source_segment(source, node) for node in ast.parse(source).body
                 if isinstance(node, (ast.Import, ast.ImportFrom))]
        cases.append((f"scripts/{script.name}", "\n".join(lines)))
    return cases


def time_imports(code: str, repo: Path, repeat: int = 3) -> tuple[float, float, bool]:
    """Best CPU and wall seconds of running ``code`` in a fresh interpreter in ``repo``, and
    whether it loaded scipy.stats."""
    best_wall = best_cpu = float("inf")
    stats = False
    for _ in range(repeat):
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", code + PROBE], capture_output=True, text=True,
                              cwd=repo, env={**os.environ, "PYTHONPATH": str(repo)})
        if proc.returncode != 0:
            sys.exit(f"import failed:\n{code}\n{proc.stderr[-2000:]}")
        best_wall = min(best_wall, time.perf_counter() - t0)
        flag, cpu = proc.stdout.split()[-2:]
        best_cpu, stats = min(best_cpu, float(cpu)), flag == "1"
    return best_cpu, best_wall, stats


def import_times(repo: Path = REPO, repeat: int = 3) -> None:
    """Print each library's and each workflow script's import CPU and wall seconds."""
    print(f"{'imports of':28s} {'cpu_s':>6s} {'wall_s':>6s}  scipy.stats")
    total_cpu = total_wall = 0.0
    for kind, cases in (("lib", LIBRARIES), ("script", script_imports(repo))):
        for name, code in cases:
            cpu, wall, stats = time_imports(code, repo, repeat)
            if kind == "script":
                total_cpu, total_wall = total_cpu + cpu, total_wall + wall
            print(f"{name:28s} {cpu:6.2f} {wall:6.2f}  {'yes' if stats else '-'}", flush=True)
    print(f"{'sum over the scripts':28s} {total_cpu:6.2f} {total_wall:6.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repo", type=Path, default=REPO, help="checkout whose scripts to time")
    parser.add_argument("--repeat", type=int, default=3, help="fresh interpreters per case (best)")
    args = parser.parse_args()
    import_times(args.repo.resolve(), args.repeat)


if __name__ == "__main__":
    main()
