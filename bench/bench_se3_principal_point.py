"""Should se3 free the principal point? se3 on a simulated session with the stills' cx, cy off.

The issue-39 render showed a calibration's principal point 11.7 px off turning into a 1.24 deg
error of T_Cm_C in se3, which holds cx, cy (and k3) at the calibration's values. For each
principal-point error (dx = dy in px) this bench runs se3 on one simulated 90 s session
(``simulate_session``: 2400 frames of 20 corners at 0.3 px, Vicon bodies from markers) with
the true intrinsics but that principal point, and prints T_Cm_C's rotation and translation
error against the truth, its stated 1-sigma, fx's error and the reprojection RMS, for:

- ``fixed``: cx, cy held at the given values (the config's ``free: [fx, fy, k1, k2, p1, p2]``),
  their stated std (``std`` cx, cy) carried into se3's standard errors;
- ``free``: cx, cy fitted too (no prior): what the video itself determines.

Usage: ``PYTHONPATH=. .venv/bin/python bench/bench_se3_principal_point.py [--seeds 0,1]
[--errors 0,2,5,11.7]``.
"""

from __future__ import annotations

import argparse

import numpy as np

from cvsflow.geometry import transforms as tf
from cvsflow.optimise import se3, simulate_session

FIXED = ("fx", "fy", "k1", "k2", "p1", "p2")
FREE = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")


def run(s, d_px: float, free, std_pp: float) -> dict:
    """se3 with the principal point moved by (d_px, d_px); errors of T_Cm_C against the truth."""
    tr = s["truth"]
    K = np.array(tr["K"], float).copy()
    K[0, 2] += d_px
    K[1, 2] += d_px
    std = {"fx": 0.2, "fy": 0.2, "cx": std_pp, "cy": std_pp, "k1": 1e-3, "k2": 1e-2,
           "p1": 1e-4, "p2": 1e-4, "k3": 0.05}
    cam = {"K": K.tolist(), "dist": np.asarray(tr["dist"], float).tolist(), "std": std}
    corners = s["corners"][s["corners"]["frame"] < 2400]
    r = se3.optimise_se3(corners, s["bodies"], cam, s["board"], tr["dt_offset_s"],
                         free=free).result
    T = np.array(r["T_Cm_C"])
    se = r["std_errors"]
    rot_sd = np.degrees(np.sqrt(sum(se[f"T_Cm_C_r{a}_rad"] ** 2 for a in "xyz")))
    Kf = np.array(r["K"])
    return {"rot_deg": np.degrees(tf.rotation_angle(tr["T_Cm_C"][:3, :3].T @ T[:3, :3])),
            "rot_sd_deg": rot_sd,
            "trans_mm": 1e3 * np.linalg.norm(T[:3, 3] - tr["T_Cm_C"][:3, 3]),
            "fx_err_px": Kf[0, 0] - tr["K"][0, 0],
            "cx_err_px": Kf[0, 2] - tr["K"][0, 2], "cy_err_px": Kf[1, 2] - tr["K"][1, 2],
            "cx_sd_px": se.get("cx", np.nan), "rms_px": r["rms_px"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--errors", default="0,2,5,11.7")
    ap.add_argument("--std-pp", type=float, default=0.4,
                    help="the stills' stated std of cx, cy (px) carried into 'fixed'")
    args = ap.parse_args()
    print("seed  dpp_px  mode   T_Cm_C rot deg (1-sigma)  trans mm  fx err px  cx err (sd) "
          "cy err px  RMS px")
    for seed in (int(x) for x in args.seeds.split(",")):
        s = simulate_session(seed, duration_s=90.0)
        for d in (float(x) for x in args.errors.split(",")):
            for mode, free in (("fixed", FIXED), ("free", FREE)):
                m = run(s, d, free, args.std_pp)
                print(f"{seed:4d} {d:7.1f}  {mode:5s}  {m['rot_deg']:8.4f} ({m['rot_sd_deg']:.4f})"
                      f"        {m['trans_mm']:7.3f}  {m['fx_err_px']:+8.3f}  "
                      f"{m['cx_err_px']:+7.2f} ({m['cx_sd_px']:.2f})  {m['cy_err_px']:+7.2f}  "
                      f"{m['rms_px']:.3f}", flush=True)


if __name__ == "__main__":
    main()
