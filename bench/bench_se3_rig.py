"""Benchmark of the N-camera se3 fit (cvsflow.rig.fit) for 1, 2 and 3 cameras.

One simulated rig session (corner level, 0.3 px, 0.3 mm markers, 15 % of each take hidden
from each camera; cameras 0 and 1 at 30 fps genlocked with their own clocks, camera 2 at
25 fps), fitted with the first 1, 2 and 3 cameras. Prints, per N: CPU time, the largest
|z| (error / stated standard error) over all parameters, the shared T_Bm_B's translation
error and standard error, each camera's dt error, and the rig frames by number of cameras;
then, per N, the fused poses' NEES against the true pose (6 expected) on rig frames seen by
1, 2, 3 cameras, with the calibration's uncertainty in their covariance and without it, and
the CPU time of :func:`~cvsflow.rig.poses.fused_rig_poses` each way (frames of
cameras not triggered together moved to one instant, its default).
Usage: ``.venv/bin/python bench/bench_se3_rig.py [seed] [duration_s]``.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from cvsflow.geometry import INTRINSIC_NAMES
from cvsflow.geometry import transforms as tf
from cvsflow.optimise import simulate_rig_session
from cvsflow.rig import fused_rig_poses, optimise_se3_rig

FREE = ("fx", "fy", "k1", "k2")


def nees(poses, truth):
    """Per rig frame (d^T S^-1 d), d the fused pose's error [dt, dtheta] against the truth."""
    T_true = truth["T_C0_B_at"](poses["t_vicon_s"].to_numpy() - truth["cameras"][0]["dt_offset_s"])
    q = poses[["cvs_qx", "cvs_qy", "cvs_qz", "cvs_qw"]].to_numpy()
    T_est = tf.make_T(tf.R_from_quat(q), poses[["cvs_x_m", "cvs_y_m", "cvs_z_m"]].to_numpy())
    d = tf.pose_error_left(T_est, T_true)
    S = poses[[f"S{a}{b}" for a in range(6) for b in range(6)]].to_numpy().reshape(-1, 6, 6)
    return np.einsum("fi,fij,fj->f", d, np.linalg.inv(S), d)


def main(seed: int = 0, duration_s: float = 20.0) -> None:
    s = simulate_rig_session(seed, n_cameras=3, duration_s=duration_s)
    held = {n: 0.0 for n in INTRINSIC_NAMES if n not in FREE}
    entries = []
    for c, t in zip(s["cameras"], s["truth"]["cameras"], strict=True):
        K0 = t["K"] + np.diag([6.0, -5.0, 0.0])
        entries.append(
            {
                "corners": c["corners"],
                "dt_offset_s": t["dt_offset_s"] + 0.01,
                "camera": {"K": K0.tolist(), "dist": t["dist"].tolist(), "std": held},
            }
        )
    tB = s["truth"]["T_Bm_B"][:3, 3]
    print(f"seed {seed}, {duration_s:.0f} s per camera, free {FREE}")
    print(
        "N  cpu_s  params  max|z|_fx,dt,t  T_Bm_B err mm (x y z)   T_Bm_B se mm (x y z)   "
        "dt err ms per camera   rig frames by cameras"
    )
    fits = {}
    for n in (1, 2, 3):
        c0 = time.process_time()
        fit = optimise_se3_rig(entries[:n], s["bodies"], s["board"], free=FREE)
        cpu = time.process_time() - c0
        fits[n] = fit
        r = fit.result
        se = r["std_errors"]
        z = []
        for i in range(n):
            tc = s["truth"]["cameras"][i]
            c = r["cameras"][i]
            z.append((np.asarray(c["K"])[0, 0] - tc["K"][0, 0]) / se[f"cam{i}_fx"])
            z.append((c["dt_offset_s"] - tc["dt_offset_s"]) / se[f"cam{i}_dt_offset_s"])
            for j, a in enumerate("xyz"):
                z.append((np.asarray(c["T_Cm_C"])[j, 3] - tc["T_Cm_C"][j, 3]) / se[f"cam{i}_T_Cm_C_{a}_m"])
        eB = 1e3 * (np.asarray(r["T_Bm_B"])[:3, 3] - tB)
        sB = 1e3 * np.array([se[f"T_Bm_B_{a}_m"] for a in "xyz"])
        z += list(eB / sB)
        ddt = [
            1e3 * (r["cameras"][i]["dt_offset_s"] - s["truth"]["cameras"][i]["dt_offset_s"]) for i in range(n)
        ]
        print(
            f"{n}  {cpu:5.2f}  {len(r['estimates']):6d}  {np.max(np.abs(z)):14.2f}  "
            f"{np.array2string(eB, precision=3):24s} {np.array2string(sB, precision=3):22s} "
            f"{np.array2string(np.array(ddt), precision=3):22s} {r['n_rig_frames_by_cameras']}"
        )

    print("N  calibration  fused_cpu_s  NEES mean (median) by cameras seeing the frame: 1, 2, 3")
    for n, fit in fits.items():
        frames = [f[f >= 0] for f in (fit.errors[f"frame_cam{i}"].to_numpy() for i in range(n))]
        for on in (False, True):
            c0 = time.process_time()
            poses = fused_rig_poses(fit.result, [e["corners"] for e in entries[:n]], s["bodies"], s["board"],
                                    frames=frames, calibration_cov=on)  # fmt: skip
            cpu = time.process_time() - c0
            e = nees(poses, s["truth"])
            k = poses["n_cameras"].to_numpy()
            by = "  ".join(f"{e[k == c].mean():6.2f} ({np.median(e[k == c]):5.2f}, {int((k == c).sum())} fr)"
                           for c in range(1, n + 1) if (k == c).any())  # fmt: skip
            print(f"{n}  {'with' if on else 'without':11s}  {cpu:11.2f}  {by}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 0, float(sys.argv[2]) if len(sys.argv) > 2 else 20.0)
