"""The headline table: numbers from the result files in report units, honest about divergence."""

import math

import numpy as np
import pytest

from cvsflow.evaluate import headline
from cvsflow.geometry.transforms import T_from_pose6

POSE_CM_C = [0.03, -0.02, 0.05, -1.5708, 0.1, -1.5708]

CAMERA = {"K": [[702.1, 0.0, 331.4], [0.0, 698.3, 247.2], [0.0, 0.0, 1.0]],
          "std": {"fx": 0.3, "fy": 0.28, "cx": 0.57, "cy": 0.47}, "rms_px": 0.045, "n_used": 15,
          "warnings": ["3 stills tilted less than 10 deg"]}
SYNC = {"dt_offset_s": 2.372, "method": "angular_speed", "quality": 0.8,
        "details": {"dt_sigma_s": 1.3e-4, "min_quality": 0.25}, "warnings": []}
SE3 = {"fx_px": 701.5, "fy_px": 697.3, "dt_offset_s": 2.3717, "rms_px": 0.3,
       "T_Cm_C": T_from_pose6(np.array(POSE_CM_C)).tolist(),
       "std_errors": {"fx": 0.68, "fy": 0.78, "dt_offset_s": 1.4e-4, "T_Cm_C_x_m": 8e-4,
                      "T_Cm_C_rx_rad": 7e-4, "T_Cm_C_ry_rad": 3e-4, "T_Cm_C_rz_rad": 1.1e-3},
       "correlation_total": {"names": ["fx", "T_Cm_C_rx_rad", "T_Cm_C_ry_rad", "T_Cm_C_rz_rad"],
                             "matrix": [[1.0, 0.2, 0.0, 0.1], [0.2, 1.0, 0.3, -0.6],
                                        [0.0, 0.3, 1.0, 0.1], [0.1, -0.6, 0.1, 1.0]]},
       "warnings": ["se3: k1 and k2 correlate at -0.964"]}
PER_DIM = {d: {"rmse": v} for d, v in zip(
    ["x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad"],
    [0.0015, 0.0016, 0.0051, 0.003, 0.0055, 0.0009], strict=True)}
COMPARISON = {"error_frame": "C", "se3": {"per_dim": PER_DIM},
              "seed": {"diverged": True, "statistics_not_measurements": {"per_dim": {
                  "x_m": {"rmse": 1804.0}}}},
              "error_model": {"inside_68_all": 0.67, "inside_95_all": 0.921, "nees_mean": 8.1}}
SEED = {"fx_px": 285.7, "fy_px": 4985.8, "diverged": True,
        "diverged_reason": "fy = 4985.8 px within a grid step (32 px) of the bound [100, 5000] px"}
TRUTH = {"camera": {"K": [[702.0, 0, 331.5], [0, 698.0, 247.0], [0, 0, 1]]}, "dt_offset_s": 2.3717,
         "T_Cm_C": T_from_pose6(np.array(POSE_CM_C)).tolist()}


CORNERS = {"n_frames_decoded": 600, "n_found": 570, "n_dropped": 2, "warnings": []}
REPAIR = {"total": {"measured": 900, "rigid": 60, "interp": 40, "missing": 0},
          "warnings": ["board:B3 missing for 0.4 s"]}


def full_rows(**over):
    kw = {"camera": CAMERA, "sync": SYNC, "se3": SE3, "seed": SEED, "comparison": COMPARISON,
          "truth": TRUTH, "corners": CORNERS, "mocap_repair": REPAIR}
    kw.update(over)
    return headline.session_headline("lab1", **kw)


def by_key(rows):
    return {(r["group"], r["quantity"]): r for r in rows}


def test_numbers_in_report_units_with_their_source():
    rows = by_key(full_rows())
    assert rows[("calibration", "fx")]["value"] == 702.1
    assert rows[("calibration", "fx")]["std"] == 0.3
    assert rows[("calibration", "fx")]["truth"] == 702.0
    assert rows[("calibration", "fx")]["text"] == "702.10 ± 0.30"
    held = rows[("held-out RMS (se3, frame C)", "z")]
    assert held["value"] == pytest.approx(5.1) and held["unit"] == "mm"
    assert held["source"] == "results/lab1/comparison.yaml: se3.per_dim.z_m.rmse"
    assert rows[("held-out RMS (se3, frame C)", "pitch")]["value"] == pytest.approx(np.degrees(0.0055))
    assert rows[("error model (se3, held-out)", "inside the 95 % band")]["value"] == pytest.approx(92.1)
    assert rows[("sync", "offset t_vicon - t_video (angular_speed)")]["std"] == 1.3e-4


def test_mountings_from_the_matrix_with_rotation_std_in_degrees():
    rows = by_key(full_rows())
    x = rows[("se3", "T_Cm_C x")]
    assert x["value"] == pytest.approx(30.0) and x["std"] == pytest.approx(0.8) and x["unit"] == "mm"
    pitch = rows[("se3", "T_Cm_C pitch")]
    assert pitch["value"] == pytest.approx(np.degrees(0.1)) and pitch["truth"] == pytest.approx(np.degrees(0.1))
    assert math.isnan(rows[("se3", "T_Cm_C y")]["std"])  # not in std_errors: not invented


def test_mounting_angle_std_is_that_of_the_euler_angles_not_of_the_perturbation():
    """The fit's rotation std is about the mounting's own axes (R0 Exp(w)); with roll near -90
    deg an Euler angle mixes them. The headline's std per angle matches a Monte Carlo of the
    Euler angles of R Exp(w), w drawn with the stated std and correlation; quoting the
    perturbation's std for the angle (as before) misses it."""
    from scipy.spatial.transform import Rotation

    from cvsflow.geometry.transforms import euler_from_R

    rows = by_key(full_rows())
    sd = np.array([7e-4, 3e-4, 1.1e-3])
    corr = np.array(SE3["correlation_total"]["matrix"])[1:, 1:]
    rng = np.random.default_rng(4)
    w = rng.multivariate_normal(np.zeros(3), np.outer(sd, sd) * corr, 20000)
    R = np.asarray(SE3["T_Cm_C"])[:3, :3]
    rpy = euler_from_R(R @ Rotation.from_rotvec(w).as_matrix())
    mc_deg = np.degrees(np.std(rpy - euler_from_R(R), axis=0))
    got = np.array([rows[("se3", f"T_Cm_C {a}")]["std"] for a in ("roll", "pitch", "yaw")])
    np.testing.assert_allclose(got, mc_deg, rtol=0.03)
    # the perturbation's own std differs from the angles' by far more than that here
    assert np.max(np.abs(np.degrees(sd) / mc_deg - 1.0)) > 0.2
    # without a correlation table the three standard errors are taken as independent
    se3 = {**SE3}
    se3.pop("correlation_total")
    rows_ind = by_key(full_rows(se3=se3))
    got_ind = np.array([rows_ind[("se3", f"T_Cm_C {a}")]["std"] for a in ("roll", "pitch", "yaw")])
    assert np.all(np.isfinite(got_ind)) and not np.allclose(got_ind, got, rtol=0.01)


def test_diverged_seed_shows_reason_and_no_numbers():
    rows = full_rows()
    rst = headline.headline_rst(rows)
    seed_rows = [r for r in rows if "seed" in r["group"]]
    assert all(math.isnan(r["value"]) for r in seed_rows)
    assert "DIVERGED: fy = 4985.8 px" in rst
    assert "1804" not in rst and "4985.8 px within" in rst
    warns = [r["text"] for r in rows if r["group"] == "warnings"]
    assert any("diverged" in w for w in warns) and any("k1 and k2" in w for w in warns)
    assert "3 stills tilted" in " ".join(warns)


def test_a_take_cut_short_is_a_headline_warning_with_its_source():
    """mocap_import.yaml's warnings (a take cut short: both counts) reach the headline's
    warnings, naming the file they come from; a whole take adds nothing."""
    cut = ("vicon.csv: the file was cut short: 693 of the 1353 frames its header states "
           "(Total Exported Frames) were read")
    rows = headline.session_headline("lab", mocap_import={"warnings": [cut]})
    (row,) = [r for r in rows if r["group"] == "warnings"]
    assert cut in row["text"] and row["source"] == "results/lab/mocap_import.yaml: warnings"
    rows = headline.session_headline("lab", mocap_import={"n_frames": 10, "warnings": []})
    assert [r["text"] for r in rows if r["group"] == "warnings"] == ["none"]


def test_converged_seed_reports_its_held_out_rms():
    seed = {"fx_px": 700.0, "fy_px": 699.0, "diverged": False}
    comparison = {**COMPARISON, "seed": {"diverged": False, "per_dim": PER_DIM}}
    rows = by_key(full_rows(seed=seed, comparison=comparison))
    assert rows[("seed", "fx")]["value"] == 700.0
    assert rows[("held-out RMS (seed, frame C)", "x")]["value"] == pytest.approx(1.5)


def test_calibration_only_session_and_no_warnings():
    rows = headline.session_headline("stills", camera={**CAMERA, "warnings": []})
    groups = {r["group"] for r in rows}
    assert groups == {"calibration", "warnings"}
    assert [r["text"] for r in rows if r["group"] == "warnings"] == ["none"]
    rst = headline.headline_rst(rows)
    assert "truth" not in rst.split("\n\n")[1]  # no truth column without a rendered truth


def test_rst_is_valid_and_escapes_markup():
    from docutils.core import publish_parts

    rows = full_rows()
    rows += headline.flight_headline("f1", {"ape_trans": {"rmse": 0.0526}, "ape_rot": {"rmse": 0.0485},
                                            "clock": {"dt_offset_s": -17.25, "quality": 0.5},
                                            "n_pairs": 1752})
    rst = headline.headline_rst(rows)
    # halt_level 2: any docutils warning (a broken table, unbalanced markup) raises.
    html = publish_parts(rst, writer="html", settings_overrides={"halt_level": 2})["body"]
    assert html.count("<table") == 2
    assert "52.60" in html and "Flight f1" in html
    table = headline.headline_table(rows)
    assert list(table.columns) == headline.COLUMNS


def test_data_quality_rows_from_corners_and_vicon_repair():
    rows = by_key(full_rows())
    assert rows[("data", "video frames with a board")]["value"] == pytest.approx(95.0)
    assert rows[("data", "video frames with a board")]["text"] == "570 of 600"
    assert rows[("data", "Vicon marker samples filled")]["value"] == pytest.approx(10.0)
    assert rows[("warnings", "vicon")]["text"] == "board:B3 missing for 0.4 s"
    assert rows[("warnings", "vicon")]["source"] == "results/lab1/mocap_repair.yaml: warnings"


def test_a_camera_pose_session_headline_states_the_pose_fit_and_its_heldout_coverage():
    """The pose-level fit's offset, mountings (mm, deg, with errors and truth) and split-half
    check, the held-out RMS and the stated uncertainty's coverage with its verdict against the
    spread of errors persisting in time; an offset the data cannot fix
    is a note with its reason, not a number."""
    from cvsflow.evaluate import pose_fit_headline

    T = np.eye(4)
    T[:3, 3] = [0.072, 0.040, 0.026]
    std = {"rx_deg": 0.2, "ry_deg": 0.2, "rz_deg": 0.2, "x_mm": 3.1, "y_mm": 3.5, "z_mm": 2.8}
    result = {"dt_offset_s": 0.0193, "dt_offset_std_s": 0.0025, "dt_used_s": 0.0193, "T_Cm_C": T.tolist(),
              "T_Bm_B": np.eye(4).tolist(), "std": {"T_Cm_C": std, "T_Bm_B": std}, "std_inflated_by": 1.46,
              "split_half": {"agree": False, "mean_z2": 2.14, "mean_z2_limit": 1.72, "n_agree": 11, "n": 13}}
    heldout = {"error_frame": "C", "per_dim": {"x_m": {"rmse": 0.004}, "yaw_rad": {"rmse": 0.01}},
               "error_model": {"inside_68_all": 0.685, "inside_95_all": 0.912, "nees_mean": 14.2,
                               "judgement": {"verdict": "too narrow",
                                             "reasons": ["nees_mean 14.2 above 4.27..11.6"]}}}
    rows = {(r["group"], r["quantity"]): r for r in pose_fit_headline("eth", result, heldout,
                                                                      truth={"dt_offset_s": 0.02})}
    dt = rows[("pose fit", "time offset dt")]
    assert dt["value"] == 0.0193 and dt["std"] == 0.0025 and dt["truth"] == 0.02
    z = rows[("pose fit", "T_Cm_C z")]
    assert z["value"] == pytest.approx(26.0) and z["std"] == pytest.approx(2.8) and z["unit"] == "mm"
    assert rows[("pose fit", "T_Cm_C yaw")]["std"] == pytest.approx(0.2, rel=1e-6)
    assert "disagrees: mean z² 2.14 (limit 1.72), 11 of 13" in rows[("pose fit", "split-half check")]["text"]
    assert rows[("held-out RMS (pose fit, frame C)", "x")]["value"] == pytest.approx(4.0)
    assert rows[("stated uncertainty (pose fit, held-out)", "inside the 95 % band")]["value"] == pytest.approx(91.2)
    judged = rows[("stated uncertainty (pose fit, held-out)", "against its spread with errors persisting in time")]
    assert judged["text"] == "too narrow (nees_mean 14.2 above 4.27..11.6)"
    still = {**result, "dt_offset_s": None, "dt_used_s": 0.0,
             "observability": {"dt": {"reason": "the camera is nearly still"}}}
    row = next(r for r in pose_fit_headline("s", still) if r["quantity"] == "time offset dt")
    assert np.isnan(row["value"]) and "not determined (the camera is nearly still); held at 0 s" in row["text"]
