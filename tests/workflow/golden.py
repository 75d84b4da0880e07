"""The demo's tables against the last release's, with stated tolerances.

The golden files in ``tests/golden/demo/`` are the tables the demo (``config/config.yaml``, its
20 s session and its flight) wrote at the release named in ``tests/golden/MANIFEST.yaml``.
A change may move a number only within these tolerances:

- counts, flags, names and other non-float values: exactly;
- floats (geometry, estimates, statistics): 1e-9 relative, to the magnitude of the value or of
  its neighbours (the other numbers of the same mapping, list or table column), so that a mean
  of 1e-15 beside an RMS of 0.05 is held to 5e-11, not to 1e-24;
- a block bootstrap's interval ends (keys ``*_lo``, ``*_hi``): three Monte Carlo standard errors
  of a quantile of ``n_boot`` resamples (about 6 % of the interval's width at 1000 resamples);
- numbers printed inside text (a diverged run's reason): to their last printed digit.

A change that moves a number beyond them regenerates the golden files (``--update``) and says
which number moved, by how much and why, in its issue note::

    .venv/bin/python -m tests.workflow.golden --update RESULTS_DIR   # RESULTS_DIR: a demo run's results/
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

REPO = Path(__file__).resolve().parents[2]
GOLDEN = REPO / "tests" / "golden"

#: Relative tolerance of geometry, estimates and statistics.
REL_TOL = 1e-9
#: The tables kept, relative to results/. The raw marker tables (1.5 MB each) are left out:
#: mocap_repair.yaml counts every repair and bodies_30hz.parquet holds the bodies fitted to them.
TABLES = (
    "demo/camera.yaml", "demo/calib_corners.parquet", "demo/corners.parquet",
    "demo/corners_summary.yaml", "demo/poses_raw.parquet", "demo/mocap_repair.yaml",
    "demo/bodies_30hz.parquet", "demo/sync.yaml", "demo/pairs.parquet",
    "demo/se3/calib/result.yaml", "demo/se3/calib/iterations.parquet",
    "demo/se3/calib/errors.parquet", "demo/se3/calib/stats.json",
    "demo/seed/calib/result.yaml", "demo/seed/calib/iterations.parquet",
    "demo/seed/calib/errors.parquet", "demo/seed/calib/stats.json",
    "demo/heldout/se3.parquet", "demo/heldout/seed.parquet", "demo/heldout/se3_folds.yaml",
    "demo/comparison.yaml", "flights/flight_demo/stats.yaml",
    "flights/flight_demo/errors.parquet", "headline.csv", "summary.csv",
)
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def bootstrap_tolerance(lo: float, hi: float, n_boot: int, level: float) -> float:
    """Three Monte Carlo standard errors of an interval end from ``n_boot`` resamples.

    A sample quantile at p has standard error sqrt(p (1 - p) / n) / f(q_p); for a bootstrap
    distribution near normal, f(q_p) = phi(z_p) / s with s = (hi - lo) / (2 z_p).
    """
    p = (1.0 - level) / 2.0
    z = math.sqrt(2.0) * _erfinv(1.0 - 2.0 * p)
    phi = math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    spread = abs(hi - lo) / (2.0 * z)
    return 3.0 * math.sqrt(p * (1.0 - p) / n_boot) / phi * spread


def _erfinv(y: float) -> float:
    from scipy.special import erfinv

    return float(erfinv(y))


def _is_float(value) -> bool:
    return isinstance(value, float) and not isinstance(value, bool)


def _numbers_scale(values) -> float:
    finite = [abs(v) for v in values if _is_float(v) or (isinstance(v, int) and not isinstance(v, bool))]
    finite = [v for v in finite if math.isfinite(v)]
    return max(finite, default=0.0)


def _close(a: float, b: float, scale: float, tol: float | None = None) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    if math.isinf(a) or math.isinf(b):
        return a == b
    tol = REL_TOL * max(abs(a), abs(b), scale) if tol is None else tol
    return abs(a - b) <= tol


def _compare_text(path: str, a: str, b: str) -> list[str]:
    if _NUMBER.sub("#", a) != _NUMBER.sub("#", b):
        return [f"{path}: text differs: {a!r} != {b!r}"]
    out = []
    for x, y in zip(_NUMBER.findall(a), _NUMBER.findall(b), strict=True):
        digits = len(x.split(".")[1].split("e")[0].split("E")[0]) if "." in x else 0
        if abs(float(x) - float(y)) > 1.5 * 10.0 ** (-digits) + 1e-6 * abs(float(x)):
            out.append(f"{path}: number in text {x} -> {y}")
    return out


def compare_values(path: str, golden, new, *, scale: float = 0.0, n_boot: int = 1000,
                   level: float = 0.95, siblings: dict | None = None) -> list[str]:
    """Differences between two parsed YAML/JSON values beyond the tolerances, one line each."""
    if isinstance(golden, dict):
        if not isinstance(new, dict):
            return [f"{path}: mapping -> {type(new).__name__}"]
        out = []
        if set(golden) != set(new):
            out.append(f"{path}: keys {sorted(map(str, set(golden) ^ set(new)))} added or removed")
        inner = _numbers_scale(golden.values())
        for key in golden.keys() & new.keys():
            out += compare_values(f"{path}.{key}", golden[key], new[key], scale=inner,
                                  n_boot=n_boot, level=level, siblings=golden)
        return out
    if isinstance(golden, list):
        if not isinstance(new, list) or len(golden) != len(new):
            return [f"{path}: list of {len(golden)} -> {new if not isinstance(new, list) else len(new)}"]
        inner = max(_numbers_scale(golden), scale if all(_is_float(v) for v in golden) else 0.0)
        out = []
        for i, (g, n) in enumerate(zip(golden, new, strict=True)):
            out += compare_values(f"{path}[{i}]", g, n, scale=inner, n_boot=n_boot, level=level)
        return out
    if _is_float(golden) or _is_float(new):
        if not isinstance(new, int | float) or isinstance(new, bool) or isinstance(golden, bool):
            return [f"{path}: {golden!r} -> {new!r}"]
        tol = None
        key = path.rsplit(".", 1)[-1]
        if siblings is not None and (key.endswith("_lo") or key.endswith("_hi")):
            lo, hi = siblings.get(key[:-3] + "_lo"), siblings.get(key[:-3] + "_hi")
            if _is_float(lo) and _is_float(hi):
                tol = max(bootstrap_tolerance(lo, hi, n_boot, level), REL_TOL * abs(golden))
        if not _close(float(golden), float(new), scale, tol):
            return [f"{path}: {golden!r} -> {new!r} (difference {float(new) - float(golden):.3g})"]
        return []
    if isinstance(golden, str) and isinstance(new, str):
        return _compare_text(path, golden, new)
    if golden != new:
        return [f"{path}: {golden!r} -> {new!r}"]
    return []


def compare_frames(path: str, golden: pd.DataFrame, new: pd.DataFrame) -> list[str]:
    """Differences between two tables: same columns and rows; floats to the column's scale."""
    if list(golden.columns) != list(new.columns):
        return [f"{path}: columns {list(golden.columns)} -> {list(new.columns)}"]
    if len(golden) != len(new):
        return [f"{path}: {len(golden)} rows -> {len(new)}"]
    out = []
    for col in golden.columns:
        g, n = golden[col], new[col]
        if pd.api.types.is_float_dtype(g) or pd.api.types.is_float_dtype(n):
            gv, nv = g.to_numpy(float), n.to_numpy(float)
            if not np.array_equal(np.isnan(gv), np.isnan(nv)):
                out.append(f"{path}: column {col}: NaNs at other rows")
                continue
            ok = ~np.isnan(gv)
            scale = float(np.max(np.abs(gv[ok]), initial=0.0))
            diff = np.abs(gv[ok] - nv[ok])
            tol = REL_TOL * np.maximum(np.maximum(np.abs(gv[ok]), np.abs(nv[ok])), scale)
            bad = np.flatnonzero(diff > tol)
            if bad.size:
                row = int(np.flatnonzero(ok)[bad[0]])
                out.append(f"{path}: column {col}: {bad.size} rows beyond tolerance, first row {row}: "
                           f"{gv[row]!r} -> {nv[row]!r} (largest difference {diff.max():.3g})")
        elif pd.api.types.is_string_dtype(g) or g.dtype == object:
            for i, (a, b) in enumerate(zip(g.tolist(), n.tolist(), strict=True)):
                if isinstance(a, str) and isinstance(b, str):
                    msgs = _compare_text(f"{path}: column {col}, row {i}", a, b)
                elif a != b and not (pd.isna(a) and pd.isna(b)):
                    msgs = [f"{path}: column {col}, row {i}: {a!r} -> {b!r}"]
                else:
                    msgs = []
                if msgs:
                    out += msgs[:1]
                    break
        elif not g.equals(n):
            row = int(np.flatnonzero(g.to_numpy() != n.to_numpy())[0])
            out.append(f"{path}: column {col}, row {row}: {g.iloc[row]!r} -> {n.iloc[row]!r}")
    return out


def read_table(path: Path):
    if path.suffix == ".parquet":
        return pd.read_parquet(path)
    if path.suffix == ".csv":
        return pd.read_csv(path)
    if path.suffix == ".json":
        return json.loads(path.read_text())
    return yaml.safe_load(path.read_text())


def compare_results(golden_dir: Path, results_dir: Path, *, n_boot: int = 1000,
                    level: float = 0.95) -> list[str]:
    """Every difference beyond the tolerances between the golden tables and a run's results/."""
    out = []
    for rel in TABLES:
        new_path = results_dir / rel
        if not new_path.exists():
            out.append(f"{rel}: not written")
            continue
        golden, new = read_table(golden_dir / rel), read_table(new_path)
        if isinstance(golden, pd.DataFrame):
            out += compare_frames(rel, golden, new)
        else:
            out += compare_values(rel, golden, new, n_boot=n_boot, level=level)
    return out


def update(results_dir: Path) -> None:
    """Copy a demo run's tables into tests/golden/demo and record the commit they came from."""
    target = GOLDEN / "demo"
    if target.exists():
        shutil.rmtree(target)
    for rel in TABLES:
        dest = target / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        src = results_dir / rel
        if src.suffix == ".parquet":
            pd.read_parquet(src).to_parquet(dest, compression="zstd", index=False)
        else:
            shutil.copyfile(src, dest)
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    manifest = {"release": commit, "config": "config/config.yaml",
                "tables": list(TABLES), "rel_tol": REL_TOL}
    (GOLDEN / "MANIFEST.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path, help="a demo run's results/ folder")
    parser.add_argument("--update", action="store_true", help="make its tables the golden ones")
    args = parser.parse_args(argv)
    if args.update:
        update(args.results)
        return
    diffs = compare_results(GOLDEN / "demo", args.results)
    print("\n".join(diffs) if diffs else "all tables within tolerance")
    sys.exit(1 if diffs else 0)


if __name__ == "__main__":
    main()
