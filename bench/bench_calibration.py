"""Is the calibration's stated standard deviation right? Its error over its std, on renders.

For each camera of the demo, of bench/uncertainty_sessions.yaml and the issue-39 camera
(``issue39``: fx 540, k1 -0.2, 8x6 squares of 6 cm, 16 stills, whose tilted stills an 11 px
window overreaches), and each of ``--seeds`` still sets (``synth.seed`` 5000 + 17 k: another
still plan and other pixels; a seed whose still plan does not fit the lens is passed over),
renders the calibration stills (``render_stills``), calibrates them as the workflow does
(``calibrate_camera``: per-corner windows, 4-sigma outlier rejection; ``--window 11`` for
OpenCV's fixed window) and prints the RMS over the seeds of (estimate - truth) / std per
intrinsic (1 when the stated std is right) and, pooled, the share of |z| below 1 and 2
(68.3 % and 95.4 % when right), for:

- ``detected``: the stage's own corners and camera.yaml's ``std`` (``s^2 (J^T J)^-1``);
- ``jackknife``: the same estimate over camera.yaml's ``std_jackknife`` (leave-one-still-out:
  an error shared by a still's corners, which the Gauss-Newton std takes as independent,
  shows here);
- ``iid``: the true corners plus independent Gaussian noise of the detected corners' RMS
  error, calibrated alike (what the std assumes).

and the detected corners' error against the truth: RMS (px), and the share of its variance
that is common to a still's corners (a per-still shift). Usage::

    PYTHONPATH=. .venv/bin/python bench/bench_calibration.py [--seeds 8] [--cameras demo,u_wide]
        [--window 11] [--no-rejection]
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import cv2
import numpy as np
import yaml

from cvsflow.board import board_object_points
from cvsflow.calibration import INTRINSIC_STD_NAMES, calibrate_camera
from cvsflow.exceptions import ConfigError
from cvsflow.synth.imaging import project_in_view
from cvsflow.synth.render import render_stills

REPO = Path(__file__).resolve().parents[1]
NAMES = INTRINSIC_STD_NAMES[:9]


def camera_configs():
    with open(REPO / "config" / "config.yaml") as fh:
        cfgs = {"demo": yaml.safe_load(fh)["sessions"]["demo"]}
    with open(REPO / "bench" / "uncertainty_sessions.yaml") as fh:
        more = yaml.safe_load(fh)["sessions"]
    cfgs.update({k: v for k, v in more.items() if k != "u_demo"})  # u_demo: the demo's camera
    issue = copy.deepcopy(cfgs["demo"])
    issue["synth"].update(n_stills=16, camera={"fx_px": 540.0, "fy_px": 540.0, "cx_px": 320.0,
                                              "cy_px": 240.0,
                                              "dist": [-0.2, 0.04, 0.0005, -0.0003, 0.0]})
    issue["board"] = {"squares_x": 8, "squares_y": 6, "square_m": 0.06}
    cfgs["issue39"] = issue
    return cfgs


def _params(K, dist):
    K = np.asarray(K, float)
    return np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.ravel(dist)[:5]]


def one_set(cfg, seed, window=None, reject=True):
    """z of detected, jackknife and iid; corner error RMS and common share; one still set."""
    c = copy.deepcopy(cfg)
    c["synth"]["seed"] = seed
    c["synth"].setdefault("n_stills", 15)
    stills = render_stills(c)
    gray = [(n, im if im.ndim == 2 else cv2.cvtColor(im, cv2.COLOR_BGR2GRAY)) for n, im, _ in stills]
    cam, table = calibrate_camera(gray, c["board"], subpix_window_px=window,
                                  reject_outliers=reject, cross_validation=False)
    table = table[table["used"]]
    cm = c["synth"]["camera"]
    K_true = np.array([[cm["fx_px"], 0, cm["cx_px"]], [0, cm["fy_px"], cm["cy_px"]], [0, 0, 1.0]])
    d_true = np.asarray(cm["dist"], float)
    truth = _params(K_true, d_true)
    est = _params(cam["K"], cam["dist"])
    sd = np.array([cam["std"][n] for n in NAMES])
    p_B = board_object_points(c["board"])
    T_by_name = {n: T for n, _, T in stills}
    size_wh = (cam["width"], cam["height"])
    obj, img, true_uv, errs = [], [], [], []
    for name, g in table.groupby("image", sort=False):
        k = g["corner"].to_numpy()
        uv = g[["u_px", "v_px"]].to_numpy(float)
        uv_true = project_in_view(T_by_name[name], p_B[k], K_true, d_true).reshape(-1, 2)
        obj.append(p_B[k].astype(np.float32).reshape(-1, 1, 3))
        img.append(uv.astype(np.float32).reshape(-1, 1, 2))
        true_uv.append(uv_true)
        errs.append(uv - uv_true)
    sd_jk = np.array([cam["std_jackknife"][n] for n in NAMES])
    e = np.concatenate(errs)
    rms = float(np.sqrt(np.mean(e**2)))  # per coordinate
    common = np.concatenate([np.broadcast_to(x.mean(0), x.shape) for x in errs])
    common_share = float(np.mean(common**2) / np.mean(e**2))
    rng = np.random.default_rng(seed)
    img_iid = [(t + rng.normal(0.0, rms, t.shape)).astype(np.float32).reshape(-1, 1, 2)
               for t in true_uv]  # fmt: skip
    rms_iid, K_i, d_i, _, _, std_i, _, _ = cv2.calibrateCameraExtended(obj, img_iid, size_wh,
                                                                       None, None)
    z_iid = (_params(K_i, d_i) - truth) / np.ravel(std_i)[:9]
    return (est - truth) / sd, (est - truth) / sd_jk, z_iid, rms, common_share


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--cameras", default=None)
    ap.add_argument("--window", type=int, default=None, help="fixed cornerSubPix half window")
    ap.add_argument("--no-rejection", action="store_true")
    args = ap.parse_args()
    cfgs = camera_configs()
    names = args.cameras.split(",") if args.cameras else list(cfgs)
    print("RMS over still sets of (estimate - truth) / stated std; 1 when the std is right")
    print(f"{'camera':8s} {'kind':9s} " + " ".join(f"{n:>5s}" for n in NAMES)
          + "   corner err RMS px, common share")  # fmt: skip
    pooled = {"detected": [], "jackknife": [], "iid": []}
    for name in names:
        rows, k = [], 0
        while len(rows) < args.seeds and k < 3 * args.seeds:
            try:
                rows.append(one_set(cfgs[name], 5000 + 17 * k, args.window, not args.no_rejection))
            except ConfigError as exc:  # a still plan that does not fit this lens: next seed
                print(f"{name} seed {5000 + 17 * k}: {exc}", flush=True)
            k += 1
        err = np.mean([r[3] for r in rows])
        share = np.mean([r[4] for r in rows])
        for i, kind in enumerate(("detected", "jackknife", "iid")):
            z = np.array([r[i] for r in rows])
            pooled[kind].append(z)
            tail = f"   {err:.3f}, {share:.2f}" if i == 0 else ""
            print(f"{name:8s} {kind:9s} " + " ".join(f"{v:5.2f}" for v in np.sqrt(np.mean(z**2, 0)))
                  + tail, flush=True)  # fmt: skip
        z = np.array([r[0] for r in rows])
        print(f"{name:8s} {'mean z':9s} " + " ".join(f"{v:+5.2f}" for v in z.mean(0)), flush=True)
    for kind, zs in pooled.items():
        z = np.concatenate(zs)
        print(f"{'all':8s} {kind:9s} " + " ".join(f"{v:5.2f}" for v in np.sqrt(np.mean(z**2, 0)))
              + f"   |z|<1 {100 * np.mean(np.abs(z) < 1):.1f} %, |z|<2 "
              f"{100 * np.mean(np.abs(z) < 2):.1f} % of {z.size}")


if __name__ == "__main__":
    main()
