"""AprilGrid detection: tags found and time per frame by detector on the real yac frames, corner
error on renders against their truth, and the intrinsics the 30 yac frames give.

- yac (``shared/data/real/yac-mocap-aprilgrid``, 30 frames 640x480, 36 tags each): per detector
  (the default AprilTag 3 x2 + ArUco, AprilTag 3 alone, ArUco alone: the fallback without
  pupil-apriltags) the tags kept per frame (min / median / total of 1080) and the wall time of
  ``detect_aprilgrid`` per frame (best of ``--repeat``);
- renders (the yac grid through a radtan camera, 0.9-1.6 m, tilts to 45 deg, three junction
  topologies: corner squares short of the tags, touching them, overlapping them): tags found (a
  tag cut by the border counts when its corners in view pass the checks) against those wholly in
  view, and the refined corners' error against the truth (median, p95, max px);
  a wrong id or corner order would show as an error of a tag side (20 px or more);
- ``calibrate_camera`` on the 30 yac frames: fx fy cx cy (px), RMS (px), corners used.

Usage::

    PYTHONPATH=. .venv/bin/python bench/bench_aprilgrid.py [--renders 12] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from cvsflow.board import AprilGrid, detect_aprilgrid
from cvsflow.board.aprilgrid_tags import APRILTAG_PASSES, ARUCO_PASSES, AprilTagPass, passes_name
from cvsflow.calibration import calibrate_camera
from cvsflow.synth.board_image import aprilgrid_texture
from cvsflow.synth.imaging import undistortion_grid
from tests.helpers.aprilgrid_images import DIST, GRID, SIZE, K, look_at_grid, render_aprilgrid
from tests.helpers.real_data import REAL_DATA

DETECTORS = {"default": APRILTAG_PASSES, "apriltag3": (AprilTagPass(),), "aruco": ARUCO_PASSES}


def yac_frames():
    folder = REAL_DATA / "yac-mocap-aprilgrid" / "cam0" / "data"
    return [(p.name, cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for p in sorted(folder.glob("*.jpg"))]


def bench_yac(frames, grid: AprilGrid, repeat: int) -> None:
    print(f"yac: {len(frames)} frames, {grid.n_tags} tags each")
    for name, passes in DETECTORS.items():
        tags, times = [], []
        for _, gray in frames:
            best = np.inf
            for _ in range(repeat):
                t0 = time.perf_counter()
                ids, _ = detect_aprilgrid(gray, grid, passes)
                best = min(best, time.perf_counter() - t0)
            tags.append(len(np.unique(ids // 4)))
            times.append(best)
        print(f"  {name:10s} tags/frame min {min(tags):2d} median {np.median(tags):4.1f} total {sum(tags):4d}"
              f" of {grid.n_tags * len(frames)}; {1e3 * np.median(times):5.1f} ms/frame (median of "
              f"best-of-{repeat}); {passes_name(passes)}")


def bench_renders(n: int) -> None:
    xy_n = undistortion_grid(K, DIST, SIZE)
    rng = np.random.default_rng(38)
    poses = [look_at_grid(GRID, rng.uniform(0.9, 1.6), rng.uniform(0, 45), rng.uniform(0, 180),
                          rng.uniform(-180, 180), offset_m=rng.uniform(-0.25, 0.25, 2)) for _ in range(n)]
    for spread in (-0.1, 0.0, 0.1):
        texture = aprilgrid_texture(GRID, ink_spread_bits=spread)
        errors, found, visible = [], 0, 0
        for i, T in enumerate(poses):
            gray, truth = render_aprilgrid(T, texture=texture, xy_n=xy_n, seed=i)
            ids, uv = detect_aprilgrid(gray, GRID)
            inside = (np.isfinite(truth).all(axis=1) & (truth >= 3).all(axis=1)
                      & (truth <= np.array(SIZE) - 4).all(axis=1)).reshape(-1, 4).all(axis=1)
            visible += int(inside.sum())
            found += len(np.unique(ids // 4))
            errors.append(np.linalg.norm(uv - truth[ids], axis=1))
        e = np.concatenate(errors)
        print(f"renders, ink spread {spread:+.1f} bit: {found} tags found ({visible} wholly in view); corner error "
              f"median {np.median(e):.3f} p95 {np.percentile(e, 95):.3f} max {e.max():.3f} px ({len(e)} corners)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--renders", type=int, default=12)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    cv2.setNumThreads(1)
    frames = yac_frames()
    if frames:
        bench_yac(frames, GRID, args.repeat)
        t0 = time.perf_counter()
        camera, corners = calibrate_camera(frames, GRID.config())
        K_fit = np.asarray(camera["K"])
        print(f"calibrate_camera on the yac frames: fx {K_fit[0, 0]:.2f} fy {K_fit[1, 1]:.2f} cx {K_fit[0, 2]:.2f}"
              f" cy {K_fit[1, 2]:.2f} px, RMS {camera['rms_px']:.4f} px, {camera['n_used']} frames, "
              f"{len(corners)} corners, dist {np.round(camera['dist'], 4).tolist()} "
              f"({time.perf_counter() - t0:.1f} s)")
    else:
        print(f"yac frames not found under {REAL_DATA}: skipped")
    bench_renders(args.renders)


if __name__ == "__main__":
    main()
