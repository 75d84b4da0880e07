"""Time the seed optimiser on a synthetic 90 s session (2400 frames) and print the numbers.

Usage: ``.venv/bin/python bench/bench_seed.py [--frames 2400] [--k 50] [--workers 2]
[--objective sum_squares] [--seed 0]``

The corners come from projecting a 5 x 4 inner-corner board (square 0.09 m) along a random
smooth trajectory at 1-4 m with K (fx 700, fy 700, cx 320, cy 240), OpenCV distortion and
0.2 px noise. The Vicon P* is the true pose minus a constant offset, so the right answer is
f = (700, 700) px and P_bar = the offset; the optimiser starts at (660, 730) px.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
import pandas as pd

from cvsflow.optimise.seed import POSE_DIMS, board_object_points, optimise_seed
from cvsflow.transforms import T_from_pose6, rvec_tvec_from_T

BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
DIST = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02])
OFFSET = np.array([0.05, -0.03, 0.10, 0.02, -0.01, 0.03])


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


def main():
    """Run and print timings, the recovered focal lengths and the error norms."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=2400)
    ap.add_argument("--k", type=int, default=50)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--objective", default="sum_squares")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    pairs, corners, K = synthesise(args.frames, args.seed)
    t_synth = time.perf_counter() - t0
    res = optimise_seed(pairs, corners, K, DIST, BOARD, k_iterations=args.k,
                        f_init_px=(660.0, 730.0), objective=args.objective,
                        n_workers=args.workers)
    r = res.result
    print(f"frames {args.frames}  k {args.k}  workers {args.workers}  objective {args.objective}")
    print(f"synthesis_s {t_synth:.2f}")
    print(f"total_s {r['timings_s']['total']:.2f}  grid_search_s {r['timings_s']['grid_search']:.2f}"
          f"  per_iteration_s {r['timings_s']['total'] / max(args.k, 1):.3f}")
    print(f"pnp_solves {r['n_pnp_solves']}  per_solve_ms "
          f"{1e3 * r['timings_s']['grid_search'] / max(r['n_pnp_solves'], 1):.1f}")
    print(f"f_init_px 660.0 730.0  f_final_px {r['fx_px']:.2f} {r['fy_px']:.2f}  truth 700 700")
    print("P_bar_final", np.round(r["P_bar"], 4).tolist(), " truth", OFFSET.tolist())
    print(f"norm_normalised_m init {r['norm_normalised_init_m']:.5f}"
          f"  final {r['norm_normalised_final_m']:.5f}")
    it = res.iterations
    for j in (0, 1, 2, 5, 10, 20, 50):
        if j < len(it):
            row = it.iloc[j]
            print(f"  iteration {j:2d}: fx {row.fx_px:.2f} fy {row.fy_px:.2f} "
                  f"norm {row.norm_normalised:.5f} m")


if __name__ == "__main__":
    main()
