"""Vicon readers: the real Nexus CSV / C3D pair, round trips through the writer, bad input."""


import numpy as np
import pandas as pd
import pytest

from cvsflow.exceptions import InputError
from cvsflow.io.mocap.formats import detect_format, read_markers
from cvsflow.io.mocap.markers import marker_columns, marker_names, select_markers
from cvsflow.io.mocap.vicon import read_c3d, read_nexus_csv, write_nexus_csv
from tests.helpers.real_data import REAL_DATA

REAL = REAL_DATA / "vicon"
REAL_CSV = REAL / "markers.csv"


@pytest.fixture(scope="module")
def real_root():
    """shared/data/real (conftest.REAL_DATA); else skip."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real data not found at {REAL_DATA}")
    return REAL_DATA
REAL_C3D = REAL / "markers_analogs.c3d"

# SOURCES.md section 3: gap frames per marker and the longest contiguous run
REAL_GAPS = {
    "boite:gauche_ext": (6, 6),
    "boite:gauche_int": (5, 5),
    "boite:droite_int": (10, 4),
    "boite:droite_ext": (3, 2),
    "Daphnee:STERr": (32, 16),
    "Daphnee:STERl": (31, 27),
    "Daphnee:CLAV_post": (2, 2),
    "Daphnee:CLAVl": (1, 1),
    "Daphnee:SCAP_CP": (92, 71),
    "Daphnee:LARMl": (49, 45),
    "Daphnee:STYLu": (29, 14),
    "Daphnee:LASTC": (23, 4),
    "Daphnee:MEDH": (22, 20),
}


def _longest_run(mask):
    best = run = 0
    for m in mask:
        run = run + 1 if m else 0
        best = max(best, run)
    return best


def _gap_table(df):
    out = {}
    for name in marker_names(df):
        gap = np.isnan(df[marker_columns(name)].to_numpy()).any(axis=1)
        if gap.any():
            out[name] = (int(gap.sum()), _longest_run(gap))
    return out


def _synthetic_table(rng, n_frames=50, names=("camera:C1", "board:B1"), rate_hz=300.0):
    frame = np.arange(n_frames)
    data = {"frame": frame, "t_s": frame / rate_hz}
    for name in names:
        for c in marker_columns(name):
            data[c] = rng.uniform(-2.0, 2.0, n_frames)
    df = pd.DataFrame(data)
    df.attrs["rate_hz"] = rate_hz
    df.attrs["markers"] = list(names)
    return df


@pytest.fixture(scope="module")
def real_csv():
    if not REAL_CSV.exists():
        pytest.skip(f"real Vicon export not available at {REAL_CSV}")
    return read_markers(REAL_CSV)


@pytest.fixture(scope="module")
def real_c3d():
    if not REAL_C3D.exists():
        pytest.skip(f"real Vicon export not available at {REAL_C3D}")
    return read_markers(REAL_C3D)


def test_real_csv_header_and_shape(real_csv):
    """The real Nexus CSV gives 100 Hz, 580 frames (0..579), 51 markers in file order, metres."""
    assert real_csv.attrs["rate_hz"] == 100.0
    assert len(real_csv) == 580
    np.testing.assert_array_equal(real_csv["frame"], np.arange(580))
    np.testing.assert_allclose(real_csv["t_s"], np.arange(580) / 100.0, atol=1e-12)
    names = marker_names(real_csv)
    assert len(names) == 51
    assert names[:2] == ["boite:gauche_ext", "boite:gauche_int"]
    assert sum(n.startswith("boite:") for n in names) == 8
    assert sum(n.startswith("Daphnee:") for n in names) == 43
    # first data row of boite:gauche_ext, SOURCES.md: 44.1628, -276.862, 675.697 mm
    first = real_csv.loc[0, marker_columns("boite:gauche_ext")].to_numpy(float)
    np.testing.assert_allclose(first, [0.0441628, -0.276862, 0.675697], atol=1e-9)


def test_real_csv_gaps_counted_exactly(real_csv):
    """915 empty cells = 305 (marker, frame) gaps on 13 markers, 219 frames with a gap, per-marker
    gap counts and longest runs exactly as SOURCES.md section 3 states."""
    xyz = real_csv[[c for n in marker_names(real_csv) for c in marker_columns(n)]].to_numpy()
    assert int(np.isnan(xyz).sum()) == 915
    gap = np.isnan(xyz.reshape(580, 51, 3))
    # X, Y and Z are empty together
    assert np.array_equal(gap.any(axis=2), gap.all(axis=2))
    assert int(gap.any(axis=2).sum()) == 305
    assert int(gap.any(axis=2).any(axis=1).sum()) == 219
    assert _gap_table(real_csv) == REAL_GAPS


def test_real_c3d_equals_csv(real_csv, real_c3d):
    """The C3D of the same trial gives the same markers, frames, gaps and values within 0.01 mm."""
    assert real_c3d.attrs["rate_hz"] == 100.0
    assert marker_names(real_c3d) == marker_names(real_csv)
    assert list(real_c3d.columns) == list(real_csv.columns)
    np.testing.assert_array_equal(real_c3d["frame"], real_csv["frame"])
    a = real_csv.to_numpy(float)
    b = real_c3d.to_numpy(float)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    assert np.nanmax(np.abs(a - b)) < 1e-5  # 0.01 mm
    assert _gap_table(real_c3d) == REAL_GAPS


@pytest.mark.parametrize("newline", ["\r\n", "\n"])
def test_writer_reader_round_trip(tmp_path, newline):
    """write_nexus_csv then read_nexus_csv returns the same table (0.1 um rounding), gaps as
    NaN, with CRLF or LF line ends."""
    rng = np.random.default_rng(1)
    df = _synthetic_table(rng)
    df.iloc[5:9, 2:5] = np.nan
    path = tmp_path / "v.csv"
    write_nexus_csv(df, path, rate_hz=300.0)
    if newline == "\n":
        path.write_bytes(path.read_bytes().replace(b"\r\n", b"\n"))
    back = read_nexus_csv(path)
    assert back.attrs["rate_hz"] == 300.0
    assert marker_names(back) == ["camera:C1", "board:B1"]
    np.testing.assert_array_equal(np.isnan(back.to_numpy()), np.isnan(df.to_numpy()))
    np.testing.assert_allclose(back.to_numpy(), df.to_numpy(), atol=1e-7, equal_nan=True)


@pytest.mark.parametrize("unit,scale", [("mm", 1e-3), ("cm", 1e-2), ("m", 1.0)])
def test_units_row_scales_to_metres(tmp_path, unit, scale):
    """The units row (mm, cm, m) scales values to metres."""
    text = (
        "Trajectories\r\n100\r\n,,S:A,,\r\nFrame,Sub Frame,X,Y,Z\r\n"
        f",,{unit},{unit},{unit}\r\n1,0,1.5,2,3\r\n2,0,4,5,6\r\n"
    )
    path = tmp_path / "u.csv"
    path.write_text(text, newline="")
    df = read_nexus_csv(path)
    expected_m = np.array([[1.5, 2.0, 3.0], [4.0, 5.0, 6.0]]) * scale
    np.testing.assert_allclose(df[marker_columns("S:A")].to_numpy(), expected_m, rtol=1e-12)


def test_other_blocks_are_skipped(tmp_path):
    """A Devices block before and a blank line plus a Model Outputs block after are ignored."""
    text = (
        "Devices\n1000\n,,Force\nFrame,Sub Frame,Fx\n,,N\n1,0,3\n\n"
        "Trajectories\n100\n,,S:A,,\nFrame,Sub Frame,X,Y,Z\n,,mm,mm,mm\n1,0,1,2,3\n2,0,,,\n\n"
        "Model Outputs\n100\n"
    )
    path = tmp_path / "blocks.csv"
    path.write_text(text)
    df = read_nexus_csv(path)
    assert len(df) == 2
    assert np.isnan(df.loc[1, "S:A_x_m"])


def test_parses_a_90s_300hz_file(tmp_path):
    """A 90 s, 300 Hz, 8-marker export (27000 rows) parses completely and exactly."""
    rng = np.random.default_rng(2)
    names = [f"camera:C{i}" for i in range(1, 5)] + [f"board:B{i}" for i in range(1, 5)]
    df = _synthetic_table(rng, n_frames=27000, names=names)
    path = tmp_path / "long.csv"
    write_nexus_csv(df, path, rate_hz=300.0)
    back = read_markers(path, names=names[::-1])
    assert len(back) == 27000
    assert marker_names(back) == names[::-1]
    np.testing.assert_allclose(back["board:B4_z_m"], df["board:B4_z_m"], atol=1e-7)


# --------------------------------------------------------------------------- bad input


def _write_small(tmp_path, rng, name="v.csv"):
    df = _synthetic_table(rng, n_frames=20)
    path = tmp_path / name
    write_nexus_csv(df, path, rate_hz=300.0)
    return path


def test_file_cut_short_names_last_line(tmp_path, caplog):
    """A file cut in its last row (Nexus states no frame count, so this is the only sign): the
    row is left out and one WARNING names the file and that 1-based line."""
    path = _write_small(tmp_path, np.random.default_rng(3))
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 30])  # cut inside the last row (frame 20, line 25)
    with caplog.at_level("WARNING"):
        df = read_markers(path)
    assert len(df) == 19 and df.attrs["n_frames_stated"] is None
    (msg,) = df.attrs["warnings"]
    assert "v.csv: the file was cut short: its last row (line 25) was cut mid-row" in msg
    assert msg in caplog.text


def test_real_c3d_cut_to_half_warns_with_both_counts(tmp_path, caplog):
    """The real C3D cut to half its bytes: ezc3d reads 288 frames and rewrites its header to
    them; the reader takes the count from the file's own header block (580) and warns with
    both, and the marker table carries them for mocap_import's summary."""
    if not REAL_C3D.exists():
        pytest.skip(f"real Vicon export not available at {REAL_C3D}")
    raw = REAL_C3D.read_bytes()
    path = tmp_path / "cut.c3d"
    path.write_bytes(raw[: len(raw) // 2])
    with caplog.at_level("WARNING"):
        df = read_markers(path)
    assert len(df) == 288 and df.attrs["n_frames_stated"] == 580 and df.attrs["format"] == "c3d"
    (msg,) = df.attrs["warnings"]
    assert f"{path}: the file was cut short: 288 of the 580 frames its header states" in msg
    assert msg in caplog.text
    whole = read_markers(REAL_C3D)
    assert whole.attrs["n_frames_stated"] == 580 and whole.attrs["warnings"] == []


def test_truncated_row_inside_file(tmp_path):
    """A row with fewer cells than the header in the middle of the file names its line."""
    path = _write_small(tmp_path, np.random.default_rng(4))
    lines = path.read_text().splitlines()
    lines[9] = ",".join(lines[9].split(",")[:4])  # line 10 = frame 5
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"v\.csv, line 10: 4 cells, expected 8"):
        read_markers(path)


def test_missing_marker_lists_what_the_file_has(tmp_path):
    """A configured marker absent from the file raises InputError naming it and the file's markers."""
    path = _write_small(tmp_path, np.random.default_rng(5))
    with pytest.raises(InputError, match=r"camera:C9.*not in the file.*camera:C1, board:B1"):
        read_markers(path, names=["camera:C1", "camera:C9"])


def test_non_numeric_cell_names_line_and_column(tmp_path):
    """A non-numeric cell raises InputError naming the line, the marker column and the cell."""
    path = _write_small(tmp_path, np.random.default_rng(6))
    lines = path.read_text().splitlines()
    cells = lines[11].split(",")
    cells[6] = "abc"  # board:B1 Y
    lines[11] = ",".join(cells)
    path.write_text("\r\n".join(lines) + "\r\n")
    with pytest.raises(InputError, match=r"line 12, column board:B1_Y: non-numeric cell 'abc'"):
        read_markers(path)


def test_nan_text_is_a_gap_and_bad_cell_after_it_is_still_named(tmp_path):
    """'NaN' written by other tools reads as a gap; a bad cell later in the file is still found."""
    path = _write_small(tmp_path, np.random.default_rng(6))
    lines = path.read_text().splitlines()
    cells = lines[8].split(",")
    cells[2:5] = ["NaN", "nan", "NULL"]  # camera:C1 at line 9 = frame 4
    lines[8] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    df = read_markers(path)
    assert df.loc[3, marker_columns("camera:C1")].isna().all()
    assert np.isfinite(df.loc[4, marker_columns("camera:C1")].to_numpy(float)).all()
    cells = lines[14].split(",")
    cells[5] = "1.2.3"  # board:B1 X at line 15
    lines[14] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 15, column board:B1_X: non-numeric cell '1\.2\.3'"):
        read_markers(path)


def test_no_rate_line(tmp_path):
    """A Trajectories block without its rate line raises InputError naming line 2."""
    path = _write_small(tmp_path, np.random.default_rng(7))
    lines = path.read_text().splitlines()
    del lines[1]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 2: no rate line"):
        read_markers(path)


def test_marker_absent_for_whole_take(tmp_path):
    """A configured marker that is empty in every frame raises InputError naming it."""
    rng = np.random.default_rng(8)
    df = _synthetic_table(rng, n_frames=20)
    df[marker_columns("board:B1")] = np.nan
    path = tmp_path / "v.csv"
    write_nexus_csv(df, path, rate_hz=300.0)
    with pytest.raises(InputError, match=r"marker 'board:B1' is absent for the whole take"):
        read_markers(path, names=["camera:C1", "board:B1"])


def test_real_marker_with_one_coordinate_column_empty_is_named(tmp_path):
    """The real Nexus export with one marker's Z column emptied for the whole take: before,
    the marker was a gap in every frame and silently rebuilt from the layout (the body moved
    3.7 mm); now an InputError names the file, the marker and the empty column."""
    if not REAL_CSV.exists():
        pytest.skip(f"real Vicon export not available at {REAL_CSV}")
    lines = REAL_CSV.read_text().splitlines()
    j = lines[2].split(",").index("boite:droite_int") + 2  # its Z cell
    for i in range(5, len(lines)):
        cells = lines[i].split(",")
        cells[j] = ""
        lines[i] = ",".join(cells)
    path = tmp_path / "markers.csv"
    path.write_text("\r\n".join(lines) + "\r\n")
    names = [f"boite:{n}" for n in ("gauche_ext", "gauche_int", "droite_int", "droite_ext")]
    with pytest.raises(InputError, match=rf"{path}: marker 'boite:droite_int': its Z column is "
                       r"empty in all 580 frames while X/Y hold values"):
        read_markers(path, names=names)
    assert len(read_markers(path, names=names[:2])) == 580  # a marker not used is no concern


def test_non_consecutive_frames(tmp_path):
    """A jump in the Frame column raises InputError naming the line."""
    path = _write_small(tmp_path, np.random.default_rng(9))
    lines = path.read_text().splitlines()
    cells = lines[7].split(",")
    cells[0] = "40"
    lines[7] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"line 8: frame 40 follows frame 2"):
        read_markers(path)


def test_unknown_content_and_missing_file(tmp_path):
    """Unrecognised content or a missing file raises InputError naming the path and what was expected."""
    path = tmp_path / "x.txt"
    path.write_text("hello,world\n1,2\n")
    with pytest.raises(InputError, match=r"x\.txt, line 1: unrecognised content 'hello,world'.*expected a motion-capture export"):
        read_markers(path)
    with pytest.raises(InputError, match=r"nope\.csv: file not found"):
        read_markers(tmp_path / "nope.csv")
    with pytest.raises(InputError, match=r"nope\.c3d: file not found"):
        read_c3d(tmp_path / "nope.c3d")


def test_content_not_suffix_chooses_the_reader(tmp_path):
    """A Nexus CSV saved as .txt is read; the format named in the config must agree with the content."""
    path = _write_small(tmp_path, np.random.default_rng(20))
    renamed = tmp_path / "take.txt"
    renamed.write_bytes(path.read_bytes())
    assert detect_format(renamed) == "vicon_csv"
    np.testing.assert_array_equal(read_markers(renamed).to_numpy(), read_markers(path).to_numpy())
    with pytest.raises(InputError, match=r"config says OptiTrack Motive CSV \(motive_csv\) but the file is a Vicon Nexus"):
        read_markers(path, format="motive_csv")
    with pytest.raises(InputError, match=r"unknown format 'optitrak'"):
        read_markers(path, format="optitrak")


def test_real_nexus_devices_export_is_named(real_root):
    """The real Devices-only Nexus export: 'no Trajectories block', with the block and its rate."""
    path = real_root / "mocap" / "vicon-nexus-devices" / "analogs.csv"
    if not path.exists():
        pytest.skip(f"{path} not available")
    with pytest.raises(InputError, match=r"analogs\.csv: a Vicon Nexus CSV with only the block\(s\) Devices "
                                         r"\(Devices at 2000 Hz.*no Trajectories block.*Expected the Trajectories"):
        read_markers(path)


def test_real_tum_file_is_named(real_root):
    """A real TUM trajectory given as a motion-capture export: named a TUM pose list."""
    path = real_root / "tum-fr2-desk" / "fr2_desk_groundtruth.txt"
    if not path.exists():
        pytest.skip(f"{path} not available")
    with pytest.raises(InputError, match=r"a TUM trajectory .*the poses of one body, not a motion-capture export"):
        read_markers(path)


def test_other_wrong_files(tmp_path):
    """Empty files, TRC files, binary non-C3D files and 6D-only exports are named as what they are."""
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(InputError, match="empty.csv: empty file"):
        read_markers(empty)
    trc = tmp_path / "walk.trc"
    trc.write_text("PathFileType\t4\t(X/Y/Z)\twalk.trc\n")
    with pytest.raises(InputError, match="a TRC marker file"):
        read_markers(trc)
    blob = tmp_path / "x.bin"
    blob.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(InputError, match="binary file that is not C3D"):
        read_markers(blob)
    six = tmp_path / "take_6d.tsv"
    six.write_text("NO_OF_FRAMES\t1\nNO_OF_BODIES\t1\nFREQUENCY\t100\nDATA_INCLUDED\t6D\nBODY_NAMES\tcam\n"
                   "Frame\tTime\tcam X\tcam Y\tcam Z\tRoll\tPitch\tYaw\tResidual\t"
                   + "\t".join(f"Rot[{k}]" for k in range(9)) + "\n"
                   "1\t0\t1\t2\t3\t0\t0\t0\t0.5\t1\t0\t0\t0\t1\t0\t0\t0\t1\n")
    with pytest.raises(InputError, match=r"without marker positions \(its rigid bodies: 'cam'\).*bodies_from: system"):
        read_markers(six)


def test_select_markers_keeps_order_and_attrs():
    """select_markers returns the named markers in the asked order with rate and names in attrs."""
    df = _synthetic_table(np.random.default_rng(10))
    out = select_markers(df, ["board:B1", "camera:C1"])
    assert marker_names(out) == ["board:B1", "camera:C1"]
    assert out.attrs["rate_hz"] == 300.0
    np.testing.assert_array_equal(out["board:B1_x_m"], df["board:B1_x_m"])
