"""Qualisys QTM TSV reader: the three real exports (SOURCES.md section 6), both layouts, bad input."""


import numpy as np
import pandas as pd
import pytest

from cvsflow.exceptions import InputError
from cvsflow.io.mocap.formats import detect_format, read_mocap
from cvsflow.io.mocap.markers import marker_columns, marker_names
from cvsflow.io.mocap.qualisys import read_qtm_tsv, write_qtm_tsv
from cvsflow.mocap.bodies import body_poses, fit_bodies
from tests.helpers.real_data import REAL_DATA, need_real_file

QTM = REAL_DATA / "mocap" / "qualisys-qtm"
SWING_3D = QTM / "imusim_swing_3D" / "swing_3D.tsv"
SWING_6D = QTM / "imusim_swing_6D" / "swing_6D.tsv"
STAND_6D = QTM / "imusim_stand_6D" / "stand_6D.tsv"
NAMES_3D = ["Hip", "Thigh", "Knee Hinge", "Shin", "Ankle"] + [
    f"{b} IMU - {k}" for b in ("Upper Leg", "Foot", "Lower Leg") for k in (1, 2, 3)
]
BODIES = ["Upper Leg IMU", "Foot IMU", "Lower Leg IMU"]


_need = need_real_file


@pytest.fixture(scope="module")
def swing3d():
    return read_qtm_tsv(_need(SWING_3D))


@pytest.fixture(scope="module")
def swing6d():
    return read_qtm_tsv(_need(SWING_6D))


def test_real_3d_header_names_and_values(swing3d):
    """swing_3D.tsv: 256 Hz, 904 frames, 14 markers in file order, old layout, mm -> m."""
    assert detect_format(SWING_3D) == "qtm_tsv"
    assert swing3d.rate_hz == 256.0
    assert swing3d.meta["layout"] == "old"
    m = swing3d.markers
    assert len(m) == 904
    assert marker_names(m) == NAMES_3D
    np.testing.assert_array_equal(m["frame"], np.arange(904))
    np.testing.assert_allclose(m["t_s"].iloc[-1], 903 / 256.0)
    # line 11 of the file, first two markers
    np.testing.assert_allclose(m.loc[0, marker_columns("Hip")].to_numpy(float), [-0.853445, 0.066329, -1.027941])
    np.testing.assert_allclose(m.loc[0, marker_columns("Thigh")].to_numpy(float), [-0.720727, 0.083979, -0.862729])


def test_real_3d_gaps(swing3d):
    """The only gap: 'Foot IMU - 1' is the literal NaN in the last 7 frames (897..903)."""
    assert {k: v for k, v in swing3d.meta["n_gap_samples"].items() if v} == {"Foot IMU - 1": 7}
    m = swing3d.markers
    gap = m[marker_columns("Foot IMU - 1")].isna().all(axis=1).to_numpy()
    assert np.flatnonzero(gap).tolist() == list(range(897, 904))
    assert int(m.iloc[:, 2:].isna().sum().sum()) == 21


def test_real_6d_header_bodies_and_values(swing6d):
    """swing_6D.tsv: 3 bodies, 904 frames at 256 Hz; line 12 read back (X Y Z mm, residual, Rot)."""
    assert swing6d.meta["layout"] == "old"
    assert swing6d.body_names == BODIES
    assert swing6d.rate_hz == 256.0
    assert marker_names(swing6d.markers) == []
    b = swing6d.bodies
    assert len(b) == 3 * 904
    row = b[(b["body"] == "Upper Leg IMU") & (b["frame"] == 0)].iloc[0]
    np.testing.assert_allclose(row[["x_m", "y_m", "z_m"]].to_numpy(float), [-0.76116144, 0.01851688, -0.67777112])
    assert row["fit_rms_m"] == pytest.approx(0.44674e-3)
    _, T, _ = body_poses(b, "Upper Leg IMU")
    rot = np.array([-0.18262, 0.02734, -0.98280, -0.97698, -0.11712, 0.17828, -0.11023, 0.99274, 0.04810])
    np.testing.assert_allclose(T[0, :3, :3], rot.reshape(3, 3).T, atol=2e-5)
    # the file's Yaw Pitch Roll (deg) are R = Rz(yaw) Ry(pitch) Rx(roll), our Euler convention
    np.testing.assert_allclose(np.degrees(row[["roll_rad", "pitch_rad", "yaw_rad"]].to_numpy(float)),
                               [74.90202, 79.35878, 171.48624], atol=3e-3)


def test_real_6d_not_tracked_is_a_gap(swing6d):
    """'Foot IMU' written as zeros with residual -1 in the last 7 frames: invalid there, nowhere else."""
    assert swing6d.meta["n_gap_samples"] == {"Upper Leg IMU": 0, "Foot IMU": 7, "Lower Leg IMU": 0}
    b = swing6d.bodies
    lost = b[~b["valid"]]
    assert set(lost["body"]) == {"Foot IMU"}
    assert lost["frame"].tolist() == list(range(897, 904))
    assert lost[["x_m", "qw", "fit_rms_m"]].isna().all().all()


def test_real_6d_rotation_is_column_order(swing3d, swing6d):
    """Each body's three markers (from the 3D export of the same capture) stay put in the body frame.

    With Rot[0..8] read in column order the local coordinates vary by under 1 mm over the swing;
    read in row order (the transpose) they would move by centimetres.
    """
    for body in BODIES:
        _, T, valid = body_poses(swing6d.bodies, body)
        for k in (1, 2, 3):
            p = swing3d.markers[marker_columns(f"{body} - {k}")].to_numpy(float)
            ok = valid & np.isfinite(p).all(axis=1)
            d = p[ok] - T[ok, :3, 3]
            local = np.einsum("nji,nj->ni", T[ok, :3, :3], d)
            wrong = np.einsum("nij,nj->ni", T[ok, :3, :3], d)
            assert np.std(local, axis=0).max() < 1e-3
            if k > 1:  # marker 1 is the body's origin: no lever arm to tell the two apart
                assert np.std(wrong, axis=0).max() > 5e-3


def test_real_stand_6d():
    """stand_6D.tsv: 513 frames, 3 bodies, no gaps, near static (each body moves < 5 cm)."""
    e = read_mocap(_need(STAND_6D))
    assert e.format == "qtm_tsv"
    assert e.body_names == ["Upper Leg IMU", "Foot IMU", "Lower Leg IMU"]
    assert e.meta["n_gap_samples"] == dict.fromkeys(e.body_names, 0)
    for body in e.body_names:
        sub = e.bodies[e.bodies["body"] == body]
        assert len(sub) == 513
        assert sub["valid"].all()
        assert np.ptp(sub[["x_m", "y_m", "z_m"]].to_numpy(float), axis=0).max() < 0.05


def _table(rng, n=30, names=("cam:C1", "cam:C2", "cam:C3"), rate=100.0):
    data = {"frame": np.arange(n), "t_s": np.arange(n) / rate}
    for name in names:
        for c in marker_columns(name):
            data[c] = rng.uniform(-2, 2, n)
    df = pd.DataFrame(data)
    df.attrs.update(rate_hz=rate, markers=list(names))
    return df


@pytest.mark.parametrize("layout", ["current", "old"])
def test_3d_round_trip(tmp_path, layout):
    """write_qtm_tsv -> read_qtm_tsv: markers and gaps (empty or 0,0,0) come back, in both layouts."""
    rng = np.random.default_rng(11)
    m = _table(rng)
    m.iloc[4:9, 5:8] = np.nan
    path = tmp_path / "take.tsv"
    write_qtm_tsv(path, markers=m, layout=layout)
    back = read_mocap(path, format="qtm_tsv")
    assert back.meta["layout"] == layout
    assert back.meta["n_gap_samples"] == {"cam:C1": 0, "cam:C2": 5, "cam:C3": 0}
    np.testing.assert_allclose(back.markers.to_numpy(float), m.to_numpy(float), atol=1e-8, equal_nan=True)


@pytest.mark.parametrize("layout", ["current", "old"])
def test_6d_round_trip(tmp_path, layout):
    """Two bodies, one lost in some frames: poses, residuals and the gap come back, in both layouts."""
    rng = np.random.default_rng(12)
    m = _table(rng, names=("a1", "a2", "a3", "b1", "b2", "b3"))
    layout_m = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], float)
    bodies = fit_bodies(m, {"a": {"names": ["a1", "a2", "a3"], "layout_m": layout_m},
                            "b": {"names": ["b1", "b2", "b3"], "layout_m": layout_m}})
    lost = (bodies["body"] == "b") & bodies["frame"].between(10, 13)
    bodies.loc[lost, "valid"] = False
    bodies.attrs["rate_hz"] = 100.0
    path = tmp_path / "take_6d.tsv"
    write_qtm_tsv(path, bodies=bodies, layout=layout)
    back = read_qtm_tsv(path)
    assert back.body_names == ["a", "b"]
    assert back.meta["n_gap_samples"] == {"a": 0, "b": 4}
    for body in ("a", "b"):
        _, T0, v0 = body_poses(bodies, body)
        _, T1, v1 = body_poses(back.bodies, body)
        np.testing.assert_array_equal(v0, v1)
        np.testing.assert_allclose(T1[v1], T0[v0], atol=2e-5)


def test_bad_cell_names_file_line_and_column(tmp_path):
    """A non-numeric cell: the message names the file, the 1-based line and the marker coordinate."""
    rng = np.random.default_rng(13)
    path = tmp_path / "take.tsv"
    write_qtm_tsv(path, markers=_table(rng), layout="current")
    lines = path.read_text().splitlines()
    cells = lines[20].split("\t")
    cells[6] = "x12"
    lines[20] = "\t".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"take\.tsv, line 21, column cam:C2 Y: non-numeric cell 'x12'"):
        read_qtm_tsv(path)


def test_cut_short_and_count_mismatch(tmp_path, caplog):
    """Fewer rows than NO_OF_FRAMES (cut at a row boundary or mid-row) are read as far as they go
    with a WARNING naming both counts, as the Motive and C3D readers do; MARKER_NAMES that
    disagree with NO_OF_MARKERS are an error naming both."""
    rng = np.random.default_rng(14)
    path = tmp_path / "take.tsv"
    write_qtm_tsv(path, markers=_table(rng), layout="old")
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:-3]) + "\n")
    with caplog.at_level("WARNING"):
        export = read_qtm_tsv(path)
    assert len(export.markers) == 27 and export.markers.attrs["n_frames_stated"] == 30
    (msg,) = export.markers.attrs["warnings"]
    assert "take.tsv: the file was cut short: 27 of the 30 frames its header states (NO_OF_FRAMES)" in msg
    assert msg in caplog.text
    text = "\n".join(lines[:-3]) + "\n"
    path.write_text(text[: len(text) - 12])  # and the last row cut mid-row
    export = read_qtm_tsv(path)
    assert len(export.markers) == 26
    assert f"last row (line {len(lines) - 3}) was cut mid-row" in export.markers.attrs["warnings"][0]
    path.write_text("\n".join(lines).replace("NO_OF_MARKERS\t3", "NO_OF_MARKERS\t4") + "\n")
    with pytest.raises(InputError, match="3 MARKER_NAMES, NO_OF_MARKERS says 4"):
        read_qtm_tsv(path)


@pytest.mark.parametrize("key", ["NO_OF_FRAMES", "FREQUENCY"])
@pytest.mark.parametrize("rel", [SWING_3D, STAND_6D], ids=["3D", "6D"])
def test_missing_header_line_is_named(tmp_path, rel, key):
    """A real QTM export without its NO_OF_FRAMES or FREQUENCY line: still recognised as a QTM
    TSV (whatever its first line), and the error names the missing header line."""
    lines = _need(rel).read_text().splitlines()
    path = tmp_path / "take.tsv"
    path.write_text("\n".join(ln for ln in lines if not ln.startswith(key + "\t")) + "\n")
    assert detect_format(path) == "qtm_tsv"
    with pytest.raises(InputError, match=rf"take\.tsv, lines 1-\d+: no {key} header line"):
        read_mocap(path)


@pytest.mark.parametrize("rel, kind", [(SWING_3D, "3D"), (STAND_6D, "6D")], ids=["3D", "6D"])
def test_missing_data_included_is_read_from_the_names_line(tmp_path, caplog, rel, kind):
    """Without DATA_INCLUDED a real export is read as its names line says (MARKER_NAMES: 3D,
    BODY_NAMES: 6D; a 6D file was refused as '3D export without MARKER_NAMES'), with a WARNING
    naming the missing line; with neither names line the error names DATA_INCLUDED."""
    lines = _need(rel).read_text().splitlines()
    path = tmp_path / "take.tsv"
    path.write_text("\n".join(ln for ln in lines if not ln.startswith("DATA_INCLUDED\t")) + "\n")
    with caplog.at_level("WARNING"):
        export = read_mocap(path)
    assert export.format == "qtm_tsv" and (export.bodies is not None) == (kind == "6D")
    assert any(f"no DATA_INCLUDED header line; read as {kind}" in w for w in export.markers.attrs["warnings"])
    names = "MARKER_NAMES" if kind == "3D" else "BODY_NAMES"
    path.write_text("\n".join(ln for ln in lines if not ln.startswith(("DATA_INCLUDED\t", names))) + "\n")
    with pytest.raises(InputError, match=r"no DATA_INCLUDED header line \(expected 'DATA_INCLUDED<tab>3D'"):
        read_mocap(path)


def test_2d_export_is_refused(tmp_path):
    """A QTM 2D export is named as such, with what to export instead."""
    path = tmp_path / "take_2d.tsv"
    path.write_text("NO_OF_FRAMES\t2\nFREQUENCY\t100\nDATA_INCLUDED\t2D\n1\t2\n3\t4\n")
    with pytest.raises(InputError, match="DATA_INCLUDED '2D'"):
        read_mocap(path)
