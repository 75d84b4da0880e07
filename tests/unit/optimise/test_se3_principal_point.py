"""The se3 fit's principal point against the stills', and its known correlation with the mounting."""

from __future__ import annotations

import numpy as np

from cvsflow.optimise.se3 import EXPECTED_CORRELATIONS, correlation_warnings
from cvsflow.optimise.se3_cov import principal_point_warnings

CAMERA = {"K": [[700.0, 0.0, 331.98], [0.0, 698.0, 246.99], [0.0, 0.0, 1.0]],
          "std": {"cx": 0.33, "cy": 0.27}}


def test_a_principal_point_within_the_combined_sigmas_is_quiet():
    """The demo: video 331.51 +- 0.14, stills 331.98 +- 0.33 (1.3 sigma): no warning."""
    names = ["fx", "cx", "cy"]
    assert principal_point_warnings(CAMERA, names, np.r_[700.0, 331.51, 246.93],
                                    np.r_[0.04, 0.14, 0.11]) == []


def test_a_principal_point_off_the_stills_is_named_with_both_values():
    """The stills' cy 5 px off the video's (17 combined sigmas): one warning naming both."""
    names = ["fx", "cx", "cy"]
    out = principal_point_warnings(CAMERA, names, np.r_[700.0, 331.9, 241.99],
                                   np.r_[0.04, 0.14, 0.11])
    assert len(out) == 1 and "cy at 241.99 +- 0.11 px" in out[0]
    assert "246.99 +- 0.27 px" in out[0] and "combined sigma" in out[0]


def test_fixed_principal_point_is_not_checked():
    """cx, cy held fixed (not among the names): nothing to compare."""
    assert principal_point_warnings(CAMERA, ["fx", "fy"], np.r_[700.0, 698.0],
                                    np.r_[0.1, 0.1]) == []


def test_the_principal_points_correlation_with_the_mounting_is_not_a_warning():
    """cx ~ T_Cm_C_ry and cy ~ T_Cm_C_rx correlate at ~1 by construction; k1 ~ k2 is reported."""
    names = ["cx", "cy", "k1", "k2", "T_Cm_C_rx_rad", "T_Cm_C_ry_rad"]
    corr = np.eye(6)
    corr[0, 5] = corr[5, 0] = 0.9999
    corr[1, 4] = corr[4, 1] = -0.999
    corr[2, 3] = corr[3, 2] = -0.97
    out = correlation_warnings(corr, names, 0.95, "se3", EXPECTED_CORRELATIONS)
    assert len(out) == 1 and "k1 and k2" in out[0]
    assert len(correlation_warnings(corr, names, 0.95, "se3")) == 3
