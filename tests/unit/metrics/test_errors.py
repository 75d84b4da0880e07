"""cvsflow.metrics.errors: the error definitions shared by analyse, evaluate and uncertainty."""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow import geometry as geo
from cvsflow.evaluate import analyse
from cvsflow.evaluate import heldout as evaluate
from cvsflow.metrics import errors as metrics


def _errors(seed, n=200):
    rng = np.random.default_rng(seed)
    E = rng.normal(0.0, 1.0, (n, 6)) * [1e-3, 2e-3, 4e-3, 1e-3, 2e-3, 5e-4] + [1e-4, 0, 0, 0, 0, 2e-4]
    return pd.DataFrame(E, columns=[f"eps_{d}" for d in metrics.ERROR_DIMS])


def test_error_moments_are_mean_std_and_rms_about_zero():
    """mean, sample std (ddof 1) and RMS about zero (not about the mean)."""
    x = np.array([1.0, 2.0, 3.0, 6.0])
    mean, std, rms = metrics.error_moments(x)
    assert mean == 3.0 and std == np.std(x, ddof=1) and rms == np.sqrt(50.0 / 4.0)


def test_analyse_and_evaluate_state_the_same_moments():
    """The per-run statistics (analyse) and the method comparison (evaluate) use one
    definition: on the same table their mean, std and rms are equal, bit for bit."""
    table = _errors(1)
    per_run = analyse.normality_tests(table)
    compared = evaluate.compare_methods({"se3": table}, block_len=5, n_boot=20)["se3"]["per_dim"]
    for d in metrics.ERROR_DIMS:
        for k in ("mean", "std", "rms"):
            assert compared[d][k] == per_run.loc[d, k], (d, k)


def test_pose_errors_of_a_pure_yaw_error_and_the_table_form():
    """A 1-degree yaw error about C's z axis is err_yaw 1 degree, nothing else; frame_errors
    on a table of the same poses gives the same columns."""
    T_ref = geo.T_from_pose6(np.array([[0.1, -0.05, 1.2, 0.3, -0.2, 0.5]]))
    dR = geo.R_from_euler([0.0, 0.0, np.radians(1.0)])
    T_est = T_ref.copy()
    T_est[0, :3, :3] = dR @ T_ref[0, :3, :3]
    err = metrics.pose_errors(T_ref, T_est, frame="C")
    np.testing.assert_allclose(err[metrics.error_columns()].to_numpy()[0], [0, 0, 0, 0, 0, np.radians(1.0)],
                               atol=1e-12)
    row = {}
    for prefix, T in (("ref_", T_ref), ("cvs_", T_est)):
        q = geo.quat_from_R(T[0, :3, :3])
        row.update({f"{prefix}{a}_m": T[0, i, 3] for i, a in enumerate("xyz")})
        row.update({f"{prefix}q{a}": q[i] for i, a in enumerate("xyzw")})
    table = metrics.frame_errors(pd.DataFrame([row]))
    np.testing.assert_allclose(table[metrics.error_columns()].to_numpy(), err[metrics.error_columns()].to_numpy(),
                               atol=1e-12)
