"""Coverage of the stated standard errors of the hand-eye from pose streams, on simulated streams.

Simulated pairs of streams (:func:`cvsflow.handeye.stream_sim.simulate_streams`: camera 30 Hz
with 5 detection gaps, motion capture 100 Hz, a known offset, AR(1) detector noise of
correlation time ``--tau``) are fitted by :func:`cvsflow.handeye.stream_fit.estimate_streams`.
Per parameter: the share of draws with ``|error| / std < 2`` (95.4 % for a normal error, the
target) and the mean of ``(error / std)^2`` (1), for the stated errors (``std``: the block
sandwich times ``sqrt(nu / (nu - 2))``), the sandwich alone and the independent-residual
(Gauss-Newton) errors; the mean degrees of freedom ``nu``. With ``--split-half`` also the
errors after the split-half rule (``cvsflow handeye --camera-poses``: widened by the halves'
Birge ratio when they disagree) and how often it fired.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python bench/bench_streams_coverage.py --draws 50 [--duration 40] [--split-half]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from cvsflow.geometry import rvec_from_R
from cvsflow.handeye.stream_fit import StreamsOptions, estimate_streams
from cvsflow.handeye.stream_model import PARAM_NAMES
from cvsflow.handeye.stream_report import inflate, split_half_check, split_half_inflation
from cvsflow.handeye.stream_sim import simulate_streams


def errors(res, sim) -> dict:
    """The fit's error per parameter in its own local coordinates (rad, m, s)."""
    e = {"dt_offset_s": res.estimate["dt_s"] - sim["dt_offset_s"]}
    for name in ("T_Cm_C", "T_W_B"):
        T_est, T_true = res.estimate[name], sim[name]
        dr = rvec_from_R(T_true[:3, :3].T @ T_est[:3, :3])
        for k, axis in enumerate("xyz"):
            e[f"{name}_r{axis}"] = dr[k]
            e[f"{name}_{axis}"] = T_est[k, 3] - T_true[k, 3]
    return e


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=50)
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--duration", type=float, default=40.0, help="camera stream length, s")
    ap.add_argument("--tau", type=float, default=0.3, help="AR(1) correlation time, s")
    ap.add_argument("--block", type=float, default=None, help="sandwich block, s (default: from the residuals)")
    ap.add_argument("--json", default=None, help="write the per-draw z values here")
    ap.add_argument("--split-half", action="store_true", help="also the split-half rule (3 fits a draw)")
    args = ap.parse_args(argv)
    kinds = ("std", "std_sandwich", "std_gn") + (("std_split",) if args.split_half else ())
    fired = []
    z = {k: {m: [] for m in kinds} for k in PARAM_NAMES}
    dof = {k: [] for k in PARAM_NAMES}
    blocks = []
    t0 = time.time()
    for i in range(args.draws):
        sim = simulate_streams(args.seed0 + i, duration_s=args.duration, tau_corr_s=args.tau)
        streams = (sim["t_cam_ns"], sim["T_B_C"], sim["t_mocap_ns"], sim["T_W_Cm"])
        options = StreamsOptions(block_s=args.block)
        res = estimate_streams(*streams, options)
        blocks.append((res.block_s, res.counts["n_blocks"]))
        std = {"std": res.std, "std_sandwich": res.std_sandwich, "std_gn": res.std_gn}
        if args.split_half:
            factor = split_half_inflation(split_half_check(*streams, options))
            fired.append(factor)
            std["std_split"] = inflate(res, factor).std
        for k, err in errors(res, sim).items():
            dof[k].append(res.dof[k])
            for m in kinds:
                z[k][m].append(err / std[m][k])
    print(f"{args.draws} draws of {args.duration:g} s, AR(1) tau {args.tau:g} s, block "
          f"{np.mean([b for b, _ in blocks]):.2f} s ({np.mean([n for _, n in blocks]):.1f} blocks), "
          f"{time.time() - t0:.0f} s")  # fmt: skip
    if fired:
        f = np.asarray(fired)
        print(f"split-half rule fired in {np.mean(f > 1):.2f} of the draws (factor median "
              f"{np.median(f[f > 1]) if (f > 1).any() else 1:.2f})")  # fmt: skip
    print(f"{'parameter':14s} {'nu':>5s} | " + " | ".join(f"{m:>12s} |z|<2  E z^2" for m in kinds))
    pooled = {m: [] for m in kinds}
    for k in PARAM_NAMES:
        cells = []
        for m in kinds:
            a = np.asarray(z[k][m])
            pooled[m].append(a)
            cells.append(f"{np.mean(np.abs(a) < 2):18.2f} {np.mean(a**2):6.2f}")
        print(f"{k:14s} {np.mean(dof[k]):5.1f} | " + " | ".join(cells))
    cells = []
    for m in kinds:
        a = np.concatenate(pooled[m])
        cells.append(f"{np.mean(np.abs(a) < 2):18.3f} {np.mean(a**2):6.2f}")
    print(f"{'all':14s} {'':5s} | " + " | ".join(cells))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({k: {m: list(map(float, v)) for m, v in d.items()} for k, d in z.items()}, fh)


if __name__ == "__main__":
    main()
