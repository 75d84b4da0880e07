"""Speed and accuracy of the corners stage on the demo session (90 s, 2700 frames).

Usage: .venv/bin/python bench/bench_corners.py [--cache DIR] [--duration-s 90] [--workers 2]

Renders the demo session of config/config.yaml once into DIR (default
/tmp/cvsflow_bench_corners; ~70 s; reused while its truth.yaml matches the duration), then
runs each variant of the corners stage in a fresh process, reading the video as the workflow
does (decoding included):

- ``decode``: reading the video to grey frames only (the ceiling);
- ``full``: full detection on every frame (``extract_corners(track=False)``, the former stage);
- ``fast``: tracking, quick detection and backward tracking (``extract_corners``), one core;
- ``parallel``: ``fast`` in chunks on ``--workers`` processes (``extract_corners_parallel``).

For each it prints wall time, CPU time (its processes together), frames/s by wall and by
CPU (= frames/s on one core), peak resident memory (largest process), and against the
renderer's truth: recall over frames with the board wholly in view (``in_view``), frames found
while not in view, and corner error (px) of corner k against true corner k, over all found
frames and over the frames both ``full`` and that variant found. ``parallel`` is checked to
equal ``fast`` row for row. The end-to-end pipeline time is measured by the lead (snakemake).
"""

from __future__ import annotations

import argparse
import copy
import functools
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
VARIANTS = ("decode", "full", "fast", "parallel")


def _render(cache: Path, duration_s: float) -> None:
    """Render the demo session into ``cache`` unless a render of that length is there."""
    import yaml

    from cvsflow.synth import render_session

    truth = cache / "truth.yaml"
    if truth.is_file() and (cache / "video.mp4").is_file():
        n = yaml.safe_load(truth.read_text()).get("n_frames")
        if n == int(round(duration_s * 30)):
            return
    with open(REPO / "config" / "config.yaml") as fh:
        cfg = copy.deepcopy(yaml.safe_load(fh)["sessions"]["demo"])
    cfg["synth"]["duration_s"] = duration_s
    start = time.perf_counter()
    render_session(cfg, cache)
    print(f"rendered {cache} in {time.perf_counter() - start:.1f} s", file=sys.stderr)


def _board() -> dict:
    import yaml

    with open(REPO / "config" / "config.yaml") as fh:
        return yaml.safe_load(fh)["sessions"]["demo"]["board"]


def _run_variant(name: str, cache: Path, workers: int, out: Path) -> dict:
    """One variant in this process; writes its corners table to ``out``; returns timings."""
    import cv2

    from cvsflow.corners_fast import extract_corners_parallel
    from cvsflow.io.media import iter_video_gray, video_info
    from cvsflow.pose import extract_corners

    cv2.setNumThreads(1)
    video = cache / "video.mp4"
    board = _board()
    n_frames = video_info(video)["n_frames"]
    wall0, cpu0 = time.perf_counter(), time.process_time()
    if name == "decode":
        n = sum(1 for _ in iter_video_gray(video))
        corners = None
    elif name == "full":
        corners = extract_corners(
            iter_video_gray(video), board, track=False, restart_every=None, log_every=0
        )
    elif name == "fast":
        corners = extract_corners(iter_video_gray(video), board, log_every=0)
    else:
        corners = extract_corners_parallel(
            functools.partial(iter_video_gray, video),
            n_frames,
            board,
            n_workers=workers,
            log_every=0,
        )
    wall = time.perf_counter() - wall0
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = time.process_time() - cpu0 + children.ru_utime + children.ru_stime
    if corners is not None:
        n = int(corners["frame"].nunique())
        corners.to_parquet(out)
    peak_mb = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, children.ru_maxrss) / 1024
    return {"frames": n, "wall_s": wall, "cpu_s": cpu, "peak_mb": peak_mb}


def _accuracy(corners, truth_frames, truth_corners, reference=None) -> dict:
    """Recall over in-view frames, false finds, corner errors (all and common frames)."""
    import numpy as np

    found = corners.groupby("frame")["found"].first()
    in_view = truth_frames.set_index("frame")["in_view"].reindex(found.index).fillna(False)
    merged = corners[corners["found"]].merge(
        truth_corners, on=["frame", "corner"], suffixes=("", "_true")
    )
    err = np.hypot(merged["u_px"] - merged["u_px_true"], merged["v_px"] - merged["v_px_true"])
    out = {
        "recall": float(found[in_view].mean()),
        "found_in_view": int(found[in_view].sum()),
        "in_view": int(in_view.sum()),
        "found_not_in_view": int(found[~in_view].sum()),
        "err_all": [float(np.median(err)), float(np.percentile(err, 95)), float(err.max())],
    }
    if reference is not None:
        ref_found = reference.groupby("frame")["found"].first()
        both = found.index[found & ref_found.reindex(found.index).fillna(False)]
        e = err[merged["frame"].isin(both).to_numpy()]
        out["n_common"] = len(both)
        out["err_common"] = [float(np.median(e)), float(np.percentile(e, 95)), float(e.max())]
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "cvsflow_bench_corners"
    )
    parser.add_argument("--duration-s", type=float, default=90.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--variant", help=argparse.SUPPRESS)  # internal: run one, print JSON
    args = parser.parse_args()
    cache = args.cache.resolve()
    if args.variant:
        result = _run_variant(
            args.variant, cache, args.workers, cache / f"bench_corners_{args.variant}.parquet"
        )
        print(json.dumps(result))
        return

    import pandas as pd

    _render(cache, args.duration_s)
    truth_frames = pd.read_parquet(cache / "truth_frames.parquet")
    truth_corners = pd.read_parquet(cache / "truth_corners.parquet")
    results = {}
    for name in args.variants.split(","):
        proc = subprocess.run(
            [
                sys.executable,
                __file__,
                "--cache",
                str(cache),
                "--workers",
                str(args.workers),
                "--variant",
                name,
            ],
            check=True,
            capture_output=True,
            text=True,
        )
        results[name] = json.loads(proc.stdout.strip().splitlines()[-1])
    tables = {
        name: pd.read_parquet(cache / f"bench_corners_{name}.parquet")
        for name in results
        if name != "decode"
    }
    print(
        f"session             demo, {args.duration_s:.0f} s, {len(truth_frames)} frames "
        f"({int(truth_frames['in_view'].sum())} with the board wholly in view)"
    )
    print(
        f"{'variant':10s} {'wall s':>7s} {'cpu s':>7s} {'fps wall':>9s} {'fps 1 core':>10s} "
        f"{'peak MB':>8s} {'recall':>7s} {'found!view':>10s}  corner err px median/p95/max "
        f"(all found | frames both found)"
    )
    for name, r in results.items():
        line = (
            f"{name:10s} {r['wall_s']:7.2f} {r['cpu_s']:7.2f} "
            f"{r['frames'] / r['wall_s']:9.0f} {r['frames'] / r['cpu_s']:10.0f} "
            f"{r['peak_mb']:8.0f}"
        )
        if name in tables:
            a = _accuracy(tables[name], truth_frames, truth_corners, tables.get("full"))
            line += (
                f" {a['recall']:7.4f} {a['found_not_in_view']:10d}  "
                "{:.3f}/{:.3f}/{:.3f}".format(*a["err_all"])
            )
            if "err_common" in a:
                line += " | {:.3f}/{:.3f}/{:.3f} ({} frames)".format(
                    *a["err_common"], a["n_common"]
                )
            methods = tables[name].attrs.get("order_methods")
            if methods:
                line += f"\n{'':10s} frames by method: {methods}"
        print(line)
    if "fast" in tables and "parallel" in tables:
        try:
            pd.testing.assert_frame_equal(tables["fast"], tables["parallel"])
            print("parallel == fast     identical tables")
        except AssertionError as exc:
            print(f"parallel != fast     {exc}")


if __name__ == "__main__":
    main()
