"""Pairing and scale checks of carrier poses against the camera's views (before any fit)."""

import numpy as np
import pytest

from cvsflow.exceptions import PosePairingError, ScaleMismatchError
from cvsflow.geometry import R_from_rvec
from cvsflow.handeye import closed_form as hm
from cvsflow.handeye.consistency import (
    check_motion_scale,
    check_pose_pairing,
    motion_angle_disagreement,
    motion_scale,
)
from tests.helpers.handeye_sim import simulate

NAMES = [f"v{k}.png" for k in range(10)]
POSES = [f"p{k}.yaml" for k in range(10)]


@pytest.mark.parametrize("mode", hm.MODES)
def test_exact_views_agree_in_angle_and_scale(mode):
    """Noise-free views: motion angles equal, scale 1, in both modes."""
    s = simulate(mode, n=10, seed=3)
    assert np.abs(motion_angle_disagreement(s["T_W_X"], s["T_C_B"])).max() < 1e-9
    R_X = (s["T_H"] if mode == "eye_in_hand" else s["T_G"])[:3, :3]
    assert motion_scale(s["T_W_X"], s["T_C_B"], R_X, mode) == pytest.approx(1.0, abs=1e-9)
    T = s["T_C_B"].copy()
    T[:, :3, 3] *= 10.0  # a board 10x too large in PnP
    assert motion_scale(s["T_W_X"], T, R_X, mode) == pytest.approx(0.1, abs=1e-9)


def test_shuffled_poses_are_a_pairing_error_naming_the_worst():
    """Poses shifted by one view: PosePairingError naming views with their poses and angles."""
    s = simulate("eye_in_hand", n=10, seed=4, sigma_rot_rad=np.radians(0.1))
    perm = np.roll(np.arange(10), 1)
    with pytest.raises(PosePairingError, match=r"not paired right: .*median of \d+\.\d deg over 10 views.*"
                       r"Worst pairs: v\d\.png with p\d\.yaml \(\d+\.\d deg\)"):  # fmt: skip
        check_pose_pairing(s["T_W_X"][perm], s["T_C_B"], NAMES, POSES)


def test_one_bad_pose_is_returned_as_an_outlier():
    """One carrier pose turned by 30 deg: flagged for leaving out, no error."""
    s = simulate("eye_in_hand", n=10, seed=5, sigma_rot_rad=np.radians(0.1))
    T = s["T_W_X"].copy()
    T[6, :3, :3] = T[6, :3, :3] @ R_from_rvec(np.radians([30.0, 0, 0]))
    assert check_pose_pairing(T, s["T_C_B"], NAMES, POSES).tolist() == [k == 6 for k in range(10)]


def test_scale_check_names_the_factor_and_the_square():
    """A scale of 0.1: the message says 10 times and the square size that would agree."""
    check_motion_scale(1.13, 0.0236)
    with pytest.raises(ScaleMismatchError, match=r"disagree in scale: .*are 10 times the carrier's.*"
                       r"given 0\.236 m; 0\.0236 m would agree"):  # fmt: skip
        check_motion_scale(0.1, 0.236)
    with pytest.raises(ScaleMismatchError, match="not in proportion to"):
        check_motion_scale(-0.01)
