"""cvsflow.metrics.errors: the error definitions shared by analyse, evaluate, flight and uncertainty."""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow import geometry as geo
from cvsflow.metrics import errors as metrics


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
