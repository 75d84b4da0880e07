"""summary_row (cvsflow.evaluate.summary): report units and the true P-bar of a rendered session."""

import numpy as np
import pandas as pd
import pytest

from cvsflow.evaluate.summary import summary_row
from cvsflow.metrics.errors import ERROR_DIMS


def test_summary_row_converts_to_report_units_and_true_p_bar():
    """summary_row gives px, mm and deg, and the true P̄ equals mean(F_true - P*) by hand."""
    rng = np.random.default_rng(11)
    frames = np.arange(20)
    F_true = rng.normal(size=(20, 6)) * [0.5, 0.5, 1.0, 0.2, 0.2, 0.2]
    P_star = F_true - np.array([0.1, -0.2, 0.3, 0.05, -0.05, 0.02])
    truth_frames = pd.DataFrame(F_true, columns=list(ERROR_DIMS)).assign(frame=frames)
    pairs = pd.DataFrame(P_star, columns=[f"vic_{d}" for d in ERROR_DIMS]).assign(frame=frames)
    result = {"fx_px": 701.0, "fy_px": 699.0, "P_bar": [0.1, -0.2, 0.3, 0.05, -0.05, 0.02],
              "n_pairs": 20}
    stats = {"per_dim": {d: {"std": 0.01} for d in ERROR_DIMS},
             "optimum": {"norm_normalised_init_m": 0.02, "norm_normalised_final_m": 0.01}}
    truth = {"camera": {"K": [[702.0, 0, 320], [0, 698.0, 240], [0, 0, 1]]}}
    row = summary_row("demo", "seed", "calib", result, stats, truth, pairs, truth_frames)
    assert row["fx_true_px"] == 702.0 and row["fy_true_px"] == 698.0
    assert row["P_bar_x_mm"] == pytest.approx(100.0)
    assert row["P_bar_roll_deg"] == pytest.approx(np.degrees(0.05))
    assert row["P_bar_true_z_mm"] == pytest.approx(300.0)
    assert row["P_bar_true_yaw_deg"] == pytest.approx(np.degrees(0.02))
    assert row["std_x_mm"] == pytest.approx(10.0)
    assert row["std_pitch_deg"] == pytest.approx(np.degrees(0.01))
    assert row["norm_final_mm"] == pytest.approx(10.0)
