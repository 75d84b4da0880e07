"""How much of each rendered session's corner error PnP takes for a pose change.

For every frame of a rendered session (bench/uncertainty_sessions.yaml, rendered and run to
results/<s>/corners.parquet), the detected corners minus the renderer's true corners
(data/<s>/truth_corners.parquet) split into the part in PnP's 6-dimensional column space at
the true pose (with the true lens) and the rest. Independent corner noise of variance s^2 puts
6 s^2 into that space, and the rest estimates s^2 per residual degree of freedom, so

    kappa = (energy in the pose space) / (6 s^2)

is 1 for independent corners and above 1 when the corners err together like a pose change,
which the reprojection residual cannot show and model (T)'s corner-noise term (scaled by the
residual) therefore cannot predict. Printed per session, for moving (image speed over
1 px/frame) and still frames: kappa, the energy of the common shift (x, y), scale and in-plane
rotation modes per s^2 (1 when independent), and the correlation of neighbouring corners'
errors, true and as the PnP residual (at the true pose: all a user sees) shows it, beside the
residual's value for independent corners. Beside it, the session's held-out z RMS per axis under model (T) fitted on the other
sessions (results/bench_uncertainty/loso.yaml, from bench_uncertainty.py), whose spread
between sessions kappa explains (docs/findings.md, 2026-12-05).

Usage::

    PYTHONPATH=. .venv/bin/python bench/bench_corner_pose_share.py [session ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import yaml

from cvsflow.board import board_object_points
from cvsflow.io.files import read_parquet
from cvsflow.metrics import ERROR_DIMS

ROOT = Path(__file__).resolve().parents[1]
SESSIONS = ("u_demo", "u_wide", "u_tele", "u_rs", "u_far")
MOVING_PX = 1.0  # px/frame: under it the codec's still-board term applies instead


def corner_arrays(table, n_frames, n_corners):
    uv = np.full((n_frames, n_corners, 2), np.nan)
    uv[table["frame"].to_numpy(), table["corner"].to_numpy()] = table[["u_px", "v_px"]].to_numpy()
    return uv


def frame_shares(err_px, true_px, p_B, K, dist):
    """Energies of one frame's corner error (n, 2): pose space, residual, the four modes and
    the neighbours' error products."""
    n = len(err_px)
    _, rvec, tvec = cv2.solvePnP(p_B, true_px, K, dist, flags=cv2.SOLVEPNP_IPPE)
    _, jac = cv2.projectPoints(p_B, rvec, tvec, K, dist)
    Q, _ = np.linalg.qr(jac[:, :6])
    e = err_px.ravel()
    a = Q.T @ e
    c = true_px - true_px.mean(axis=0)
    modes = {"shift_x": np.c_[np.ones(n), np.zeros(n)], "shift_y": np.c_[np.zeros(n), np.ones(n)],
             "scale": c, "rotation": np.c_[-c[:, 1], c[:, 0]]}
    d = np.linalg.norm(true_px[:, None] - true_px[None], axis=-1)
    iu = np.triu_indices(n, 1)
    spacing = np.median(np.sort(d, axis=1)[:, 1])
    near = d[iu] < 1.2 * spacing
    # what a user can see: the PnP residual's neighbour products, and their value under
    # independent noise (E r r^T = s^2 M, M = I - Q Q^T)
    r = (e - Q @ a).reshape(-1, 2)
    A = np.zeros((n, n))
    A[iu[0][near], iu[1][near]] = 1.0
    M = np.eye(2 * n) - Q @ Q.T
    return {"pose": float(a @ a), "resid": float(e @ e - a @ a), "dof": 2 * n - 6,
            "nn_res": float(np.sum(np.sum(r[iu[0]] * r[iu[1]], axis=1)[near])),
            "nn_res_iid": float(np.trace(M @ np.kron(A, np.eye(2)))),
            "res_sq": float(np.sum(r**2) / n), "res_sq_iid": float(np.trace(M) / n),
            **{k: float((v.ravel() / np.linalg.norm(v) @ e) ** 2) for k, v in modes.items()},
            "nn_dot": float(np.sum(np.sum(err_px[iu[0]] * err_px[iu[1]], axis=1)[near])),
            "nn_pairs": int(near.sum()), "sq": float(np.sum(err_px**2) / n)}


def session_shares(name):
    truth = yaml.safe_load((ROOT / "data" / name / "truth.yaml").read_text())
    K = np.array(truth["camera"]["K"], float)
    dist = np.array(truth["camera"]["dist"], float)
    p_B = board_object_points(truth["board"]).astype(float)
    true_c = read_parquet(ROOT / "data" / name / "truth_corners.parquet")
    found = read_parquet(ROOT / "results" / name / "corners.parquet")
    found = found[found["found"]]
    n_frames = int(true_c["frame"].max()) + 1
    T = corner_arrays(true_c, n_frames, len(p_B))
    D = corner_arrays(found, n_frames, len(p_B))
    rows = {"moving": [], "still": []}
    for k in range(1, n_frames - 1):
        ok = np.isfinite(D[k, :, 0]) & np.isfinite(T[k, :, 0])
        if ok.sum() < 8:
            continue
        err = D[k, ok] - T[k, ok]
        if np.abs(err).max() > 3.0:  # a wrong grid or a flip: not corner noise
            continue
        speed = 0.5 * np.sqrt(np.nanmean(np.sum((T[k + 1] - T[k - 1]) ** 2, axis=1)))
        kind = "moving" if speed > MOVING_PX else "still"
        rows[kind].append(frame_shares(err, T[k, ok], p_B[ok], K, dist))
    out = {}
    for kind, r in rows.items():
        if not r:
            continue
        s2 = sum(x["resid"] for x in r) / sum(x["dof"] for x in r)
        out[kind] = {"n_frames": len(r), "sigma_px": float(np.sqrt(s2)),
                     "kappa": float(np.mean([x["pose"] for x in r]) / (6 * s2)),
                     **{m: float(np.mean([x[m] for x in r]) / s2)
                        for m in ("shift_x", "shift_y", "scale", "rotation")},
                     "neighbour_corr": float(sum(x["nn_dot"] for x in r) / sum(x["nn_pairs"] for x in r)
                                             / np.mean([x["sq"] for x in r])),
                     "residual_neighbour_corr": float(
                         sum(x["nn_res"] for x in r) / sum(x["nn_pairs"] for x in r)
                         / np.mean([x["res_sq"] for x in r])),
                     "residual_neighbour_corr_iid": float(
                         sum(x["nn_res_iid"] for x in r) / sum(x["nn_pairs"] for x in r)
                         / np.mean([x["res_sq_iid"] for x in r]))}
    return out


def main(names):
    names = names or list(SESSIONS)
    loso_path = ROOT / "results" / "bench_uncertainty" / "loso.yaml"
    loso = yaml.safe_load(loso_path.read_text())["sessions"] if loso_path.exists() else {}
    print("kappa: corner error energy PnP takes for a pose, per 6 s^2 (1 when independent); "
          "modes per s^2; neighbour correlation of the errors")
    for name in names:
        res = session_shares(name)
        for kind, r in res.items():
            print(f"{name:7s} {kind:6s} frames {r['n_frames']:3d}  s {r['sigma_px']:.3f} px  "
                  f"kappa {r['kappa']:.2f}  shift x/y {r['shift_x']:.2f}/{r['shift_y']:.2f}  "
                  f"scale {r['scale']:.2f}  rotation {r['rotation']:.2f}  "
                  f"neighbours {r['neighbour_corr']:+.3f}; in the PnP residual "
                  f"{r['residual_neighbour_corr']:+.3f} (independent: "
                  f"{r['residual_neighbour_corr_iid']:+.3f})")
        if name in loso:
            z = loso[name]["score"]["z_rms"]
            print(f"{name:7s} held-out z RMS under model (T) from the other sessions: "
                  + " ".join(f"{z[d]:.2f}" for d in ERROR_DIMS)
                  + f"  (NEES {loso[name]['score']['nees_mean']:.2f})")


if __name__ == "__main__":
    main(sys.argv[1:])
