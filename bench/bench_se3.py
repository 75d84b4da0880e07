"""Benchmark of the se3 joint calibration on a synthetic 90 s session.

2700 frames at 30 fps (2400 used, as the chapter), 20 corners each, fx ~ 700 px with
distortion, 0.3 px corner noise, Vicon bodies at 300 Hz fitted from markers with 0.3 mm noise.
Prints the solve time, the recovery errors against truth, and the held-out error spread
and error-model calibration. Usage: ``.venv/bin/python bench/bench_se3.py [seed]``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from cvsflow import metrics
from cvsflow import uncertainty as un
from cvsflow.board import board_object_points
from cvsflow.evaluate import heldout as ev
from cvsflow.geometry import transforms as tf
from cvsflow.optimise import se3, simulate_session


def main(seed: int = 0) -> None:
    t0 = time.perf_counter()
    s = simulate_session(seed, duration_s=90.0)
    tr = s["truth"]
    corners = s["corners"][s["corners"]["frame"] < 2400]
    print(f"synthesis: {time.perf_counter() - t0:.2f} s, 2400 frames x 20 corners")
    K0 = tr["K"] + np.diag([10.0, -10.0, 0.0])
    cam = {"K": K0.tolist(), "dist": (0.8 * tr["dist"]).tolist()}
    dt0 = tr["dt_offset_s"] + 0.015
    for solver in ("lm", "scipy"):
        t0 = time.perf_counter()
        fit = se3.optimise_se3(corners, s["bodies"], cam, s["board"], dt0, solver=solver)
        wall = time.perf_counter() - t0
        r = fit.result
        print(f"\nsolver {solver}: wall {wall:.2f} s (result time_s {r['time_s']:.2f}), "
              f"{r['n_iterations']} evaluations, {r['n_jacobians']} Jacobians, "
              f"RMS {r['rms_px']:.3f} px, cost {r['cost']:.3f}")
        K = np.array(r["K"])
        se = r["std_errors"]
        for i, n in ((0, "fx"), (1, "fy")):
            err = K[i, i] - tr["K"][i, i]
            print(f"  {n}: error {err:+.3f} px ({100 * err / tr['K'][i, i]:+.4f} %), "
                  f"3 sigma {3 * se[n]:.3f} px")
        for n in ("T_Cm_C", "T_Bm_B"):
            T = np.array(r[n])
            d = np.linalg.norm(T[:3, 3] - tr[n][:3, 3]) * 1e3
            a = np.degrees(tf.rotation_angle(tr[n][:3, :3].T @ T[:3, :3]))
            print(f"  {n}: {d:.3f} mm, {a:.4f} deg")
        print(f"  dt: error {1e3 * (r['dt_offset_s'] - tr['dt_offset_s']):+.3f} ms, "
              f"3 sigma {3e3 * se['dt_offset_s']:.3f} ms")
        print(f"  warnings: {r['warnings']}")

    t0 = time.perf_counter()
    held, fits = ev.cross_validate_se3(
        corners, s["bodies"], cam, s["board"], dt0, n_folds=5, block_s=5.0, seed=seed
    )
    print(f"\n5-fold held-out cross-validation: {time.perf_counter() - t0:.2f} s")
    summ = metrics.axis_statistics(held[metrics.error_columns()].to_numpy(float))
    scale = [1e3] * 3 + [np.degrees(1.0)] * 3
    print("  held-out std (mm, deg):",
          np.round(np.array([summ[d]["std"] for d in metrics.ERROR_DIMS]) * scale, 3).tolist())
    d6 = held[[f"d6_{d}" for d in metrics.ERROR_DIMS]].std().to_numpy()
    print("  same errors as 6-vector differences, std (mm, deg):", np.round(d6 * scale, 3).tolist())
    b = metrics.bootstrap_error_stats(held[metrics.error_columns()], block_len=60, n_boot=1000, seed=seed)
    print("  95 % block-bootstrap CI of std, lo:", np.round(b["std_lo"] * scale, 3).tolist())
    print("                                  hi:", np.round(b["std_hi"] * scale, 3).tolist())

    p_B = board_object_points(s["board"])
    feats, cov = un.error_features(held, p_B, np.array(fits[0]["K"]), np.array(fits[0]["dist"]),
                                   fits[0]["sigma_px"])
    train = held["fold"].isin([0, 1, 2]).to_numpy()
    model = un.fit_error_model(feats[train], held[train])
    sc = un.score_error_model(model, feats[~train], held[~train])
    print(f"\nerror model (train folds 0-2, score folds 3-4, {sc['n']} frames):")
    print(f"  inside 68 % band: {sc['inside_68_all']:.3f}; inside 95 % band: "
          f"{sc['inside_95_all']:.3f}; NEES mean {sc['nees_mean']:.2f} (6 if consistent)")
    print("  inside 95 % per dim:", {k: round(v, 3) for k, v in sc["inside_95"].items()})


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 0)
