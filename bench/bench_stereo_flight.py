"""Mono against stereo references on the same rendered flight (issue 19).

Renders the flight demo's trajectory (``flight_synth.render_flight``, 3-20 m from camera 0)
and, for a single camera and for two-camera rigs with baselines of 0.3, 1 and 3 m (camera 1
to the right of camera 0, turned in so the optical axes cross 10 m ahead), states each frame's
reference covariance from the corners the cameras see (``stereo_fusion.fused_board_pose``, 0.3 px
iid corner noise, the board's 20 corners, corners within 2 px of the border dropped). The same
flight is then drawn with that covariance and evaluated by ``flight.evaluate_flight`` (true
clock, fitted SE(3) alignment), which gives the share of samples whose error the reference
cannot resolve (sigma > |error|) per axis. It prints:

- the reference's depth sigma (along camera 0's axis) and rotation sigma against distance, per rig;
- the unresolved share per axis (x y z roll pitch yaw) at 3-20 m, per rig;
- the fused pose's calibration: NEES of Monte-Carlo solves (noisy corners, Gauss-Newton from
  the truth kicked by 1 cm / 5 cm in depth / 10 mrad) against the stated covariance, per distance bin (6 is right).

    PYTHONPATH=. .venv/bin/python bench/bench_stereo_flight.py [--seed 1] [--mc-frames 300] [--design]
                                                                 [--no-calibrated]

The covariance is the corner noise's only (calibration and rig extrinsics exact), for the
mono rig too, so the rigs compare like for like; the flight stage's own reference model adds
the calibration terms on top.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from cvsflow import flight as F
from cvsflow.board import board_object_points
from cvsflow.geometry import R_from_rvec, invert_T, pose_error_left
from cvsflow.metrics import ERROR_DIMS
from cvsflow.optimise import K_from_intrinsics
from cvsflow.rig import board_pose_starts, fused_board_pose, fused_board_pose_best
from cvsflow.synth.flight_demo import render_flight
from cvsflow.synth.flight_reference import BOARD_DEFAULT, CAMERA_DEMO, observe_rig, stereo_rig

AXES = ERROR_DIMS
#: --design: a 1080p camera and a board of twice the side (8 x 6 squares of 12.5 cm).
FHD = {"fx_px": 1400.0, "fy_px": 1400.0, "cx_px": 959.5, "cy_px": 539.5, "dist": [0.0] * 5,
       "width_px": 1920, "height_px": 1080}
BOARD_LARGE = {"squares_x": 8, "squares_y": 6, "square_m": 0.125}
BASELINES_M = (0.3, 1.0, 3.0)
CROSS_M = 10.0
DIST_BINS_M = (3.0, 5.0, 8.0, 12.0, 16.0, 20.5)
SIGMA_PX = 0.3
CHI2_6_95 = 12.592  # 95 % quantile of chi-square with 6 dof (median 5.35)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--mc-frames", type=int, default=300)
    ap.add_argument("--iterations", type=int, default=10, help="Gauss-Newton steps of the Monte-Carlo solves")
    ap.add_argument("--no-calibrated", action="store_true", help="leave out the flights with a calibration error")
    ap.add_argument("--design", action="store_true",
                    help="also sweep camera (640x480 at 702 px, 1920x1080 at 1400 px) x board (0.5, 1.0 m) x rig")
    args = ap.parse_args()
    t0 = time.process_time()
    K = np.array([[CAMERA_DEMO["fx_px"], 0, CAMERA_DEMO["cx_px"]], [0, CAMERA_DEMO["fy_px"], CAMERA_DEMO["cy_px"]],
                  [0, 0, 1.0]])
    dist = np.asarray(CAMERA_DEMO["dist"], float)
    size = (int(CAMERA_DEMO.get("width_px", 640)), int(CAMERA_DEMO.get("height_px", 480)))
    p_B = board_object_points(BOARD_DEFAULT)
    base = render_flight(seed=args.seed, duration_s=args.duration_s, reference="model")
    T_L_Q = F.T_from_traj(base.truth)
    T_C0_B = invert_T(base.T_L_C) @ T_L_Q @ base.T_Q_B
    d_m = np.linalg.norm(T_C0_B[:, :3, 3], axis=1)
    bins = np.digitize(d_m, DIST_BINS_M) - 1
    print(f"flight seed {args.seed}: {len(T_C0_B)} frames, board {d_m.min():.1f}-{d_m.max():.1f} m from "
          f"camera 0; camera {size[0]}x{size[1]} fx {K[0, 0]:.0f} px; {len(p_B)} corners, {SIGMA_PX} px")
    rigs = {"mono": None} | {f"stereo {b:g} m": b for b in BASELINES_M}
    rows, nees_rows, seen_rows = {}, {}, {}
    for name, b in rigs.items():
        T_Ci_C0 = [np.eye(4)] if b is None else stereo_rig(b, CROSS_M)
        cams = [(K, dist)] * len(T_Ci_C0)
        uv, seen = observe_rig(T_C0_B, T_Ci_C0, p_B, [CAMERA_DEMO] * len(T_Ci_C0))
        _, Sigma, n_seen = fused_board_pose(uv, seen, p_B, cams, T_Ci_C0, T_C0_B, sigma_px=SIGMA_PX,
                                            n_iterations=0)
        lost = ~np.isfinite(Sigma[:, 0, 0])
        Sigma[lost] = np.diag([1e2] * 3 + [1.0] * 3)  # never seen: the flight marks it missed
        seen_rows[name] = (n_seen > 0).mean(axis=0)
        d = render_flight(seed=args.seed, duration_s=args.duration_s, Sigma_ref=Sigma)
        valid = d.reference["pos_valid"].to_numpy(bool) & ~lost
        d.reference.loc[~valid, ["pos_valid", "rot_valid"]] = False
        r = F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref, clock=d.clock)
        ax = r.stats["axes"]
        sig_z = np.sqrt(Sigma[:, 2, 2])
        sig_rot = np.sqrt(np.trace(Sigma[:, 3:, 3:], axis1=1, axis2=2) / 3.0)
        rows[name] = {
            "depth_mm": [1e3 * np.median(sig_z[(bins == k) & ~lost]) for k in range(len(DIST_BINS_M) - 1)],
            "rot_deg": [np.degrees(np.median(sig_rot[(bins == k) & ~lost])) for k in range(len(DIST_BINS_M) - 1)],
            "unresolved": [ax[a]["unresolved_fraction"] for a in AXES],
        }
        # calibration of the fused pose: Monte-Carlo solves on a subset of frames
        rng = np.random.default_rng(args.seed)
        pick = np.sort(rng.choice(np.flatnonzero(~lost), min(args.mc_frames, int((~lost).sum())), replace=False))
        uv_n, seen_n = observe_rig(T_C0_B[pick], T_Ci_C0, p_B, [CAMERA_DEMO] * len(T_Ci_C0),
                                   SIGMA_PX * rng.standard_normal((len(pick), len(T_Ci_C0), len(p_B), 2)))
        start = T_C0_B[pick].copy()
        kick = rng.standard_normal((len(pick), 6)) * [0.01, 0.01, 0.05, 0.01, 0.01, 0.01]
        start[:, :3, 3] += kick[:, :3]
        start[:, :3, :3] = R_from_rvec(kick[:, 3:]) @ start[:, :3, :3]
        T_hat, S_hat, _ = fused_board_pose(uv_n, seen_n, p_B, cams, T_Ci_C0, start, sigma_px=SIGMA_PX,
                                          n_iterations=args.iterations)
        # as the flight reference solves it: from both IPPE poses of every camera, with the flip term
        starts = board_pose_starts(uv_n, seen_n, p_B, cams, T_Ci_C0)
        T_b, S_b, _ = fused_board_pose_best(uv_n, seen_n, p_B, cams, T_Ci_C0, starts, sigma_px=SIGMA_PX,
                                            n_iterations=args.iterations, flip_term=True)  # fmt: skip
        e_b = pose_error_left(T_b, T_C0_B[pick])
        nees_b = np.einsum("fi,fij,fj->f", e_b, np.linalg.inv(S_b), e_b)
        e = pose_error_left(T_hat, T_C0_B[pick])
        nees = np.einsum("fi,fij,fj->f", e, np.linalg.inv(S_hat), e)
        nb = bins[pick]
        nees_rows[name] = [float(np.mean(nees[nb == k])) if np.any(nb == k) else np.nan
                           for k in range(len(DIST_BINS_M) - 1)] + [float(np.mean(nees)), float(np.median(nees)),
                                                                    float(np.mean(nees > CHI2_6_95))]
        nees_rows[name + " +flip"] = [float(np.mean(nees_b[nb == k])) if np.any(nb == k) else np.nan
                                      for k in range(len(DIST_BINS_M) - 1)] + [
            float(np.mean(nees_b)), float(np.median(nees_b)), float(np.mean(nees_b > CHI2_6_95))]
    edges = [f"{a:g}-{b:g}" for a, b in zip(DIST_BINS_M[:-1], DIST_BINS_M[1:], strict=True)]
    print("\nreference depth sigma (mm), median per distance bin (m):")
    print(f"{'rig':18s} " + " ".join(f"{e:>8s}" for e in edges) + "   share of frames seen by camera 0 / 1")
    for name, row in rows.items():
        print(f"{name:18s} " + " ".join(f"{v:8.1f}" for v in row["depth_mm"]) + "   "
              + " / ".join(f"{100 * s:.0f} %" for s in seen_rows[name]))
    print("\nreference rotation sigma (deg, RMS over the three axes), median per distance bin (m):")
    for name, row in rows.items():
        print(f"{name:18s} " + " ".join(f"{v:8.2f}" for v in row["rot_deg"]))
    print("\nunresolved share (sigma > |on-board error|), % of samples, 3-20 m:")
    print(f"{'rig':18s} " + " ".join(f"{a:>6s}" for a in AXES))
    for name, row in rows.items():
        print(f"{name:18s} " + " ".join(f"{100 * v:6.1f}" for v in row["unresolved"]))
    print(f"\nNEES of the fused pose (Monte Carlo, {args.mc_frames} frames; 6 is consistent; one solve from the "
          "kicked truth, and '+flip' from every camera's IPPE poses with the flip term):")
    print(f"{'rig':18s} " + " ".join(f"{e:>8s}" for e in edges) + "      all   median  > chi2 95 %")
    for name, row in nees_rows.items():
        print(f"{name:18s} " + " ".join(f"{v:8.2f}" for v in row[:-1]) + f"   {100 * row[-1]:5.1f} %")
    if not args.no_calibrated:
        print("\nwith the calibration's error (one draw per flight: each camera's intrinsics off by their std, "
              "the rig fitted on 20 shared views with them; render_flight reference='pnp' / 'stereo'):")
        print(f"{'rig':18s} " + " ".join(f"{a:>6s}" for a in AXES) + "   | truth check z RMS per axis,"
              + " own alignment | fitted to the truth (unresolved share %, then z; weighted alignment)")
        for name, b in rigs.items():
            kw = {"reference": "pnp"} if b is None else {"reference": "stereo", "rig": {"baseline_m": b}}
            d = render_flight(seed=args.seed, duration_s=args.duration_s, **kw)
            r = F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref, clock=d.clock,
                                  weighted_alignment=True, flip_ref=d.flip_ref,
                                  cal_factor=d.cal_factor)  # fmt: skip
            chk = F.check_against_truth(r, d.onboard, d.truth, d.T_L_C, d.clock)
            ax = r.stats["axes"]
            print(f"{name:18s} " + " ".join(f"{100 * ax[a]['unresolved_fraction']:6.1f}" for a in AXES) + "   | "
                  + " ".join(f"{chk['z_rms'][a]:5.2f}" for a in AXES) + " | "
                  + " ".join(f"{chk['z_rms_truth_alignment'][a]:5.2f}" for a in AXES))
    if args.design:
        print("\nunresolved share % (x y z roll pitch yaw), corner noise only, by camera, board and rig:")
        for cam_name, cam in (("640x480 702px", CAMERA_DEMO), ("1920x1080 1400px", FHD)):
            for board_name, board in (("0.5 m", BOARD_DEFAULT), ("1.0 m", BOARD_LARGE)):
                p_d = board_object_points(board)
                for name, b in rigs.items():
                    T_Ci_C0 = [np.eye(4)] if b is None else stereo_rig(b, CROSS_M)
                    uv, seen = observe_rig(T_C0_B, T_Ci_C0, p_d, [cam] * len(T_Ci_C0))
                    K_d = K_from_intrinsics(cam["fx_px"], cam["fy_px"], cam["cx_px"], cam["cy_px"])
                    cams_d = [(K_d, np.asarray(cam["dist"], float))] * len(T_Ci_C0)
                    _, Sigma, _ = fused_board_pose(uv, seen, p_d, cams_d, T_Ci_C0, T_C0_B, sigma_px=SIGMA_PX,
                                                   n_iterations=0)  # fmt: skip
                    lost = ~np.isfinite(Sigma[:, 0, 0])
                    Sigma[lost] = np.diag([1e2] * 3 + [1.0] * 3)
                    d = render_flight(seed=args.seed, duration_s=args.duration_s, Sigma_ref=Sigma)
                    d.reference.loc[lost, ["pos_valid", "rot_valid"]] = False
                    ax = F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref, clock=d.clock).stats["axes"]
                    print(f"{cam_name:17s} {board_name:6s} {name:14s} "
                          + " ".join(f"{100 * ax[a]['unresolved_fraction']:6.1f}" for a in AXES))
    print(f"\n{time.process_time() - t0:.1f} s CPU")


if __name__ == "__main__":
    main()
