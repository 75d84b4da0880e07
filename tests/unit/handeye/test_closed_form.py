"""The hand-eye closed forms (OpenCV's AX = XB and AX = ZB solvers) on exact data."""

from __future__ import annotations

import numpy as np
import pytest

from cvsflow.handeye import closed_form as hm
from tests.helpers.handeye_sim import pose_errors, simulate


@pytest.mark.parametrize("mode", hm.MODES)
@pytest.mark.parametrize("method", ["park", "tsai", "daniilidis", "shah", "li"])
def test_closed_form_is_exact_on_exact_data(mode, method):
    """Every OpenCV closed form recovers H and G from noise-free pose pairs (both modes)."""
    s = simulate(mode, n=8, seed=3)
    T_H, T_G = hm.closed_form_hand_eye(s["T_W_X"], s["T_C_B"], mode, method)
    for T_true, T_est in ((s["T_H"], T_H), (s["T_G"], T_G)):
        e = pose_errors(T_true, T_est)
        assert np.degrees(np.linalg.norm(e[:3])) < 1e-3
        assert np.linalg.norm(e[3:]) < 1e-5
