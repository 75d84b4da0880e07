"""Synthetic features and errors drawn from the error model (T) with known parameters."""

import numpy as np
import pandas as pd

from cvsflow import uncertainty as un
from cvsflow.metrics.errors import ERROR_DIMS


def draw_transfer(rng, n, truth, n_blocks=8, reproj=None):
    """Synthetic features and errors drawn from model (T) with known parameters: U from random
    SPD matrices, a parameter covariance P shared by blocks of frames whose error is one draw
    per block (the correlated term), Student-t frames."""
    A = rng.normal(size=(n, 6, 6)) * np.r_[1e-3, 1e-3, 3e-3, 2e-3, 2e-3, 1e-3][None, :, None]
    U = A @ np.swapaxes(A, 1, 2) + np.eye(6) * 1e-8
    B = rng.normal(size=(6, 6)) * 3e-4
    P0 = B @ B.T
    speed = rng.uniform(0, 10, n)
    reproj = rng.uniform(0.1, 0.5, n) if reproj is None else np.asarray(reproj, float)
    # reproj_rms_px of many corners: the implied corner noise is reproj_rms / sqrt(2) = reproj
    feats = pd.DataFrame({"speed_px": speed, "reproj_rms_px": np.sqrt(2.0) * reproj,
                          "n_corners": 1e9})  # fmt: skip
    iu = np.triu_indices(6)
    for c, name in enumerate(un.cov_columns("unitcov")):
        feats[name] = U[:, iu[0][c], iu[1][c]]
    for c, name in enumerate(un.cov_columns("parcov")):
        feats[name] = P0[iu[0][c], iu[1][c]]
    model = {"kind": "T", **truth}
    S = un.transfer_covariance(model, feats)
    var_px = truth["s0_px"] ** 2 + (truth["s_speed"] * speed) ** 2 + (truth["s_reproj"] * reproj) ** 2
    floor = np.r_[[truth["b_pos_m"]] * 3, [truth["b_rot_rad"]] * 3] ** 2
    indep = var_px[:, None, None] * U + np.diag(floor)
    block = np.arange(n) * n_blocks // n
    shared = rng.multivariate_normal(np.zeros(6), truth["c_cal"] ** 2 * P0, n_blocks)[block]
    nu = truth["nu"]
    w = np.sqrt((nu - 2) / rng.chisquare(nu, n))
    e = np.einsum("nij,nj->ni", np.linalg.cholesky(indep), rng.normal(size=(n, 6))) * w[:, None]
    E = pd.DataFrame(e + shared, columns=[f"err_{d}" for d in ERROR_DIMS])
    return feats, E, S


TRUTH_T = {"s0_px": 0.15, "s_speed": 0.03, "s_reproj": 0.5, "c_cal": 1.0, "s_rs": 1.0, "b_pos_m": 4e-4,
           "b_rot_rad": 3e-4, "b_fill_pos_m": 2e-3, "b_fill_rot_rad": 2e-3, "nu": 6.0}  # fmt: skip
