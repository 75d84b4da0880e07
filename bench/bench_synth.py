"""Speed of the demo-session renderer: prints frames/s of the video and the total time.

Usage: .venv/bin/python bench/bench_synth.py [duration_s] [--detect]
``--detect`` also runs cv2.findChessboardCorners on every frame of the rendered video and
prints the share of frames where the board is found (against the truth's in_view share).
"""

from __future__ import annotations

import argparse
import copy
import tempfile
import time
from pathlib import Path

import yaml

from cvsflow.synth.render import render_session

REPO = Path(__file__).resolve().parents[1]


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("duration_s", nargs="?", type=float, default=90.0)
    parser.add_argument("--detect", action="store_true")
    parser.add_argument("--seed", type=int, default=None)
    args = parser.parse_args()
    with open(REPO / "config" / "config.yaml") as fh:
        cfg = copy.deepcopy(yaml.safe_load(fh)["sessions"]["demo"])
    cfg["synth"]["duration_s"] = args.duration_s
    if args.seed is not None:
        cfg["synth"]["seed"] = args.seed
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "demo"
        start = time.perf_counter()
        summary = render_session(cfg, out)
        total_s = time.perf_counter() - start
        print(f"duration_s          {args.duration_s:.1f}")
        print(f"frames              {summary['n_frames']}")
        print(f"video frames/s      {summary['video_fps_rendered']:.1f}")
        print(f"video render s      {summary['video_render_s']:.1f}")
        print(f"total s             {total_s:.1f}")
        print(f"in view (truth)     {summary['in_view_fraction']:.3f}")
        print(f"median blur px      {summary['median_blur_px']:.2f}")
        print(f"dropouts            {summary['n_dropouts']}")
        if args.detect:
            _detect(out, cfg)


def _detect(out, cfg):
    import cv2
    import numpy as np
    import pandas as pd

    from cvsflow.io.media import iter_video_gray

    board = cfg["board"]
    pattern = (board["squares_x"] - 1, board["squares_y"] - 1)
    truth = pd.read_parquet(out / "truth_frames.parquet")
    corners = pd.read_parquet(out / "truth_corners.parquet")
    uv = corners[["u_px", "v_px"]].to_numpy().reshape(len(truth), -1, 2)
    found, errors = [], []
    start = time.perf_counter()
    for k, _, gray in iter_video_gray(out / "video.mp4"):
        ok, c = cv2.findChessboardCorners(
            gray, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        )
        found.append(ok)
        if ok:
            c = cv2.cornerSubPix(
                gray, c, (5, 5), (-1, -1),
                (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 1e-3),
            )[:, 0]
            err = min(
                np.linalg.norm(c - uv[k], axis=1).max(),
                np.linalg.norm(c[::-1] - uv[k], axis=1).max(),
            )
            errors.append(err)
    found = np.array(found)
    in_view = truth["in_view"].to_numpy()[: len(found)]
    print(f"detect s            {time.perf_counter() - start:.1f}")
    print(f"found share         {found.mean():.3f}")
    print(f"found | in view     {found[in_view].mean():.3f}")
    print(f"found | not in view {found[~in_view].mean():.3f}")
    errors = np.array(errors)
    p50, p95 = np.percentile(errors, [50, 95])
    print(f"max corner err px   median {p50:.3f}  p95 {p95:.3f}")


if __name__ == "__main__":
    main()
