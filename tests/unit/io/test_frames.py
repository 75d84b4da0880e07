"""Timestamped frame folders: the ASL and named-by-ns layouts, exact times, the corners stage
on a folder, and every bad-input class named."""

from __future__ import annotations

import functools
import logging

import cv2
import numpy as np
import pytest

from cvsflow.corners import extract_corners, extract_corners_parallel
from cvsflow.exceptions import FrameFolderError
from cvsflow.io.frames import add_frame_ns, frame_folder_info, frame_list, image_is_complete, iter_frames_gray
from tests.helpers.board_images import BOARD, drifting_board_frame
from tests.helpers.real_data import REAL_DATA

T0 = 1606153907495166540  # 19 digits: float64 seconds would not hold it to the ns


def _asl(tmp_path, n=6, suffix=".png", named=".png", header="#timestamp [ns],filename"):
    """An ASL camera folder of n drifting-board frames, 33_333_333 ns apart (+ 1 ns jitter)."""
    cam = tmp_path / "cam0"
    (cam / "data").mkdir(parents=True)
    t = [T0 + k * 33_333_333 + (k % 2) for k in range(n)]
    for k, tk in enumerate(t):
        cv2.imwrite(str(cam / "data" / f"{tk}{suffix}"), drifting_board_frame(k))
    (cam / "data.csv").write_text(header + "\n" + "".join(f"{tk},{tk}{named}\n" for tk in t))
    return cam, t


def test_asl_folder_exact_ns(tmp_path):
    """ASL cam0: frames in time order with their ns exactly; the dataset folder finds cam0."""
    cam, t = _asl(tmp_path)
    f = frame_list(cam)
    assert f["t_ns"].tolist() == t and f["t_ns"].dtype == np.int64 and f.attrs["layout"] == "asl"
    assert frame_list(tmp_path)["t_ns"].tolist() == t
    info = frame_folder_info(cam)
    assert (info["width"], info["height"], info["n_frames"]) == (640, 480, 6)
    assert info["fps"] == pytest.approx(30.0, rel=1e-6)


def test_csv_naming_png_where_files_are_jpg(tmp_path, caplog):
    """yac's csv names .png, the files are .jpg: read with a warning that says so."""
    cam, t = _asl(tmp_path, suffix=".jpg", named=".png", header="timestamp [ns],filename")
    with caplog.at_level(logging.WARNING):
        f = frame_list(cam)
    assert [p.suffix for p in f["path"]] == [".jpg"] * 6
    assert "6 of 6 rows name a file" in caplog.text


def test_named_by_ns_sorted_by_value(tmp_path):
    """Images named by integer ns, sorted by their value (not as text)."""
    d = tmp_path / "frames"
    d.mkdir()
    for t in (9_999_999_999_999_999, 10_000_000_000_000_001):  # 16 and 17 digits
        cv2.imwrite(str(d / f"{t}.png"), drifting_board_frame(0))
    assert frame_list(d)["t_ns"].tolist() == [9_999_999_999_999_999, 10_000_000_000_000_001]


def test_corners_stage_runs_on_a_folder(tmp_path):
    """The corners stage takes a folder as it takes a video: same rows as on the images, t_ns exact."""
    cam, t = _asl(tmp_path)
    c = extract_corners(iter_frames_gray(cam), BOARD)
    ref = extract_corners(((k, t[k] / 1e9, drifting_board_frame(k)) for k in range(6)), BOARD)
    np.testing.assert_array_equal(c[["frame", "corner"]].to_numpy(), ref[["frame", "corner"]].to_numpy())
    np.testing.assert_allclose(c[["u_px", "v_px"]].to_numpy(), ref[["u_px", "v_px"]].to_numpy(), atol=1e-9)
    c = add_frame_ns(c, frame_list(cam))
    assert list(c.columns[:3]) == ["frame", "t_s", "t_ns"]
    assert c.groupby("frame")["t_ns"].first().tolist() == t
    par = extract_corners_parallel(functools.partial(iter_frames_gray, cam), 6, BOARD, n_workers=2)
    np.testing.assert_allclose(par[["u_px", "v_px"]].to_numpy(), ref[["u_px", "v_px"]].to_numpy(), atol=1e-9)


def test_frames_without_timestamps(tmp_path):
    """Images named by frame number, no data.csv: named, with what was expected."""
    d = tmp_path / "stills"
    d.mkdir()
    for k in range(3):
        cv2.imwrite(str(d / f"{k:04d}.png"), drifting_board_frame(k))
    with pytest.raises(FrameFolderError, match=r"stills: 3 of 3 images carry no timestamp .*'0000\.png'"):
        frame_list(d)


def test_csv_row_naming_a_missing_file(tmp_path):
    """A data.csv row whose image is absent names the csv line and the file."""
    cam, t = _asl(tmp_path)
    (cam / "data" / f"{t[3]}.png").unlink()
    with pytest.raises(FrameFolderError, match=rf"data\.csv, line 5: names '{t[3]}\.png', which is not in"):
        frame_list(cam)


@pytest.mark.parametrize(("rows", "match"), [
    ("1.5,a.png\n", r"line 2: '1\.5,a\.png'; expected 'timestamp \[ns\],filename'"),
    (f"{T0 + 10},b.png\n{T0},a.png\n", r"line 3: time .* is earlier than line 2's"),
    (f"{T0},a.png\n{T0},b.png\n", r"line 2 and line 3 are both at"),
])  # fmt: skip
def test_csv_times_bad(tmp_path, rows, match):
    """A time that is not an integer, goes back or repeats: the lines named."""
    cam = tmp_path / "cam0"
    (cam / "data").mkdir(parents=True)
    for name in ("a.png", "b.png"):
        cv2.imwrite(str(cam / "data" / name), drifting_board_frame(0))
    (cam / "data.csv").write_text("#timestamp [ns],filename\n" + rows)
    with pytest.raises(FrameFolderError, match=match):
        frame_list(cam)


def test_csv_row_without_a_timestamp_is_named(tmp_path):
    """A data.csv row ',name.png' (its time lost): before, skipped as a blank row, the frame gone
    without a word; now the line is named."""
    cam, t = _asl(tmp_path)
    lines = (cam / "data.csv").read_text().splitlines()
    lines[3] = "," + lines[3].split(",", 1)[1]
    (cam / "data.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(FrameFolderError, match=rf"data\.csv, line 4: ',{t[2]}\.png'; expected 'timestamp"):
        frame_list(cam)


def test_csv_cut_short_is_read_as_far_as_it_goes_with_a_warning(tmp_path, caplog):
    """data.csv cut at a row boundary (images in data/ no row names) or inside its last row: the
    rows before are read, a WARNING names the line or the counts, as a cut motion-capture take."""
    cam, t = _asl(tmp_path)
    text = (cam / "data.csv").read_text()
    (cam / "data.csv").write_text(text[: len(text) - 12])  # inside the last row's file name
    with caplog.at_level(logging.WARNING):
        f = frame_list(cam)
    assert f["t_ns"].tolist() == t[:5]
    assert "data.csv, line 7: the file ends inside this row" in caplog.text
    assert "1 of the 6 images in" in caplog.text and "named by no row" in caplog.text
    caplog.clear()
    (cam / "data.csv").write_text("".join(text.splitlines(keepends=True)[:4]))  # header + 3 rows
    with caplog.at_level(logging.WARNING):
        assert len(frame_list(cam)) == 3
    assert f"3 of the 6 images in {cam / 'data'} are named by no row" in caplog.text


def test_a_frame_of_another_size_is_named(tmp_path):
    """A frame folder mixing sizes (another camera's or a resized image): before, every frame was
    used with the first one's intrinsics; now an error naming the frame and both sizes."""
    cam, t = _asl(tmp_path)
    cv2.imwrite(str(cam / "data" / f"{t[3]}.png"), cv2.resize(drifting_board_frame(3), (320, 240)))
    with pytest.raises(FrameFolderError, match=rf"{t[3]}\.png: frame 3 is 320x240 px, the folder's first "
                       r"frame 640x480 px"):
        list(iter_frames_gray(cam))
    with pytest.raises(FrameFolderError, match="frame 3 is 320x240 px"):
        list(iter_frames_gray(cam, start=2, stop=5))  # a chunk checks against the folder's first


def test_truncated_and_unreadable_frames_are_named(tmp_path, caplog):
    """A JPEG cut short (imread would decode it grey) and a garbage file: named, yielded as None."""
    cam, t = _asl(tmp_path, suffix=".jpg", named=".jpg")
    full = (cam / "data" / f"{t[1]}.jpg").read_bytes()
    (cam / "data" / f"{t[1]}.jpg").write_bytes(full[: len(full) // 2])
    (cam / "data" / f"{t[2]}.jpg").write_bytes(b"not an image")
    assert not image_is_complete(cam / "data" / f"{t[1]}.jpg")
    assert cv2.imread(str(cam / "data" / f"{t[1]}.jpg")) is not None  # why the end marker is checked
    with caplog.at_level(logging.WARNING):
        got = [(k, g is None) for k, _, g in iter_frames_gray(cam, undecodable=True)]
    assert got == [(0, False), (1, True), (2, True), (3, False), (4, False), (5, False)]
    assert f"2 frames cannot be decoded or are cut short (truncated?): {t[1]}.jpg, {t[2]}.jpg" in caplog.text
    assert [k for k, _, _ in iter_frames_gray(cam)] == [0, 3, 4, 5]


def test_no_frame_decodes(tmp_path):
    """A folder of which no frame decodes is an error naming it."""
    d = tmp_path / "f"
    d.mkdir()
    (d / f"{T0}.png").write_bytes(b"junk")
    with pytest.raises(FrameFolderError, match="not one of 1 frames decodes"):
        list(iter_frames_gray(d))


def test_not_a_folder_and_two_cameras(tmp_path):
    """A missing folder, and a dataset with cam0 and cam1: named, with what to give."""
    with pytest.raises(FrameFolderError, match="nope: not found"):
        frame_list(tmp_path / "nope")
    for cam in ("cam0", "cam1"):
        (tmp_path / "ds" / cam / "data").mkdir(parents=True)
        (tmp_path / "ds" / cam / "data.csv").write_text("#timestamp [ns],filename\n")
    with pytest.raises(FrameFolderError, match=r"2 ASL camera folders \(cam0, cam1\)"):
        frame_list(tmp_path / "ds")


def test_yac_frames():
    """yac's cam0: 30 frames, csv naming .png for .jpg files, exact ns; the data/ folder alone too."""
    cam = REAL_DATA / "yac-mocap-aprilgrid" / "cam0"
    if not (cam / "data.csv").is_file():
        pytest.skip(f"real data not available ({cam})")
    f = frame_list(cam)
    assert len(f) == 30 and f["t_ns"].iloc[0] == 1606153907495166540
    assert frame_list(cam / "data")["t_ns"].tolist() == f["t_ns"].tolist()
