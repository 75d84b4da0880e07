"""Accuracy of the video/Vicon synchronisation on rendered sessions against their truth.

Renders a few demo sessions (``cvsflow.synth``, 20 s each, different seeds) in a temporary
directory, runs the camera half (calibration, corners, PnP poses) and the Vicon half (read,
repair, rigid bodies) exactly as the workflow scripts do, then synchronises with both
methods and prints, per seed, the error of every estimate against ``truth.yaml``'s
``dt_offset_s`` in milliseconds: the angular-speed method's parabolic correlation peak
(``dt_parabolic_s``), its result before (``--before``: ``cvsflow/align.py``, now ``cvsflow/sync/offset.py``, at that git
revision, the angular-speed mismatch refinement) and now (relative-rotation-angle refinement,
with its jackknife standard error), and the chapter's gesture method. Target: |error| < 2 ms for the angular-speed result on every
seed (the issue asks for 3 ms).

Usage::

    .venv/bin/python bench/bench_sync.py [--seeds 7 11 23 42] [--duration 20]
        [--cache DIR]   # keep/reuse the stage outputs per seed in DIR (default: temp dir)
        [--demo]        # also the workflow's own demo outputs under results/demo
        [--before REV]  # git revision of cvsflow/align.py for the "before" column

Rendering and corner extraction dominate (about a minute per 20 s seed on one core).
"""

from __future__ import annotations

import argparse
import copy
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

REPO = Path(__file__).resolve().parents[1]


def _session_cfg(seed, duration_s):
    with open(REPO / "config" / "config.yaml") as fh:
        cfg = yaml.safe_load(fh)
    session = copy.deepcopy(cfg["sessions"]["demo"])
    session["synth"].update(seed=int(seed), duration_s=float(duration_s))
    return cfg, session


def run_stages(seed, duration_s, work):
    """Render one session and run the stages up to the sync inputs; cached in ``work``.

    Returns
    -------
    poses_raw, bodies : DataFrame
    truth : dict
    """
    from cvsflow.calibration import calibrate_camera, estimate_poses
    from cvsflow.corners import extract_corners
    from cvsflow.io.media import iter_video_gray, list_stills, read_gray, video_info
    from cvsflow.io.mocap.formats import read_markers
    from cvsflow.io.mocap.markers import select_markers
    from cvsflow.mocap import fit_bodies, repair_markers
    from cvsflow.synth.render import render_session

    work = Path(work)
    f_poses, f_bodies, f_truth = work / "poses_raw.parquet", work / "bodies.parquet", work / "data" / "truth.yaml"
    if f_poses.exists() and f_bodies.exists() and f_truth.exists():
        return pd.read_parquet(f_poses), pd.read_parquet(f_bodies), yaml.safe_load(f_truth.read_text())
    cfg, session = _session_cfg(seed, duration_s)
    data = work / "data"
    render_session(session, data)
    images = [(p.name, read_gray(p)) for p in list_stills(data / "calib")]
    camera, _ = calibrate_camera(images, session["board"], **cfg["calibrate"])
    info = video_info(data / "video.mp4")
    corners = extract_corners(iter_video_gray(data / "video.mp4"), session["board"],
                              subpix_window_px=cfg["corners"]["subpix_window_px"], n_frames=info["n_frames"])
    poses = estimate_poses(corners, np.array(camera["K"]), np.array(camera["dist"]), session["board"], **cfg["pnp"])
    mk = session["markers"]
    markers = select_markers(read_markers(data / "vicon.csv"), mk["camera"]["names"] + mk["board"]["names"])
    filled, _ = repair_markers(markers, mk, cfg["mocap"])
    bodies = fit_bodies(filled, mk)
    poses.to_parquet(f_poses)
    bodies.to_parquet(f_bodies)
    return poses, bodies, yaml.safe_load(f_truth.read_text())


def load_align_at(rev):
    """``cvsflow/align.py`` as it was at git revision ``rev``, as a module (None if unavailable)."""
    import importlib.util
    import subprocess
    import sys

    try:
        src = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:cvsflow/align.py"],
                             capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError) as err:
        print(f"before: cannot read cvsflow/align.py at {rev}: {err}", file=sys.stderr)
        return None
    spec = importlib.util.spec_from_loader(f"align_{rev}", loader=None)
    module = importlib.util.module_from_spec(spec)
    exec(compile(src, f"align.py@{rev}", "exec"), module.__dict__)
    return module


def sync_errors(poses, bodies, truth, before=None):
    """Errors (ms) of the sync estimates against the truth."""
    from cvsflow.exceptions import SyncError
    from cvsflow.sync import synchronise

    dt_true = float(truth["dt_offset_s"])
    row = {}
    if before is not None:
        old = before.synchronise(poses, bodies, method="angular_speed", max_offset_s=30.0, min_quality=0.0)
        row["before_ms"] = 1e3 * (old["dt_offset_s"] - dt_true)
    t0 = time.perf_counter()
    # min_quality 0: report the quality instead of refusing (the workflow's default is 0.5)
    out = synchronise(poses, bodies, method="angular_speed", max_offset_s=30.0, min_quality=0.0)
    row["sync_s"] = time.perf_counter() - t0
    d = out["details"]
    row["parabolic_ms"] = 1e3 * (d["dt_parabolic_s"] - dt_true)
    row["angular_speed_ms"] = 1e3 * (out["dt_offset_s"] - dt_true)
    row["sigma_ms"] = 1e3 * d["dt_sigma_s"] if d.get("dt_sigma_s") is not None else np.nan
    row["quality"] = out["quality"]
    try:
        g = synchronise(poses, bodies, method="gesture", max_offset_s=30.0, min_quality=0.0)
        row["gesture_ms"] = 1e3 * (g["dt_offset_s"] - dt_true)
    except SyncError as err:
        print("  gesture:", err)
        row["gesture_ms"] = np.nan
    row["valid_frames"] = int(poses["valid"].sum())
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[7, 11, 23, 42])
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--cache", type=Path, default=None)
    parser.add_argument("--demo", action="store_true")
    parser.add_argument("--before", default="fe5ac5d", help="git revision of the 'before' align.py")
    args = parser.parse_args()
    before = load_align_at(args.before) if args.before else None
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = args.cache or Path(tmp)
        if args.demo:
            res = REPO / "results" / "demo"
            rows["demo"] = sync_errors(pd.read_parquet(res / "poses_raw.parquet"), pd.read_parquet(res / "bodies.parquet"),
                                       yaml.safe_load((REPO / "data" / "demo" / "truth.yaml").read_text()), before)
        for seed in args.seeds:
            t0 = time.perf_counter()
            poses, bodies, truth = run_stages(seed, args.duration, root / f"seed{seed}_{args.duration:g}s")
            print(f"seed {seed}: stages {time.perf_counter() - t0:.0f} s", flush=True)
            rows[f"seed {seed}"] = sync_errors(poses, bodies, truth, before)
    table = pd.DataFrame(rows).T
    with pd.option_context("display.float_format", "{:8.3f}".format, "display.width", 200, "display.max_columns", 20):
        print(table)
    if "before_ms" in table:
        b = table["before_ms"].abs()
        print(f"before ({args.before}) |error|: max {b.max():.3f} ms, mean {b.mean():.3f} ms")
    err = table["angular_speed_ms"].abs()
    print(f"angular_speed |error|: max {err.max():.3f} ms, mean {err.mean():.3f} ms "
          f"({'all' if (err < 2.0).all() else 'NOT all'} below 2 ms)")


if __name__ == "__main__":
    main()
