"""Time the seed optimiser and its held-out scoring, before and after a change, and check that
the outputs are byte-identical.

Usage::

    .venv/bin/python bench/bench_seed.py                                   # synthetic session
    .venv/bin/python bench/bench_seed.py --results results/demo --cv       # a pipeline session
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

``--impl before`` runs the whole ``cvsflow`` package as it was at git revision ``--before``
(default: the last commit before this round's changes; ``git archive`` into a temporary folder),
``after`` the working tree's, ``both`` (default) one then the other. Each runs in a fresh
interpreter with that package first on ``PYTHONPATH`` (swapping modules in one process left
the held-out scoring on the other revision's PnP), writes result.yaml (without the wall
times), iterations.parquet, errors.parquet and, with ``--cv``, the held-out table as the
workflow scripts do, and prints their sha256 and wall and CPU seconds (``time.process_time``:
the machine may be shared, so CPU seconds are the steadier number; with threads, CPU seconds
can exceed wall seconds). ``--repeat N`` runs each implementation N times and keeps each
stage's least CPU (the outputs of every repeat must hash alike): on a shared machine one run's
CPU seconds scatter by +-10 %.

``--after REV`` runs revision REV as 'after' instead of the working tree. ``--paths`` replaces
byte identity by the condition a faster route to the seed method must meet: on the session,
the focal path (``fx_px, fy_px`` of every row of ``iterations``) and the verdict
(``diverged``, ``diverged_reason``) of the full fit and of every held-out fold are the same,
and the final focal lengths move by less than a tenth of a grid step; it prints the largest
focal-path difference in grid steps, the verdicts, and how far P_bar and the held-out errors
moved (exit status 1 when the condition fails)::

    .venv/bin/python bench/bench_seed.py --results DIR --cv --before main --paths
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import yaml

from cvsflow.board import board_object_points
from cvsflow.evaluate import cross_validate_seed
from cvsflow.geometry import T_from_pose6, rvec_tvec_from_T
from cvsflow.io.files import read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.metrics import ERROR_DIMS
from cvsflow.optimise import optimise_seed

REPO = Path(__file__).resolve().parents[1]
#: The package before the Jacobian planes and the folds' shared PnP rows (issue 20, third round;
#: c41661e is the one before the lazy Jacobian and buffered projection, ddf966f the one before
#: the batched multi-candidate solver; the 'before' of those rounds swapped seed.py alone)
BEFORE_REV = "72e1f3f"
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
    for i, d in enumerate(ERROR_DIMS):
        pairs[f"cvs_{d}"] = pose[:, i]
        pairs[f"vic_{d}"] = pose[:, i] - OFFSET[i]
    for i in range(3):
        pairs[f"cvs_rvec_{i}"] = rvec[:, i]
    return pairs, corners, K


def package_at(rev):
    """A folder holding the ``cvsflow`` package of git revision ``rev`` (``git archive``)."""
    archive = subprocess.run(["git", "-C", str(REPO), "archive", rev, "cvsflow"],
                             capture_output=True, check=True).stdout
    root = Path(tempfile.mkdtemp(prefix=f"bench_seed_{rev}_"))
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(root, filter="data")
    return root


def sha(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def timed(fn):
    """fn(), its wall and CPU seconds."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w0, time.process_time() - c0


def run(inputs, opts, cv, out_dir):
    """Run the imported package once; write its outputs as the workflow does; timings, hashes."""
    out_dir.mkdir(parents=True, exist_ok=True)
    pairs, corners, K, dist, board, folds, ev = inputs
    res, wall, cpu = timed(lambda: optimise_seed(pairs, corners, K, dist, board, **opts))
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
    result = {k: res.result[k] for k in ("fx_px", "fy_px", "norm_normalised_init_m",
                                         "norm_normalised_final_m")}
    return stats, {f: sha(out_dir / f) for f in files}, result


def compare_paths(before, after, opts):
    """Print how the after run's focal paths and verdicts compare with the before run's.

    The grid step is the first level's, 2 grid_half_width_px / (grid_points - 1). Returns
    True when the focal paths and verdicts (full fit and held-out folds) are the same and the
    final focal lengths moved by less than a tenth of a grid step.
    """
    half = float(opts.get("grid_half_width_px", 32.0))
    step = 2.0 * half / (int(opts.get("grid_points", 5)) - 1)
    ib, ia = (read_parquet(d / "iterations.parquet") for d in (before, after))
    rb, ra = (read_yaml(d / "result.yaml") for d in (before, after))
    fb, fa = (x[["fx_px", "fy_px"]].to_numpy(float) for x in (ib, ia))
    df = np.abs(fb - fa).max(axis=1) / step if fb.shape == fa.shape else np.array([np.inf])
    first = int(np.argmax(df > 0)) if (df > 0).any() else None
    final = max(abs(rb["fx_px"] - ra["fx_px"]), abs(rb["fy_px"] - ra["fy_px"])) / step
    verdict = (rb["diverged"], rb["diverged_reason"]) == (ra["diverged"], ra["diverged_reason"])
    d_pbar = np.abs(np.subtract(rb["P_bar"], ra["P_bar"])).max()
    print(f"grid step {step:g} px; full fit: focal path max diff {df.max():.3g} grid steps "
          f"(first differing row {first}), final f diff {final:.3g} grid steps, verdict same "
          f"{verdict} (diverged {rb['diverged']} -> {ra['diverged']}), max |dP_bar| {d_pbar:.3g}")
    if not verdict:
        print(f"  before: {rb['diverged_reason']}\n  after:  {ra['diverged_reason']}")
    ok = bool(df.max() == 0 and verdict and final < 0.1)
    hb_path, ha_path = before / "heldout_seed.parquet", after / "heldout_seed.parquet"
    if hb_path.exists() and ha_path.exists():
        hb, ha = read_parquet(hb_path), read_parquet(ha_path)
        cols = ["fold", "fx_px", "fy_px", "diverged", "diverged_reason"]
        fold_b, fold_a = (h[cols].drop_duplicates().sort_values("fold").reset_index(drop=True)
                          for h in (hb, ha))
        same_folds = fold_b.equals(fold_a)
        eps = [f"eps_{d}" for d in ERROR_DIMS]
        d_eps = (np.nanmax(np.abs(hb[eps].to_numpy(float) - ha[eps].to_numpy(float)))
                 if hb["frame"].equals(ha["frame"]) else np.inf)
        print(f"held-out folds: focal lengths and verdicts same {same_folds} ({len(fold_b)} folds), "
              f"max |d eps| {d_eps:.3g} (m, rad)")
        if not same_folds:
            print(fold_b.compare(fold_a) if fold_b.shape == fold_a.shape else (fold_b, fold_a))
        ok = ok and same_folds
    print("condition (same focal paths and verdicts, final f within 0.1 grid step):", ok)
    return ok


def inputs_and_options(args):
    """The session (pipeline folder or synthetic), its options and a label."""
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
    return (pairs, corners, K, dist, board, folds, ev), opts, label


def child(args):
    """One implementation (the cvsflow on PYTHONPATH), ``--repeat`` times; JSON on stdout."""
    import cvsflow

    inputs, opts, _ = inputs_and_options(args)
    best, hashes = None, None
    for i in range(args.repeat):
        stats, h, result = run(inputs, opts, args.cv, args.out / f"run{i}")
        if hashes is not None and h != hashes:
            sys.exit(f"repeat {i}: outputs differ from repeat 0")
        hashes = h
        best = stats if best is None else {  # each stage's least CPU over the repeats
            k: min(best[k], v, key=lambda x: x[1]) for k, v in stats.items()}
    print("BENCH_JSON " + json.dumps({"stats": best, "hashes": hashes, "result": result,
                                      "package": str(Path(cvsflow.__file__).parent)}))


def main():
    """Parse, run before and/or after (each in its own interpreter), print timings and hashes."""
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
    ap.add_argument("--after", help="git revision of the 'after' code (default: working tree)")
    ap.add_argument("--paths", action="store_true",
                    help="compare focal paths and verdicts instead of requiring identical bytes")
    ap.add_argument("--repeat", type=int, default=1, help="runs per implementation (least CPU)")
    ap.add_argument("--out", type=Path, help="keep the outputs here")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args)
        return

    _, opts, label = inputs_and_options(args)
    print(f"session: {label}; options {opts}")
    chosen = ["before", "after"] if args.impl == "both" else [args.impl]
    out_root = args.out or Path(tempfile.mkdtemp(prefix="bench_seed_out_"))
    runs = {}
    for name in chosen:
        rev = args.before if name == "before" else args.after
        package = REPO if rev is None else package_at(rev)
        argv = [a for a in sys.argv[1:] if a != "--child"]
        for flag in ("--out", "--impl"):  # the parent's, replaced below
            if flag in argv:
                i = argv.index(flag)
                del argv[i:i + 2]
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [str(package), *filter(None, [os.environ.get("PYTHONPATH")])])}
        proc = subprocess.run([sys.executable, __file__, *argv, "--child", "--out",
                               str(out_root / name)], env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"{name} failed:\n{proc.stderr[-3000:]}")
        line = next(x for x in proc.stdout.splitlines() if x.startswith("BENCH_JSON "))
        runs[name] = json.loads(line[len("BENCH_JSON "):])
        stats, hashes, result = runs[name]["stats"], runs[name]["hashes"], runs[name]["result"]
        print(f"{name:6s} package {runs[name]['package']}")
        for stage, (wall, cpu, solves) in stats.items():
            extra = f"  pnp_solves {solves}" if solves is not None else ""
            print(f"{name:6s} {stage:20s} wall_s {wall:7.2f}  cpu_s {cpu:7.2f}{extra}")
        print(f"{name:6s} f ({result['fx_px']:.4f}, {result['fy_px']:.4f}) px  "
              f"norm {result['norm_normalised_init_m']:.5f} -> "
              f"{result['norm_normalised_final_m']:.5f} m")
        for f, h in hashes.items():
            print(f"{name:6s} sha256 {h[:16]}  {f}")
    if len(runs) == 2 and args.paths:
        for stage in runs["before"]["stats"]:
            cb, ca = runs["before"]["stats"][stage][1], runs["after"]["stats"][stage][1]
            print(f"cpu {stage:20s} before {cb:7.2f} s  after {ca:7.2f} s  x{cb / ca:5.2f}")
        if not compare_paths(out_root / "before" / "run0", out_root / "after" / "run0", opts):
            sys.exit(1)
    elif len(runs) == 2:
        sb, hb = runs["before"]["stats"], runs["before"]["hashes"]
        sa, ha = runs["after"]["stats"], runs["after"]["hashes"]
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
