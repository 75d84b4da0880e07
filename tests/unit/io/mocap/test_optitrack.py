"""OptiTrack Motive CSV reader: the two real exports (SOURCES.md section 6), round trips, bad input."""


import numpy as np
import pandas as pd
import pytest

from cvsflow.exceptions import InputError
from cvsflow.io.files import read_yaml
from cvsflow.io.mocap.formats import detect_format, read_markers, read_mocap
from cvsflow.io.mocap.markers import marker_columns, marker_names
from cvsflow.io.mocap.optitrack import read_motive_csv, write_motive_csv
from cvsflow.mocap.bodies import body_poses, fit_bodies
from tests.helpers.real_data import REAL_DATA, need_real_file
from tests.helpers.stages import run_stage

MOTIVE = REAL_DATA / "mocap" / "optitrack-motive"
RIGID = MOTIVE / "grvc_rigidbody_test" / "test.csv"
UNLAB = MOTIVE / "ha5dzs_unlabeled_markers_360hz" / "test_markers_enabled.csv"
_need = need_real_file


@pytest.fixture(scope="module")
def rigid():
    return read_motive_csv(_need(RIGID))


@pytest.fixture(scope="module")
def unlabeled():
    return read_motive_csv(_need(UNLAB))


def test_real_rigid_body_export_header(rigid):
    """test.csv: 120 Hz, 499 frames 0..498, 4 measured markers, one rigid body, metres."""
    assert detect_format(RIGID) == "motive_csv"
    assert rigid.format == "motive_csv"
    assert rigid.rate_hz == 120.0
    assert rigid.meta["Format Version"] == "1.23"
    assert rigid.meta["Length Units"] == "Meters"
    m = rigid.markers
    assert len(m) == 499
    np.testing.assert_array_equal(m["frame"], np.arange(499))
    np.testing.assert_allclose(m["t_s"].iloc[-1], 498 / 120.0)
    assert marker_names(m) == [f"ernesto_body:Marker{k}" for k in range(1, 5)]
    assert rigid.body_names == ["ernesto_body"]
    # the Time column (6 decimals) agrees with frame / rate
    assert rigid.meta["time_column_max_dev_s"] < 1e-6


def test_real_rigid_body_values_against_the_file(rigid):
    """Line 8 of test.csv, read back: quaternion X,Y,Z,W, position, Mean Marker Error, markers."""
    b = rigid.bodies
    row = b[(b["body"] == "ernesto_body") & (b["frame"] == 0)].iloc[0]
    q = row[["qx", "qy", "qz", "qw"]].to_numpy(float)
    q_file = np.array([-0.008570, -0.649345, -0.001615, -0.760444])
    # q and -q are one rotation; the table keeps qw >= 0
    np.testing.assert_allclose(q * np.sign(q @ q_file), q_file, atol=2e-6)
    np.testing.assert_allclose(row[["x_m", "y_m", "z_m"]].to_numpy(float), [3.717927, 0.045963, -2.209530])
    assert row["fit_rms_m"] == pytest.approx(0.000727)
    assert row["n_markers"] == 4
    m0 = rigid.markers.loc[0, marker_columns("ernesto_body:Marker1")].to_numpy(float)
    np.testing.assert_allclose(m0, [3.833445, 0.032409, -2.237666])
    bm = rigid.meta["body_markers"]
    np.testing.assert_allclose(bm.loc[0, marker_columns("ernesto_body:Marker1")].to_numpy(float),
                               [3.833308, 0.032543, -2.237125])
    assert bm.loc[0, "ernesto_body:Marker1_quality"] == pytest.approx(0.856564)


def test_real_rigid_body_gap_in_frame_4(rigid):
    """Frame 4: body and rigid-body markers empty (24 cells) while the measured markers are there."""
    b = rigid.bodies
    assert b["valid"].sum() == 498
    assert b.loc[~b["valid"], "frame"].tolist() == [4]
    assert np.isfinite(rigid.markers.iloc[4, 2:].to_numpy(float)).all()
    assert int(rigid.markers.iloc[:, 2:].isna().sum().sum()) == 0
    bm = rigid.meta["body_markers"]
    xyz = bm[[c for n in marker_names(bm) for c in marker_columns(n)]]
    assert int(xyz.isna().sum().sum()) == 12
    assert xyz.iloc[4].isna().all()


def test_real_rigid_body_quaternion_order(rigid):
    """The solved markers sit still in the body frame (X,Y,Z,W read in that order): rigid to 0.01 mm.

    Read in another order the rotation would change the local coordinates by centimetres.
    """
    _, T, valid = body_poses(rigid.bodies, "ernesto_body")
    bm = rigid.meta["body_markers"]
    for name in marker_names(bm):
        p = bm[marker_columns(name)].to_numpy(float)[valid]
        local = np.einsum("nji,nj->ni", T[valid, :3, :3], p - T[valid, :3, 3])
        assert np.std(local, axis=0).max() < 1e-5
    # the measured markers agree with the solved ones to a few millimetres
    meas = rigid.markers[[c for n in marker_names(rigid.markers) for c in marker_columns(n)]].to_numpy()
    solved = bm[[c for n in marker_names(bm) for c in marker_columns(n)]].to_numpy()
    d = np.linalg.norm((meas - solved).reshape(len(meas), 4, 3), axis=2)
    assert np.nanmedian(d) < 0.003


def test_real_system_body_matches_marker_fit(rigid):
    """Fitting the measured markers (cvsflow's path) tracks the same motion as Motive's rigid body.

    The two body frames differ by a constant transform; it must be constant to about 1 mm / 0.5 deg.
    """
    names = marker_names(rigid.markers)
    bm = rigid.meta["body_markers"]
    _, T_sys, valid = body_poses(rigid.bodies, "ernesto_body")
    # layout = the solved markers in Motive's body frame at frame 0
    p0 = np.stack([bm.loc[0, marker_columns(n)].to_numpy(float) for n in names])
    layout = (p0 - T_sys[0, :3, 3]) @ T_sys[0, :3, :3]
    ours = fit_bodies(rigid.markers, {"body": {"names": names, "layout_m": layout}})
    _, T_fit, ok = body_poses(ours, "body")
    both = valid & ok
    D = np.linalg.inv(T_sys[both]) @ T_fit[both]
    assert np.abs(D[:, :3, 3]).max() < 0.002
    ang = np.degrees(np.arccos(np.clip((np.trace(D[:, :3, :3], axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert np.median(ang) < 0.5


def test_real_unlabeled_360hz_export(unlabeled):
    """test_markers_enabled.csv: 360 Hz, 1353 frames, 18 unlabeled markers, mm -> m, 6147 empty cells."""
    m = unlabeled.markers
    assert unlabeled.rate_hz == 360.0
    assert len(m) == 1353
    assert unlabeled.bodies is None
    assert unlabeled.meta["Length Units"] == "Millimeters"
    assert marker_names(m) == [f"Unlabeled {k}" for k in range(1036, 1054)]
    xyz = m[[c for n in marker_names(m) for c in marker_columns(n)]].to_numpy(float)
    assert int(np.isnan(xyz).sum()) == 6147
    assert int(np.isnan(xyz).any(axis=1).sum()) == 1352
    # a gap is a whole marker (three empty cells), never one coordinate
    per_marker = np.isnan(xyz.reshape(len(m), 18, 3))
    assert (per_marker.all(axis=2) == per_marker.any(axis=2)).all()
    np.testing.assert_allclose(xyz[0, :3], [2.659741943, -0.830793884, -2.862191650])
    # the Time column is rounded to 1 ms; t_s is frame / rate exactly
    np.testing.assert_allclose(np.diff(m["t_s"]), 1 / 360.0)
    assert 1e-4 < unlabeled.meta["time_column_max_dev_s"] < 1e-3


def _table(rng, n=40, names=("cam:C1", "cam:C2", "cam:C3"), rate=240.0):
    data = {"frame": np.arange(n), "t_s": np.arange(n) / rate}
    for name in names:
        for c in marker_columns(name):
            data[c] = rng.uniform(-2, 2, n)
    df = pd.DataFrame(data)
    df.attrs.update(rate_hz=rate, markers=list(names))
    return df


@pytest.mark.parametrize("units, decimals", [("Meters", 6), ("Millimeters", 9)])
def test_writer_round_trip_with_gaps_and_body(tmp_path, units, decimals):
    """write_motive_csv -> read_motive_csv gives the markers, gaps and rigid body back."""
    rng = np.random.default_rng(3)
    m = _table(rng)
    m.iloc[5:8, 2:5] = np.nan
    layout = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], float)
    bodies = fit_bodies(m, {"cam": {"names": marker_names(m), "layout_m": layout}})
    path = tmp_path / "take.csv"
    write_motive_csv(path, m, bodies, units=units)
    back = read_mocap(path)
    assert back.format == "motive_csv"
    assert back.rate_hz == 240.0
    np.testing.assert_allclose(back.markers.to_numpy(float), m.to_numpy(float), atol=1e-6, equal_nan=True)
    assert back.body_names == ["cam"]
    _, T0, v0 = body_poses(bodies, "cam")
    _, T1, v1 = body_poses(back.bodies, "cam")
    np.testing.assert_array_equal(v0, v1)
    np.testing.assert_allclose(T1[v1], T0[v0], atol=5e-6)


def test_bad_cell_names_file_line_and_column(tmp_path):
    """A non-numeric cell: the message names the file, the 1-based line and the column."""
    rng = np.random.default_rng(4)
    path = tmp_path / "take.csv"
    write_motive_csv(path, _table(rng))
    lines = path.read_text().splitlines()
    cells = lines[10].split(",")
    cells[3] = "abc"
    lines[10] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"take\.csv, line 11, column cam:C1 Position Y: non-numeric cell 'abc'"):
        read_motive_csv(path)


def test_file_cut_short(tmp_path, caplog):
    """A last row cut mid-row is left out and the take read as far as it goes: one WARNING (and
    the table's ``warnings``) names the line and both counts."""
    rng = np.random.default_rng(5)
    path = tmp_path / "take.csv"
    write_motive_csv(path, _table(rng))
    text = path.read_text()
    path.write_text(text[: len(text) - 30])
    with caplog.at_level("WARNING"):
        export = read_motive_csv(path)
    assert len(export.markers) == 39 and export.markers.attrs["n_frames_stated"] == 40
    msg = export.markers.attrs["warnings"]
    assert len(msg) == 1 and msg[0] in caplog.text
    assert "take.csv: the file was cut short: 39 of the 40 frames" in msg[0]
    assert "(Total Exported Frames)" in msg[0] and "last row (line 47) was cut mid-row" in msg[0]


def test_real_export_cut_at_a_row_boundary_warns_with_both_counts(tmp_path, caplog):
    """The real 360 Hz Motive export cut after 693 of the 1353 rows its header states (at a
    row boundary, so every row is whole): read as far as it goes, the WARNING names the file
    and both counts, and the marker table carries them for mocap_import's summary."""
    lines = _need(UNLAB).read_text().splitlines(keepends=True)
    path = tmp_path / "cut.csv"
    path.write_text("".join(lines[: 7 + 693]))
    with caplog.at_level("WARNING"):
        df = read_markers(path)
    assert len(df) == 693 and df.attrs["n_frames_stated"] == 1353
    assert df.attrs["format"] == "motive_csv"
    (msg,) = df.attrs["warnings"]
    assert f"{path}: the file was cut short: 693 of the 1353 frames its header states" in msg
    assert msg in caplog.text
    whole = read_markers(_need(UNLAB))
    assert whole.attrs["n_frames_stated"] == 1353 and whole.attrs.get("warnings", []) == []
    # the stage's summary (mocap_import.yaml, which the headline's warnings read) has both counts
    names = marker_names(whole)
    specs = {"camera": {"names": names[:4]}, "board": {"names": names[4:8]}}
    out = {"markers": tmp_path / "markers.parquet", "summary": tmp_path / "mocap_import.yaml"}
    run_stage("mocap_import", tmp_path, {"export": path}, out, {"markers": specs, "max_scale_ratio": 3.0})
    summary = read_yaml(out["summary"])
    assert summary["format"] == "motive_csv" and summary["rate_hz"] == 360.0
    assert summary["n_frames"] == 693 and summary["n_frames_stated"] == 1353
    assert summary["warnings"] == [msg]


@pytest.mark.parametrize(
    "old, new, match",
    [
        ("Length Units,Meters", "Length Units,Inches", "Length Units 'Inches'"),
        ("Format Version,1.23", "Format Version,1.1", "Format Version '1.1'"),
        ("Export Frame Rate,240.000000", "Export Frame Rate,abc", "Export Frame Rate 'abc'"),
        ("Rotation Type,Quaternion", "Rotation Type,XYZ", "Rotation Type 'XYZ'"),
        (",Name,", ",Nome,", "no ',Name,...' header row"),
    ],
)
def test_bad_header(tmp_path, old, new, match):
    """Unsupported units, versions, rates, Euler rotation types and missing rows are named."""
    rng = np.random.default_rng(6)
    m = _table(rng)
    layout = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], float)
    bodies = fit_bodies(m, {"cam": {"names": marker_names(m), "layout_m": layout}})
    path = tmp_path / "take.csv"
    write_motive_csv(path, m, bodies)
    path.write_text(path.read_text().replace(old, new))
    with pytest.raises(InputError, match=match):
        read_motive_csv(path)


def test_non_consecutive_frames(tmp_path):
    """A dropped frame row is named by its line."""
    rng = np.random.default_rng(7)
    path = tmp_path / "take.csv"
    write_motive_csv(path, _table(rng))
    lines = path.read_text().splitlines()
    del lines[12]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 13: frame 6 follows frame 4"):
        read_motive_csv(path)


def test_read_system_bodies_real_and_markers_only():
    """The real rigid body as the pipeline's camera; the markers-only export is refused with the fix."""
    from cvsflow.exceptions import MocapError
    from cvsflow.io.mocap.formats import read_system_bodies

    bodies = read_system_bodies(_need(RIGID), {"camera": "ernesto_body"})
    assert set(bodies["body"]) == {"camera"}
    assert bodies["valid"].sum() == 498
    assert bodies.attrs["rate_hz"] == 120.0
    with pytest.raises(MocapError, match=r"no rigid body 'board_rb' for the board \(the export has 1 bodies: 'ernesto_body'\)"):
        read_system_bodies(RIGID, {"camera": "ernesto_body", "board": "board_rb"})
    with pytest.raises(InputError, match=r"OptiTrack Motive CSV with 18 markers and no rigid-body poses.*bodies_from: markers"):
        read_system_bodies(_need(UNLAB), {"camera": "x"})


def test_mocap_settings_checks_the_bodies():
    """mocap_settings fills the defaults and names the body key a bodies_from choice needs."""
    from cvsflow.exceptions import ConfigError
    from cvsflow.io.mocap.formats import mocap_settings

    cfg = {"markers": {"camera": {"names": ["a", "b", "c"]}, "board": {"names": ["d", "e", "f"]}}}
    assert mocap_settings("s", cfg) == {"format": "auto", "bodies_from": "markers"}
    cfg["mocap"] = {"bodies_from": "system"}
    with pytest.raises(ConfigError, match=r"sessions.s.markers.camera: mocap.bodies_from is system, so system_body"):
        mocap_settings("s", cfg)
    cfg = {"mocap": {"bodies_from": "markers"}, "markers": {"camera": {"system_body": "x"}, "board": {"names": []}}}
    with pytest.raises(ConfigError, match=r"markers.camera: mocap.bodies_from is markers, so names is needed"):
        mocap_settings("s", cfg)


def test_rigid_body_markers_stand_in_for_missing_markers(tmp_path, caplog):
    """An export with only Rigid Body Marker columns gives those to read_markers, with a warning."""
    from cvsflow.io.mocap.formats import read_markers

    rng = np.random.default_rng(8)
    m = _table(rng)
    path = tmp_path / "take.csv"
    write_motive_csv(path, m)
    lines = path.read_text().splitlines()
    lines[2] = lines[2].replace(",Marker", ",Rigid Body Marker")
    path.write_text("\n".join(lines) + "\n")
    e = read_motive_csv(path)
    assert marker_names(e.markers) == []
    with caplog.at_level("WARNING"):
        got = read_markers(path, names=["cam:C2"])
    assert "Rigid Body Marker (solved) positions" in caplog.text
    np.testing.assert_allclose(got["cam:C2_x_m"], m["cam:C2_x_m"], atol=1e-6)


@pytest.mark.parametrize(
    "rel, fmt",
    [
        ("mocap/optitrack-motive/grvc_rigidbody_test/test.csv", "motive_csv"),
        ("mocap/optitrack-motive/ha5dzs_unlabeled_markers_360hz/test_markers_enabled.csv", "motive_csv"),
        ("mocap/qualisys-qtm/imusim_swing_3D/swing_3D.tsv", "qtm_tsv"),
        ("mocap/qualisys-qtm/imusim_swing_6D/swing_6D.tsv", "qtm_tsv"),
        ("mocap/qualisys-qtm/imusim_stand_6D/stand_6D.tsv", "qtm_tsv"),
        ("vicon/markers.csv", "vicon_csv"),
        ("vicon/markers_analogs.c3d", "c3d"),
    ],
)
def test_detect_format_on_every_real_export(rel, fmt):
    """Each real export is recognised from its content."""
    assert detect_format(need_real_file(rel)) == fmt
