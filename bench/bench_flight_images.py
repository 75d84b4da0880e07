"""Flights rendered as video, measured as a user measures them, against their truth.

For each validation session (bench/uncertainty_sessions.yaml, run to its comparison.yaml and
se3 result first) and seed, :func:`cvsflow.synth.flight_video.render_flight_video` films a
rendered flight (the body carrying the session's board, 1-4 m or the session's own range)
with that session's camera, lens, image effects and codec. Then the workflow's own functions
run on the video: corners (``extract_corners_parallel``, the corners stage's settings), PnP
with the validation session's se3 calibration (``estimate_poses``), the reference covariance
(``reference_covariance_transfer``: model (T) as the validation session fitted it, its
comparison.yaml ``error_model_fit``; and the rendered sessions' model for comparison), and the
flight evaluation (weighted SE(3) alignment, the true clock). Printed: the truth check, z RMS
per axis (x y z roll pitch yaw) of recovered minus injected error over the stated sigma, with
the evaluation's alignment and with the one fitted to the true poses (1 when the stated
uncertainty is right); a third line measures with the true lens and states no calibration
share (c_cal 0): the per-frame part of the statement alone, since one flight sees one draw of
its calibration error (a single flight's z on an axis the calibration dominates is that draw's
size, not a check of its distribution); and the corners' pose-like share on the flight's own frames against
the truth (kappa, as bench_corner_pose_share.py; 1 for independent corners).

Usage (render the sessions first: bench/uncertainty_sessions.yaml says how; then
``snakemake --cores 2 --configfile bench/uncertainty_sessions.yaml -- results/u_far/comparison.yaml
results/u_far/se3/calib/result.yaml`` and the same for the others)::

    PYTHONPATH=. .venv/bin/python bench/bench_flight_images.py [--sessions u_far u_tele u_wide]
        [--seeds 1 2] [--duration-s 60] [--range-m 1.5 4.5] [--cache DIR]

Videos are cached in DIR (default /tmp/bench_flight_images/<session>_<seed>).
"""

from __future__ import annotations

import argparse
import sys
import time
from functools import partial
from pathlib import Path

import cv2
import numpy as np
import yaml
from bench_corner_pose_share import frame_shares

from cvsflow.board import board_object_points
from cvsflow.calibration import estimate_poses
from cvsflow.corners import extract_corners_parallel, summarise_corners
from cvsflow.flight import (
    Clock,
    T_from_traj,
    check_against_truth,
    correct_rolling_shutter,
    evaluate_flight,
    reference_covariance_transfer,
    reference_from_poses,
    session_error_model,
)
from cvsflow.geometry import invert_T
from cvsflow.io.files import read_parquet, read_yaml
from cvsflow.io.flightlog import read_tum
from cvsflow.io.media import iter_video_gray, video_info, video_timing
from cvsflow.synth.flight_video import render_flight_video

ROOT = Path(__file__).resolve().parents[1]


def configs():
    main = yaml.safe_load((ROOT / "config/config.yaml").read_text())
    bench = yaml.safe_load((ROOT / "bench/uncertainty_sessions.yaml").read_text())
    return main, {**main["sessions"], **bench["sessions"]}


def pose_share(corners, truth_T_C_B, p_B, K, dist):
    """kappa of the flight's detected corners against the true ones (true lens), as
    bench_corner_pose_share.py measures it on a session."""
    rows = []
    for k, g in corners[corners["found"]].groupby("frame"):
        if len(g) < 8 or k >= len(truth_T_C_B):
            continue
        obj = p_B[g["corner"].to_numpy()]
        T = truth_T_C_B[k]
        true = cv2.projectPoints(obj, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], K, dist)[0].reshape(-1, 2)
        err = g[["u_px", "v_px"]].to_numpy() - true
        if np.abs(err).max() <= 3.0:  # a wrong grid or a flip: not corner noise
            rows.append(frame_shares(err, true, obj, K, dist))
    if not rows:
        return float("nan")
    s2 = sum(r["resid"] for r in rows) / sum(r["dof"] for r in rows)
    return float(np.mean([r["pose"] for r in rows]) / (6.0 * s2))


def run(name, seed, main_cfg, sessions, duration_s, range_m, cache):
    cfg = sessions[name]
    res = ROOT / "results" / name
    calib = read_yaml(res / "se3" / "calib" / "result.yaml")
    model = session_error_model(read_yaml(res / "comparison.yaml"), res / "comparison.yaml")
    out = Path(cache) / f"{name}_{seed}"
    t0 = time.perf_counter()
    if not (out / "truth.yaml").exists():
        render_flight_video(cfg, out, seed=seed, duration_s=duration_s, range_m=range_m)
    t_render = time.perf_counter() - t0
    truth_doc = read_yaml(out / "truth.yaml")
    video = out / "video.mp4"
    board = cfg["board"]
    c = main_cfg["corners"]
    t0 = time.perf_counter()
    corners = extract_corners_parallel(partial(iter_video_gray, str(video), undecodable=True),
                                       video_info(video)["n_frames"], board, n_workers=2,
                                       subpix_window_px=c["subpix_window_px"],
                                       max_grid_deviation=c["max_grid_deviation"],
                                       restart_every=c["restart_every_frames"])  # fmt: skip
    summary = summarise_corners(corners, video_timing(video))
    K, dist = np.array(calib["K"], float), np.array(calib["dist"], float)
    poses = estimate_poses(corners, K, dist, board, **main_cfg["pnp"])
    t_measure = time.perf_counter() - t0
    p_B = board_object_points(board)
    truth = read_parquet(out / "truth.parquet")
    onboard = read_tum(out / "onboard.tum")
    T_L_C = np.array(truth_doc["T_L_C"])
    T_Q_B = np.array(truth_doc["T_Q_B"])
    clock = Clock(**truth_doc["clock"])
    T_true_C_B = invert_T(T_L_C) @ T_from_traj(truth) @ T_Q_B
    true_cam = yaml.safe_load((ROOT / "data" / name / "truth.yaml").read_text())["camera"]
    kappa = pose_share(corners, T_true_C_B, p_B, np.array(true_cam["K"], float),
                       np.array(true_cam["dist"], float))
    print(f"{name} seed {seed}: {int(poses['valid'].sum())} of {len(poses)} frames with a pose, "
          f"range {truth_doc['range_m']} m, codec {summary.get('codec')} "
          f"(inter-coded {summary.get('inter_coded')}), corners' kappa {kappa:.2f}; "
          f"render {t_render:.0f} s, measure {t_measure:.0f} s", flush=True)
    ld = float(calib.get("line_delay_s") or 0.0)

    def reference_of(p, cal):
        """The flight stage's reference: a rolling shutter's shear taken out, timed at the rows."""
        if ld:
            p, _ = correct_rolling_shutter(p, corners, p_B, cal)
        return p, reference_from_poses(p, corners, ld)

    # the per-frame part alone: PnP with the true lens, the calibration's share stated as none
    true_lens = {**calib, "K": true_cam["K"], "dist": true_cam["dist"]}
    poses_true = estimate_poses(corners, np.array(true_cam["K"], float),
                                np.array(true_cam["dist"], float), board, **main_cfg["pnp"])
    variants = (("validation session's model", model, *reference_of(poses, calib), calib),
                ("rendered sessions' model", None, *reference_of(poses, calib), calib),
                ("validation's, true lens", {**model, "c_cal": 0.0},
                 *reference_of(poses_true, true_lens), true_lens))
    for label, m, p, ref, cal in variants:
        Sigma, flip, G = reference_covariance_transfer(
            p, corners, p_B, cal, model=m, inter_coded=bool(summary.get("inter_coded")),
            return_terms=True, shear_corrected=bool(ld))  # fmt: skip
        r = evaluate_flight(ref, onboard, T_Q_B, Sigma, clock=clock, weighted_alignment=True,
                            flip_ref=flip, cal_factor=G)  # fmt: skip
        chk = check_against_truth(r, onboard, truth, T_L_C, clock)
        z = " ".join(f"{v:.2f}" for v in chk["z_rms"].values())
        zt = " ".join(f"{v:.2f}" for v in chk["z_rms_truth_alignment"].values())
        print(f"    {label:28s}: {z} | {zt} | n {chk['n']}", flush=True)


def main(argv):
    ap = argparse.ArgumentParser()
    ap.add_argument("--sessions", nargs="+", default=["u_far", "u_tele", "u_wide"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--range-m", nargs=2, type=float, default=None)
    ap.add_argument("--cache", default="/tmp/bench_flight_images")
    a = ap.parse_args(argv)
    main_cfg, sessions = configs()
    print("truth check, z RMS per axis (x y z roll pitch yaw): own alignment | alignment fitted "
          "to the truth")
    for name in a.sessions:
        for seed in a.seeds:
            run(name, seed, main_cfg, sessions, a.duration_s, a.range_m, a.cache)


if __name__ == "__main__":
    main(sys.argv[1:])
