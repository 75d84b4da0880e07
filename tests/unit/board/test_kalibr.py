"""Kalibr target files: aprilgrid and checkerboard (and yac's and hand_eye_calibration's spellings),
the checkerboard's frame against cvsflow's chessboard, and every bad input named."""

import numpy as np
import pytest

from cvsflow.board import R_B_KALIBR_CHECKERBOARD, AprilGrid, KalibrCheckerboard, board_object_points
from cvsflow.exceptions import ConfigError, InputError
from cvsflow.io.targets import read_kalibr_target, read_target_board
from tests.helpers.real_data import need_real_file


def write(tmp_path, text, name="target.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_kalibr_aprilgrid(tmp_path):
    """Kalibr's aprilgrid keys give the grid and its board block."""
    path = write(tmp_path, "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 7\ntagSize: 0.088\ntagSpacing: 0.3\n")
    assert read_kalibr_target(path) == AprilGrid(6, 7, 0.088, 0.3)
    assert read_target_board(path) == {"type": "aprilgrid", "tag_cols": 6, "tag_rows": 7,
                                       "tag_size_m": 0.088, "tag_spacing": 0.3}


def test_kalibr_checkerboard_is_a_chessboard_of_squares(tmp_path):
    """Kalibr counts inner corners, cvsflow squares: targetCols 6 x targetRows 7 = 7 x 8 squares."""
    path = write(tmp_path, "target_type: 'checkerboard'\ntargetCols: 6\ntargetRows: 7\n"
                           "rowSpacingMeters: 0.06\ncolSpacingMeters: 0.06\n")
    assert read_kalibr_target(path) == KalibrCheckerboard(6, 7, 0.06, 0.06)
    assert read_target_board(path) == {"squares_x": 7, "squares_y": 8, "square_m": 0.06}


def test_kalibr_checkerboard_frame_is_cvsflow_frame_turned():
    """Kalibr's point r * cols + c at (r rowSpacing, c colSpacing, 0) is cvsflow's corner of the
    same index mapped by R_B_K (x and y swapped, z turned): a proper rotation."""
    target = KalibrCheckerboard(6, 7, 0.06, 0.06)
    r, c = np.divmod(np.arange(6 * 7), 6)
    p_K = np.stack([r * 0.06, c * 0.06, np.zeros(42)], axis=1)
    p_B = board_object_points(target.config())
    np.testing.assert_allclose(p_K @ R_B_KALIBR_CHECKERBOARD.T, p_B, atol=1e-15)
    assert np.linalg.det(R_B_KALIBR_CHECKERBOARD) == pytest.approx(1.0)


def test_rectangular_squares_have_no_cvsflow_board(tmp_path):
    path = write(tmp_path, "target_type: checkerboard\ntargetCols: 6\ntargetRows: 7\n"
                           "rowSpacingMeters: 0.06\ncolSpacingMeters: 0.05\n")
    with pytest.raises(ConfigError, match="colSpacingMeters") as info:
        read_target_board(path)
    assert str(path) in str(info.value)


def test_yac_calib_target_block():
    """yac's calib_target block (tag_rows, tag_cols, tag_size, tag_spacing)."""
    path = need_real_file("yac-mocap-aprilgrid/calib_mocap-intel_d435i.yaml")
    assert read_kalibr_target(path) == AprilGrid(6, 6, 0.088, 0.3)


@pytest.mark.parametrize("name, size", [("target_55_165.yaml", 0.055), ("target_83_249.yaml", 0.083)])
def test_hand_eye_calibration_targets(name, size):
    """ETH hand_eye_calibration's targets give the gap in metres: ratio = gap / size."""
    grid = read_kalibr_target(need_real_file(f"ethz-hand-eye/calib/{name}"))
    assert (grid.tag_cols, grid.tag_rows, grid.tag_size_m, grid.border_bits) == (6, 6, size, 2)
    assert grid.tag_spacing == pytest.approx(0.3)


@pytest.mark.parametrize("text, match", [
    ("target_type: circlegrid\ntargetCols: 6\ntargetRows: 7\nspacingMeters: 0.02\nasymmetricGrid: false\n",
     "target_type='circlegrid' is not supported"),
    ("tagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n", "missing key 'target_type'"),
    ("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSpacing: 0.3\n", "missing key 'tagSize'"),
    ("target_type: aprilgrid\ntagCols: six\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n", "tagCols='six'"),
    ("target_type: aprilgrid\ntagCols: 6\ntagRows: 0\ntagSize: 0.088\ntagSpacing: 0.3\n", "tagRows=0"),
    ("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0\ntagSpacing: 0.3\n", "tagSize=0"),
    ("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 2.64\n", "tagSpacing=2.64"),
    ("target_type: aprilgrid\ntagCols: 1\ntagRows: 2\ntagSize: 0.088\ntagSpacing: 0.3\n", "at least 3 tags"),
    ("target_type: checkerboard\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\n",
     "missing key 'colSpacingMeters'"),
    ("target_type: checkerboard\ntargetCols: 6.5\ntargetRows: 7\nrowSpacingMeters: 0.06\n"
     "colSpacingMeters: 0.06\n", "targetCols=6.5"),
    ("target_type: checkerboard\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: -1\n"
     "colSpacingMeters: 0.06\n", "rowSpacingMeters=-1"),
    ("calib_target:\n  target_type: aprilgrid\n  tag_rows: 6\n  tag_cols: 6\n  tag_size: 0.088\n",
     "calib_target: missing key 'tag_spacing'"),
    ("april_tag_number_horizontal: 6\napril_tag_number_vertical: 6\napril_tag_size_m: 0.05\n"
     "april_tag_gap_size_m: 0.08\n", "april_tag_gap_size_m=0.08 is larger"),
])
def test_errors_name_file_and_key(tmp_path, text, match):
    """Each bad target file is a ConfigError naming the file and the key."""
    path = write(tmp_path, text)
    with pytest.raises(ConfigError, match=match) as info:
        read_kalibr_target(path)
    assert str(path) in str(info.value)


def test_unreadable_or_malformed_file(tmp_path):
    """A missing file, broken YAML and a list are InputErrors naming the file."""
    for path, match in ((tmp_path / "missing.yaml", "file not found"),
                        (write(tmp_path, "target_type: [aprilgrid\n"), "not valid YAML"),
                        (write(tmp_path, "- 1\n- 2\n", "list.yaml"), "mapping")):
        with pytest.raises(InputError, match=match) as info:
            read_kalibr_target(path)
        assert str(path) in str(info.value)
