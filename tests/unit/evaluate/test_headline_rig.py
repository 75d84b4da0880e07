"""The rig rows of the headline table (cvsflow.evaluate.headline.rig_headline)."""

from __future__ import annotations

import numpy as np

from cvsflow.evaluate.headline import headline_table, rig_headline
from cvsflow.geometry.transforms import T_from_pose6


def _result():
    T0 = T_from_pose6([0.03, -0.02, 0.05, -1.5708, 0.0, -1.7682])
    cams = []
    for i, name in enumerate(("left", "right")):
        cams.append({"name": name, "K": [[700.0 + i, 0, 320], [0, 698.0, 240], [0, 0, 1]],
                     "dt_offset_s": 2.0 - 0.8 * i, "T_Cm_C": T0.tolist(), "rms_px": 0.07,
                     "std_errors": {"fx": 0.1, "fy": 0.1, "dt_offset_s": 1e-5, "T_Cm_C_x_m": 2e-4,
                                    "T_Cm_C_y_m": 1e-4, "T_Cm_C_z_m": 1e-4}})
    return {"cameras": cams, "T_Bm_B": np.eye(4).tolist(),
            "T_Bm_B_std_errors": {"T_Bm_B_x_m": 3e-5}, "n_rig_frames_by_cameras": {"2": 86, "1": 880},
            "warnings": ["a warning"]}


def test_rig_rows_name_each_camera_with_its_truth_and_source():
    truth = {"cameras": [{"name": "right", "camera": {"K": [[701.5, 0, 320], [0, 698, 240], [0, 0, 1]]},
                          "dt_offset_s": 1.2001, "T_Cm_C": np.eye(4).tolist()}]}
    heldout = {"scores": {"by_cameras": {"1": {"rms_dist_m": 0.0016, "rms_angle_rad": 0.002},
                                         "2": {"rms_dist_m": 0.0004, "rms_angle_rad": 0.001}}}}
    rows = rig_headline("stereo", _result(), heldout=heldout, truth=truth)
    table = headline_table(rows).set_index(["group", "quantity"])
    assert set(table["session"]) == {"stereo"}
    fx = table.loc[("se3 rig: right", "fx")]
    assert fx["value"] == 701.0 and fx["std"] == 0.1 and fx["truth"] == 701.5
    assert "cameras[1].K" in fx["source"]
    dt = table.loc[("se3 rig: right", "time offset dt")]
    assert dt["truth"] == 1.2001 and dt["std"] == 1e-5
    assert np.isnan(table.loc[("se3 rig: left", "fx")]["truth"])  # no truth for the left camera
    x = table.loc[("se3 rig: left", "T_Cm_C x")]
    assert x["value"] == 30.0 and x["std"] == 0.2 and x["unit"] == "mm"
    assert np.isnan(table.loc[("se3 rig: left", "T_Cm_C yaw")]["std"])  # no rotation std given
    assert table.loc[("se3 rig: board", "rig frames by number of cameras")]["text"] == "1: 880, 2: 86"
    d2 = table.loc[("held-out RMS (se3 rig, fused poses seen by 2)", "distance")]
    assert d2["value"] == 0.4 and d2["unit"] == "mm"
    assert table.loc[("warnings", "se3 rig")]["text"] == "a warning"


def test_rig_mounting_angles_take_their_camera_s_rotation_covariance():
    """Each camera's roll/pitch/yaw std comes from its own rotation std and its block of the
    rig's correlation_total (names cam<i>_...): the right camera's here, with roll -90 deg,
    swaps the perturbation's y and z std onto yaw and pitch."""
    result = _result()
    result["cameras"][1]["std_errors"].update(T_Cm_C_rx_rad=1e-3, T_Cm_C_ry_rad=2e-3,
                                              T_Cm_C_rz_rad=5e-5)
    result["correlation_total"] = {
        "names": ["cam1_T_Cm_C_rx_rad", "cam1_T_Cm_C_ry_rad", "cam1_T_Cm_C_rz_rad"],
        "matrix": np.eye(3).tolist()}
    table = headline_table(rig_headline("stereo", result)).set_index(["group", "quantity"])
    std = [table.loc[("se3 rig: right", f"T_Cm_C {a}")]["std"] for a in ("roll", "pitch", "yaw")]
    np.testing.assert_allclose(std, np.degrees([1e-3, 5e-5, 2e-3]), rtol=0.05)
    assert np.isnan(table.loc[("se3 rig: left", "T_Cm_C roll")]["std"])
