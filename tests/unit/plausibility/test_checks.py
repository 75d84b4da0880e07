"""Plausibility checks at the stage boundaries (issue 14, data side): one test per failure row.

Each test builds the broken input in memory (or as a small file in tmp_path), asserts the
error type and that its message names the file, the body, frame or row and what was expected,
and, where a stage script is run, that the stage left no output behind.
"""

import logging

import cv2
import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from cvsflow.exceptions import (
    BoardNotSeenError,
    NoUsableRowsError,
    OverlapError,
    ResultRangeError,
    ScaleMismatchError,
    StaticBoardError,
    SyncError,
    UnitsError,
)
from cvsflow.geometry.transforms import make_T, transform_points
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.mocap.vicon import read_nexus_csv, write_nexus_csv
from cvsflow.mocap.bodies import fit_bodies
from cvsflow.plausibility.checks import (
    check_body_fits,
    check_marker_scale,
    check_overlap,
    check_pair_distances,
    check_poses_found,
    check_rows,
    check_sync_inputs,
)
from cvsflow.plausibility.results import check_se3_result, check_seed_result
from tests.helpers.stages import run_stage

CAMERA_NAMES = ["camera:C1", "camera:C2", "camera:C3", "camera:C4"]
BOARD_NAMES = ["board:B1", "board:B2", "board:B3", "board:B4"]
SPECS = {
    "camera": {"names": CAMERA_NAMES,
               "layout_m": [[0.0, 0.0, 0.0], [0.0, 0.16, 0.0], [0.0, 0.0, 0.12], [0.0, 0.11, 0.17]]},
    "board": {"names": BOARD_NAMES,
              "layout_m": [[0.0, 0.0, 0.0], [0.76, 0.0, 0.0], [0.0, 0.52, 0.0], [0.58, 0.5, 0.0]]},
}
VICON_CFG = {"max_fit_rms_m": 0.01, "max_fit_rms_share": 0.1}
K = [[700.0, 0.0, 320.0], [0.0, 698.0, 240.0], [0.0, 0.0, 1.0]]


def markers_table(n=300, rate_hz=300.0, seed=0, noise_m=0.0003):
    """Wide marker table (metres, W) of both bodies moving rigidly, with marker noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    data = {"frame": np.arange(n), "t_s": t}
    for body, origin in (("camera", [0.2, -1.5, 1.0]), ("board", [0.5, 0.3, 1.2])):
        rot = Rotation.from_rotvec(np.outer(np.sin(2 * np.pi * 0.5 * t), [0.2, 0.1, 0.3])).as_matrix()
        T = make_T(rot, np.asarray(origin) + np.outer(t, [0.1, 0.0, 0.05]))
        for name, p in zip(SPECS[body]["names"], SPECS[body]["layout_m"], strict=True):
            xyz = transform_points(T, np.asarray(p)) + rng.normal(0, noise_m, (n, 3))
            for a, axis in enumerate("xyz"):
                data[f"{name}_{axis}_m"] = xyz[:, a]
    df = pd.DataFrame(data)
    df.attrs["rate_hz"] = rate_hz
    df.attrs["markers"] = CAMERA_NAMES + BOARD_NAMES
    return df


def poses_table(n=90, fps=30.0, moving=True, valid=True, seed=0):
    """poses_raw-like table: a board 1.5 m in front of the camera, turning or static."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fps
    amp = 0.4 if moving else 0.0
    rv = np.outer(np.sin(2 * np.pi * 0.7 * t), [amp, 0.5 * amp, 0.0]) + [np.pi, 0.0, 0.0]
    rv = rv + rng.normal(0, 1e-4, rv.shape)
    return pd.DataFrame({
        "frame": np.arange(n), "t_s": t, "valid": np.full(n, valid),
        "rvec_0": rv[:, 0], "rvec_1": rv[:, 1], "rvec_2": rv[:, 2],
        "x_m": 0.1, "y_m": 0.05, "z_m": 1.5,
    })


# ----------------------------------------------------------------- Vicon units and cells


def test_units_row_m_on_mm_data_stops_vicon_import(tmp_path):
    """Row 'units row says m on data in mm': mocap_import stops with a UnitsError naming the
    file, the body, both spans and 'says m where the values are mm'; no markers.parquet."""
    csv = tmp_path / "vicon.csv"
    write_nexus_csv(markers_table(), csv, rate_hz=300.0)
    lines = csv.read_bytes().decode().split("\r\n")
    lines[4] = lines[4].replace("mm", "m")
    csv.write_text("\r\n".join(lines))
    out = tmp_path / "markers.parquet"
    with pytest.raises(UnitsError, match=r"vicon\.csv: body 'camera'.*span 2\d\d(\.\d+)? m.*layout_m spans "
                       r"0\.2\d* m.*ratio 1\d\d\d.*says m where the values are mm"):
        run_stage("mocap_import", tmp_path, {"csv": csv}, {"markers": out, "summary": tmp_path / "s.yaml"},
                  {"markers": SPECS, "max_scale_ratio": 3.0})
    assert not out.exists() and not (tmp_path / "s.yaml").exists()
    assert "Traceback" not in (tmp_path / "logs" / "mocap_import.log").read_text()
    assert "mocap_import failed (UnitsError)" in (tmp_path / "logs" / "mocap_import.log").read_text()
    assert "vicon.csv: body 'camera'" in (tmp_path / "logs" / "mocap_import.log").read_text()


def test_marker_scale_right_units_pass_and_cm_named():
    """Right units: no error; values in cm read as mm (ratio 0.1): the hint names it."""
    m = markers_table()
    assert check_marker_scale(m, SPECS, "vicon.csv") == []
    small = m.copy()
    small[[c for c in m.columns if c.endswith("_m")]] *= 0.1
    with pytest.raises(UnitsError, match="says mm where the values are cm"):
        check_marker_scale(small, SPECS, "vicon.csv")


def test_fit_rms_against_layout_scale_stops_vicon_bodies(tmp_path):
    """Markers 1000x the layout (the units row past mocap_import): the rigid-body fit RMS is
    hundreds of metres; mocap_bodies stops naming the body, the RMS and the limit, writes
    nothing. Right units: a fit RMS of 0.3 mm passes without warnings."""
    good = markers_table()
    assert check_body_fits(fit_bodies(good, SPECS), SPECS, "markers_filled.parquet", **VICON_CFG) == []
    bad = good.copy()
    bad[[c for c in good.columns if c.endswith("_m")]] *= 1000.0
    src = tmp_path / "markers_filled.parquet"
    write_parquet(bad, src)
    outs = {"bodies": tmp_path / "bodies.parquet", "fig": tmp_path / "mocap_fit.png"}
    with pytest.raises(UnitsError, match=r"markers_filled\.parquet: body 'board': rigid-body fit RMS "
                       r"\d{3}(\.\d+)? m.*expected at most 0\.04\d* m"):
        run_stage("mocap_bodies", tmp_path, {"m": src}, outs, {"markers": SPECS, "bag": None, **VICON_CFG})
    assert not any(p.exists() for p in outs.values())


def test_body_never_valid_is_an_error():
    """A body with no valid sample: NoUsableRowsError naming the body and the sample count."""
    m = markers_table()
    for n in BOARD_NAMES[1:]:
        m[[f"{n}_{a}_m" for a in "xyz"]] = np.nan
    with pytest.raises(NoUsableRowsError, match=r"markers\.parquet: body 'board' has no valid pose in any of its 300"):
        check_body_fits(fit_bodies(m, SPECS), SPECS, "markers.parquet")


def test_nonfinite_cells_are_gaps_with_count_and_first_line(tmp_path, caplog):
    """Row 'inf, -inf, 1e999 cells': read as NaN gaps (never +-inf), one WARNING with the count
    and the first line and column."""
    csv = tmp_path / "vicon.csv"
    write_nexus_csv(markers_table(n=20), csv, rate_hz=300.0)
    lines = csv.read_bytes().decode().split("\r\n")
    for line_no, col, text in ((8, 2, "inf"), (12, 5, "-inf"), (15, 9, "1e999")):
        cells = lines[line_no - 1].split(",")
        cells[col] = text
        lines[line_no - 1] = ",".join(cells)
    csv.write_text("\r\n".join(lines))
    with caplog.at_level(logging.WARNING, logger="cvsflow.io.mocap.vicon"):
        df = read_nexus_csv(csv)
    xyz = df[[c for c in df.columns if c.endswith("_m")]].to_numpy()
    assert not np.isinf(xyz).any()
    assert np.isnan(xyz).sum() == 3
    assert np.isnan(df.loc[2, "camera:C1_x_m"]) and np.isnan(df.loc[6, "camera:C2_x_m"])
    assert "3 non-finite coordinate cells" in caplog.text
    assert "first at line 8, column camera:C1_X ('inf')" in caplog.text


# ----------------------------------------------------------------- video poses


def test_board_never_appears_stops_poses(tmp_path):
    """Row 'a video where the board never appears': poses stops with BoardNotSeenError naming
    the video and corners.parquet with the found count (0 of 90), and writes no poses table."""
    n = 90
    corners = pd.DataFrame({"frame": np.arange(n), "t_s": np.arange(n) / 30.0, "found": False,
                            "corner": -1, "u_px": np.nan, "v_px": np.nan})
    src = tmp_path / "corners.parquet"
    write_parquet(corners, src)
    cam = tmp_path / "camera.yaml"
    write_yaml({"K": K, "dist": [0.0] * 5}, cam)
    outs = {"poses": tmp_path / "poses_raw.parquet", "fig": tmp_path / "poses_raw.png"}
    video = _black_video(tmp_path / "data" / "black" / "video.mp4")
    params = {"bag": None, "board": {"squares_x": 6, "squares_y": 5, "square_m": 0.09},
              "pnp": {"ransac_reproj_px": 3.0, "ransac_iterations": 200, "ransac_confidence": 0.999, "seed": 0},
              "video": str(video)}
    with pytest.raises(BoardNotSeenError, match=r"data/black/video\.mp4: 0 of 90 video frames have a board "
                       r"pose; the board was found in 0 of them \(.*corners\.parquet\)"):
        run_stage("poses", tmp_path, {"corners": src, "camera": cam, "video": video}, outs, params)
    assert not any(p.exists() for p in outs.values())


def _black_video(path, size=(640, 480), n=3):
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, size)
    for _ in range(n):
        writer.write(np.zeros((size[1], size[0], 3), np.uint8))
    writer.release()
    return path


def test_video_of_another_size_than_the_calibration_stops_poses(tmp_path):
    """Row 'a video at another size than the calibration stills': poses stops with
    ImageSizeError naming the video, its size, camera.yaml and the stills' size; no output."""
    from cvsflow.exceptions import ImageSizeError

    corners = pd.DataFrame({"frame": np.arange(3), "t_s": np.arange(3) / 30.0, "found": False,
                            "corner": -1, "u_px": np.nan, "v_px": np.nan})
    src = tmp_path / "corners.parquet"
    write_parquet(corners, src)
    cam = tmp_path / "camera.yaml"
    write_yaml({"K": K, "dist": [0.0] * 5, "width": 480, "height": 640}, cam)
    video = _black_video(tmp_path / "video.mp4")
    outs = {"poses": tmp_path / "poses_raw.parquet", "fig": tmp_path / "poses_raw.png"}
    params = {"bag": None, "board": {"squares_x": 6, "squares_y": 5, "square_m": 0.09},
              "pnp": {"ransac_reproj_px": 3.0, "ransac_iterations": 200, "ransac_confidence": 0.999, "seed": 0},
              "video": str(video)}
    with pytest.raises(ImageSizeError, match=r"video\.mp4: frames are 640x480 px, but .*camera\.yaml was "
                       r"calibrated on 480x640 px stills; the stills are the frames turned a quarter"):
        run_stage("poses", tmp_path, {"corners": src, "camera": cam, "video": video}, outs, params)
    assert not any(p.exists() for p in outs.values())


def test_few_poses_warn():
    """A few valid frames: a warning with the counts, no error."""
    p = poses_table()
    p["valid"] = np.arange(len(p)) < 9
    w = check_poses_found(p, None, "video.mp4")
    assert len(w) == 1 and "only 9 of 90 video frames (10.0 %)" in w[0]


# ----------------------------------------------------------------- sync


def _bodies(n=300):
    return fit_bodies(markers_table(n=n), SPECS)


def test_static_board_stops_angular_speed_sync():
    """Row 'static board with angular-speed sync': StaticBoardError saying how little the board
    moved, that angular-speed sync needs motion, and what to do; gesture is not refused here."""
    bodies = _bodies()
    static = poses_table(moving=False)
    with pytest.raises(StaticBoardError, match=r"poses_raw\.parquet: the board moved by at most 0\.\d+ deg/s "
                       r".*angular-speed sync needs motion.*use sync\.method: gesture, or move the board"):
        check_sync_inputs(static, bodies, "angular_speed")
    assert check_sync_inputs(static, bodies, "gesture") == []
    assert check_sync_inputs(poses_table(moving=True), bodies, "angular_speed") == []


def test_black_video_names_frames_in_sync():
    """Row 'black video': SyncError 'the board was found in 0 of 90 video frames: nothing to
    synchronise', naming poses_raw.parquet."""
    with pytest.raises(SyncError, match=r"results/s/poses_raw\.parquet: the board was found in 0 of 90 "
                       r"video frames.*nothing to synchronise"):
        check_sync_inputs(poses_table(valid=False), _bodies(), "angular_speed", "results/s/poses_raw.parquet")


def test_overlap_share_warning_and_floor():
    """A take stopping 1 s before a 20 s video ends: share 0.95, a warning under 0.98 and none
    under 0.8; a take covering 10 % of it: OverlapError naming both spans."""
    t = np.arange(600) / 30.0
    share, w = check_overlap(t, 2.0, (0.0, 21.0 - 1e-9 + 0.0), min_share=0.8)
    assert abs(share - 19 / 20) < 0.01 and w == []
    _, w = check_overlap(t, 2.0, (0.0, 21.0), min_share=0.98)
    assert len(w) == 1 and "95.2 %" in w[0]
    with pytest.raises(OverlapError, match=r"only 6\d of 600 video frames \(1\d\.\d %\).*take spans 0\.000\.\.4\.000 s"):
        check_overlap(t, 2.0, (0.0, 4.0))


# ----------------------------------------------------------------- pairs


def _pairs(d_vic=1.6, d_cvs=1.5, n=50):
    z = np.zeros(n)
    return pd.DataFrame({"cmbm_x_m": z, "cmbm_y_m": z, "cmbm_z_m": z + d_vic,
                         "cvs_x_m": z, "cvs_y_m": z, "cvs_z_m": z + d_cvs})


def test_camera_to_board_km_is_an_error():
    """Row 'units' at pairs: a Vicon camera-to-board distance of 2.4 km against PnP's 2.4 m is a
    ScaleMismatchError naming both medians; a 10 cm difference (the mountings) passes."""
    assert check_pair_distances(_pairs(1.6, 1.5), "pairs") == []
    with pytest.raises(ScaleMismatchError, match=r"2400 m from the Vicon.*2\.4 m from PnP.*ratio 1000.*"
                       r"says m where the values are mm"):
        check_pair_distances(_pairs(2400.0, 2.4), "pairs")
    with pytest.raises(NoUsableRowsError, match="pairs: 0 pairs"):
        check_pair_distances(_pairs(n=0), "pairs")


# ----------------------------------------------------------------- optimisers, analyse


def test_se3_result_out_of_range():
    """Row 'se3 writes fx_px: 1.85e-10': a ResultRangeError naming the key, value and range;
    mountings of kilometres and an offset beyond max_offset_s likewise; a sane result passes."""
    good = {"fx_px": 701.5, "fy_px": 697.3, "dt_offset_s": 2.37,
            "T_Cm_C": np.eye(4).tolist(), "T_Bm_B": np.eye(4).tolist()}
    assert check_se3_result(good, K, 30.0) == []
    with pytest.raises(ResultRangeError, match=r"se3 fx_px = 1\.85e-10 px is outside its physical range.*"
                       r"175\.\.2800 px"):
        check_se3_result({**good, "fx_px": 1.85e-10}, K, 30.0)
    T = np.eye(4)
    T[0, 3] = 2400.0
    with pytest.raises(ResultRangeError, match=r"T_Bm_B translation 2400 m"):
        check_se3_result({**good, "T_Bm_B": T.tolist()}, K, 30.0)
    with pytest.raises(ResultRangeError, match=r"dt_offset_s = 45 s is outside \+-30 s"):
        check_se3_result({**good, "dt_offset_s": 45.0}, K, 30.0)
    with pytest.raises(ResultRangeError, match="fy_px = nan"):
        check_se3_result({**good, "fy_px": float("nan")}, K, 30.0)


def test_seed_result_out_of_range():
    """seed: a negative or non-finite focal length, or a non-finite P_bar, is an error."""
    assert check_seed_result({"fx_px": 650.0, "fy_px": 640.0, "P_bar": [0.1] * 6}, K) == []
    with pytest.raises(ResultRangeError, match="seed fx_px = -5"):
        check_seed_result({"fx_px": -5.0, "fy_px": 640.0}, K)
    with pytest.raises(ResultRangeError, match="P_bar has non-finite"):
        check_seed_result({"fx_px": 650.0, "fy_px": 640.0, "P_bar": [np.inf] * 6}, K)


def test_zero_rows_is_an_error():
    """A stage never succeeds on an empty table: the error names the table."""
    with pytest.raises(NoUsableRowsError, match=r"se3/calib/errors\.parquet: 0 error rows"):
        check_rows(pd.DataFrame({"a": []}), "se3/calib/errors.parquet", "error rows")
    assert check_rows(pd.DataFrame({"a": [1]}), "x") == []


def test_diverged_seed_is_reported_not_stopped():
    """A seed run that drifted to its grid bound is flagged diverged by the optimiser and goes
    on as such (the report says so); without the flag the same focal length stops the stage,
    and a non-finite one stops it either way."""
    K = [[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]]
    flagged = {"fx_px": 285.7, "fy_px": 4985.8, "P_bar": [0.1] * 6, "diverged": True}
    assert check_seed_result(flagged, K) == []
    with pytest.raises(ResultRangeError, match="fy_px = 4985.8 px"):
        check_seed_result({**flagged, "diverged": False}, K)
    with pytest.raises(ResultRangeError, match="fx_px"):
        check_seed_result({**flagged, "fx_px": float("nan")}, K)
