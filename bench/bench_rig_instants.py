"""Fused-pose NEES of a rendered rig session at the 2 ms and the default match tolerance,
with and without the moved views' interpolation term, against the rendered truth.

The rig's inputs (each camera's corners, camera.yaml, sync.yaml and the rig's bodies) come
from a workflow run of config/stereo.yaml's session (tests/workflow/test_rig.stereo_config,
10 s); the fit and the held-out folds' fits are made once (the match tolerance and the term
change the fused poses only). Prints, per tolerance and term, the NEES mean (6 expected) in
sample and held out on frames seen by one and by both cameras, and the moved corners' errors
against the renderer's true corners: interpolation (true corners interpolated as the
detected ones), time offset (the fit's dt error times image velocity) and noise.
Usage (a render into /tmp/rig, seed 19 or another)::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_rig_instants.py /tmp/rig --render [seed]
    PYTHONPATH=$PWD .venv/bin/python bench/bench_rig_instants.py /tmp/rig
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from cvsflow.board import board_object_points
from cvsflow.evaluate import make_time_blocks
from cvsflow.io.files import read_parquet, read_yaml
from cvsflow.optimise import corner_arrays
from cvsflow.rig import (
    common_times,
    corners_at_instants,
    fused_pose_nees,
    fused_rig_poses,
    optimise_se3_rig,
    rig_camera_entries,
    rig_fit_options,
)
from cvsflow.synth.imaging import project_in_view
from cvsflow.synth.motion import board_poses
from cvsflow.synth.rig_session import make_rig_truth, true_board_poses_C0

REPO = Path(__file__).resolve().parents[1]


def render(workdir: Path, seed: int | None) -> None:
    """The 10 s stereo session's camera and mocap rules into ``workdir``."""
    sys.path.insert(0, str(REPO))
    from tests.workflow.test_rig import stereo_config
    from tests.workflow.test_workflow import write_config

    config = stereo_config()
    if seed is not None:
        config["sessions"]["stereo"]["synth"]["seed"] = seed
    write_config(workdir, config)
    names = [c["name"] for c in config["sessions"]["stereo"]["cameras"]]
    subprocess.run([sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--directory",
                    str(workdir), "--cores", "2", "results/stereo/bodies.parquet",
                    *(f"results/stereo-{n}/sync.yaml" for n in names)], check=True)  # fmt: skip


def main(workdir: Path) -> None:
    cfg = yaml.safe_load((workdir / "config/config.yaml").read_text())
    sess = cfg["sessions"]["stereo"]
    ss = [f"stereo-{c['name']}" for c in sess["cameras"]]
    entries = rig_camera_entries([read_parquet(workdir / f"results/{s}/corners.parquet") for s in ss],
                                 [read_yaml(workdir / f"results/{s}/camera.yaml") for s in ss],
                                 [read_yaml(workdir / f"results/{s}/sync.yaml")["dt_offset_s"] for s in ss])
    bodies, board, truth = read_parquet(workdir / "results/stereo/bodies.parquet"), sess["board"], make_rig_truth(sess)
    opts, ev = rig_fit_options(cfg["rig"]), cfg["evaluate"]
    full = optimise_se3_rig(entries, bodies, board, **opts).result
    p_B = board_object_points(board)
    arrays = [corner_arrays(e["corners"], len(p_B)) for e in entries]
    t_common = common_times(entries, [a[1] for a in arrays])
    fold = np.split(make_time_blocks(np.concatenate(t_common), ev["block_s"], ev["n_folds"], ev["seed"]),
                    np.cumsum([len(t) for t in t_common])[:-1])  # fmt: skip
    folds = []
    for k in range(ev["n_folds"]):
        train = [dict(e, frames=a[0][f != k]) for e, a, f in zip(entries, arrays, fold, strict=True)]
        folds.append((optimise_se3_rig(train, bodies, board, **opts).result,
                      [a[0][f == k] for a, f in zip(arrays, fold, strict=True)]))  # fmt: skip
    corners = [e["corners"] for e in entries]
    print(f"{workdir}: seed {sess['synth']['seed']}, {sess['synth']['duration_s']:.0f} s, {ev['n_folds']} folds")
    print("tolerance  term  NEES in sample 1 cam, 2 cams (frames; 2 cams' median, largest 3)"
          "   held out, the same")
    for tol in (0.002, None):
        for term in (False, True):
            cells = []
            for runs in ([(full, None)], folds):
                p = pd.concat([fused_rig_poses(r, corners, bodies, board, frames=fr, match_tol_s=tol,
                                               interpolation_cov=term) for r, fr in runs], ignore_index=True)
                e = fused_pose_nees(p, true_board_poses_C0(truth, p["t_vicon_s"].to_numpy()))
                n = p["n_cameras"].to_numpy()
                two = np.sort(e[n == 2])
                cells.append(f"{e[n == 1].mean():5.2f}, {two.mean():5.2f} ({len(two)}; median "
                             f"{np.median(two):4.2f}, largest {', '.join(f'{v:.0f}' for v in two[-3:][::-1])})")
            print(f"{'2 ms' if tol else 'default':9s}  {'with' if term else 'no':4s}  {cells[0]:50s}  {cells[1]}")
    # camera 1's moved corners against the truth, at the default tolerance (in sample)
    i = 1
    fr, tv, uv = arrays[i]
    dt = [c["dt_offset_s"] for c in full["cameras"]]
    t_s, t0 = tv + dt[i], arrays[0][1] + dt[0]
    near = t0[np.clip(np.searchsorted(t0, t_s), 1, len(t0) - 1)[:, None] - np.array([0, 1])]
    near = near[np.arange(len(near)), np.argmin(np.abs(near - t_s[:, None]), axis=1)]
    target = np.where(np.abs(near - t_s) <= 0.25 * np.median(np.diff(t0)), near, t_s)
    gap = 1.5 * np.median(np.diff(t_s))
    uv_at, _, moved, usable = corners_at_instants(uv, t_s, target, gap)
    spec, view = truth.specs[i], truth.view(i)

    def true_uv(t):
        return project_in_view(board_poses(view, t), spec.board.corners_B(), spec.K, spec.dist)

    t_true = target - dt[0] + truth.dt_offset_s[0] - truth.dt_offset_s[i]
    own = np.where(np.isfinite(uv), true_uv(tv), np.nan)
    interp = corners_at_instants(own, t_s, target, gap)[0] - true_uv(target - dt[i])
    m = moved & usable

    def rms(x):
        return float(np.sqrt(np.nanmean(x[m] ** 2)))

    print(f"camera {i}, {int(m.sum())} moved frames, px RMS per axis: interpolation {rms(interp):.4f} "
          f"(common to the view {rms(np.nanmean(interp, axis=1, keepdims=True)):.4f}), time offset "
          f"{rms(true_uv(target - dt[i]) - true_uv(t_true)):.4f}, noise {rms(uv - own):.4f}, "
          f"total {rms(uv_at - true_uv(t_true)):.4f}; the fit's sigma {full['sigma_px']:.4f}")


if __name__ == "__main__":
    wd = Path(sys.argv[1])
    if "--render" in sys.argv:
        rest = [a for a in sys.argv[2:] if a != "--render"]
        render(wd, int(rest[0]) if rest else None)
    main(wd)
