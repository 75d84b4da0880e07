"""Tests of the workflow side of the rig fit (optimise.se3_rig_run) on a corner-level simulated
rig: the entries, the result named by camera, held-out scores and the fused poses' NEES."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cvsflow.exceptions import OptimiseError
from cvsflow.geometry.camera import INTRINSIC_NAMES
from cvsflow.optimise.se3_sim import simulate_rig_session
from cvsflow.rig.fit import optimise_se3_rig
from cvsflow.rig.poses import fused_rig_poses
from cvsflow.rig.run import (
    fused_pose_nees,
    heldout_scores,
    name_rig_result,
    rig_camera_entries,
    rig_fit_options,
)

FREE = ("fx", "fy", "k1", "k2")


@pytest.fixture(scope="module")
def rig():
    return simulate_rig_session(3, n_cameras=2, duration_s=6.0)


@pytest.fixture(scope="module")
def fitted(rig):
    held = {n: 0.0 for n in INTRINSIC_NAMES if n not in FREE}
    cams = [{"K": (t["K"] + np.diag([6.0, -5.0, 0.0])).tolist(), "dist": t["dist"].tolist(), "std": held}
            for t in rig["truth"]["cameras"]]
    entries = rig_camera_entries([c["corners"] for c in rig["cameras"]], cams,
                                 [t["dt_offset_s"] + 0.01 for t in rig["truth"]["cameras"]])
    options = rig_fit_options({"free": list(FREE), "loss": "soft_l1", "unknown_here": 1})
    assert options == {"free": FREE, "loss": "soft_l1"}
    assert rig_fit_options({}) == {"free": ("fx", "fy", "k1", "k2", "p1", "p2")}
    return optimise_se3_rig(entries, rig["bodies"], rig["board"], **options)


def test_entries_need_one_of_each_per_camera(rig):
    c = rig["cameras"][0]
    with pytest.raises(OptimiseError, match="2 corner tables, 1 cameras and 2 offsets"):
        rig_camera_entries([c["corners"]] * 2, [c["camera"]], [2.0, 2.1])


def test_named_result_splits_the_estimates_by_camera(fitted):
    """Each camera's own estimates and standard errors under the mono names; no wall time."""
    res = name_rig_result(fitted.result, ["left", "right"], ["s-left", "s-right"])
    assert "time_s" not in res and "time_s" in fitted.result
    assert res["camera_names"] == ["left", "right"]
    for i, c in enumerate(res["cameras"]):
        assert c["name"] == ["left", "right"][i] and c["session"] == ["s-left", "s-right"][i]
        assert c["std_errors"]["fx"] == fitted.result["std_errors"][f"cam{i}_fx"]
        assert c["estimates"]["dt_offset_s"] == pytest.approx(c["dt_offset_s"])
        assert set(c["std_errors"]) == {"fx", "fy", "k1", "k2", "T_Cm_C_x_m", "T_Cm_C_y_m", "T_Cm_C_z_m",
                                        "T_Cm_C_rx_rad", "T_Cm_C_ry_rad", "T_Cm_C_rz_rad", "dt_offset_s"}
    assert set(res["T_Bm_B_std_errors"]) == {f"T_Bm_B_{a}_m" for a in "xyz"} | {
        f"T_Bm_B_r{a}_rad" for a in "xyz"}
    with pytest.raises(OptimiseError, match="1 camera names for 2 cameras"):
        name_rig_result(fitted.result, ["left"])


def test_fused_pose_nees_against_the_simulated_truth(fitted, rig):
    """The fused poses' NEES against the true pose is near 6; a wrong pose makes it large."""
    poses = fitted.errors
    truth = rig["truth"]
    T_true = truth["T_C0_B_at"](poses["t_vicon_s"].to_numpy() - truth["cameras"][0]["dt_offset_s"])
    nees = fused_pose_nees(poses, T_true)
    assert nees.shape == (len(poses),) and np.all(nees >= 0)
    assert 4.0 < nees.mean() < 8.5
    shifted = T_true.copy()
    shifted[:, 0, 3] += 0.005
    assert fused_pose_nees(poses, shifted).mean() > 10 * nees.mean()


def test_heldout_scores_by_number_of_cameras():
    df = pd.DataFrame({"n_cameras": [1, 1, 2], "err_dist_m": [0.003, 0.004, 0.001],
                       "err_angle_rad": [0.0, 0.002, 0.001]})
    s = heldout_scores(df)
    assert s["n_frames"] == 3 and s["by_cameras"][1]["n_frames"] == 2
    assert s["by_cameras"][1]["rms_dist_m"] == pytest.approx(np.sqrt((0.003**2 + 0.004**2) / 2))
    assert s["rms_angle_rad"] == pytest.approx(np.sqrt(0.000005 / 3))


def test_views_with_a_corner_on_the_wrong_crossing_are_left_out_of_the_fusion(fitted, rig):
    """A camera's view with one corner 40 px off: with max_residual_px it is left out (the frame
    fused from the other camera or dropped), and the fused poses' NEES stays near 6."""
    corners = [c["corners"].copy() for c in rig["cameras"]]
    c1 = corners[1]
    frames = np.sort(c1.loc[c1["found"], "frame"].unique())[::15][:8]
    first = c1.index[c1["frame"].isin(frames) & c1["found"]].to_series().groupby(c1["frame"]).first()
    c1.loc[first.to_numpy(), "u_px"] += 40.0
    truth = rig["truth"]

    def nees(poses):
        T = truth["T_C0_B_at"](poses["t_vicon_s"].to_numpy() - truth["cameras"][0]["dt_offset_s"])
        return fused_pose_nees(poses, T)

    plain = fused_rig_poses(fitted.result, corners, rig["bodies"], rig["board"])
    gated = fused_rig_poses(fitted.result, corners, rig["bodies"], rig["board"], max_residual_px=2.0)
    hit = plain["frame_cam1"].isin(frames)
    assert hit.sum() == len(frames) and nees(plain)[hit.to_numpy()].min() > 100
    assert not gated["frame_cam1"].isin(frames).any()  # those views are out
    assert 4.0 < nees(gated).mean() < 8.5
    # clean views are all kept: the gate takes out only the corrupted ones
    assert len(gated[gated["frame_cam1"] >= 0]) == len(plain[plain["frame_cam1"] >= 0]) - len(frames)
