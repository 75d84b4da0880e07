"""Time the seed optimiser and its held-out scoring, before and after a change, and check that
the outputs are byte-identical.

Usage::

    .venv/bin/python bench/bench_seed.py                                   # synthetic session
    .venv/bin/python bench/bench_seed.py --results results/demo            # a pipeline session
    .venv/bin/python bench/bench_seed.py --results results/demo --impl after --cv

``--results DIR`` takes ``pairs.parquet``, ``corners.parquet`` and ``camera.yaml`` from a
pipeline results folder, the board of ``--session`` and the options ``optimise.seed`` and
``evaluate`` from ``--config`` (default config/config.yaml), like the workflow's
``optimise_seed`` and ``heldout_seed`` rules (``heldout/se3.parquet``, when present, gives the
held-out blocks as in the workflow). Without it a synthetic session is made: a 5 x 4
inner-corner board (square 0.09 m) along a random smooth trajectory at 1-4 m with K (fx 700,
fy 700, cx 320, cy 240), OpenCV distortion and 0.2 px noise; P* is the true pose minus a
constant offset, so the right answer is f = (700, 700) px and P_bar = the offset; the
optimiser starts at (660, 730) px.

``--impl before`` runs cvsflow/optimise/seed.py as it was at git revision ``--before``
(default: the last commit before this round's changes), ``after`` the working tree's module,
``both`` (default) one then the other. Each run writes result.yaml (without the wall times),
iterations.parquet, errors.parquet and, with ``--cv``, the held-out table as the workflow
scripts do, and prints their sha256 and wall and CPU seconds (``time.process_time``: the
machine may be shared, so CPU seconds are the steadier number; with threads, CPU seconds
can exceed wall seconds).
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import yaml

import cvsflow.evaluate_seed as evaluate_seed
import cvsflow.optimise.seed as seed_after
from cvsflow.evaluate_seed import cross_validate_seed
from cvsflow.io import read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.optimise.seed import POSE_DIMS, board_object_points
from cvsflow.transforms import T_from_pose6, rvec_tvec_from_T

REPO = Path(__file__).resolve().parents[1]
#: cvsflow/optimise/seed.py before the lazy Jacobian and buffered projection (issue 20, second
#: round; ddf966f is the one before the batched multi-candidate solver)
BEFORE_REV = "c41661e"
BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
DIST = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02])
OFFSET = np.array([0.05, -0.03, 0.10, 0.02, -0.01, 0.03])
OUTPUTS = ("result.yaml", "iterations.parquet", "errors.parquet")


def synthesise(n_frames, seed, noise_px=0.2):
    """pairs, corners and K of a synthetic session (truth f = 700 px)."""
    rng = np.random.default_rng(seed)
    X_B = board_object_points(BOARD)
    K = np.array([[700.0, 0.0, 320.0], [0.0, 700.0, 240.0], [0.0, 0.0, 1.0]])
    t_s = np.arange(n_frames) / 30.0
    s = np.sin(2 * np.pi * rng.uniform(0.05, 0.25, 6) * t_s[:, None] + rng.uniform(0, 6.3, 6))
    z = 2.5 + 1.4 * s[:, 2]
    pose = np.stack([0.2 * z * s[:, 0] - 0.18, 0.15 * z * s[:, 1] - 0.135, z,
                     0.5 * s[:, 3], 0.5 * s[:, 4], 0.3 * s[:, 5]], axis=1)
    rvec, tvec = rvec_tvec_from_T(T_from_pose6(pose))
    uv = np.stack([cv2.projectPoints(X_B, rvec[i], tvec[i], K, DIST)[0][:, 0]
                   for i in range(n_frames)])
    uv += rng.normal(0.0, noise_px, uv.shape)
    n_c = X_B.shape[0]
    frames = np.arange(n_frames)
    corners = pd.DataFrame({"frame": np.repeat(frames, n_c), "found": True,
                            "corner": np.tile(np.arange(n_c), n_frames),
                            "u_px": uv[..., 0].ravel(), "v_px": uv[..., 1].ravel()})
    pairs = pd.DataFrame({"frame": frames, "t_s": t_s})
    for i, d in enumerate(POSE_DIMS):
        pairs[f"cvs_{d}"] = pose[:, i]
        pairs[f"vic_{d}"] = pose[:, i] - OFFSET[i]
    for i in range(3):
        pairs[f"cvs_rvec_{i}"] = rvec[:, i]
    return pairs, corners, K


def load_before(rev):
    """cvsflow/optimise/seed.py at git revision ``rev``, as a module of its own."""
    src = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:cvsflow/optimise/seed.py"],
                         capture_output=True, text=True, check=True).stdout
    path = Path(tempfile.mkdtemp(prefix="bench_seed_")) / "seed_before.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("cvsflow_seed_before", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@contextmanager
def using(module):
    """Let cross_validate_seed call ``module``'s optimiser.

    cvsflow.evaluate_seed binds ``optimise_seed`` by name at import, so its name is the one to swap
    (swapping the seed module's attribute alone left the held-out scoring on the new code).
    """
    saved = seed_after.optimise_seed, evaluate_seed.optimise_seed
    seed_after.optimise_seed = evaluate_seed.optimise_seed = module.optimise_seed
    try:
        yield
    finally:
        seed_after.optimise_seed, evaluate_seed.optimise_seed = saved


def sha(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def timed(fn):
    """fn(), its wall and CPU seconds."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def run(module, inputs, opts, cv, out_dir):
    """Run one implementation; write its outputs as the workflow does; timings and hashes."""
    out_dir.mkdir(parents=True, exist_ok=True)
    pairs, corners, K, dist, board, folds, ev = inputs
    with using(module):
        res, wall, cpu = timed(lambda: module.optimise_seed(pairs, corners, K, dist, board,
                                                            **opts))
        stats = {"optimise_seed": (wall, cpu, res.result["n_pnp_solves"])}
        write_parquet(res.iterations, out_dir / "iterations.parquet")
        write_parquet(res.errors, out_dir / "errors.parquet")
        res.result.pop("timings_s", None)
        write_yaml(res.result, out_dir / "result.yaml")
        files = list(OUTPUTS)
        if cv:
            cv_opts = {**opts, "k_iterations": ev["seed_k_iterations"]}
            held, wall, cpu = timed(lambda: cross_validate_seed(
                pairs, corners, K, dist, board, n_folds=ev["n_folds"], block_s=ev["block_s"],
                seed=ev["seed"], folds=folds, **cv_opts))
            stats["cross_validate_seed"] = (wall, cpu, None)
            write_parquet(held, out_dir / "heldout_seed.parquet")
            files.append("heldout_seed.parquet")
    return stats, {f: sha(out_dir / f) for f in files}, res.result


def main():
    """Parse, run before and/or after, print timings, ratios and hash equality."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, help="pipeline results folder of one session")
    ap.add_argument("--config", type=Path, default=REPO / "config" / "config.yaml")
    ap.add_argument("--session", default="demo")
    ap.add_argument("--frames", type=int, default=2400, help="synthetic session length")
    ap.add_argument("--seed", type=int, default=0, help="synthetic session seed")
    ap.add_argument("--k", type=int, help="k_iterations (default: config, or 50)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--objective", help="default: config, or sum_squares")
    ap.add_argument("--cv", action="store_true", help="also time cross_validate_seed")
    ap.add_argument("--impl", choices=("before", "after", "both"), default="both")
    ap.add_argument("--before", default=BEFORE_REV, help="git revision of the 'before' code")
    ap.add_argument("--out", type=Path, help="keep the outputs here")
    args = ap.parse_args()

    config = yaml.safe_load(args.config.read_text())
    ev = config["evaluate"]
    if args.results is not None:
        camera = read_yaml(args.results / "camera.yaml")
        pairs = read_parquet(args.results / "pairs.parquet")
        corners = read_parquet(args.results / "corners.parquet")
        K, dist = np.array(camera["K"]), np.array(camera["dist"])
        board = config["sessions"][args.session]["board"]
        se3 = args.results / "heldout" / "se3.parquet"
        folds = read_parquet(se3, columns=["t_s", "fold"]) if se3.exists() else None
        opts = dict(config["optimise"]["seed"])
        label = f"{args.results} (board of session {args.session!r})"
    else:
        pairs, corners, K = synthesise(args.frames, args.seed)
        dist, board, folds = DIST, BOARD, None
        opts = {"k_iterations": 50, "f_init_px": (660.0, 730.0)}
        label = f"synthetic, {args.frames} frames, seed {args.seed}"
    if args.k is not None:
        opts["k_iterations"] = args.k
    if args.objective is not None:
        opts["objective"] = args.objective
    opts["n_workers"] = args.workers
    inputs = (pairs, corners, K, dist, board, folds, ev)
    print(f"session: {label}; {len(pairs)} pairs; options {opts}")

    impls = {"before": lambda: load_before(args.before), "after": lambda: seed_after}
    chosen = ["before", "after"] if args.impl == "both" else [args.impl]
    out_root = args.out or Path(tempfile.mkdtemp(prefix="bench_seed_out_"))
    runs = {}
    for name in chosen:
        runs[name] = run(impls[name](), inputs, opts, args.cv, out_root / name)
        stats, hashes, result = runs[name]
        for stage, (wall, cpu, solves) in stats.items():
            extra = f"  pnp_solves {solves}" if solves is not None else ""
            print(f"{name:6s} {stage:20s} wall_s {wall:7.2f}  cpu_s {cpu:7.2f}{extra}")
        print(f"{name:6s} f ({result['fx_px']:.4f}, {result['fy_px']:.4f}) px  "
              f"norm {result['norm_normalised_init_m']:.5f} -> "
              f"{result['norm_normalised_final_m']:.5f} m")
        for f, h in hashes.items():
            print(f"{name:6s} sha256 {h[:16]}  {f}")
    if len(runs) == 2:
        (sb, hb, _), (sa, ha, _) = runs["before"], runs["after"]
        for stage in sb:
            (wb, cb, _), (wa, ca, _) = sb[stage], sa[stage]
            print(f"speed-up {stage:20s} wall x{wb / wa:5.2f}  cpu x{cb / ca:5.2f}")
        same = all(hb[f] == ha[f] for f in hb)
        for f in hb:
            print(f"identical {f:22s} {hb[f] == ha[f]}")
        print("outputs byte-identical:", same)
        if not same:
            sys.exit(1)
    if args.out is None:
        print(f"outputs in {out_root}")


if __name__ == "__main__":
    main()
