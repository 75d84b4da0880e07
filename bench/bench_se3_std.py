"""Are se3's standard errors right on rendered sessions? Each held-out fold's fit against truth.

For each session (default: bench/uncertainty_sessions.yaml's five plus ``demo``) reads the
fits of rule heldout_se3 (results/<s>/heldout/se3_folds.yaml, one se3 fit per fold on the
other folds' blocks) and the renderer's truth (data/<s>/truth.yaml, truth_frames.parquet),
and prints, per parameter group, the RMS over the folds of z = (estimate - truth) / std
(``std_errors``: the data and the fixed intrinsics together; 1 when the std is right).

The truth of a mounting is the one the Vicon bodies of the session imply: the body poses
come from noisy markers and a marker layout the mocap stage estimates, so the Vicon's camera
body differs from the renderer's by a constant E_c, and the board body by a constant D (the
mean over frames of inv(T_W_Bm measured) T_W_Bm true). se3 fits T_Cm_C against the measured
body, so its target is E_c T_Cm_C_true (likewise D T_Bm_B_true); comparing with the raw
truth would count the body's own offset as se3's error. Rotation errors are the local
perturbation w of ``R = R_truth exp([w]x)`` (axes of C / B, as se3's parameters).

The folds of one session share 80 % of their data, so their z are correlated: read a
session's RMS as one draw that is more stable than a single fit, not as five.

The free intrinsics are also scored jointly: the squared Mahalanobis distance of (fx, fy and
the free distortion coefficients) from the truth under the fit's total covariance
(``std_errors`` with ``correlation_total``). Its expectation is their number only for a
known covariance; the cluster sandwich estimates it from ~10 one-second blocks, which alone
raises the mean above that (Hotelling's T^2), so read it for the folds far out, not the mean.

Usage: ``PYTHONPATH=. .venv/bin/python bench/bench_se3_std.py [session ...]``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from cvsflow.geometry import transforms as tf
from cvsflow.io.files import read_parquet, read_yaml
from cvsflow.optimise import CAMERA_MOVING_SMOOTH_S, BodyTrack

REPO = Path(__file__).resolve().parents[1]
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")
INTRINSICS = ("fx", "fy", *DIST_NAMES)
GROUPS = {
    "fx fy": ("fx", "fy"),
    "distortion": ("k1", "k2", "p1", "p2", "k3"),
    "dt": ("dt_offset_s",),
    "T_Cm_C t": ("T_Cm_C_x_m", "T_Cm_C_y_m", "T_Cm_C_z_m"),
    "T_Cm_C r": ("T_Cm_C_rx_rad", "T_Cm_C_ry_rad", "T_Cm_C_rz_rad"),
    "T_Bm_B t": ("T_Bm_B_x_m", "T_Bm_B_y_m", "T_Bm_B_z_m"),
    "T_Bm_B r": ("T_Bm_B_rx_rad", "T_Bm_B_ry_rad", "T_Bm_B_rz_rad"),
}


def _mean_T(T):
    """Mean of rigid transforms: chordal mean rotation, mean translation."""
    R = Rotation.from_matrix(T[:, :3, :3]).mean().as_matrix()
    return tf.make_T(R, T[:, :3, 3].mean(axis=0))


def effective_truth(session_dir: Path, results_dir: Path) -> dict:
    """The truth of T_Cm_C and T_Bm_B relative to the session's measured Vicon bodies."""
    truth = read_yaml(session_dir / "truth.yaml")
    frames = read_parquet(session_dir / "truth_frames.parquet")
    bodies = read_parquet(results_dir / "bodies.parquet")
    dt = float(truth["dt_offset_s"])
    T_Cm_C = np.asarray(truth["T_Cm_C"], float)
    T_Bm_B = np.asarray(truth["T_Bm_B"], float)
    T_W_Cm = np.asarray(truth["T_W_Cm"], float)
    t_q = frames["t_s"].to_numpy() + dt
    cam = BodyTrack.from_bodies(bodies, "camera", smooth_s=1.0, static_tol=(0.002, 0.002),
                    moving_smooth_s=CAMERA_MOVING_SMOOTH_S)
    brd = BodyTrack.from_bodies(bodies, "board", smooth_s=0.01)
    q = frames[["qx", "qy", "qz", "qw"]].to_numpy()
    T_C_B = tf.make_T(Rotation.from_quat(q).as_matrix(), frames[["x_m", "y_m", "z_m"]].to_numpy())
    T_W_Bm_true = T_W_Cm @ T_Cm_C @ T_C_B @ tf.invert_T(T_Bm_B)
    inside = cam.ok(t_q) & brd.ok(t_q)
    E_c = tf.invert_T(cam(t_q[inside])) @ T_W_Cm
    D = tf.invert_T(brd(t_q[inside])) @ T_W_Bm_true[inside]
    return {"K": np.asarray(truth["camera"]["K"], float), "dt_offset_s": dt,
            "dist": np.asarray(truth["camera"]["dist"], float),
            "T_Cm_C": _mean_T(E_c) @ T_Cm_C, "T_Bm_B": _mean_T(D) @ T_Bm_B}


def fold_errors(fit: dict, truth: dict) -> dict:
    """estimate - truth per se3 parameter of one fit (rotations as local perturbations)."""
    K = np.asarray(fit["K"], float)
    err = {"fx": K[0, 0] - truth["K"][0, 0], "fy": K[1, 1] - truth["K"][1, 1],
           "dt_offset_s": fit["dt_offset_s"] - truth["dt_offset_s"]}
    for i, name in enumerate(DIST_NAMES):
        if name in fit["std_errors"]:
            err[name] = fit["dist"][i] - truth["dist"][i]
    for name in ("T_Cm_C", "T_Bm_B"):
        T, T0 = np.asarray(fit[name], float), truth[name]
        w = tf.rvec_from_R(T0[:3, :3].T @ T[:3, :3])
        for j, ax in enumerate("xyz"):
            err[f"{name}_{ax}_m"] = T[j, 3] - T0[j, 3]
            err[f"{name}_r{ax}_rad"] = w[j]
    return err


def intrinsics_mahalanobis(fit: dict, err: dict) -> tuple[float, int]:
    """Squared Mahalanobis distance of the fit's free intrinsics from the truth under its total
    covariance (``std_errors``, ``correlation_total``), and their number (its expectation)."""
    corr = fit["correlation_total"]
    names = [n for n in INTRINSICS if n in err and n in corr["names"]]
    idx = [corr["names"].index(n) for n in names]
    sd = np.array([fit["std_errors"][n] for n in names])
    C = np.asarray(corr["matrix"], float)[np.ix_(idx, idx)] * np.outer(sd, sd)
    d = np.array([err[n] for n in names])
    return float(d @ np.linalg.solve(C, d)), len(names)


def _rms(z):
    return np.sqrt(np.mean(z**2)) if len(z) else np.nan


def main(sessions):
    rows, joint = [], []
    for s in sessions:
        res = REPO / "results" / s
        folds = read_yaml(res / "heldout" / "se3_folds.yaml")["folds"]
        truth = effective_truth(REPO / "data" / s, res)
        for k, fit in enumerate(folds):
            err = fold_errors(fit, truth)
            joint.append((s, *intrinsics_mahalanobis(fit, err)))
            for n, e in err.items():
                std_cl = np.hypot(fit["std_errors_cluster"][n], fit["std_errors_fixed"][n])
                rows.append({"session": s, "fold": k, "param": n, "err": e,
                             "std": fit["std_errors"][n], "std_data": fit["std_errors_data"][n],
                             "std_cluster": std_cl})
    t = pd.DataFrame(rows)
    t["z"] = t["err"] / t["std"]
    t["z_data"] = t["err"] / t["std_data"]
    t["z_cluster"] = t["err"] / t["std_cluster"]
    print("RMS over the folds of (estimate - truth) / std; 1 = std right "
          "(z with the data-only std in brackets)")
    print(f"{'session':10s} " + " ".join(f"{g:>16s}" for g in GROUPS) + f" {'all':>12s}")
    for s, g in [*t.groupby("session", sort=False), ("pooled", t)]:
        cells = []
        for params in GROUPS.values():
            sub = g[g["param"].isin(params)]
            cells.append(f"{_rms(sub.z):7.2f} ({_rms(sub.z_data):5.2f})")
        print(f"{s:10s} " + " ".join(f"{c:>16s}" for c in cells)
              + f" {np.sqrt(np.mean(g.z**2)):6.2f} ({np.sqrt(np.mean(g.z_data**2)):4.2f})")
    print("\nthe same with the cluster-robust std alone (and the fixed intrinsics'), per group")
    for s, g in [*t.groupby("session", sort=False), ("pooled", t)]:
        cells = [f"{_rms(g[g['param'].isin(p)].z_cluster):7.2f}" for p in GROUPS.values()]
        print(f"{s:10s} " + " ".join(f"{c:>16s}" for c in cells)
              + f" {np.sqrt(np.mean(g.z_cluster**2)):6.2f}")
    # the distortion coefficients are strongly correlated (k1-k2 about -0.93): their marginal
    # z can look right while the joint error is not
    print("\nfree intrinsics jointly: squared Mahalanobis distance from the truth per fold "
          "(its expectation = their number)")
    jt = pd.DataFrame(joint, columns=["session", "d2", "n"])
    for s, g in [*jt.groupby("session", sort=False), ("pooled", jt)]:
        print(f"{s:10s} mean {g.d2.mean():6.1f} of {g.n.mean():.0f}   folds "
              + " ".join(f"{v:.1f}" for v in g.d2))
    print("\nmean z over the folds, per parameter (a shared bias shows here)")
    piv = t.pivot_table(index="param", columns="session", values="z", aggfunc="mean", sort=False)
    print(piv[[s for s in sessions]].round(2).to_string())


if __name__ == "__main__":
    names = sys.argv[1:]
    if not names:
        cfg = read_yaml(REPO / "bench" / "uncertainty_sessions.yaml")
        names = [*cfg["sessions"], *(["demo"] if (REPO / "results/demo/heldout").is_dir() else [])]
    main(names)
